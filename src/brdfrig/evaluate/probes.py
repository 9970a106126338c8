"""The benchmarks' lighting: real lat-long probes, box-downsampled, as environments that keep their map."""

from __future__ import annotations

import functools
import re
from pathlib import Path

import numpy as np

from brdfrig.errors import InputError
from brdfrig.fit.rotation import axis_rotation
from brdfrig.fit.scene import Environment

__all__ = ["DEFAULT_PROBE_DIR", "TURNED", "box_downsample", "probe_environment", "probe_turn"]

DEFAULT_PROBE_DIR = Path(__file__).resolve().parents[4] / "shared" / "data" / "probes"
"""``../shared/data/probes`` beside the source tree (grace, pisa, ennis: 256x128 Radiance ``.hdr``)."""


def box_downsample(image, rows: int) -> np.ndarray:
    """Average blocks of a lat-long image down to ``rows x 2 rows`` (rows must divide the height)."""
    image = np.asarray(image)
    h, w = image.shape[:2]
    if rows < 1 or h % rows or w != 2 * h:
        raise InputError(f"lat-long map of {w}x{h} cannot be box-downsampled to {2 * rows}x{rows} "
                         f"(need width = 2 height, height divisible by {rows})")
    f = h // rows
    return image.reshape(rows, f, 2 * rows, f, -1).mean(axis=(1, 3))


@functools.lru_cache(maxsize=16)
def _probe(path: Path, rows: int) -> Environment:
    from brdfrig.hdr.exr import read_image
    from brdfrig.lighting import environment_from_latlong

    image = np.asarray(read_image(path), np.float64)[..., :3]
    return environment_from_latlong(box_downsample(image, rows), name=str(path))


#: A probe turned about an axis: ``NAME@AXISDEGREES`` (``grace@y180``: grace turned 180 degrees about +y).
TURNED = re.compile(r"^(?P<probe>.+)@(?P<axis>[xyz])(?P<degrees>[-+]?\d+(?:\.\d*)?)$")


def probe_environment(probe: str | Path, rows: int = 64, probe_dir: Path = DEFAULT_PROBE_DIR) -> Environment:
    """Environment of a real probe, box-downsampled to ``2 rows x rows`` (RGB, lat-long map kept), optionally turned.

    Parameters
    ----------
    probe : str or path
        A probe name (``"grace"`` -> ``probe_dir/grace.hdr``, else ``.exr``) or a file path, optionally followed by
        a turn :data:`TURNED` (``"grace@y180"``: the lighting turned by
        :func:`brdfrig.fit.rotation.axis_rotation` ``("y", 180)``).
    rows : int
        Lat-long rows after downsampling (must divide the map's height).
    probe_dir : path
        Where probe names are looked up.

    Raises
    ------
    InputError
        If no such probe file exists (the message names where it looked).
    """
    name, rotation = probe_turn(probe)
    if name != str(probe):
        return probe_environment(name, rows, probe_dir).rotated(rotation)
    path = Path(probe)
    if not path.suffix:
        candidates = [Path(probe_dir) / f"{probe}{ext}" for ext in (".hdr", ".exr")]
        path = next((p for p in candidates if p.is_file()), candidates[0])
    if not path.is_file():
        form = " (a turned probe is NAME@AXISDEGREES, e.g. grace@y180)" if "@" in str(probe) else ""
        raise InputError(f"light probe {probe!r} not found (looked for {path}){form}")
    return _probe(path.resolve(), int(rows))


def probe_turn(probe: str | Path) -> tuple[str, np.ndarray]:
    """``probe`` split into the probe it names and the (3, 3) rotation of its turn (:data:`TURNED`; the identity
    for a probe named without one): ``"grace@y180"`` -> ``("grace", axis_rotation("y", 180))``."""
    turn = TURNED.match(str(probe))
    if turn:
        return turn["probe"], axis_rotation(turn["axis"], float(turn["degrees"]))
    return str(probe), np.eye(3)
