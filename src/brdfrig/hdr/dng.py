"""Write a real Bayer-mosaic DNG (Adobe Digital Negative) in pure Python with tifffile.

The file is an uncompressed 16-bit CFA TIFF with the DNG tags a raw decoder
needs (``DNGVersion``, ``CFAPattern``, ``BlackLevel``, ``WhiteLevel``,
``ColorMatrix1``, ``AsShotNeutral``) and the exposure tags (``ExposureTime``,
``FNumber``, ``ISOSpeedRatings``) in IFD0, where TIFF/EP (the base of DNG)
places them and where LibRaw (rawpy) and OpenImageIO read them.  The simulated
camera (``brdfrig.sim.camera``) and the tests write their raw files with it; it is
read back by :func:`brdfrig.hdr.raw.decode_raw`.

Hand-written with tifffile because pidng, the only Python DNG writer, is
source-only here and its 14-bit and compressed paths fail; a plain CFA TIFF
with these tags is read back by rawpy exactly.
"""

from __future__ import annotations

import os
from fractions import Fraction
from pathlib import Path

import numpy as np

from brdfrig._atomic import temp_path

__all__ = ["write_dng", "CFA_PATTERNS"]

#: Bayer layouts of the top-left 2x2 block, as DNG colour indices (0=R, 1=G, 2=B).
CFA_PATTERNS: dict[str, tuple[int, int, int, int]] = {
    "RGGB": (0, 1, 1, 2),
    "BGGR": (2, 1, 1, 0),
    "GRBG": (1, 0, 2, 1),
    "GBRG": (1, 2, 0, 1),
}

#: LibRaw (rawpy) refuses raw images narrower or shorter than 22 pixels.
_MIN_SIDE = 22

# TIFF field types (TIFF 6.0 section 2).
_BYTE, _ASCII, _SHORT, _LONG, _RATIONAL, _SRATIONAL = 1, 2, 3, 4, 5, 10

# sRGB (D65) -> XYZ inverse, i.e. XYZ -> camera for a camera whose native RGB is linear sRGB.
_XYZ_TO_SRGB = (
    (3.2404542, -1.5371385, -0.4985314),
    (-0.9692660, 1.8760108, 0.0415560),
    (0.0556434, -0.2040259, 1.0572252),
)


