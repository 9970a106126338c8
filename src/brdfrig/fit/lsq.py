"""Small constrained linear least-squares solves: the closed-form inner step of the variable-projection fits.

Both reduce a tall problem ``min |A x - b|`` (A: M x K, K small) to its K x K triangle first (QR: the same
minimiser, residual recovered exactly).

- :func:`box_lsq`: ``lower <= x <= upper`` (bounded-variable least squares, scipy's BVLS);
- :func:`polytope_lsq`: ``G x <= h`` for a handful of constraints, exactly, by trying every active set
  of at most K constraints (the optimum is the best feasible equality-constrained minimiser of one of
  them when ``A`` has full column rank).
"""

from __future__ import annotations

import itertools

import numpy as np
from scipy.optimize import lsq_linear

__all__ = ["box_lsq", "polytope_lsq"]


def _triangle(cols: np.ndarray, target: np.ndarray):
    """Column scales, R and Q^T b of the scaled columns, and |b|^2 - |Q^T b|^2 (the unreachable residual)."""
    scale = np.maximum(np.linalg.norm(cols, axis=0), 1e-300)
    q, r = np.linalg.qr(cols / scale)
    qt = q.T @ target
    return scale, r, qt, max(float(target @ target - qt @ qt), 0.0)


def box_lsq(cols: np.ndarray, target: np.ndarray, lower, upper) -> tuple[float, np.ndarray]:
    """``min |cols x - target|^2`` subject to ``lower <= x <= upper``.

    Parameters
    ----------
    cols : (M, K) array
    target : (M,) array
    lower, upper : (K,) array_like
        Bounds with ``lower < upper`` (use +-inf for none).

    Returns
    -------
    (squared residual, x (K,)).
    """
    cols = np.asarray(cols, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    if not np.any(cols):
        x = np.clip(np.zeros(cols.shape[1]), lower, upper)
        return float(np.sum((cols @ x - target) ** 2)), x
    scale, r, qt, rest = _triangle(cols, target)
    res = lsq_linear(r, qt, bounds=(np.asarray(lower) * scale, np.asarray(upper) * scale), method="bvls")
    x = res.x / scale
    return float(np.sum((cols @ x - target) ** 2)), x


def polytope_lsq(cols: np.ndarray, target: np.ndarray, g: np.ndarray, h: np.ndarray) -> tuple[float, np.ndarray]:
    """``min |cols x - target|^2`` subject to ``g x <= h`` (a few constraints; exact, see module docstring).

    Returns (squared residual, x (K,)); x = 0 projected feasible is not attempted: ``g 0 <= h`` must hold
    (every caller's constraints contain the origin), which keeps at least one candidate feasible.
    """
    cols = np.asarray(cols, dtype=np.float64)
    g = np.asarray(g, dtype=np.float64)
    h = np.asarray(h, dtype=np.float64)
    k = cols.shape[1]
    scale, r, qt, rest = _triangle(cols, target) if np.any(cols) else (np.ones(k), np.zeros((k, k)), np.zeros(k), 0.0)
    gs = g / scale  # constraints on the scaled variable y = scale * x
    gram, rhs = r.T @ r, r.T @ qt
    best = (np.inf, np.zeros(k))
    for m in range(min(k, len(h)) + 1):
        for active in itertools.combinations(range(len(h)), m):
            act = list(active)
            kkt = np.zeros((k + m, k + m))
            kkt[:k, :k] = gram
            kkt[:k, k:], kkt[k:, :k] = gs[act].T, gs[act]
            sol = np.linalg.lstsq(kkt, np.r_[rhs, h[act]], rcond=None)[0][:k]
            if np.all(gs @ sol <= h + 1e-10 * (1 + np.abs(h))):
                r2 = float(np.sum((r @ sol - qt) ** 2))
                if r2 < best[0]:
                    best = (r2, sol)
    x = best[1] / scale
    return float(np.sum((cols @ x - target) ** 2)), x
