"""Frames of a bracket read by rows, so a merge holds a band of rows of each frame, never whole frames.

A frame source has a ``shape`` (H, W, C), a ``saturation`` (the value of full
scale) and ``rows(y0, y1)``, which returns rows ``y0:y1`` as an (rows, W, C)
array.  :class:`ImageFileFrame` reads TIFF/JPEG/PNG/EXR files through
OpenImageIO's scanline reader in the file's own integer type (a 16-bit TIFF
row band costs 2 bytes per sample, not 4 or 8); :class:`ArrayFrame` serves an
array in memory (frames decoded from raw files, tests); :class:`MappedFrame`
applies a per-band function (a response curve) to another source.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Callable

import numpy as np

from brdfrig.errors import InputError

__all__ = ["ArrayFrame", "ImageFileFrame", "MappedFrame", "as_frame", "read_whole"]


class ArrayFrame:
    """An (H, W, C) or (H, W) array as a frame source; ``saturation`` 1.0 for floats, the dtype's maximum for integers."""

    def __init__(self, array: np.ndarray, name: str = "frame", saturation: float | None = None) -> None:
        a = np.asarray(array)
        self.array = a[:, :, None] if a.ndim == 2 else a
        self.name = name
        self.shape = self.array.shape
        self.dtype = self.array.dtype
        integer = np.issubdtype(self.dtype, np.integer)
        self.saturation = float(np.iinfo(self.dtype).max) if saturation is None and integer else (saturation or 1.0)

    def rows(self, y0: int, y1: int) -> np.ndarray:
        return self.array[y0:y1]


class ImageFileFrame:
    """An image file (TIFF, JPEG, PNG, EXR, ...) read by rows through OpenImageIO, first 3 channels.

    Integer files keep their integer type (``saturation`` = its maximum);
    float files are read as float32 (``saturation`` 1.0).  A single-channel
    file is served as 3 equal channels.
    """

    def __init__(self, path: str | os.PathLike) -> None:
        import OpenImageIO as oiio

        self.path = Path(path)
        self.name = str(self.path)
        if not self.path.is_file():
            raise FileNotFoundError(f"{self.path}: no such image file")
        inp = oiio.ImageInput.open(str(self.path))
        if inp is None:
            raise InputError(f"{self.path}: not a readable image: {oiio.geterror()}")
        spec = inp.spec()
        inp.close()
        base = spec.format.basetype
        types = {oiio.UINT8: (np.uint8, oiio.UINT8), oiio.UINT16: (np.uint16, oiio.UINT16)}
        self.is_float = base in (oiio.FLOAT, oiio.HALF, oiio.DOUBLE)
        self.dtype, self._format = types.get(base, (np.float32, oiio.FLOAT))
        self.saturation = float(np.iinfo(self.dtype).max) if self.dtype != np.float32 else 1.0
        if base not in types and not self.is_float:  # other integer types: scaled to [0, 1] by OpenImageIO
            self.saturation = 1.0
        self._nch = spec.nchannels
        self.shape = (spec.height, spec.width, 3)
        self._input = None

    def rows(self, y0: int, y1: int) -> np.ndarray:
        import OpenImageIO as oiio

        if self._input is None:
            self._input = oiio.ImageInput.open(str(self.path))
        chans = min(self._nch, 3)
        pixels = self._input.read_scanlines(0, 0, y0, y1, 0, 0, chans, self._format)
        if pixels is None or self._input.has_error:
            raise InputError(f"{self.path}: truncated or corrupt image: {self._input.geterror() or 'no pixels read'}")
        pixels = np.asarray(pixels, dtype=self.dtype).reshape(y1 - y0, self.shape[1], chans)
        if chans < 3:
            pixels = np.repeat(pixels[:, :, :1], 3, axis=2)
        if self.is_float and not np.all(np.isfinite(pixels)):
            raise InputError(f"{self.path}: NaN/inf pixel values")
        return pixels

    def close(self) -> None:
        if self._input is not None:
            self._input.close()
            self._input = None


class MappedFrame:
    """Another source with ``func`` applied to every band of rows (e.g. linearisation by a response curve)."""

    def __init__(self, source, func: Callable[[np.ndarray], np.ndarray], saturation: float = 1.0) -> None:
        self.source, self.func = source, func
        self.name, self.shape = source.name, source.shape
        self.dtype = np.dtype(np.float32)
        self.saturation = saturation

    def rows(self, y0: int, y1: int) -> np.ndarray:
        return self.func(self.source.rows(y0, y1) / np.float32(self.source.saturation))


def as_frame(frame, name: str = "frame"):
    """A frame source as it is, an array wrapped in :class:`ArrayFrame`."""
    return frame if hasattr(frame, "rows") and hasattr(frame, "saturation") else ArrayFrame(frame, name)


def read_whole(source) -> np.ndarray:
    """All rows of a source, as fractions of full scale (float32)."""
    rows = source.rows(0, source.shape[0])
    return rows.astype(np.float32) / np.float32(source.saturation) if source.saturation != 1.0 else \
        np.asarray(rows, np.float32)
