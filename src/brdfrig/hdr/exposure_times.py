"""Exposure times re-estimated from the overlap of well-exposed pixels of consecutive frames.

For consecutive frames ``a``, ``b`` in order of nominal time (``t_a <= t_b``),
the exposure ratio is the ratio of sums ``sum b / sum a`` over the
pixel-channels

- whose pair radiance estimate ``x = (a + b) / (t_a + t_b)`` is well exposed
  in both frames: ``x t_a >= window[0]`` (away from the black level in the
  shorter frame) and ``x t_b <= window[1]`` (away from the clip level in the
  longer frame), fractions of ``saturation``;
- whose ``(2 clip_radius + 1)^2`` neighbourhood has no value at or above
  ``clip`` in any channel of either frame
  (:func:`brdfrig.hdr.merge.clipped_neighbourhood`, the pixels the merge
  weights out): demosaicing interpolates clipped samples into neighbours that
  stay below the clip level, biased low.  Selecting on each frame's own
  values and ignoring neighbourhoods made the 4 s frame of a simulated DNG
  bracket look 3.19 s long;
- not gross outliers of the pair's robust fit (trimmed).

A pair with fewer than ``min_samples`` such values, or whose ratio has a
relative standard error above ``max_std_error`` (a few hundred values at the
bottom of the window: a noisy ratio would shift every time chained after
it), keeps its nominal ratio; so does a pair whose re-estimated ratio departs
from the nominal one by more than ``max_deviation`` (relative), with an
:class:`ExposureTimeWarning`: camera labels round full-stop times by at most
6.7% (1/15 s for 1/16 s), so a larger departure means motion, flicker or a
wrong frame, not rounding.  The chained times are anchored so that the
median of ``t_est / t_nominal`` is 1 (one wrong nominal time does not shift
the others).
"""

from __future__ import annotations

import logging
import warnings
from typing import Sequence

import numpy as np

__all__ = ["ExposureTimeWarning", "estimate_times", "RATIO_MAX_SAMPLES"]

log = logging.getLogger("brdfrig.hdr.merge")

#: Well-exposed window (fraction of full scale) used to re-estimate exposure ratios.
#: 0.02 of a 4000 e- well is 80 e-: shot noise dominates a 4 e- read noise and no sample nears the black
#: level (20 read sigmas); 0.9 stays 0.05 below the merge's clip threshold.
_RATIO_WINDOW = (0.02, 0.9)
_RATIO_MIN_SAMPLES = 200
_RATIO_MAX_SAMPLES = 2_000_000  # pixel-channels read per frame (whole rows, evenly spaced)
#: Largest relative departure of a re-estimated exposure ratio from the nominal one.
_RATIO_MAX_DEVIATION = 0.1
#: Largest relative standard error of a re-estimated exposure ratio (from its residuals).
_RATIO_MAX_STD_ERROR = 0.002
#: Outlier trim of the ratio fit, in robust (MAD) sigmas.
_RATIO_TRIM = 6.0


#: Pixel-channels per frame the ratios are measured on (whole rows, evenly spaced).
RATIO_MAX_SAMPLES = _RATIO_MAX_SAMPLES


class ExposureTimeWarning(UserWarning):
    """A re-estimated exposure ratio departs too far from the nominal one: the nominal ratio is kept."""


def _overlap_ratio(a: np.ndarray, b: np.ndarray, near_clip: np.ndarray, t_a: float, t_b: float,
                   lo: float, hi: float, min_samples: int) -> tuple[float | None, int, float]:
    """Exposure ratio ``t_b / t_a`` from the overlap of two frames (``t_a < t_b``).

    Samples are selected on ``(a + b) / (t_a + t_b)``, the radiance estimate
    of the pair, never on ``a`` or ``b`` alone: selecting on each frame's own
    noisy value (``a > lo``, ``b < hi``) keeps the upward noise of ``a`` at
    the bottom of the window and the downward noise of ``b`` at its top, a
    low bias of the ratio (-1.2% for 1/16 s to 0.5 s on the simulated
    camera's 4000 e- sensor, with the clipped neighbourhoods excluded), and
    keeps long-frame values pulled below ``hi`` by clipped neighbours (the
    pair's sum still sees their true level through ``a``).  Given the sum
    of the photon counts, a Poisson split between the frames is binomial
    with the probability ``t_b / (t_a + t_b)`` whatever the radiance, so the
    ratio of sums over a sum-selected set is unbiased under shot noise
    (demosaicing is linear, so this holds for interpolated values too).
    Gross outliers (motion, hot pixels) are trimmed beyond
    ``_RATIO_TRIM`` robust sigmas of the residual ``b - r a`` scaled by its
    shot-noise sigma ``sqrt(b + r^2 a)``.

    Returns
    -------
    ratio : float or None
        None if fewer than ``min_samples`` pixel-channels qualify.
    n : int
        Pixel-channels used.
    rel_se : float
        Relative standard error of ``ratio`` from its residuals (linearised
        ratio of sums; neighbouring demosaiced values share samples, so it
        is an underestimate by up to ~2x); inf if ``ratio`` is None.
    """
    x = (a + b) / (t_a + t_b)  # NaN (no data after alignment) compares false
    ok = (x * t_a >= lo) & (x * t_b <= hi) & ~near_clip & (a > 0) & (b > 0)
    if np.count_nonzero(ok) < min_samples:
        return None, int(np.count_nonzero(ok)), np.inf
    a, b = a[ok], b[ok]
    r = np.exp(np.median(np.log(b / a)))
    z = (b - r * a) / np.sqrt(b + r * r * a)
    dev = np.abs(z - np.median(z))
    mad = np.median(dev)
    keep = dev <= _RATIO_TRIM * 1.4826 * mad if mad > 0 else np.ones(len(z), bool)  # noiseless: nothing to trim
    a, b = a[keep], b[keep]
    ratio = b.sum() / a.sum()
    rel_se = np.sqrt(np.sum((b - ratio * a) ** 2)) / b.sum()
    return float(ratio), len(a), float(rel_se)


