"""Camera RGB to a declared linear colour space (Rec.709 or ACEScg), from the raw file's own colour metadata.

A raw file carries ``ColorMatrix1`` (XYZ -> camera native RGB for its calibration
illuminant, D65 here) and ``AsShotNeutral`` (the camera RGB of a white surface
under the scene light).  Following the DNG specification (through colour-hdri's
implementation): the neutral gives the scene white's chromaticity, the colour
matrix is inverted into camera -> XYZ adapted to D50 (Bradford), and colour-science's
RGB colour spaces take XYZ (D50) to the target space, adapted to its white point
(Bradford again).  The result is one 3 x 3 matrix per file, applied per pixel to
linear camera RGB; the white balance is part of it (the neutral maps to R = G = B,
at the neutral's camera green level, so radiance keeps its scale).

``camera`` means no conversion: radiance stays in camera RGB (brdfrig's default
before a colour space is asked for).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from brdfrig.errors import InputError
from brdfrig.ranges import COLOUR_SPACES

__all__ = ["COLOUR_SPACES", "CameraColour", "read_camera_colour", "camera_to_space", "chromaticities", "convert",
           "raw_file_matrix", "convert_merged", "declared_colour_space"]

_COLOUR_NAMES = {"rec709": "ITU-R BT.709", "acescg": "ACEScg"}
D65_CCT = 6504.0
"""Correlated colour temperature (K) of the calibration illuminant brdfrig assumes for ``ColorMatrix1`` (D65)."""


@dataclass(frozen=True)
class CameraColour:
    """A camera's colour metadata: ``color_matrix`` (3, 3) XYZ (D65) -> camera RGB, ``as_shot_neutral`` (3,)."""

    color_matrix: np.ndarray
    as_shot_neutral: np.ndarray


def _rationals(value, count: int) -> np.ndarray:
    v = np.asarray(value, dtype=np.float64).reshape(-1)
    return v[0::2][:count] / v[1::2][:count] if v.size == 2 * count else v[:count]


def _dng_tags(path) -> tuple[np.ndarray, np.ndarray] | None:
    """(ColorMatrix1 (3, 3), AsShotNeutral (3,)) from a DNG's first IFD, or None when absent."""
    import tifffile

    with tifffile.TiffFile(path) as tif:
        tags = tif.pages[0].tags
        if 50721 not in tags or 50728 not in tags:
            return None
        return _rationals(tags[50721].value, 9).reshape(3, 3), _rationals(tags[50728].value, 3)


def read_camera_colour(path) -> CameraColour:
    """The colour metadata of a raw file: the DNG tags, or LibRaw's camera table for other raw formats.

    Raises
    ------
    InputError
        If the file carries no usable colour matrix or neutral.
    """
    import rawpy

    try:
        tags = _dng_tags(path) if str(path).lower().endswith(".dng") else None
        if tags is None:
            with rawpy.imread(str(path)) as raw:
                wb = np.asarray(raw.camera_whitebalance, dtype=np.float64)[:3]
                tags = np.asarray(raw.rgb_xyz_matrix, dtype=np.float64)[:3, :3], (1.0 / wb) / np.max(1.0 / wb)
    except (rawpy.LibRawError, OSError, ValueError, ZeroDivisionError) as exc:
        raise InputError(f"{path}: cannot read its colour metadata ({exc})") from None
    cm, neutral = tags
    if not np.all(np.isfinite(cm)) or abs(np.linalg.det(cm)) < 1e-12 or not np.all(np.isfinite(neutral) & (neutral > 0)):
        raise InputError(f"{path}: no usable colour matrix / as-shot neutral in the file; "
                         "keep the camera's colour space (--colour-space camera)")
    return CameraColour(cm, neutral)


