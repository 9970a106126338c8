"""Shared fixtures: the real probes in ../shared (skipped cleanly when absent), a headless browser."""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import pytest

PROBE_DIR = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "probes"


def pytest_configure(config):
    """Fits recorded by commands under test go to a private catalogue, never the user's library.  Under
    pytest-xdist each of the ``n`` workers (and the commands it starts) gets ``cores / n`` numba threads, so the
    workers' parallel kernels do not oversubscribe the cores (set before any test module imports numba)."""
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "0"))
    if workers > 1 and "NUMBA_NUM_THREADS" not in os.environ:
        os.environ["NUMBA_NUM_THREADS"] = str(max(1, (os.cpu_count() or 1) // workers))
    config._brdfrig_library = Path(tempfile.mkdtemp(prefix="brdfrig-test-library-"))
    os.environ["BRDFRIG_LIBRARY"] = str(config._brdfrig_library / "library.sqlite")


def pytest_unconfigure(config):
    shutil.rmtree(getattr(config, "_brdfrig_library", ""), ignore_errors=True)


def probe_paths() -> list[Path]:
    """Real measured light probes (lat-long Radiance .hdr), or [] when ../shared is absent."""
    return sorted(PROBE_DIR.glob("*.hdr")) if PROBE_DIR.is_dir() else []


@pytest.fixture
def real_probes() -> list[Path]:
    paths = probe_paths()
    if not paths:
        pytest.skip("../shared/data/probes is absent")
    return paths


class ColourChart:
    """A simulated camera of known colour matrix shooting a chart of known linear Rec.709 reflectances under D65.

    The forward model is the tests' oracle: each patch's Rec.709 RGB -> XYZ by colour-science's BT.709 matrix ->
    camera native RGB by ``mc`` (XYZ -> camera), mosaicked (RGGB) into a DNG whose ColorMatrix1 and AsShotNeutral
    describe that camera.  Patches are 32 x 32 pixels side by side; at ``exposure`` 1 the white of the illuminant
    sits at 0.8 of full scale in the brightest camera channel.
    """

    mc = ((0.9, 0.3, -0.15), (-0.2, 1.1, 0.1), (0.05, -0.1, 0.8))
    patches = {"grey": (0.18, 0.18, 0.18), "orange": (0.6, 0.3, 0.1), "blue": (0.1, 0.35, 0.7),
               "white": (0.9, 0.9, 0.9)}

    def write(self, path, *, exposure: float = 1.0, exposure_time_s: float = 0.01):
        """Write the chart shot with relative ``exposure`` (values clipped at full scale) as a DNG; its path."""
        import colour
        import numpy as np

        from brdfrig.hdr.dng import CFA_PATTERNS, write_dng

        mc = np.array(self.mc)
        bt709 = colour.RGB_COLOURSPACES["ITU-R BT.709"]
        white_cam = mc @ (bt709.matrix_RGB_to_XYZ @ np.ones(3))
        scale = 0.8 / white_cam.max()
        tiles = [np.broadcast_to(mc @ (bt709.matrix_RGB_to_XYZ @ np.array(v)) * scale, (32, 32, 3))
                 for v in self.patches.values()]
        cam = np.clip(np.concatenate(tiles, axis=1) * exposure, 0, 1)
        cfa = np.empty(cam.shape[:2])
        for pos, c in enumerate(CFA_PATTERNS["RGGB"]):
            i, j = divmod(pos, 2)
            cfa[i::2, j::2] = cam[i::2, j::2, c] * 16383
        cm = mc / white_cam.max()  # DNG normalisation: the illuminant's white (Y = 1) maps to a maximum of 1
        return write_dng(path, np.round(cfa).astype(np.uint16), white_level=16383, color_matrix=cm,
                         as_shot_neutral=white_cam / white_cam.max(), exposure_time_s=exposure_time_s,
                         f_number=8, iso=100)

    @staticmethod
    def patch(img, k: int):
        """Mean colour of patch ``k`` (its central 16 x 16 pixels)."""
        return img[8:24, 32 * k + 8:32 * k + 24].reshape(-1, 3).mean(axis=0)


@pytest.fixture
def colour_chart() -> ColourChart:
    pytest.importorskip("colour")
    return ColourChart()


CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync", "--hide-scrollbars"]


@pytest.fixture
def browser(tmp_path):
    """``open(html_path, width, height) -> (screenshot (height, width, 3) floats in [0, 1], DOM text)``: the page
    as headless Chromium draws it (skipped when Chromium is not installed)."""
    if CHROMIUM is None:
        pytest.skip("chromium is not installed (scripts/setup --dev installs it)")

    def open_page(page: Path, width: int = 1200, height: int = 1400):
        import matplotlib.image

        shot, profile = tmp_path / "shot.png", tmp_path / "browser-profile"
        r = subprocess.run([CHROMIUM, *CHROMIUM_FLAGS, f"--user-data-dir={profile}", f"--window-size={width},{height}",
                            f"--screenshot={shot}", page.as_uri()], capture_output=True, text=True, timeout=120)
        assert shot.exists(), r.stderr[-2000:]
        dom = subprocess.run([CHROMIUM, *CHROMIUM_FLAGS, f"--user-data-dir={profile}", "--dump-dom", page.as_uri()],
                             capture_output=True, text=True, timeout=120).stdout
        return matplotlib.image.imread(shot)[..., :3], dom

    return open_page
