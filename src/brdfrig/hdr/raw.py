"""Camera files to linear float images, and their exposure metadata.

Colour space and white balance of :func:`decode_raw`
----------------------------------------------------
Values are the camera's native RGB (no colour matrix: LibRaw's ``raw`` output
space), with NO white balance (all multipliers 1), black level subtracted per
CFA channel and divided by ``white_level - black``: 1.0 is sensor saturation
in every channel, and values are proportional to scene radiance times
exposure.  Demosaicing is bilinear (LibRaw ``LINEAR``), a linear operator, so
linearity holds pixel by pixel.  The probe and the sample spheres are shot by
the same camera, so the fit needs no colour conversion; multiply by the
inverse of ``AsShotNeutral`` afterwards for a white-balanced image.

LibRaw's defaults are not linear: ``adjust_maximum_thr=0.75`` rescales by the
data maximum (a 12% slope error was measured), so :func:`decode_raw` passes
``adjust_maximum_thr=0``, ``gamma=(1, 1)``, ``no_auto_bright=True``,
``output_bps=16`` and ``user_flip=0`` (the image keeps the sensor's
orientation, as the sphere geometry assumes).

Exposure metadata (time, f-number, ISO) is read by OpenImageIO, a real
metadata reader that understands EXIF in DNG, TIFF and JPEG files.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from brdfrig.errors import InputError
from brdfrig.hdr.exr import oiio_input, read_oiio

__all__ = ["Exposure", "RAW_SUFFIXES", "decode_raw", "decode_raw16", "raw16_to_float", "read_exposure", "read_frame",
           "is_raw", "read_camera_model"]

#: File suffixes decoded by LibRaw (others go through OpenImageIO).
RAW_SUFFIXES = frozenset({".dng", ".cr2", ".cr3", ".crw", ".nef", ".nrw", ".arw", ".srf", ".sr2", ".raf",
                          ".orf", ".rw2", ".pef", ".srw", ".3fr", ".iiq", ".raw", ".rwl", ".x3f", ".erf"})


@dataclass(frozen=True)
class Exposure:
    """Exposure settings of one frame.

    Attributes
    ----------
    time_s : float
        Exposure (shutter) time in seconds.
    f_number : float
        Aperture f-number (N in f/N); NaN if the file does not record it.
    iso : float
        ISO sensitivity; NaN if the file does not record it.
    """

    time_s: float
    f_number: float
    iso: float


def is_raw(path: str | os.PathLike) -> bool:
    """True if ``path`` has a camera-raw suffix (decoded by LibRaw)."""
    return Path(path).suffix.lower() in RAW_SUFFIXES


def decode_raw(path: str | os.PathLike) -> np.ndarray:
    """Decode a camera raw file (DNG, CR2, NEF, ...) to a linear float image.

    Parameters
    ----------
    path : path-like
        The raw file.

    Returns
    -------
    (H, W, 3) float32
        Camera-native RGB, no white balance, black subtracted, 1.0 = the
        sensor's white level (see the module docstring); image rows and
        columns as stored by the sensor (no rotation).
    """
    return raw16_to_float(decode_raw16(path))


def raw16_to_float(rgb16: np.ndarray) -> np.ndarray:
    """LibRaw's 16-bit output (all or a band of rows) as :func:`decode_raw` returns it: float32, 1.0 = white level."""
    return rgb16.astype(np.float32) / np.float32(65535.0)


def decode_raw16(path: str | os.PathLike) -> np.ndarray:
    """Decode a camera raw file to LibRaw's 16-bit output: (H, W, 3) uint16, 65535 = white level (see decode_raw)."""
    import rawpy

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such raw file")
    try:
        with rawpy.imread(str(path)) as raw:
            rgb16 = raw.postprocess(
                demosaic_algorithm=rawpy.DemosaicAlgorithm.LINEAR,
                output_color=rawpy.ColorSpace.raw,
                user_wb=[1.0, 1.0, 1.0, 1.0],
                adjust_maximum_thr=0.0,
                gamma=(1, 1),
                no_auto_bright=True,
                output_bps=16,
                user_flip=0,
            )
    except (rawpy.LibRawError, OSError, ValueError) as exc:
        raise InputError(f"{path}: cannot decode raw file (truncated, corrupt or unsupported): "
                         f"{type(exc).__name__}: {exc}") from None
    return rgb16


def read_frame(path: str | os.PathLike) -> tuple[np.ndarray, bool]:
    """Read one frame of a bracket as float, whatever its format.

    Parameters
    ----------
    path : path-like
        A camera raw file (decoded by :func:`decode_raw`) or a TIFF/JPEG/PNG
        (read by OpenImageIO and scaled to [0, 1] by its integer range; float
        TIFF/EXR are returned as stored).

    Returns
    -------
    image : (H, W, 3) float32
        Pixel values, 1.0 = saturation for integer formats.
    linear : bool
        True for raw and float files; False for integer TIFF/JPEG/PNG, whose
        camera response may be non-linear (see :mod:`brdfrig.hdr.response`).
    """
    path = Path(path)
    if is_raw(path):
        return decode_raw(path), True
    pixels, is_float = read_oiio(path)
    if pixels.shape[2] >= 3:
        image = pixels[:, :, :3]
    else:
        image = np.repeat(pixels[:, :, :1], 3, axis=2)
    if not np.all(np.isfinite(image)):
        raise InputError(f"{path}: NaN/inf pixel values")
    return np.ascontiguousarray(image), is_float


def read_exposure(path: str | os.PathLike) -> Exposure:
    """Read exposure time, f-number and ISO from a file's metadata (EXIF / DNG / TIFF tags).

    Parameters
    ----------
    path : path-like
        Any file OpenImageIO opens (DNG and other raw formats, TIFF, JPEG).

    Returns
    -------
    Exposure
        ``time_s`` always positive; ``f_number``/``iso`` NaN when absent.

    Raises
    ------
    ValueError
        If the file cannot be opened or records no (positive) exposure time.
    """
    path = Path(path)
    with oiio_input(path, "cannot read metadata") as inp:
        spec = inp.spec()
        time_s = spec.getattribute("ExposureTime")
        f_number = spec.getattribute("FNumber")
        iso = spec.getattribute("Exif:ISOSpeedRatings")
        if iso is None:
            iso = spec.getattribute("Exif:PhotographicSensitivity")
    if time_s is None or not np.isfinite(float(time_s)) or float(time_s) <= 0:
        raise InputError(f"{path}: no exposure time in the file's metadata (EXIF ExposureTime); "
                         "give the times explicitly (e.g. --times)")

    def _opt(value) -> float:
        return float(value) if value is not None and float(value) > 0 else float("nan")

    return Exposure(time_s=float(time_s), f_number=_opt(f_number), iso=_opt(iso))


def read_camera_model(path: str | os.PathLike) -> str:
    """The camera's make and model from a file's metadata (EXIF / DNG ``Make``, ``Model``); "" when absent."""
    with oiio_input(path, "cannot read metadata") as inp:
        parts = [str(inp.spec().getattribute(k) or "").strip() for k in ("Make", "Model")]
    make, model = parts
    return model if make and model.lower().startswith(make.lower()) else " ".join(p for p in parts if p)
