"""Error measures shared by the fitter, the pipeline and the benchmarks."""

from __future__ import annotations

import numpy as np

__all__ = ["relative_rms"]


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
