"""Camera response recovery (Debevec & Malik 1997) for non-linear 8- or 16-bit brackets, and linearisation.

A JPEG or a developed 16-bit TIFF stores ``Z = f(X t)`` with an unknown
monotonic response ``f``.  Debevec & Malik ("Recovering high dynamic range
radiance maps from photographs", SIGGRAPH 1997) recover ``g = ln f^-1`` from
the bracket itself by least squares over sampled pixels::

    minimise  sum_ij [w(Z_ij) (g(Z_ij) - ln E_i - ln t_j)]^2 + lambda sum_z [w(z) g''(z)]^2

Hand-written (with a sparse least-squares solve) because OpenCV's
``CalibrateDebevec`` only accepts 8-bit images: here the code values are
binned to ``levels`` bins whatever the bit depth, so one solver serves JPEG
(256 levels) and 16-bit TIFF (1024 bins by default).  The tests check it
against OpenCV's calibration on 8-bit data.

The recovered curve is normalised so that full scale (code value 1.0)
maps to linear 1.0: linearised frames are then in the units
:func:`brdfrig.hdr.merge.merge_bracket` expects (``saturation=1``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from brdfrig.errors import InputError
__all__ = ["ResponseCurve", "recover_response", "linearize"]


@dataclass(frozen=True)
class ResponseCurve:
    """Inverse camera response per channel.

    Attributes
    ----------
    codes : (n,) float64
        Code values ``i / (n - 1)``, as fractions of full scale in [0, 1].
    linear : (n, C) float64
        Linear exposure (relative; 1.0 at full scale) for each code value.
    """

    codes: np.ndarray
    linear: np.ndarray


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


def recover_response(
    frames: Sequence[np.ndarray],
    times: Sequence[float],
    *,
    levels: int = 1024,
    n_samples: int = 600,
    smoothness: float = 10.0,
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
    n_samples : int
        Number of pixels sampled; needs ``n_samples * (K - 1) > levels``.
    smoothness : float
        Weight ``lambda`` of the second-difference smoothness term (scaled by ``levels``).
    seed : int
        Seed of the pixel sampling jitter.

    Returns
    -------
    ResponseCurve
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.linalg import spsolve

    frames = [np.asarray(f, dtype=np.float64) for f in frames]
    frames = [f[:, :, None] if f.ndim == 2 else f for f in frames]
    times = np.asarray(times, dtype=float)
    if len(frames) < 2 or len(times) != len(frames):
        raise InputError(f"response: need >= 2 frames with one exposure time each, got {len(frames)} frames "
                         f"and {len(times)} times")
    if any(f.shape != frames[0].shape for f in frames):
        raise ValueError("response: the frames of a bracket must have one shape")
    if n_samples * (len(frames) - 1) <= levels:
        raise InputError(f"response: n_samples * (K - 1) = {n_samples * (len(frames) - 1)} must exceed "
                         f"levels = {levels}")
    rng = np.random.default_rng(seed)
    codes = np.arange(levels) / (levels - 1)
    weight = _hat(levels)
    # Smoothness everywhere, also at the unweighted end bins, which it extrapolates.
    smooth = weight + 1.0 / levels
    pix = _sample_pixels(frames, times, n_samples, rng)
    nch = frames[0].shape[-1]
    lam = smoothness * levels / 256.0
    log_t = np.log(times)
    curves = np.empty((levels, nch))
    for c in range(nch):
        z = np.stack([np.clip(f.reshape(-1, nch)[pix, c], 0, 1) for f in frames], axis=1)  # (N, K)
        zi = np.rint(z * (levels - 1)).astype(int)
        zi = zi[weight[zi].sum(axis=1) > 0]  # pixels black or saturated in every frame carry no information
        n, k = zi.shape
        if n * (k - 1) <= levels // 4:
            raise InputError(f"response: only {n} sampled pixels are neither black nor saturated in every frame")
        rows_d = np.arange(n * k)
        w = weight[zi].ravel()
        # Data rows: w (g[z] - lnE_i) = w ln t_j.  Unknowns: g (levels) then lnE (n).
        r = [rows_d, rows_d]
        cidx = [zi.ravel(), levels + np.repeat(np.arange(n), k)]
        vals = [w, -w]
        rhs = [w * np.tile(log_t, n)]
        # Anchor g(mid) = 0.
        row0 = n * k
        r.append(np.array([row0]))
        cidx.append(np.array([levels // 2]))
        vals.append(np.array([1.0]))
        rhs.append(np.array([0.0]))
        # Smoothness rows: lam w(z) (g[z-1] - 2 g[z] + g[z+1]) = 0.
        zz = np.arange(1, levels - 1)
        rows_s = row0 + 1 + np.repeat(np.arange(levels - 2), 3)
        r.append(rows_s)
        cidx.append(np.stack([zz - 1, zz, zz + 1], axis=1).ravel())
        vals.append((lam * smooth[zz][:, None] * np.array([1.0, -2.0, 1.0])).ravel())
        rhs.append(np.zeros(levels - 2))
        a = coo_matrix((np.concatenate(vals), (np.concatenate(r), np.concatenate(cidx))),
                       shape=(row0 + 1 + levels - 2, levels + n)).tocsr()
        # Normal equations of a small, well-posed sparse system (anchor + smoothness): a direct solve.
        sol = spsolve((a.T @ a).tocsc(), a.T @ np.concatenate(rhs))
        g = np.maximum.accumulate(sol[:levels])  # a response is monotonic
        curves[:, c] = np.exp(g - g[-1])
    return ResponseCurve(codes=codes, linear=curves)


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
