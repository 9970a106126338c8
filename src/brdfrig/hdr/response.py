"""Camera response recovery (Debevec & Malik 1997) for non-linear 8- or 16-bit brackets, linearity test, linearisation.

A JPEG or a developed 16-bit TIFF stores ``Z = f(X t)`` with an unknown
monotonic response ``f``.  Debevec & Malik ("Recovering high dynamic range
radiance maps from photographs", SIGGRAPH 1997) recover ``g = ln f^-1`` from
the bracket itself by least squares over sampled pixels::

    minimise  sum_ij [w(Z_ij) (g(Z_ij) - ln E_i - ln t_j)]^2 + lambda sum_z [w(z) h''(z)]^2

with two changes that keep the curve accurate on 16-bit data: ``g`` is read
between its bins by linear interpolation (no rounding of code values to
bins), and the smoothness term acts on ``h(z) = g(z) - p ln z``, the departure
from a power law, so the prior is exact for a linear camera (``p = 1``;
smoothing ``g`` itself bends ``ln z`` near black by 15% at code 0.002) and for
a gamma camera (``p = 2.2``).  The per-pixel unknowns ``ln E_i`` are
eliminated in closed form, which leaves a dense ``levels x levels`` solve.  Hand-written
(with a sparse least-squares solve) because OpenCV's ``CalibrateDebevec``
only accepts 8-bit images: here the code values are binned to ``levels``
bins whatever the bit depth, so one solver serves JPEG (256 levels) and
16-bit TIFF (1024 bins by default).  The tests check it against OpenCV's
calibration on 8-bit data.

The curve is recovered from 6 disjoint pixel samples; their mean is the
curve and its standard error, from their spread, its uncertainty, which
:func:`linearity` compares with the curve's departure from a straight line.

The recovered curve is normalised so that full scale (code value 1.0)
maps to linear 1.0: linearised frames are then in the units
:func:`brdfrig.hdr.merge.merge_bracket` expects (``saturation=1``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from brdfrig.errors import InputError
#: Disjoint pixel subsets the curve is recovered from (their spread is its uncertainty).
_SPLITS = 6

__all__ = ["ResponseCurve", "Linearity", "recover_response", "power_slope", "linearity", "linearize"]


@dataclass(frozen=True)
class ResponseCurve:
    """Inverse camera response per channel.

    Attributes
    ----------
    codes : (n,) float64
        Code values ``i / (n - 1)``, as fractions of full scale in [0, 1].
    linear : (n, C) float64
        Linear exposure (relative; 1.0 at full scale) for each code value.
    log_sigma : (n, C) float64 or None
        Standard error of ``ln linear`` (from independent recoveries), or None.
    support : (n,) float64 or None
        Data weight per code bin (sum of the hat weights of the samples read there), or None.
    """

    codes: np.ndarray
    linear: np.ndarray
    log_sigma: np.ndarray | None = None
    support: np.ndarray | None = None


@dataclass(frozen=True)
class Linearity:
    """How far a recovered response departs from a straight line through 0, against its own uncertainty.

    Attributes
    ----------
    linear : bool
        True if the departure is within the uncertainty (``rms_z <= threshold``).
    rms_z : float
        RMS over well-supported codes and channels of (departure / standard error).
    max_departure : float
        Largest ``|linear(z) / (s z) - 1|`` over those codes (``s`` fitted per channel).
    """

    linear: bool
    rms_z: float
    max_departure: float

    def describe(self) -> str:
        verdict = "linear within its uncertainty" if self.linear else "not linear"
        return (f"recovered response {verdict} (departure from a straight line up to "
                f"{100 * self.max_departure:.2g}%, {self.rms_z:.2g} standard errors RMS)")


def _hat(levels: int) -> np.ndarray:
    """Debevec's hat weight per bin, 0 for the first and last bins (clipped black and saturated codes)."""
    i = np.arange(levels)
    return np.minimum(i, levels - 1 - i) / (levels / 2)


