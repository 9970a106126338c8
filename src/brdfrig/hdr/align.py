"""Translation alignment of the frames of a bracket (OpenCV's median threshold bitmaps, Ward 2003)."""

from __future__ import annotations

from typing import Sequence

import numpy as np

__all__ = ["align_frames"]


def align_frames(frames: Sequence[np.ndarray], times: Sequence[float], *, saturation: float = 1.0,
                 max_bits: int | None = None) -> tuple[list[np.ndarray], np.ndarray]:
    """Align frames by translation with OpenCV's median threshold bitmaps (Ward 2003).

    Each frame is shifted onto the frame of median exposure time; pixels
    shifted in from outside the frame become NaN (no data for the merge).
    The bitmaps of a smooth or uniform scene can tie and report a shift of an
    already aligned frame (-1 px per pyramid level), so a shift is kept only if
    it lowers the mean relative difference from the reference frame (scaled by
    the exposure ratio, over pixels well exposed in both) below 0.9 of the
    unshifted one.

    Parameters
    ----------
    frames : sequence of K (H, W, C) arrays
        Linear frames.
    times : (K,) float
        Exposure times (only used to pick the reference frame).
    saturation : float
        Frame value of full scale.
    max_bits : int, optional
        log2 of the largest shift searched (default: 6, i.e. up to 64 px,
        reduced for small images so the coarsest pyramid level keeps >= 24 px).

    Returns
    -------
    aligned : list of K (H, W, C) float32
    shifts : (K, 2) int
        (dx, dy) applied to each frame.
    """
    import cv2

    ref = int(np.argsort(times)[len(times) // 2])
    if max_bits is None:
        max_bits = int(np.clip(np.log2(min(np.shape(frames[0])[:2]) / 24), 1, 6))
    mtb = cv2.createAlignMTB(max_bits=max_bits)

    def grey8(f):
        g = np.asarray(f, dtype=np.float32).mean(axis=2) / saturation
        return (np.clip(g, 0, 1) ** (1 / 2.2) * 255).astype(np.uint8)

    ref8 = grey8(frames[ref])
    ref_grey = np.asarray(frames[ref], dtype=np.float32).mean(axis=2) / saturation
    aligned, shifts = [], []
    for k, f in enumerate(frames):
        f = np.asarray(f, dtype=np.float32)
        dx, dy = (0, 0) if k == ref else (int(v) for v in mtb.calculateShift(ref8, grey8(f)))
        if (dx, dy) != (0, 0):
            grey = f.mean(axis=2) / saturation
            scale = float(times[ref]) / float(times[k])
            if _mismatch(ref_grey, grey, scale, dx, dy) > _KEEP_SHIFT * _mismatch(ref_grey, grey, scale, 0, 0):
                dx, dy = 0, 0  # the bitmaps' shift does not bring the frames closer: they were aligned already
        aligned.append(_shifted(f, dx, dy))
        shifts.append((dx, dy))
    return aligned, np.asarray(shifts, dtype=int)


#: A shift found by the bitmaps is kept only if it reduces the frames' mismatch below this fraction of the unshifted one.
_KEEP_SHIFT = 0.9


def _shifted(f: np.ndarray, dx: int, dy: int) -> np.ndarray:
    """``f`` moved by (dx, dy) pixels; pixels shifted in from outside are NaN."""
    out = np.full_like(f, np.nan)
    h, w = f.shape[:2]
    ys, yd = (slice(0, h - dy), slice(dy, h)) if dy >= 0 else (slice(-dy, h), slice(0, h + dy))
    xs, xd = (slice(0, w - dx), slice(dx, w)) if dx >= 0 else (slice(-dx, w), slice(0, w + dx))
    out[yd, xd] = f[ys, xs]
    return out


def _mismatch(ref: np.ndarray, grey: np.ndarray, scale: float, dx: int, dy: int) -> float:
    """Mean relative difference between ``ref`` and ``grey * scale`` moved by (dx, dy), over pixels well exposed in both."""
    moved = _shifted(grey[:, :, None], dx, dy)[:, :, 0]
    ok = (ref > 0.02) & (ref < 0.9) & (moved > 0.02) & (moved < 0.9)  # NaN compares false
    if np.count_nonzero(ok) < 100:
        return np.inf
    return float(np.mean(np.abs(moved[ok] * scale - ref[ok]) / ref[ok]))