def _rationals(values, signed: bool) -> list[int]:
    """Flatten floats to TIFF (numerator, denominator) pairs with 1e-6 precision."""
    out: list[int] = []
    for v in np.asarray(values, dtype=float).ravel():
        f = Fraction(float(v)).limit_denominator(1_000_000)
        num, den = f.numerator, f.denominator
        limit = 2**31 - 1 if signed else 2**32 - 1
        while abs(num) > limit or den > limit:
            num, den = int(round(num / 2)), max(1, den // 2)
        out += [num, den]
    return out


def _checked(path, cfa, pattern, black_level, white_level, color_matrix, as_shot_neutral, exposure_time_s,
             f_number, iso) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ValueError naming the file for a bad argument of :func:`write_dng`; the black levels (4,), matrix, neutral."""
    if cfa.ndim != 2 or cfa.dtype != np.uint16:
        raise ValueError(f"write_dng {path}: cfa must be a 2-D uint16 array, got {cfa.dtype} {cfa.shape}")
    if cfa.shape[0] % 2 or cfa.shape[1] % 2 or min(cfa.shape) < _MIN_SIDE:
        raise ValueError(f"write_dng {path}: cfa height and width must be even and >= {_MIN_SIDE} "
                         f"(LibRaw rejects smaller images), got {cfa.shape}")
    if pattern not in CFA_PATTERNS:
        raise ValueError(f"write_dng {path}: pattern must be one of {sorted(CFA_PATTERNS)}, got {pattern!r}")
    black = np.broadcast_to(np.asarray(black_level, dtype=float), (4,)) if np.ndim(black_level) == 0 \
        else np.asarray(black_level, dtype=float)
    if black.shape != (4,) or np.any(black < 0) or np.any(black >= white_level):
        raise ValueError(f"write_dng {path}: black_level must be 1 or 4 values in [0, white_level), got {black_level}")
    if not 0 < int(white_level) <= 65535:
        raise ValueError(f"write_dng {path}: white_level must be in 1..65535, got {white_level}")
    cm = np.asarray(color_matrix, dtype=float)
    neutral = np.asarray(as_shot_neutral, dtype=float)
    if cm.shape != (3, 3) or not np.all(np.isfinite(cm)):
        raise ValueError(f"write_dng {path}: color_matrix must be a finite 3x3 matrix")
    if neutral.shape != (3,) or np.any(neutral <= 0):
        raise ValueError(f"write_dng {path}: as_shot_neutral must be 3 positive values, got {as_shot_neutral}")
    for name, value in (("exposure_time_s", exposure_time_s), ("f_number", f_number), ("iso", iso)):
        if not (np.isfinite(value) and value > 0):
            raise ValueError(f"write_dng {path}: {name} must be a positive number, got {value}")
    return black, cm, neutral


def _dng_tags(pattern, black, white_level, cm, neutral, exposure_time_s, f_number, iso, make, model) -> list:
    """The DNG and EXIF tags of IFD0, as tifffile ``extratags``."""
    ident = f"{make} {model}".encode("ascii", "replace").decode()
    tags = [
        (254, _LONG, 1, 0, True),  # NewSubfileType: main image
        (271, _ASCII, 0, make, True),  # Make
        (272, _ASCII, 0, model, True),  # Model
        (33421, _SHORT, 2, (2, 2), True),  # CFARepeatPatternDim
        (33422, _BYTE, 4, CFA_PATTERNS[pattern], True),  # CFAPattern
        (33434, _RATIONAL, 1, _rationals([exposure_time_s], False), True),  # ExposureTime
        (33437, _RATIONAL, 1, _rationals([f_number], False), True),  # FNumber
        (34855, _SHORT, 1, int(round(min(iso, 65535))), True),  # ISOSpeedRatings
        (50706, _BYTE, 4, (1, 4, 0, 0), True),  # DNGVersion
        (50707, _BYTE, 4, (1, 1, 0, 0), True),  # DNGBackwardVersion
        (50708, _ASCII, 0, ident, True),  # UniqueCameraModel
        (50710, _BYTE, 3, (0, 1, 2), True),  # CFAPlaneColor
        (50711, _SHORT, 1, 1, True),  # CFALayout: rectangular
        (50713, _SHORT, 2, (2, 2), True),  # BlackLevelRepeatDim
        (50714, _RATIONAL, 4, _rationals(black, False), True),  # BlackLevel
        (50717, _LONG, 1, int(white_level), True),  # WhiteLevel
        (50721, _SRATIONAL, 9, _rationals(cm, True), True),  # ColorMatrix1
        (50728, _RATIONAL, 3, _rationals(neutral, False), True),  # AsShotNeutral
        (50778, _SHORT, 1, 21, True),  # CalibrationIlluminant1: D65
    ]
    return tags


def write_dng(
    path: str | os.PathLike,
    cfa: np.ndarray,
    *,
    pattern: str = "RGGB",
    black_level: float | tuple[float, float, float, float] = 0,
    white_level: int = 65535,
    color_matrix=_XYZ_TO_SRGB,
    as_shot_neutral=(1.0, 1.0, 1.0),
    exposure_time_s: float,
    f_number: float,
    iso: float,
    make: str = "brdfrig",
    model: str = "simulated",
) -> Path:
    """Write a Bayer mosaic as an uncompressed DNG, atomically.

    Parameters
    ----------
    path : path-like
        Output ``.dng`` file; written to a temporary name in the same
        directory and renamed, so a failure never leaves a partial file.
    cfa : (H, W) uint16
        Raw sensor values (black level included, not yet subtracted), one
        colour per pixel laid out as ``pattern``; H and W even, >= 22.
    pattern : {"RGGB", "BGGR", "GRBG", "GBRG"}
        Colours of the top-left 2x2 block, row by row.
    black_level : float or 4 floats
        Sensor black level in raw units: one value, or one per position of
        the 2x2 block (row-major, same order as ``pattern``).
    white_level : int
        Raw value at which the sensor saturates (<= 65535).
    color_matrix : (3, 3) array_like
        DNG ``ColorMatrix1``: XYZ (D65) -> camera native RGB.  The default
        is that of a camera whose native RGB is linear sRGB.
    as_shot_neutral : 3 floats
        DNG ``AsShotNeutral``: camera RGB of a neutral (white) surface under
        the scene light, each in (0, 1].
    exposure_time_s, f_number, iso : float
        Exposure in seconds, aperture f-number and ISO sensitivity (> 0),
        written as EXIF ``ExposureTime``, ``FNumber`` and ``ISOSpeedRatings``.
    make, model : str
        Camera make and model (``Make``, ``Model``, ``UniqueCameraModel``).

    Returns
    -------
    Path
        The path written.
    """
    import tifffile

    path = Path(path)
    cfa = np.asarray(cfa)
    black, cm, neutral = _checked(path, cfa, pattern, black_level, white_level, color_matrix, as_shot_neutral,
                                  exposure_time_s, f_number, iso)
    tags = _dng_tags(pattern, black, white_level, cm, neutral, exposure_time_s, f_number, iso, make, model)
    with temp_path(path) as tmp:
        tifffile.imwrite(
            tmp,
            cfa,
            photometric=32803,  # CFA
            planarconfig="contig",
            compression=None,
            software="brdfrig",
            extratags=tags,
            metadata=None,
        )
    return path
