"""Frames of a bracket read by rows, so a merge holds a band of rows of each frame, never whole frames.

A frame source has a ``shape`` (H, W, C), a ``saturation`` (the value of full
scale) and ``rows(y0, y1)``, which returns rows ``y0:y1`` as an (rows, W, C)
array.  :class:`ImageFileFrame` reads TIFF/JPEG/PNG/EXR files through
OpenImageIO's scanline reader in the file's own integer type (a 16-bit TIFF
row band costs 2 bytes per sample, not 4 or 8); :class:`RawFrame` decodes a
camera raw file once into a temporary file of its 16-bit samples and serves
bands of it (one decoded frame in memory only while it is decoded);
:class:`ArrayFrame` serves an array in memory (tests); :class:`MappedFrame`
applies a per-band function (a response curve) to another source;
:class:`ShiftedFrame` moves another source by whole pixels (alignment).
"""

from __future__ import annotations

import errno
import os
import tempfile
from pathlib import Path
from typing import Callable

import numpy as np

from brdfrig.errors import DiskFullError, InputError

__all__ = ["ArrayFrame", "ImageFileFrame", "RawFrame", "MappedFrame", "ShiftedFrame", "as_frame", "read_whole",
           "read_scaled"]


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


class RawFrame:
    """A camera raw file decoded once (:func:`brdfrig.hdr.raw.decode_raw16`), served by rows.

    The 16-bit samples go to an unlinked temporary file (``tempfile``'s
    directory, 6 bytes per pixel) and each band is read back and converted as
    :func:`brdfrig.hdr.raw.decode_raw` converts the whole image (float32, 1.0 =
    white level, ``saturation`` 1.0): the same values, one band in memory.
    """

    def __init__(self, path: str | os.PathLike) -> None:
        from brdfrig.hdr.raw import decode_raw16

        self.path = Path(path)
        self.name = str(self.path)
        rgb16 = np.ascontiguousarray(decode_raw16(self.path))
        self.shape = rgb16.shape
        self.dtype = np.dtype(np.float32)
        self.saturation, self.is_float = 1.0, False
        self._file = tempfile.TemporaryFile(prefix="brdfrig-raw-")
        try:
            self._file.write(memoryview(rgb16).cast("B"))  # not tofile: its short writes carry no errno
            self._file.flush()
        except OSError as exc:
            self._file.close()
            if exc.errno != errno.ENOSPC:
                raise
            raise DiskFullError(errno.ENOSPC, f"disk full while decoding {self.path} into {tempfile.gettempdir()} "
                                f"({rgb16.nbytes / 1e6:.0f} MB per raw frame): free some space there or set "
                                "TMPDIR to a disk with room") from exc

    def rows(self, y0: int, y1: int) -> np.ndarray:
        from brdfrig.hdr.raw import raw16_to_float

        w, c = self.shape[1:]
        band = np.empty((y1 - y0, w, c), np.uint16)
        view, offset = memoryview(band).cast("B"), y0 * w * c * 2
        done = 0
        while done < len(view):  # pread may return short counts
            n = os.preadv(self._file.fileno(), [view[done:]], offset + done)
            if n <= 0:
                raise InputError(f"{self.path}: its decoded copy in {tempfile.gettempdir()} was cut short")
            done += n
        return raw16_to_float(band)

    def close(self) -> None:
        self._file.close()


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


class ShiftedFrame:
    """Another source, as fractions of full scale (float32, ``saturation`` 1.0), moved by (dx, dy) whole pixels.

    Pixels shifted in from outside the frame are NaN (no data).
    """

    def __init__(self, source, dx: int, dy: int) -> None:
        self.source, self.dx, self.dy = source, int(dx), int(dy)
        self.name, self.shape = source.name, source.shape
        self.dtype = np.dtype(np.float32)
        self.saturation = 1.0

    def rows(self, y0: int, y1: int) -> np.ndarray:
        h, w = self.shape[:2]
        dx, dy = self.dx, self.dy
        out = np.full((y1 - y0, w, self.shape[2]), np.nan, np.float32)
        a, b = max(y0, dy, 0), min(y1, h, h + dy)  # destination rows with a source row
        if a < b:
            xs, xd = (slice(0, w - dx), slice(dx, w)) if dx >= 0 else (slice(-dx, w), slice(0, w + dx))
            out[a - y0:b - y0, xd] = read_scaled(self.source, a - dy, b - dy)[:, xs]
        return out


def read_scaled(source, y0: int, y1: int) -> np.ndarray:
    """Rows ``y0:y1`` of a source, as fractions of full scale (float32)."""
    rows = source.rows(y0, y1)
    return rows.astype(np.float32) / np.float32(source.saturation) if source.saturation != 1.0 else \
        np.asarray(rows, np.float32)


def read_whole(source) -> np.ndarray:
    """All rows of a source, as fractions of full scale (float32)."""
    return read_scaled(source, 0, source.shape[0])