def camera_to_space(colour: CameraColour, space: str) -> np.ndarray:
    """The (3, 3) matrix ``M`` with ``rgb_space = M @ rgb_camera`` (white-balanced to the scene's neutral)."""
    import colour as cs
    from colour_hdri.models.dng import camera_neutral_to_xy, matrix_camera_space_to_XYZ

    if space not in COLOUR_SPACES:
        raise InputError(f"unknown colour space {space!r} (expected one of {', '.join(COLOUR_SPACES)})")
    if space == "camera":
        return np.eye(3)
    cm, eye = np.asarray(colour.color_matrix, float), np.eye(3)
    neutral = np.asarray(colour.as_shot_neutral, float)
    xy = camera_neutral_to_xy(neutral, D65_CCT, D65_CCT, cm, cm, eye, eye, np.ones(3))
    # identity forward matrices: none in the file, so the colour matrix is inverted (DNG spec, chapter 6)
    cam_to_xyz = matrix_camera_space_to_XYZ(xy, D65_CCT, D65_CCT, cm, cm, eye, eye, np.ones(3), eye, eye)
    target = cs.RGB_COLOURSPACES[_COLOUR_NAMES[space]]
    d50 = cs.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D50"]
    xyz_to_rgb = cs.XYZ_to_RGB(np.eye(3), target, illuminant=d50, chromatic_adaptation_transform="Bradford")
    # xyz_to_rgb's rows are the images of the XYZ basis vectors: transpose into a column-vector matrix
    m = xyz_to_rgb.T @ cam_to_xyz
    return m * (neutral[1] / (m @ neutral)[1])  # a neutral keeps its camera green level


def chromaticities(space: str) -> tuple[float, ...] | None:
    """(red x, y, green x, y, blue x, y, white x, y) of a colour space, for EXR's ``chromaticities``; None for camera."""
    if space == "camera":
        return None
    import colour as cs

    c = cs.RGB_COLOURSPACES[_COLOUR_NAMES[space]]
    return tuple(float(v) for v in np.concatenate([np.ravel(c.primaries), np.ravel(c.whitepoint)]))


def convert(image: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """Apply a (3, 3) colour matrix to an (H, W, 3) linear image (float32 out)."""
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3:
        raise InputError(f"colour conversion needs an RGB image, got shape {img.shape}")
    return np.einsum("ij,hwj->hwi", np.asarray(matrix, np.float64), img, optimize=True).astype(np.float32)


def raw_file_matrix(path, space: str) -> np.ndarray | None:
    """The camera RGB -> ``space`` matrix of a raw file (None for ``"camera"``: no conversion).

    Raises
    ------
    InputError
        Unknown ``space``, a file that is not raw, or one without usable colour metadata.
    """
    from brdfrig.hdr.raw import is_raw

    if space not in COLOUR_SPACES:
        raise InputError(f"unknown colour space {space!r} (expected one of {', '.join(COLOUR_SPACES)})")
    if space == "camera":
        return None
    if not is_raw(path):
        raise InputError(f"{path}: colour space {space!r} needs raw frames (their colour matrix and neutral); "
                         "keep the camera's colour space (--colour-space camera) for TIFF/JPEG frames")
    return camera_to_space(read_camera_colour(path), space)


def convert_merged(radiance: np.ndarray, variance: np.ndarray, flags: np.ndarray, matrix: np.ndarray) -> int:
    """Convert a merged (H, W, 3) image in place: radiance by ``matrix``, variance by ``matrix**2``.

    Channels are taken as independent (variance), a pixel flagged in any channel
    is flagged in all (every output channel mixes them), and negative radiance
    (noise, colours outside the target gamut) is set to 0.

    Returns
    -------
    int
        The number of pixel-channels set to 0.
    """
    out = convert(radiance, matrix)
    negative = out < 0
    out[negative] = 0.0
    radiance[...] = out
    variance[...] = convert(variance, np.asarray(matrix) ** 2)
    flags[...] = flags.max(axis=2, keepdims=True)
    return int(negative.sum())


def declared_colour_space(paths) -> str:
    """The colour space the EXR files among ``paths`` declare (``brdfrig:colour_space``), ``"camera"`` if none does.

    Files that are not EXR, or EXRs without the attribute, declare nothing.

    Raises
    ------
    InputError
        If two files declare different spaces (images and lighting must share one).
    """
    from pathlib import Path

    from brdfrig.hdr.exr import read_exr_attributes

    declared: dict[str, str] = {}
    for path in paths:
        if Path(path).suffix.lower() == ".exr" and Path(path).is_file():
            space = read_exr_attributes(path).get("colour_space")
            if space is not None:
                declared.setdefault(str(space), str(path))
    if len(declared) > 1:
        raise InputError("the inputs are in different colour spaces: "
                         + ", ".join(f"{p} in {s}" for s, p in declared.items())
                         + "; merge them all with one --colour-space")
    space = next(iter(declared), "camera")
    if space not in COLOUR_SPACES:
        raise InputError(f"{declared[space]}: unknown colour_space {space!r}")
    return space