def estimate_times(
    frames: Sequence[np.ndarray],
    times: Sequence[float],
    *,
    saturation: float = 1.0,
    window: tuple[float, float] = _RATIO_WINDOW,
    clip: float = 0.95,
    clip_radius: int = 1,
    max_deviation: float = _RATIO_MAX_DEVIATION,
    max_std_error: float = _RATIO_MAX_STD_ERROR,
    min_samples: int = _RATIO_MIN_SAMPLES,
    near_clip: Sequence[np.ndarray] | None = None,
) -> np.ndarray:
    """Re-estimate exposure times from the overlap of well-exposed pixels (see the module docstring).

    Parameters
    ----------
    frames : sequence of K (H, W, C) or (H, W) arrays
        Linear frames (same shape); NaN = no data.
    times : (K,) float
        Nominal exposure times in seconds.
    saturation : float
        Frame value of full scale.
    window : (lo, hi)
        Well-exposed range as fractions of ``saturation``.
    clip : float
        Clip level as a fraction of ``saturation`` (the merge's ``clip_threshold``).
    clip_radius : int
        Radius in pixels of the demosaicing support around clipped values
        (1 covers bilinear demosaicing, :func:`brdfrig.hdr.raw.decode_raw`; 0
        suits frames that were not demosaiced).
    max_deviation : float
        Largest accepted relative departure of a re-estimated ratio from the nominal ratio.
    max_std_error : float
        Largest accepted relative standard error of a re-estimated ratio.
    min_samples : int
        Minimum overlap size (pixel-channels) for a ratio to be trusted.
    near_clip : sequence of K (H, W) bool, optional
        ``clipped_neighbourhood(frame, clip * saturation, clip_radius)`` of
        each frame, if already computed (:func:`brdfrig.hdr.merge.merge_bracket`
        passes the masks it weights out with); computed here when None.

    Returns
    -------
    (K,) float64
        Re-estimated exposure times, in input order.
    """
    from brdfrig.hdr.merge import clipped_neighbourhood

    times = np.asarray(times, dtype=float)
    order = np.argsort(times)
    frames = [f[:, :, None] if np.ndim(f) == 2 else f for f in map(np.asarray, frames)]
    h, w, c = frames[0].shape
    rows = np.arange(0, h, max(1, int(np.ceil(h * w * c / _RATIO_MAX_SAMPLES))))
    lo, hi, clip = window[0] * saturation, window[1] * saturation, clip * saturation
    if near_clip is None:
        near_clip = [clipped_neighbourhood(f, clip, clip_radius) for f in frames]
    log_t = np.zeros(len(times))
    for i in range(1, len(order)):
        ka, kb = order[i - 1], order[i]
        ratio, n, rel_se = _overlap_ratio(frames[ka][rows].astype(np.float64), frames[kb][rows].astype(np.float64),
                                          (near_clip[ka][rows] | near_clip[kb][rows])[:, :, None], times[ka],
                                          times[kb], lo, hi, min_samples)
        log_t[i] = log_t[i - 1] + np.log(_accepted_ratio(ratio, n, rel_se, times[ka], times[kb], max_deviation,
                                                         max_std_error))
    est = np.empty(len(times))
    est[order] = np.exp(log_t)
    return est * np.exp(np.median(np.log(times / est)))


def _accepted_ratio(ratio, n, rel_se, t_a, t_b, max_deviation, max_std_error) -> float:
    """The measured ratio ``t_b / t_a`` if it is precise and near the nominal one, else the nominal ratio."""
    nominal = t_b / t_a
    if ratio is None or rel_se > max_std_error:
        log.info("merge: %d well-exposed samples shared by %.6g s and %.6g s (relative standard error %.3g): "
                 "nominal ratio kept", n, t_a, t_b, rel_se)
        return nominal
    if abs(ratio / nominal - 1) > max_deviation:
        warnings.warn(
            f"merge: exposure ratio {t_b:.6g} s / {t_a:.6g} s measured as {ratio:.6g} on {n} pixel-channels, "
            f"{100 * (ratio / nominal - 1):+.1f}% from the nominal {nominal:.6g} (beyond the "
            f"{100 * max_deviation:.3g}% tolerance): nominal ratio kept (motion, flicker or a wrong time?)",
            ExposureTimeWarning,
            stacklevel=3,
        )
        return nominal
    return ratio
