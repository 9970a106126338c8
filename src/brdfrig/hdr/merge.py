"""Merge an exposure bracket of linear frames into radiance plus a per-pixel variance.

Model (MATH.md pitfall 7).  Frame ``k`` records, per pixel and channel,
``z_k = X t_k + noise`` in frame units (1.0 = ``saturation``), with
``Var(z_k) = z/full_well + (read_noise/full_well)^2`` (shot + read noise, both
expressed in units of the full-well capacity).  Each frame gives the estimate
``X_k = z_k / t_k`` of the radiance ``X`` (frame units per second); the merge
is the weighted mean ``X = sum w_k X_k / sum w_k``:

- ``weighting="optimal"`` (default, Granados et al. 2010, "Optimal HDR
  reconstruction with linear digital cameras"): ``w_k = t_k^2 / Var(z_k)``
  with the variance evaluated at the current estimate ``X t_k`` (not at the
  noisy ``z_k``, which would favour samples with negative noise), iterated;
  the variance of the result is ``1 / sum w_k``.
- ``weighting="debevec"`` (baseline, Debevec & Malik 1997): the hat
  ``w(z) = min(z - lo, hi - z)``; variance ``sum w_k^2 Var(X_k) / (sum w_k)^2``.

Samples at or above ``hi`` (saturated, default 0.95 of full scale) or at or
below ``lo`` (black, default 0: clipped at the black level, i.e. censored)
get zero weight, per channel.  So do all channels of a pixel within
``clip_radius`` pixels (default 1) of a pixel saturated in any channel of
the same frame (:func:`clipped_neighbourhood`): demosaicing interpolates a
clipped sample into its neighbours, which then read low while staying below
``hi``.  Near-black samples above ``lo`` get vanishing weight
smoothly: the hat goes to 0 at ``lo``, and the optimal weight of a frame
whose signal is buried in read noise is ``t^2 / read_var``, negligible beside
a longer exposure's.  (A higher ``lo`` drops the negative-noise half of the
faintest samples and biases them up: 2e-4 gave +16% instead of +10% at 11
electrons in the tests' sensor model.)  A pixel with no usable sample falls
back to the longest unsaturated frame (dark pixel,
flag ``FLAG_DARK``) or, when it is saturated in every frame, to the shortest
frame's value, a lower bound (``FLAG_SATURATED``, variance = value^2, and a
:class:`SaturationWarning`; a sample weighted out as a neighbour of a clipped
one counts as saturated here, and its value is a lower bound too:
demosaicing mixed a clipped, too low, value into it).

Exposure times: nominal times are rounded by cameras (1/125 s is not
1/128 s), so the ratio between consecutive exposures is re-estimated from
pixels well exposed in both (ratio of sums, selected on the pair's summed
signal, away from demosaiced neighbours of clipped samples, outliers
trimmed; a ratio with a standard error above 0.2% is not used, one more
than 10% from the nominal one is rejected with an
:class:`ExposureTimeWarning`) and, when it differs from the nominal ratio
by more than ``ratio_tolerance``, the re-estimated times are used, anchored
so that the median of ``t_estimated / t_nominal`` is 1 (one wrong nominal
time does not shift the others).  Optional alignment (OpenCV's
median threshold bitmaps) runs before the re-estimation.

The per-pixel loop is one fused numba kernel, parallel over blocks of
pixels: each block of every frame is gathered once (frames read in their own
dtype, no stacked copy of the bracket), then merged per pixel and channel.
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass
from typing import Sequence

import numba as nb
import numpy as np

from brdfrig.errors import InputError
__all__ = [
    "MergeResult",
    "SaturationWarning",
    "ExposureTimeWarning",
    "merge_bracket",
    "estimate_times",
    "align_frames",
    "clipped_neighbourhood",
    "FLAG_DARK",
    "FLAG_SATURATED",
    "DEFAULT_FULL_WELL",
    "DEFAULT_READ_NOISE",
]

log = logging.getLogger(__name__)

FLAG_DARK = 1
FLAG_SATURATED = 2
#: Default sensor noise model, in electrons (a typical APS-C/full-frame sensor at base ISO).
DEFAULT_FULL_WELL = 20000.0
DEFAULT_READ_NOISE = 5.0
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


class SaturationWarning(UserWarning):
    """Some pixels are saturated in every frame of a bracket: their radiance is only a lower bound."""


class ExposureTimeWarning(UserWarning):
    """A re-estimated exposure ratio departs too far from the nominal one: the nominal ratio is kept."""


@dataclass(frozen=True)
class MergeResult:
    """Merged HDR image.

    Attributes
    ----------
    radiance : (H, W, C) float32
        Linear radiance in frame units per second of exposure (``z / t``).
    variance : (H, W, C) float32
        Variance of ``radiance`` under the noise model (same units squared).
    flags : (H, W, C) uint8
        0 = merged from usable samples, ``FLAG_DARK`` = below the black
        threshold in every frame, ``FLAG_SATURATED`` = saturated, or within
        ``clip_radius`` of a saturated pixel, in every frame.
    times : (K,) float64
        Exposure times used (re-estimated or nominal), in input order.
    nominal_times : (K,) float64
        Exposure times given.
    shifts : (K, 2) int or None
        (dx, dy) shift applied to each frame by alignment, or None.
    weighting : str
        ``"optimal"`` or ``"debevec"``.
    """

    radiance: np.ndarray
    variance: np.ndarray
    flags: np.ndarray
    times: np.ndarray
    nominal_times: np.ndarray
    shifts: np.ndarray | None
    weighting: str

    @property
    def saturated_fraction(self) -> float:
        """Fraction of pixel-channels saturated in every frame."""
        return float(np.mean(self.flags == FLAG_SATURATED))


_BLOCK = 512  # pixels per block of the merge kernel (the gathered block stays in L1/L2 cache)


@nb.njit(parallel=True, cache=True)  # no fastmath: NaN (no data after alignment) must compare false
def _merge_kernel(frames, near, times, inv_sat, lo, hi, optimal, inv_well, read_var, iterations,
                  out_rad, out_var, out_flag):  # pragma: no cover - compiled
    npix, nch = out_rad.shape
    nfr = len(frames)
    use_near = near[0].size > 0  # per frame, (npix,) bool: near a clipped pixel, weighted out like saturation
    mid = 0.5 * (lo + hi)
    inv_t = 1.0 / times
    nblocks = (npix + _BLOCK - 1) // _BLOCK
    for b in nb.prange(nblocks):
        p0 = b * _BLOCK
        p1 = min(p0 + _BLOCK, npix)
        # Gather the block of every frame once, normalised (contiguous reads, one tuple dispatch per frame).
        # A sample near a clipped pixel is gathered as +inf: weighted out like a saturated one.
        zb = np.empty((nfr, p1 - p0, nch), np.float32)
        for k in range(nfr):
            fk = frames[k]
            for p in range(p0, p1):
                for c in range(nch):
                    zb[k, p - p0, c] = fk[p, c] * inv_sat
            if use_near:
                nk = near[k]
                for p in range(p0, p1):
                    if nk[p]:
                        zb[k, p - p0, :] = np.inf
        for q in range(p1 - p0):
            p = p0 + q
            for c in range(nch):
                # Debevec hat estimate (the result for "debevec", the starting point for "optimal").
                num = 0.0
                den = 0.0
                for k in range(nfr):
                    z = zb[k, q, c]
                    if z > lo and z < hi:
                        w = z - lo if z <= mid else hi - z
                        num += w * z * inv_t[k]
                        den += w
                if den <= 0.0:
                    # No usable sample: longest unsaturated frame (dark), else shortest (saturated).
                    best = -1
                    for k in range(nfr):
                        z = zb[k, q, c]
                        if z == z and z < hi and (best < 0 or times[k] > times[best]):
                            best = k
                    if best >= 0:
                        x = max(zb[best, q, c], 0.0) * inv_t[best]
                        out_rad[p, c] = x
                        out_var[p, c] = (x * times[best] * inv_well + read_var) * inv_t[best] * inv_t[best]
                        out_flag[p, c] = 1
                    else:
                        for k in range(nfr):
                            if best < 0 or times[k] < times[best]:
                                best = k
                        x = np.float32(frames[best][p, c] * inv_sat) * inv_t[best]  # the value, not the +inf mark
                        out_rad[p, c] = x
                        out_var[p, c] = x * x
                        out_flag[p, c] = 2
                    continue
                x = num / den
                if optimal:
                    for _ in range(iterations):
                        num = 0.0
                        den = 0.0
                        xs = max(x, 0.0) * inv_well
                        for k in range(nfr):
                            z = zb[k, q, c]
                            if z > lo and z < hi:
                                # u = t / Var(z_k) = w_k / t_k, Var(z_k) = x t / well + read_var, w_k = t^2 / Var
                                u = 1.0 / (xs + read_var * inv_t[k])
                                num += u * z  # sum w_k (z_k / t_k)
                                den += u * times[k]  # sum w_k
                        x = num / den
                    var = 1.0 / den  # at the weights of the last iteration
                else:
                    xs = max(x, 0.0)
                    acc = 0.0
                    for k in range(nfr):
                        z = zb[k, q, c]
                        if z > lo and z < hi:
                            w = z - lo if z <= mid else hi - z
                            acc += w * w * (xs * times[k] * inv_well + read_var) * inv_t[k] * inv_t[k]
                    var = acc / (den * den)
                out_rad[p, c] = x
                out_var[p, c] = var
                out_flag[p, c] = 0


def _validate(frames, times, names) -> tuple[list[np.ndarray], np.ndarray, list[str]]:
    if len(frames) == 0:
        raise InputError("merge: the bracket has no frames")
    names = list(names) if names is not None else [f"frame {k}" for k in range(len(frames))]
    if len(names) != len(frames):
        raise InputError(f"merge: {len(names)} names for {len(frames)} frames")
    if times is None:
        raise InputError("merge: exposure times are missing")
    times = np.asarray(times, dtype=float).ravel()
    if times.size != len(frames):
        raise InputError(f"merge: {times.size} exposure times for {len(frames)} frames")
    for name, t in zip(names, times):
        if not (np.isfinite(t) and t > 0):
            raise InputError(f"merge: {name}: exposure time must be a positive number, got {t}")
    arrays = []
    for name, f in zip(names, frames):
        f = np.asarray(f)
        if f.ndim == 2:
            f = f[:, :, None]
        if f.ndim != 3:
            raise InputError(f"merge: {name}: expected an (H, W, C) image, got shape {f.shape}")
        if arrays and f.shape != arrays[0].shape:
            raise InputError(f"merge: {name} has size {f.shape}, {names[0]} has {arrays[0].shape}: "
                             "a bracket must have one image size")
        if not (np.issubdtype(f.dtype, np.integer) or np.issubdtype(f.dtype, np.floating)):
            raise InputError(f"merge: {name}: unsupported pixel type {f.dtype}")
        if np.issubdtype(f.dtype, np.floating) and not np.all(np.isfinite(f)):
            raise InputError(f"merge: {name}: contains NaN/inf pixel values")
        arrays.append(f)
    return arrays, times, names


@nb.njit(parallel=True, cache=True)
def _clipped_pixels(frame, clip, out):  # pragma: no cover - compiled
    # Hand-written: numpy's (frame >= clip).any(axis=-1) takes ~0.7 s on a 12 MP RGB frame, this ~0.03 s.
    h, w, nch = frame.shape
    for i in nb.prange(h):
        for j in range(w):
            hit = False
            for c in range(nch):
                hit |= frame[i, j, c] >= clip  # NaN (no data) compares false
            out[i, j] = hit


def clipped_neighbourhood(frame: np.ndarray, clip: float, radius: int) -> np.ndarray:
    """Pixels within ``radius`` of a pixel that reaches ``clip`` in any channel.

    A demosaiced value interpolates the samples within the demosaicing support
    (bilinear, :func:`brdfrig.hdr.raw.decode_raw`: the 3x3 neighbourhood, ``radius``
    1), so next to a clipped sample it reads low while staying below the clip
    level.  Any channel, not only the same one.  With ``decode_raw``
    (bilinear, camera colour, no white balance) the damage stays in the
    clipped channel (four clipped lights in a 32x32 DNG: all 62 unclipped
    samples more than 1% off the demosaiced truth lie within radius 1 of a
    clipped sample of their own channel; the lights of the tests' bracket
    merge within 0.8% under either rule).  But frames colour-converted after
    demosaicing (camera TIFF/JPEG: a camera-to-sRGB matrix) carry a clipped
    camera channel into every output channel of the neighbours: a saturated
    red light (16, 3, 1 x full scale) merged within 0.7% with this any-channel
    rule, up to 226% off (13 pixel-channels beyond 2%) with a same-channel
    rule (``tests/test_merge.py``).  The price is small: 231 instead of 107
    samples weighted out around the four lights of the 32x32 DNG, which the
    merge takes from the next shorter exposure.

    Parameters
    ----------
    frame : (H, W, C) or (H, W) array
        Linear frame (any real dtype); NaN (no data) is never clipped.
    clip : float
        Clip level, in frame units (``clip_threshold * saturation``).
    radius : int
        Neighbourhood radius in pixels (a ``(2 radius + 1)^2`` square; 0 = the
        clipped pixels themselves).  Beyond the image edge nothing is clipped.

    Returns
    -------
    (H, W) bool
    """
    frame = np.asarray(frame)
    if frame.ndim == 2:
        frame = frame[:, :, None]
    hit = np.empty(frame.shape[:2], np.uint8)
    _clipped_pixels(frame, clip, hit)
    if radius > 0 and hit.any():
        import cv2

        hit = cv2.dilate(hit, np.ones((2 * radius + 1, 2 * radius + 1), np.uint8))
    return hit.view(bool)


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
    """Re-estimate exposure times from the overlap of well-exposed pixels.

    For consecutive frames ``a``, ``b`` in order of nominal time
    (``t_a <= t_b``), the exposure ratio is the ratio of sums ``sum b / sum a``
    over the pixel-channels

    - whose pair radiance estimate ``x = (a + b) / (t_a + t_b)`` is well
      exposed in both frames: ``x t_a >= window[0]`` (away from the black
      level in the shorter frame) and ``x t_b <= window[1]`` (away from the
      clip level in the longer frame), fractions of ``saturation``;
    - whose ``(2 clip_radius + 1)^2`` neighbourhood has no value at or above
      ``clip`` (fraction of ``saturation``) in any channel of either frame
      (:func:`clipped_neighbourhood`, the pixels the merge weights out):
      demosaicing interpolates clipped samples into neighbours that stay
      below the clip level, biased low (``clip_radius=1`` covers the 3x3
      support of bilinear demosaicing, :func:`brdfrig.hdr.raw.decode_raw`; 0 suits
      frames that were not demosaiced, in-camera demosaicing may need 2).
      Selecting on each frame's own values and ignoring neighbourhoods made
      the 4 s frame of a simulated DNG bracket look 3.19 s long;
    - not gross outliers of the pair's robust fit (trimmed).

    A pair with fewer than ``min_samples`` such values, or whose ratio has a
    relative standard error above ``max_std_error`` (a few hundred values at
    the bottom of the window: a noisy ratio would shift every time chained
    after it), keeps its nominal ratio; so does a pair whose re-estimated
    ratio departs from the nominal one by more than ``max_deviation``
    (relative), with an :class:`ExposureTimeWarning`: camera labels round
    full-stop times by at most 6.7% (1/15 s for 1/16 s), so a larger
    departure means motion, flicker or a wrong frame, not rounding.  The
    chained times are anchored so that the median of ``t_est / t_nominal``
    is 1.

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
        Radius in pixels of the demosaicing support around clipped values.
    max_deviation : float
        Largest accepted relative departure of a re-estimated ratio from the nominal ratio.
    max_std_error : float
        Largest accepted relative standard error of a re-estimated ratio.
    min_samples : int
        Minimum overlap size (pixel-channels) for a ratio to be trusted.
    near_clip : sequence of K (H, W) bool, optional
        ``clipped_neighbourhood(frame, clip * saturation, clip_radius)`` of
        each frame, if already computed (:func:`merge_bracket` passes the
        masks it weights out with); computed here when None.

    Returns
    -------
    (K,) float64
        Re-estimated exposure times, in input order.
    """
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
        t_a, t_b = times[ka], times[kb]
        ratio, n, rel_se = _overlap_ratio(frames[ka][rows].astype(np.float64), frames[kb][rows].astype(np.float64),
                                          (near_clip[ka][rows] | near_clip[kb][rows])[:, :, None], t_a, t_b, lo, hi,
                                          min_samples)
        nominal = t_b / t_a
        if ratio is None or rel_se > max_std_error:
            log.info("merge: %d well-exposed samples shared by %.6g s and %.6g s (relative standard error %.3g): "
                     "nominal ratio kept", n, t_a, t_b, rel_se)
            ratio = nominal
        elif abs(ratio / nominal - 1) > max_deviation:
            warnings.warn(
                f"merge: exposure ratio {t_b:.6g} s / {t_a:.6g} s measured as {ratio:.6g} on {n} pixel-channels, "
                f"{100 * (ratio / nominal - 1):+.1f}% from the nominal {nominal:.6g} (beyond the "
                f"{100 * max_deviation:.3g}% tolerance): nominal ratio kept (motion, flicker or a wrong time?)",
                ExposureTimeWarning,
                stacklevel=2,
            )
            ratio = nominal
        log_t[i] = log_t[i - 1] + np.log(ratio)
    est = np.empty(len(times))
    est[order] = np.exp(log_t)
    return est * np.exp(np.median(np.log(times / est)))


def align_frames(frames: Sequence[np.ndarray], times: Sequence[float], *, saturation: float = 1.0,
                 max_bits: int | None = None) -> tuple[list[np.ndarray], np.ndarray]:
    """Align frames by translation with OpenCV's median threshold bitmaps (Ward 2003).

    Each frame is shifted onto the frame of median exposure time; pixels
    shifted in from outside the frame become NaN (no data for the merge).

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
    aligned, shifts = [], []
    for k, f in enumerate(frames):
        f = np.asarray(f, dtype=np.float32)
        dx, dy = (0, 0) if k == ref else (int(v) for v in mtb.calculateShift(ref8, grey8(f)))
        out = np.full_like(f, np.nan)
        h, w = f.shape[:2]
        ys, yd = (slice(0, h - dy), slice(dy, h)) if dy >= 0 else (slice(-dy, h), slice(0, h + dy))
        xs, xd = (slice(0, w - dx), slice(dx, w)) if dx >= 0 else (slice(-dx, w), slice(0, w + dx))
        out[yd, xd] = f[ys, xs]
        aligned.append(out)
        shifts.append((dx, dy))
    return aligned, np.asarray(shifts, dtype=int)


