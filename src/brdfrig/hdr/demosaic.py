"""How far apart pixels share sensor samples: the demosaicing support of a bracket, from its noise.

A frame that was never demosaiced measures every pixel independently, so
the noise of neighbouring pixels is uncorrelated; demosaicing interpolates
each pixel from the samples within its support (radius ``r``), so pixels up to
``2 r`` apart share samples and their noise is correlated.  The scene cancels
in the residual ``b - rho a`` of two frames of a bracket (``rho`` their
exposure ratio, measured as a ratio of sums), which leaves the noise alone:
its correlation at lags 1..4 pixels (rows and columns, every channel) gives
the support radius ``ceil(L / 2)``, ``L`` the largest lag correlated above
``threshold``.  Bilinear demosaicing (:func:`brdfrig.hdr.raw.decode_raw`)
correlates lags 1 and 2 (radius 1); independent pixels correlate none (0).
The merge weights out the pixels within this radius of a clipped one
(:func:`brdfrig.hdr.merge.clipped_neighbourhood`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from brdfrig.hdr.merge import clipped_neighbourhood

__all__ = ["SupportEstimate", "demosaic_radius"]

#: Window of the frames examined (pixels per side, centred): enough pairs for correlations to +-0.003.
_WINDOW = 1024
#: Well-exposed range (fractions of full scale) of the pixels whose residual is used.
_WELL_EXPOSED = (0.05, 0.9)
#: Clip level (fraction of full scale) of the merge (``merge_bracket``'s default ``clip_threshold``).
CLIP = 0.95


@dataclass(frozen=True)
class SupportEstimate:
    """Demosaicing support radius of a bracket, from the correlation of its noise.

    Attributes
    ----------
    radius : int
        Support radius in pixels (0 = pixels measured independently), at most ``max_lag // 2``.
    correlation : (max_lag,) float
        Noise correlation at lags 1..max_lag (mean of rows and columns).
    pairs : int
        Pixel-channel pairs at lag 1 the estimate rests on.
    """

    radius: int
    correlation: np.ndarray
    pairs: int

    def describe(self) -> str:
        lags = ", ".join(f"{c:.2f}" for c in self.correlation)
        kind = "pixels measured independently" if self.radius == 0 else "frames demosaiced"
        return f"noise correlation of neighbours at 1..{len(self.correlation)} px: {lags} ({kind})"


def _window(frame: np.ndarray) -> np.ndarray:
    h, w = frame.shape[:2]
    y0, x0 = max(0, (h - _WINDOW) // 2), max(0, (w - _WINDOW) // 2)
    return np.asarray(frame[y0:y0 + _WINDOW, x0:x0 + _WINDOW], np.float64)


def _residual(a: np.ndarray, b: np.ndarray, reach: int) -> np.ndarray:
    """Noise of ``b - rho a`` in units of its sigma, NaN where either frame is not well exposed.

    Pixels within ``reach`` of a clipped pixel of ``b`` are left out too: demosaicing mixed a clipped
    value into them, so ``b`` is no longer proportional to ``a`` there.
    """
    lo, hi = _WELL_EXPOSED
    ok = (a > lo) & (a < hi) & (b > lo) & (b < hi) & ~clipped_neighbourhood(b, CLIP, reach)[:, :, None]
    if np.count_nonzero(ok) == 0:
        return np.full(a.shape, np.nan)
    rho = b[ok].sum() / a[ok].sum()
    with np.errstate(invalid="ignore", divide="ignore"):
        d = (b - rho * a) / np.sqrt(b + rho * rho * a)
    return np.where(ok, d, np.nan)


def _correlation(d: np.ndarray, lag: int) -> tuple[float, int]:
    num = den1 = den2 = 0.0
    n = 0
    for x, y in ((d[:, :-lag], d[:, lag:]), (d[:-lag], d[lag:])):
        ok = np.isfinite(x) & np.isfinite(y)
        x, y = x[ok], y[ok]
        x, y = x - x.mean() if x.size else x, y - y.mean() if y.size else y
        num += float(np.dot(x, y))
        den1 += float(np.dot(x, x))
        den2 += float(np.dot(y, y))
        n += x.size
    return (num / np.sqrt(den1 * den2) if den1 > 0 and den2 > 0 else 0.0), n


def demosaic_radius(frames: Sequence[np.ndarray], times: Sequence[float], *, max_lag: int = 4,
                    threshold: float = 0.05, min_pairs: int = 2000) -> SupportEstimate | None:
    """Estimate the demosaicing support radius of a bracket of linear frames from its noise.

    Parameters
    ----------
    frames : sequence of K (H, W, C) arrays
        Linear frames, 1.0 = full scale (the centre ``1024 x 1024`` is examined).
    times : (K,) float
        Exposure times (orders the frames; consecutive frames are paired).
    max_lag : int
        Largest lag examined, pixels.
    threshold : float
        Smallest correlation counted as shared samples.
    min_pairs : int
        Fewest well-exposed pixel-channel pairs at lag 1 for an estimate.

    Returns
    -------
    SupportEstimate or None
        None when no pair of consecutive frames shares ``min_pairs`` well-exposed neighbours.
    """
    order = np.argsort(np.asarray(times, dtype=float))
    best, best_n = None, 0
    for ka, kb in zip(order[:-1], order[1:]):
        d = _residual(_window(frames[ka]), _window(frames[kb]), max(1, max_lag // 2))
        n = int(np.count_nonzero(np.isfinite(d[:, :-1]) & np.isfinite(d[:, 1:])))
        if n > best_n:
            best, best_n = d, n
    if best is None or best_n < min_pairs:
        return None
    corr = np.array([_correlation(best, lag)[0] for lag in range(1, max_lag + 1)])
    above = np.nonzero(corr > threshold)[0]
    radius = int(np.ceil((above[-1] + 1) / 2)) if above.size else 0
    return SupportEstimate(radius, corr, best_n)
