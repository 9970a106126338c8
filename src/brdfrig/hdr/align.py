"""Translation alignment of the frames of a bracket (OpenCV's median threshold bitmaps, Ward 2003).

:func:`find_shifts` works on frame sources (:mod:`brdfrig.hdr.frames`) and
holds two grey planes at a time, the reference frame's and the one being
aligned (4 + 1 bytes per pixel each), never an RGB frame;
:func:`align_sources` wraps the sources in :class:`~brdfrig.hdr.frames.ShiftedFrame`,
so the merge reads the shifted frames band by band.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from brdfrig.hdr.frames import ArrayFrame, ShiftedFrame, read_scaled

__all__ = ["find_shifts", "align_sources", "align_frames"]

#: A shift found by the bitmaps is kept only if it reduces the frames' mismatch below this fraction of the unshifted one.
_KEEP_SHIFT = 0.9
_GREY_ROWS = 256  # rows read at a time to build a grey plane


def find_shifts(sources: Sequence, times: Sequence[float], *, max_bits: int | None = None) -> np.ndarray:
    """(dx, dy) that moves each source onto the source of median exposure time, in whole pixels.

    The bitmaps of a smooth or uniform scene can tie and report a shift of an
    already aligned frame (-1 px per pyramid level), so a shift is kept only if
    it lowers the mean relative difference from the reference frame (scaled by
    the exposure ratio, over pixels well exposed in both) below 0.9 of the
    unshifted one.

    Parameters
    ----------
    sources : sequence of K frame sources
        Linear frames, one shape.
    times : (K,) float
        Exposure times (only used to pick the reference frame and scale the mismatch).
    max_bits : int, optional
        log2 of the largest shift searched (default: 6, i.e. up to 64 px,
        reduced for small images so the coarsest pyramid level keeps >= 24 px).

    Returns
    -------
    (K, 2) int
    """
    import cv2

    ref = int(np.argsort(times)[len(times) // 2])
    if max_bits is None:
        max_bits = int(np.clip(np.log2(min(sources[0].shape[:2]) / 24), 1, 6))
    mtb = cv2.createAlignMTB(max_bits=max_bits)
    ref_grey = _grey(sources[ref])
    ref8 = _grey8(ref_grey)
    shifts = []
    for k, src in enumerate(sources):
        if k == ref:
            shifts.append((0, 0))
            continue
        grey = _grey(src)
        dx, dy = (int(v) for v in mtb.calculateShift(ref8, _grey8(grey)))
        if (dx, dy) != (0, 0):
            scale = float(times[ref]) / float(times[k])
            if _mismatch(ref_grey, grey, scale, dx, dy) > _KEEP_SHIFT * _mismatch(ref_grey, grey, scale, 0, 0):
                dx, dy = 0, 0  # the bitmaps' shift does not bring the frames closer: they were aligned already
        shifts.append((dx, dy))
    return np.asarray(shifts, dtype=int)


def align_sources(sources: Sequence, times: Sequence[float], *, max_bits: int | None = None) -> tuple[list, np.ndarray]:
    """Sources moved onto the median-exposure one (:func:`find_shifts`), as fractions of full scale; and the shifts.

    Pixels shifted in from outside the frame are NaN (no data for the merge).
    """
    shifts = find_shifts(sources, times, max_bits=max_bits)
    return [ShiftedFrame(s, dx, dy) for s, (dx, dy) in zip(sources, shifts)], shifts


def align_frames(frames: Sequence[np.ndarray], times: Sequence[float], *, saturation: float = 1.0,
                 max_bits: int | None = None) -> tuple[list[np.ndarray], np.ndarray]:
    """Arrays in memory aligned as :func:`align_sources` aligns sources: K (H, W, C) float32 (frame units), shifts."""
    sources = [ArrayFrame(np.asarray(f, np.float32), f"frame {k}", saturation) for k, f in enumerate(frames)]
    shifts = find_shifts(sources, times, max_bits=max_bits)
    return [ShiftedFrame(ArrayFrame(s.array, s.name, 1.0), dx, dy).rows(0, s.shape[0])
            for s, (dx, dy) in zip(sources, shifts)], shifts


def _grey(source) -> np.ndarray:
    """The mean of a source's channels, as a fraction of full scale, (H, W) float32, read band by band."""
    h, w = source.shape[:2]
    grey = np.empty((h, w), np.float32)
    for y0 in range(0, h, _GREY_ROWS):
        y1 = min(h, y0 + _GREY_ROWS)
        grey[y0:y1] = read_scaled(source, y0, y1).mean(axis=2)
    return grey


def _grey8(grey: np.ndarray) -> np.ndarray:
    """A grey plane as OpenCV's bitmaps take it: 8 bits, gamma 1/2.2."""
    return (np.clip(grey, 0, 1) ** (1 / 2.2) * 255).astype(np.uint8)


def _mismatch(ref: np.ndarray, grey: np.ndarray, scale: float, dx: int, dy: int) -> float:
    """Mean relative difference between ``ref`` and ``grey * scale`` moved by (dx, dy), over pixels well exposed in both."""
    moved = ShiftedFrame(ArrayFrame(grey, "grey", 1.0), dx, dy).rows(0, grey.shape[0])[:, :, 0]
    ok = (ref > 0.02) & (ref < 0.9) & (moved > 0.02) & (moved < 0.9)  # NaN compares false
    if np.count_nonzero(ok) < 100:
        return np.inf
    return float(np.mean(np.abs(moved[ok] * scale - ref[ok]) / ref[ok]))