def merge_bracket(
    frames: Sequence[np.ndarray],
    times: Sequence[float],
    *,
    weighting: str = "optimal",
    saturation: float | None = None,
    clip_threshold: float = 0.95,
    clip_radius: int = 1,
    black_threshold: float = 0.0,
    full_well: float = DEFAULT_FULL_WELL,
    read_noise: float = DEFAULT_READ_NOISE,
    reestimate_times: bool = True,
    ratio_tolerance: float = 0.005,
    align: bool = False,
    iterations: int = 2,
    names: Sequence[str] | None = None,
) -> MergeResult:
    """Merge a bracket of linear frames into radiance and variance.

    Parameters
    ----------
    frames : sequence of K (H, W, C) or (H, W) arrays
        Linear frames of one scene (float or integer), all the same shape.
    times : (K,) float
        Nominal exposure times in seconds (any order).
    weighting : {"optimal", "debevec"}
        Noise-optimal ``t^2 / variance`` weights (default) or Debevec's hat.
    saturation : float, optional
        Frame value of full scale: 1.0 for float frames, the dtype's maximum
        for integer frames by default.
    clip_threshold, black_threshold : float
        Samples ``>= clip_threshold`` or ``<= black_threshold`` (fractions of
        ``saturation``) get zero weight, per channel.
    clip_radius : int
        Every channel of a pixel within ``clip_radius`` pixels (a
        ``(2 clip_radius + 1)^2`` square) of a pixel ``>= clip_threshold`` in
        any channel gets zero weight in that frame, as if saturated
        (:func:`clipped_neighbourhood`; also the exclusion of
        :func:`estimate_times`).  1 (default) covers bilinear demosaicing
        (:func:`brdfrig.hdr.raw.decode_raw`): small lights clipped at 16x full scale
        next to unclipped pixels (a 32x40 DNG bracket) merged up to 84% low at
        their demosaiced rim with 0, within 0.8% (14-bit quantisation) with 1.
        0 suits frames that were not demosaiced (every pixel measured
        independently); in-camera demosaicing (TIFF/JPEG) may need 2.
    full_well, read_noise : float
        Noise model in electrons: full-scale signal and read-noise sigma.
    reestimate_times : bool
        Re-estimate exposure ratios from well-exposed overlap
        (:func:`estimate_times`) and use them when they differ from the
        nominal ratios by more than ``ratio_tolerance`` (relative).
    align : bool
        Translate frames onto the median-exposure frame first (:func:`align_frames`).
    iterations : int
        Re-weighting iterations of the optimal merge.
    names : sequence of str, optional
        Frame names (file names) used in error messages.

    Returns
    -------
    MergeResult
    """
    arrays, nominal, names = _validate(frames, times, names)
    if weighting not in ("optimal", "debevec"):
        raise InputError(f"merge: weighting must be 'optimal' or 'debevec', got {weighting!r}")
    if not 0 <= black_threshold < clip_threshold <= 1:
        raise InputError(f"merge: need 0 <= black_threshold < clip_threshold <= 1, got "
                         f"{black_threshold}, {clip_threshold}")
    if saturation is None:
        dt = arrays[0].dtype
        saturation = float(np.iinfo(dt).max) if np.issubdtype(dt, np.integer) else 1.0
    if not saturation > 0:
        raise InputError(f"merge: saturation must be positive, got {saturation}")
    if isinstance(clip_radius, bool) or not isinstance(clip_radius, (int, np.integer)) or clip_radius < 0:
        raise InputError(f"merge: clip_radius must be a non-negative integer (pixels), got {clip_radius!r}")

    shifts = None
    if align and len(arrays) > 1:
        arrays, shifts = align_frames(arrays, nominal, saturation=saturation)
    used = nominal.copy()
    reestimate = reestimate_times and len(arrays) > 1
    near = [clipped_neighbourhood(a, clip_threshold * saturation, clip_radius) for a in arrays] \
        if clip_radius > 0 or reestimate else None
    if reestimate:
        est = estimate_times(arrays, nominal, saturation=saturation, clip=clip_threshold, clip_radius=clip_radius,
                             near_clip=near)
        ratio_err = np.abs(est / nominal / np.median(est / nominal) - 1)
        if np.any(ratio_err > ratio_tolerance):
            log.info("merge: exposure times re-estimated from overlap: %s -> %s", nominal.tolist(), est.tolist())
            used = est

    h, w, c = arrays[0].shape
    dtypes = {a.dtype for a in arrays}
    if len(dtypes) > 1:
        arrays = [a.astype(np.float32) for a in arrays]
    flat = tuple(np.ascontiguousarray(a).reshape(h * w, c) for a in arrays)
    rad = np.empty((h * w, c), np.float32)
    var = np.empty((h * w, c), np.float32)
    flags = np.empty((h * w, c), np.uint8)
    near_flat = tuple(m.reshape(h * w) for m in near) if clip_radius > 0 else (np.empty(0, bool),)
    _merge_kernel(flat, near_flat, used, 1.0 / saturation, black_threshold, clip_threshold, weighting == "optimal",
                  1.0 / full_well, (read_noise / full_well) ** 2, int(iterations), rad, var, flags)
    result = MergeResult(
        radiance=rad.reshape(h, w, c),
        variance=var.reshape(h, w, c),
        flags=flags.reshape(h, w, c),
        times=used,
        nominal_times=nominal,
        shifts=shifts,
        weighting=weighting,
    )
    nsat = int(np.count_nonzero(result.flags == FLAG_SATURATED))
    if nsat:
        warnings.warn(
            f"merge: {nsat} pixel-channels ({100 * nsat / result.flags.size:.3g}%) are saturated in every "
            f"frame (or within clip_radius={clip_radius} px of a saturated pixel), shortest exposure "
            f"{used.min():.6g} s: their radiance is only a lower bound (add a shorter exposure)",
            SaturationWarning,
            stacklevel=2,
        )
    return result
