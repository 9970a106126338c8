"""Non-negative least squares on normal equations (brdfrig.fit.lsq.nnls_normal) against scipy's Lawson-Hanson
``nnls`` on the matrix form and against closed forms."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import nnls

from brdfrig.fit.lsq import nnls_normal


def _problem(rows: int, cols: int, shift: float, seed: int):
    rng = np.random.default_rng(seed)
    a = rng.standard_normal((rows, cols)) @ np.diag(np.exp(rng.uniform(-2.0, 2.0, cols)))
    y = rng.standard_normal(rows) + shift
    return a, y


@pytest.mark.parametrize("rows,cols,shift,seed", [(40, 10, 0.0, 0), (400, 200, 0.0, 1), (400, 200, -0.5, 2),
                                                  (900, 768, 0.3, 3), (60, 50, 0.0, 4)])
def test_matches_scipy_lawson_hanson(rows, cols, shift, seed):
    """Same minimiser as scipy's ``nnls(A, y)`` for ``H = A^T A``, ``b = A^T y`` (rel 1e-7 of the largest value),
    with a part of the unknowns at 0 in each case."""
    a, y = _problem(rows, cols, shift, seed)
    want, _ = nnls(a, y, maxiter=50 * cols)
    got = nnls_normal(a.T @ a, a.T @ y)
    assert 0 < np.count_nonzero(want) < cols
    assert np.all(got >= 0)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-7 * np.abs(want).max())


def test_optimality_conditions():
    """x >= 0, gradient ``H x - b >= 0`` where x = 0 and 0 where x > 0 (to 1e-9 of |b|)."""
    a, y = _problem(300, 120, -0.2, 5)
    h, b = a.T @ a, a.T @ y
    x = nnls_normal(h, b)
    grad = h @ x - b
    tol = 1e-9 * np.abs(b).max()
    assert np.all(x >= 0)
    assert np.all(grad[x == 0] >= -tol)
    assert np.all(np.abs(grad[x > 0]) <= tol)


def test_diagonal_closed_form():
    """A diagonal H separates the unknowns: ``x = max(b / d, 0)``."""
    rng = np.random.default_rng(6)
    d, b = rng.uniform(0.1, 10.0, 30), rng.standard_normal(30)
    np.testing.assert_allclose(nnls_normal(np.diag(d), b), np.maximum(b / d, 0.0), rtol=1e-12, atol=0)


def test_unconstrained_interior_and_all_bound():
    """A positive unconstrained minimiser is returned as it is; ``b <= 0`` under a positive H gives 0."""
    rng = np.random.default_rng(7)
    m = rng.uniform(0.5, 1.0, (20, 20))
    h = m @ m.T + 20 * np.eye(20)
    x0 = rng.uniform(0.1, 1.0, 20)
    np.testing.assert_allclose(nnls_normal(h, h @ x0), x0, rtol=1e-10)
    assert np.array_equal(nnls_normal(h, -rng.uniform(0.0, 1.0, 20)), np.zeros(20))


def _collinear_positive(seed: int):
    """150 unit columns mixed from 6 non-negative profiles plus 0.1% noise (like the reference prior's tables):
    nearly collinear, with fewer than half the unknowns free at the solution."""
    rng = np.random.default_rng(seed)
    base = np.abs(rng.standard_normal((400, 6)))
    a = base @ rng.uniform(0.0, 1.0, (6, 150)) + 0.001 * np.abs(rng.standard_normal((400, 150)))
    a /= np.linalg.norm(a, axis=0)
    gram = a.T @ a + 1e-6 * np.eye(150)
    return a, base @ rng.uniform(0.0, 1.0, 6), gram


@pytest.mark.parametrize("seed,cycles", [(4, True), (1, False)])
def test_cycling_pivots_hand_over_to_scipy(seed, cycles, monkeypatch):
    """On nearly collinear columns the pivoting can cycle (seed 4 takes more than NNLS_MAX_SOLVES solves, seed 1
    a handful): then scipy's ``nnls`` solves it; either way the minimiser of the ridge problem, checked against
    scipy on the stacked matrix ``[A; sqrt(1e-6) I]`` (atol 1e-6 of the largest value)."""
    import brdfrig.fit.lsq as lsq

    calls = []
    monkeypatch.setattr(lsq, "nnls", lambda *args, **kw: calls.append(1) or nnls(*args, **kw))
    a, y, gram = _collinear_positive(seed)
    got = lsq.nnls_normal(gram, a.T @ y)
    want, _ = nnls(np.vstack([a, 1e-3 * np.eye(150)]), np.r_[y, np.zeros(150)], maxiter=7500)
    assert len(calls) == int(cycles)
    assert np.all(got >= 0) and 0 < np.count_nonzero(want) < 75
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-6 * np.abs(want).max())
