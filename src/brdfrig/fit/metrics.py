"""Error measures shared by the fitter, the pipeline and the benchmarks."""

from __future__ import annotations

import numpy as np

__all__ = ["relative_rms", "relative_spread"]


def relative_rms(pred, truth, weights=None) -> float:
    """Relative RMS error ``sqrt(sum w (pred - truth)^2 / sum w truth^2)`` over pixels and channels.

    Parameters
    ----------
    pred, truth : (N, C) array_like
        Predicted and reference radiance.
    weights : (N,) array_like or None
        Per-pixel weights (None: all 1).

    Returns
    -------
    float
        0 for a perfect prediction; ``inf`` when the reference is all zero but the prediction is not.
    """
    pred = np.asarray(pred, dtype=np.float64)
    truth = np.asarray(truth, dtype=np.float64)
    w = np.ones(len(truth)) if weights is None else np.asarray(weights, dtype=np.float64)
    num = float(np.sum(w[:, None] * (pred - truth) ** 2))
    den = float(np.sum(w[:, None] * truth**2))
    if den == 0.0:
        return 0.0 if num == 0.0 else float("inf")
    return float(np.sqrt(num / den))


def relative_spread(preds, weights) -> float:
    """Relative RMS spread of several predictions about their mean.

    ``sqrt(mean_b sum_n w_n |p_b(n) - m(n)|^2 / sum_n w_n |m(n)|^2)`` with ``m = mean_b p_b``, channels summed; 0 for
    a dark mean.

    Parameters
    ----------
    preds : (B, N, C) array_like
        B predictions of the radiance of N pixels.
    weights : (N,) array_like
        Per-pixel weights.
    """
    preds = np.asarray(preds, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    mean = preds.mean(axis=0)
    energy = float(np.einsum("nc,n->", mean**2, w))
    spread = float(np.einsum("bnc,n->", (preds - mean) ** 2, w)) / len(preds)
    return float(np.sqrt(spread / energy)) if energy > 0 else 0.0
