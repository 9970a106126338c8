"""Test helper (not a test file): Mitsuba 3 sphere renders in brdfrig's conventions, cached per session.

The scene itself (orthographic unit sphere seen from +z, MATH.md image axes,
MATH.md lat-long map resampled into Mitsuba's ``envmap``) is
:func:`brdfrig.evaluate.mitsuba_peer.render_sphere`; this module adds what the
tests share: the skip rules (no Mitsuba, no ``../shared``), the real probes at
64x32, a few named Mitsuba materials, renders cached by
``(material, probe, rows, size, spp, seed, pixel)``, and the sphere-pixel comparison.

Mitsuba's pixels are box-filtered over their area (``pixel="area"``, the
``scalar_rgb`` default) while brdfrig's renderers sample the normal at the pixel
centre; for smooth shading the difference is second order in the pixel size except
near the limb, so comparisons use the pixels at least :data:`LIMB_MARGIN_PX` inside
it (as the fitter does).  Highlights narrower than a pixel need ``pixel="centre"``
(``llvm_ad_rgb``; :data:`brdfrig.evaluate.mitsuba_peer.PIXEL_MODES`).
"""

from __future__ import annotations

import functools
import importlib.util
from pathlib import Path

import numpy as np
import pytest

from brdfrig.fit.metrics import relative_rms  # noqa: F401  (the tests' error measure, re-exported)

SHARED = Path(__file__).resolve().parents[2] / "shared"
PROBE_DIR = SHARED / "data" / "probes"
PROBE_ROWS = 32
"""Probes are box-downsampled to 64x32 for these tests (cheap ground truth and fits)."""
SIZE = 48
"""Sphere image side (px): radius 24."""
SPP = 2048
"""Samples per pixel of reference renders: per-pixel noise 0.34% under grace (multijitter; 48 or 64 px)."""
SPP_FIT = 512
"""Samples per pixel of images that are only fitted (the fit averages the ~1% pixel noise)."""
LIMB_MARGIN_PX = 2.0

MATERIALS: dict[str, dict] = {
    "diffuse": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.6, 0.45, 0.3]}},
    "roughplastic": {
        "type": "roughplastic",
        "distribution": "ggx",
        "alpha": 0.2,
        "diffuse_reflectance": {"type": "rgb", "value": [0.5, 0.2, 0.1]},
    },
    "gold": {"type": "roughconductor", "distribution": "ggx", "material": "Au", "alpha": 0.2},
}
"""Named Mitsuba BSDFs of the tests (issue 10's must-show materials)."""


def require_mitsuba(variant: str = "scalar_rgb"):
    """Skip the calling test when Mitsuba 3 is absent; otherwise select ``variant`` and return the module."""
    if importlib.util.find_spec("mitsuba") is None:
        pytest.skip("mitsuba is not installed (pip install -e '.[dev]')")
    from brdfrig.evaluate.mitsuba_peer import require_mitsuba as select

    return select(variant)


def require_mitsuba_and_probes() -> None:
    """Skip the calling test when Mitsuba 3 or ``../shared/data/probes`` is absent."""
    if importlib.util.find_spec("mitsuba") is None:
        pytest.skip("mitsuba is not installed (pip install -e '.[dev]')")
    if not PROBE_DIR.is_dir():
        pytest.skip("../shared/data/probes is absent")


def require_ad_variant() -> None:
    """Skip the calling test when Mitsuba's ``llvm_ad_rgb`` cannot run here (libLLVM >= 19 missing)."""
    require_mitsuba_and_probes()
    from brdfrig.evaluate.mitsuba_peer import ad_variant

    if ad_variant() is None:
        pytest.skip("no runnable Mitsuba AD variant (llvm_ad_rgb needs libLLVM >= 19: scripts/setup --dev)")


@functools.lru_cache(maxsize=8)
def probe_latlong(name: str, rows: int = PROBE_ROWS) -> np.ndarray:
    """The real probe ``name`` (grace, pisa, ennis) box-downsampled to ``2 rows x rows``, RGB float64."""
    from brdfrig.evaluate.probes import probe_environment

    return probe_environment(name, rows=rows, probe_dir=PROBE_DIR).latlong.image


@functools.lru_cache(maxsize=32)
def _render(bsdf_key: tuple, probe: str, rows: int, size: int, spp: int, seed: int, pixel: str) -> np.ndarray:
    from brdfrig.evaluate.mitsuba_peer import render_sphere

    variant = "scalar_rgb" if pixel == "area" else "llvm_ad_rgb"
    image = render_sphere(_unfreeze(bsdf_key), probe_latlong(probe, rows), size, spp=spp, seed=seed,
                          variant=variant, pixel=pixel)
    image.setflags(write=False)
    return image


def _freeze(value):
    if isinstance(value, dict):
        return tuple(sorted((k, _freeze(v)) for k, v in value.items()))
    if isinstance(value, list):
        return ("__list__",) + tuple(_freeze(v) for v in value)
    return value


def _unfreeze(value):
    if isinstance(value, tuple) and value and value[0] == "__list__":
        return [_unfreeze(v) for v in value[1:]]
    if isinstance(value, tuple):
        return {k: _unfreeze(v) for k, v in value}
    return value


def render(material: str | dict, probe: str, size: int = SIZE, spp: int = SPP, seed: int = 0, *,
           rows: int = PROBE_ROWS, pixel: str = "area") -> np.ndarray:
    """Mitsuba render ``(size, size, 3)`` of a named :data:`MATERIALS` entry (or a BSDF dict) under a probe, cached.

    ``pixel="area"`` (camera-like pixels) renders in ``scalar_rgb``; ``"centre"`` (brdfrig's
    pixel-centre convention) in ``llvm_ad_rgb`` (call :func:`require_ad_variant` first).
    ``rows``: the probe's lat-long height.
    """
    bsdf = MATERIALS[material] if isinstance(material, str) else material
    return _render(_freeze(bsdf), probe, int(rows), int(size), int(spp), int(seed), pixel)


@functools.lru_cache(maxsize=4)
def sphere_interior(size: int = SIZE):
    """Pixels at least :data:`LIMB_MARGIN_PX` inside the limb: ``(rows, cols, normals)``."""
    from brdfrig.hdr.sphere import sphere_pixels

    px = sphere_pixels((size, size), (size / 2, size / 2, size / 2), margin_px=LIMB_MARGIN_PX)
    keep = px.weights > 0
    return px.rows[keep], px.cols[keep], px.normals[keep]
