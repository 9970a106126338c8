"""Constrained linear least-squares solves.

The first two are the closed-form inner step of the variable-projection fits; they reduce a tall problem
``min |A x - b|`` (A: M x K, K small) to its K x K triangle first (QR: the same minimiser, residual recovered
exactly).

- :func:`box_lsq`: ``lower <= x <= upper`` (bounded-variable least squares, scipy's BVLS);
- :func:`polytope_lsq`: ``G x <= h`` for a handful of constraints, exactly, by trying every active set
  of at most K constraints (the optimum is the best feasible equality-constrained minimiser of one of
  them when ``A`` has full column rank).

- :func:`nnls_normal`: ``x >= 0`` for a problem given by its normal equations ``H x = b`` (the bivariate
  table's hundreds of node values), by block principal pivoting, scipy's ``nnls`` where that cycles.
"""

from __future__ import annotations

import itertools

import numpy as np
from scipy.linalg import cho_factor, cho_solve, solve_triangular
from scipy.optimize import lsq_linear, nnls

__all__ = ["box_lsq", "polytope_lsq", "nnls_normal", "NNLS_RTOL", "NNLS_MAX_SOLVES"]

NNLS_RTOL = 1e-12
"""A held unknown may have a gradient down to ``-NNLS_RTOL max |b|`` (:func:`nnls_normal`; scipy's ``nnls`` reaches
about 1e-12 on the bivariate table's problems)."""
NNLS_MAX_SOLVES = 50
"""Free-block solves of :func:`nnls_normal` before it hands the problem to scipy's ``nnls`` (the table's problems
take at most 22 on rgl/satin_purple and rgl/cc_amber_citrine)."""


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


def nnls_normal(h: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``argmin x^T H x - 2 b^T x`` subject to ``x >= 0``, ``H`` (K, K) symmetric positive definite, ``b`` (K,).

    Block principal pivoting (Portugal, Judice & Vicente 1994; Kim & Park 2011): the unknowns are split into a
    free set, solved from ``H_FF x_F = b_F``, and a set held at 0; every free unknown that comes out negative and
    every held one whose gradient ``(H x - b)_j`` is below ``-NNLS_RTOL max |b|`` changes sides at once, until
    none does (the optimality conditions).  When a swap of all of them fails to shrink the count of violations
    three times running, only the violating unknown of largest index changes sides (Murty's rule).  It starts
    from all unknowns free (the unconstrained minimiser) and takes a median of 5 (rgl/satin_purple) to 12
    (rgl/cc_amber_citrine) Cholesky solves of the free block on the bivariate tables' problems (384 and 768
    unknowns), where scipy's Lawson-Hanson ``nnls`` adds one unknown per step.  Murty's rule terminates but may
    take exponentially many steps: on nearly collinear columns with a sparse solution (a reference prior's 150
    unit-energy tables) the pivoting can cycle through hundreds of sets, so after :data:`NNLS_MAX_SOLVES` solves
    the problem goes to scipy's ``nnls`` on the Cholesky factor of ``H`` instead.

    Returns
    -------
    x : (K,) float64
        The minimiser, >= 0.
    """
    h = np.asarray(h, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    k = len(b)
    free = np.ones(k, dtype=bool)
    best, tries = k + 1, 3
    b_tol = NNLS_RTOL * max(float(np.abs(b).max(initial=0.0)), 1e-300)
    for _ in range(NNLS_MAX_SOLVES):
        x = np.zeros(k)
        if free.any():
            x[free] = cho_solve(cho_factor(h[np.ix_(free, free)]), b[free])
        grad = h @ x - b
        bad = (free & (x < 0.0)) | (~free & (grad < -b_tol))
        count = int(bad.sum())
        if count == 0:
            return x
        if count < best:
            best, tries = count, 3
        elif tries > 0:
            tries -= 1
        else:
            bad = np.arange(k) == np.flatnonzero(bad).max()
        free ^= bad
    low = np.linalg.cholesky(h)
    return nnls(low.T, solve_triangular(low, b, lower=True), maxiter=50 * k)[0]