def _sample_pixels(frames: list[np.ndarray], times: np.ndarray, n_samples: int, rng) -> np.ndarray:
    """Pixel indices spread over the code-value range of the median-exposure frame (all channels)."""
    ref = frames[int(np.argsort(times)[len(times) // 2])]
    grey = ref.reshape(-1, ref.shape[-1]).mean(axis=1)
    order = np.argsort(grey, kind="stable")
    # Evenly spaced ranks: every brightness of the reference is represented, with a random jitter.
    ranks = np.linspace(0, len(order) - 1, n_samples)
    jitter = rng.uniform(-0.5, 0.5, n_samples) * (len(order) / n_samples)
    return order[np.clip(np.round(ranks + jitter).astype(int), 0, len(order) - 1)]


def _solve_channel(z: np.ndarray, log_t: np.ndarray, levels: int, lam: float, slope: float
                   ) -> tuple[np.ndarray, np.ndarray]:
    """``g`` (levels,) and the data weight per bin for code values ``z`` (N, K) of one channel.

    The per-pixel unknowns ``ln E_i`` are eliminated (each is the weighted mean of its frames'
    ``g(z_ij) - ln t_j``), which leaves a dense ``levels x levels`` system for ``g``.
    """
    from scipy.linalg import cho_factor, cho_solve
    from threadpoolctl import threadpool_limits
    from scipy.sparse import coo_matrix, diags

    pos = z * (levels - 1)
    i0 = np.minimum(np.floor(pos).astype(int), levels - 2)
    frac = pos - i0
    w = np.minimum(pos, levels - 1 - pos) / (levels / 2)  # the hat, read at the exact code value
    keep = w.sum(axis=1) > 0  # pixels black or saturated in every frame carry no information
    i0, frac, w = i0[keep], frac[keep], w[keep]
    n, k = i0.shape
    if n * (k - 1) <= levels // 4:
        raise InputError(f"response: only {n} sampled pixels are neither black nor saturated in every frame: "
                         "too little data to recover a response (give --response linear if the frames are linear)")
    rows = np.repeat(np.arange(n * k), 2)
    interp = coo_matrix((np.stack([1 - frac, frac], axis=-1).ravel(), (rows, np.stack([i0, i0 + 1], -1).ravel())),
                        shape=(n * k, levels)).tocsr()  # g(z_ij) = interp @ g
    u = w * w / (w * w).sum(axis=1, keepdims=True)  # weights of the per-pixel mean
    mean = coo_matrix((u.ravel(), (np.repeat(np.arange(n), k), np.arange(n * k))), shape=(n, n * k)).tocsr()
    x_t = np.tile(log_t, n)
    # Residual w_ij [(g(z_ij) - ln t_j) - mean_i(g(z) - ln t)]: B g - c.
    b = diags(w.ravel()) @ (interp - _expand(mean @ interp, k))
    c = w.ravel() * (x_t - np.repeat(mean @ x_t, k))
    normal = (b.T @ b).toarray()
    rhs = b.T @ c
    # Smoothness of h = g - slope ln z: lam s(z) (g[z-1] - 2 g[z] + g[z+1]) = lam s(z) slope (2nd difference of ln z).
    ln_code = np.log(np.maximum(np.arange(levels), 0.5) / (levels - 1))
    zz = np.arange(1, levels - 1)
    s = lam * (_hat(levels)[zz] + 1.0 / levels)  # also at the unweighted end bins, which it extrapolates
    d2 = coo_matrix((np.repeat(s, 3) * np.tile([1.0, -2.0, 1.0], levels - 2),
                     (np.repeat(np.arange(levels - 2), 3), np.stack([zz - 1, zz, zz + 1], axis=1).ravel())),
                    shape=(levels - 2, levels)).tocsr()
    normal += (d2.T @ d2).toarray()
    rhs += d2.T @ (s * slope * (ln_code[zz - 1] - 2 * ln_code[zz] + ln_code[zz + 1]))
    normal[levels // 2, levels // 2] += 1.0  # anchor g(mid) = 0 (the data fix g up to a constant)
    with threadpool_limits(limits=1, user_api="blas"):  # a 1024^2 solve: threads only contend
        g = cho_solve(cho_factor(normal), rhs)  # symmetric positive definite
    support = np.bincount(i0.ravel(), (w * (1 - frac)).ravel(), levels) + np.bincount(i0.ravel() + 1,
                                                                                     (w * frac).ravel(), levels)
    return np.maximum.accumulate(g), support  # a response is monotonic


def _expand(per_pixel, k: int):
    """Repeat each row of a sparse (n, m) matrix k times: (n k, m)."""
    return per_pixel[np.repeat(np.arange(per_pixel.shape[0]), k)]


def recover_response(
    frames: Sequence[np.ndarray],
    times: Sequence[float],
    *,
    levels: int = 1024,
    n_samples: int | None = None,
    smoothness: float = 10.0,
    slope: float = 1.0,
    seed: int = 0,
) -> ResponseCurve:
    """Recover the inverse response of a non-linear camera from a bracket (Debevec & Malik 1997).

    Parameters
    ----------
    frames : sequence of K (H, W, C) arrays
        Code values as fractions of full scale in [0, 1] (e.g. from
        :func:`brdfrig.hdr.raw.read_frame`), static scene, same shape.
    times : (K,) float
        Exposure times in seconds.
    levels : int
        Number of code-value bins the curve is solved on (256 suits 8-bit data).
    n_samples : int, optional
        Pixels sampled per subset; the curve is recovered from 6 disjoint
        subsets (their mean is the curve, their spread its uncertainty).
        Default ``max(200, 32 levels / (6 K))`` (about 32 samples per bin in
        all); needs ``n_samples * (K - 1) > levels``.
    smoothness : float
        Weight ``lambda`` of the second-difference smoothness term (scaled by ``levels / 256``).
    slope : float
        The smoothness term pulls ``g`` towards ``slope * ln z`` (plus an
        affine function of ``z``): 1 = a linear response, 2.2 = a gamma-2.2
        camera (:func:`power_slope` estimates it from a first recovery).
    seed : int
        Seed of the pixel sampling jitter.

    Returns
    -------
    ResponseCurve
        With ``log_sigma`` and ``support`` (see :func:`linearity`).
    """
    frames = [np.asarray(f) for f in frames]
    frames = [f[:, :, None] if f.ndim == 2 else f for f in frames]
    times = np.asarray(times, dtype=float)
    if len(frames) < 2 or len(times) != len(frames):
        raise InputError(f"response: need >= 2 frames with one exposure time each, got {len(frames)} frames "
                         f"and {len(times)} times (give --response linear for linear frames)")
    if any(f.shape != frames[0].shape for f in frames):
        raise InputError("response: the frames of a bracket must have one shape")
    k = len(frames)
    per = max(200, -(-32 * levels // (_SPLITS * k))) if n_samples is None else int(n_samples)
    if per * (k - 1) <= levels:
        raise InputError(f"response: n_samples * (K - 1) = {per * (k - 1)} must exceed levels = {levels}: sample "
                         f"more pixels (n_samples > {levels // (k - 1)}), shoot more frames, or give "
                         "--response linear if the frames are linear")
    pix = _sample_pixels(frames, times, per * _SPLITS, np.random.default_rng(seed))
    nch = frames[0].shape[-1]
    g = np.empty((_SPLITS, levels, nch))
    support = np.zeros(levels)
    for c in range(nch):
        z_all = np.stack([np.clip(np.asarray(f.reshape(-1, nch)[pix, c], np.float64), 0, 1) for f in frames], axis=1)
        for j in range(_SPLITS):  # disjoint subsets, each spread over every brightness
            g[j, :, c], sup = _solve_channel(z_all[j::_SPLITS], np.log(times), levels, smoothness * levels / 256.0,
                                             slope)
            support += sup
    g -= g[:, -1:, :]
    log_sigma = _smooth(g.std(axis=0, ddof=1) / np.sqrt(_SPLITS), 16)
    return ResponseCurve(codes=np.arange(levels) / (levels - 1), linear=np.exp(g.mean(axis=0)),
                         log_sigma=log_sigma, support=support)


def power_slope(curve: ResponseCurve, codes: tuple[float, float] = (0.02, 0.95)) -> float:
    """Exponent ``p`` of the power law ``linear = z^p`` closest to a recovered curve (all channels, ``codes`` range)."""
    sel = (curve.codes >= codes[0]) & (curve.codes < codes[1])
    x = np.log(curve.codes[sel])
    y = np.log(curve.linear[sel]).mean(axis=1)
    return float(np.polyfit(x, y, 1)[0])


def _smooth(x: np.ndarray, half_width: int) -> np.ndarray:
    """RMS of ``x`` (n, C) over a sliding window of ``2 half_width + 1`` bins (shorter at the ends)."""
    c = np.cumsum(np.pad(x * x, ((1, 0), (0, 0))), axis=0)
    i = np.arange(len(x))
    lo, hi = np.maximum(i - half_width, 0), np.minimum(i + half_width + 1, len(x))
    return np.sqrt((c[hi] - c[lo]) / (hi - lo)[:, None])


def linearity(curve: ResponseCurve, *, threshold: float = 3.0, min_support: float = 0.1,
              codes: tuple[float, float] = (0.02, 0.95)) -> Linearity:
    """Test a recovered response against a straight line through 0, relative to its uncertainty.

    Per channel, ``ln linear(z) - ln z`` is fitted by a constant over the
    codes the data supports (bins whose data weight is at least
    ``min_support`` of the median bin's) within ``codes``; the departure from
    that constant, divided by the curve's standard error ``log_sigma``, is
    the z-score.  Codes below 2% of full scale are left out: there the
    noise of a sample is comparable to its value and the least-squares curve
    reads ``E[ln exposure | code]``, which bends away from ``ln code`` for
    any response (-8% at code 0.001 for a linear 16-bit camera with 20000
    electrons at full scale).

    Parameters
    ----------
    curve : ResponseCurve
        From :func:`recover_response` (with ``log_sigma`` and ``support``).
    threshold : float
        Largest RMS z-score of a linear response.
    codes : (lo, hi)
        Code range tested, fractions of full scale.
    min_support : float
        Support cut, as a fraction of the median bin's data weight.

    Returns
    -------
    Linearity
    """
    if curve.log_sigma is None or curve.support is None:
        raise ValueError("linearity: the curve has no uncertainty (recover it with recover_response)")
    sup = curve.support
    sel = (sup >= min_support * np.median(sup[sup > 0])) & (curve.codes >= codes[0]) & (curve.codes < codes[1])
    if np.count_nonzero(sel) < 8:
        raise InputError("response: the bracket has too few well-exposed values to test its response for "
                         "linearity; give --response linear or --response recover")
    h = np.log(curve.linear[sel]) - np.log(curve.codes[sel])[:, None]
    sigma = np.maximum(curve.log_sigma[sel], 1e-6)
    wt = 1 / sigma**2
    h = h - (h * wt).sum(axis=0) / wt.sum(axis=0)
    rms_z = float(np.sqrt(np.mean((h / sigma) ** 2)))
    return Linearity(rms_z <= threshold, rms_z, float(np.abs(np.expm1(h)).max()))


def linearize(image: np.ndarray, curve: ResponseCurve) -> np.ndarray:
    """Map code values (fractions of full scale) to linear exposure through an inverse response.

    Parameters
    ----------
    image : (H, W, C) array
        Code values in [0, 1].
    curve : ResponseCurve
        With C channels (or 1, applied to every channel).

    Returns
    -------
    (H, W, C) float32
        Linear values, 1.0 at full scale.
    """
    image = np.asarray(image, dtype=np.float64)
    out = np.empty(image.shape, np.float32)
    nch = image.shape[-1]
    if curve.linear.shape[1] not in (1, nch):
        raise ValueError(f"linearize: curve has {curve.linear.shape[1]} channels, image has {nch}")
    for c in range(nch):
        lin = curve.linear[:, c if curve.linear.shape[1] > 1 else 0]
        out[..., c] = np.interp(image[..., c], curve.codes, lin)
    return out
