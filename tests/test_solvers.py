"""Solvers on generic matrices: streamed QR against dense numpy oracles."""

from __future__ import annotations

import math

import numpy as np
import pytest

from brdfrig.fit.solvers import StreamedQR, solve


def _stream(a: np.ndarray, b: np.ndarray, w: np.ndarray, sizes=(7, 300, 1, 64)) -> StreamedQR:
    """Fold (m, n, C) rows into a StreamedQR in irregular blocks."""
    qr = StreamedQR(a.shape[1], a.shape[2])
    start, i = 0, 0
    while start < a.shape[0]:
        stop = start + sizes[i % len(sizes)]
        qr.add(a[start:stop], b[start:stop], w[start:stop])
        start, i = stop, i + 1
    return qr


def _problem(m=900, n=12, c=2, seed=0, noise=1e-3):
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(m, n, c)) * np.logspace(0, 3, n)[None, :, None]  # columns of very different scale
    x = rng.normal(size=(n, c))
    b = np.einsum("mnc,nc->mc", a, x) + noise * rng.normal(size=(m, c))
    w = rng.uniform(0.2, 1.0, size=m)
    w[::17] = 0.0
    return a, b, w, x


def _dense(a, b, w, c):
    sw = np.sqrt(w)
    return a[:, :, c] * sw[:, None], b[:, c] * sw


def test_joint_matches_dense_weighted_lstsq():
    a, b, w, _ = _problem()
    sol = solve(_stream(a, b, w), "joint")
    for c in range(a.shape[2]):
        ad, bd = _dense(a, b, w, c)
        ref = np.linalg.lstsq(ad, bd, rcond=None)[0]
        np.testing.assert_allclose(sol.x[:, c], ref, rtol=1e-9, atol=1e-12)
        assert sol.rank[c] == a.shape[1]
        ref_res = np.sum((ad @ ref - bd) ** 2)
        assert sol.residual[c] == pytest.approx(ref_res, rel=1e-6)
        # condition number of the column-equilibrated matrix
        s = np.linalg.svd(ad / np.linalg.norm(ad, axis=0), compute_uv=False)
        assert sol.cond[c] == pytest.approx(s[0] / s[-1], rel=1e-8)


def test_joint_rank_deficient_is_minimum_norm_and_reports_rank():
    a, b, w, _ = _problem(n=8, c=1)
    a[:, 5] = a[:, 2]  # duplicate column (same scale): rank 7
    sol = solve(_stream(a, b, w), "joint")
    ad, bd = _dense(a, b, w, 0)
    d = np.linalg.norm(ad, axis=0)
    ref = np.linalg.pinv(ad / d) @ bd / d  # minimum norm in equilibrated variables
    np.testing.assert_allclose(sol.x[:, 0], ref, rtol=1e-7, atol=1e-10)
    assert sol.rank[0] == 7
    assert np.isinf(sol.cond[0])


def test_prior_fills_the_null_space():
    a, b, w, _ = _problem(n=6, c=1)
    a[:, 4] = 0.0  # unknown 4 never observed
    x0 = np.arange(6, dtype=float)[:, None] + 10.0
    sol = solve(_stream(a, b, w), "joint", x0=x0)
    assert sol.x[4, 0] == pytest.approx(14.0, abs=1e-12)
    ad, bd = _dense(a, b, w, 0)
    keep = [0, 1, 2, 3, 5]
    ref = np.linalg.lstsq(ad[:, keep], bd, rcond=None)[0]
    np.testing.assert_allclose(sol.x[keep, 0], ref, rtol=1e-8)


def test_paper_is_the_seed_band_by_band_algorithm():
    a, b, w, x_true = _problem(n=9, c=2)
    bands = np.repeat(np.arange(3), 3)
    sol = solve(_stream(a, b, w), "paper", bands=bands)
    for c in range(2):
        ad, bd = _dense(a, b, w, c)
        res, ref = bd.copy(), np.zeros(9)
        for l in range(3):  # seed 3.6: solve A_l x_l = b by normal equations, b -= A_l x_l
            cols = bands == l
            al = ad[:, cols]
            ref[cols] = np.linalg.inv(al.T @ al) @ al.T @ res
            res -= al @ ref[cols]
        np.testing.assert_allclose(sol.x[:, c], ref, rtol=1e-6)
    # Non-orthogonal blocks: the one-sweep solve is biased, the joint solve is not.
    joint = solve(_stream(a, b, w), "joint")
    assert np.linalg.norm(joint.x - x_true) < 0.1 * np.linalg.norm(sol.x - x_true)


def test_tikhonov_matches_closed_form_and_beats_joint_on_ill_posed_problem():
    rng = np.random.default_rng(3)
    m, n = 400, 12
    t = np.linspace(0, 1, m)
    a = np.stack([t**k for k in range(n)], axis=1)[:, :, None]  # monomials: cond ~ 1e8 after equilibration
    x_true = np.zeros((n, 1))
    x_true[:3, 0] = [1.0, -2.0, 1.5]
    b = np.einsum("mnc,nc->mc", a, x_true) + 1e-3 * rng.normal(size=(m, 1))
    w = np.ones(m)
    qr = _stream(a, b, w)
    tik = solve(qr, "tikhonov")
    # oracle with the chosen lambda: augmented least squares [A/D; lam I] y = [b; 0], x = y / D
    d = np.linalg.norm(a[:, :, 0], axis=0)
    s_max = np.linalg.svd(a[:, :, 0] / d, compute_uv=False)[0]
    lam = tik.lam[0] * s_max
    ad = a[:, :, 0] / d
    y = np.linalg.lstsq(np.vstack([ad, lam * np.eye(n)]), np.concatenate([b[:, 0], np.zeros(n)]), rcond=None)[0]
    np.testing.assert_allclose(tik.x[:, 0], y / d, rtol=1e-6, atol=1e-9)
    assert tik.lam[0] > 0
    # prediction error on a fine grid: regularised no worse than the truncated joint solve
    joint = solve(qr, "joint")
    tt = np.linspace(0, 1, 2000)
    g = np.stack([tt**k for k in range(n)], axis=1)
    err = lambda x: np.linalg.norm(g @ (x[:, 0] - x_true[:, 0]))
    assert err(tik.x) <= 1.05 * err(joint.x)
    assert err(tik.x) < 0.01 * np.linalg.norm(g @ x_true[:, 0])


@pytest.mark.parametrize("solver", ["paper", "joint", "tikhonov"])
def test_all_zero_system_gives_finite_zero(solver):
    a = np.zeros((50, 4, 3))
    b = np.zeros((50, 3))
    sol = solve(_stream(a, b, np.ones(50)), solver, bands=np.array([0, 1, 1, 2]))
    assert np.all(sol.x == 0.0)
    assert np.all(sol.rank == 0)
    assert np.all(np.isfinite(sol.residual))


def test_unknown_solver_is_a_clear_error():
    with pytest.raises(ValueError, match="unknown solver"):
        solve(StreamedQR(2, 1), "cholesky")


def test_paper_reports_the_condition_of_the_normal_equations_it_solves():
    # One unknown per band (the 'diffuse' layout): every per-band block is 1x1, so a per-block
    # condition number would be 1.0 whatever the system; the reported one must be the
    # column-equilibrated A^T A's (dense oracle), the square of joint's.
    a, b, w, _ = _problem(n=5, c=1)
    a[:, 4, :] = a[:, 3, :] + 1e-3 * a[:, 4, :]  # two nearly collinear columns
    bands = np.arange(5)
    sol = solve(_stream(a, b, w), "paper", bands=bands)
    ad, _ = _dense(a, b, w, 0)
    ad = ad / np.linalg.norm(ad, axis=0)
    s = np.linalg.svd(ad.T @ ad, compute_uv=False)
    assert sol.cond[0] > 1e3
    assert sol.cond[0] == pytest.approx(s[0] / s[-1], rel=1e-6)
    assert sol.rank[0] == 5
    joint = solve(_stream(a, b, w), "joint")
    assert sol.cond[0] == pytest.approx(joint.cond[0] ** 2, rel=1e-6)


def test_reduced_basis_stream_lifted_back_solves_like_the_full_stream():
    """Rows in an r-dimensional subspace folded as ``A W`` and lifted back by ``back`` (``A = A W back``)
    give the dense minimum-norm / Tikhonov / paper answers of the n-column system."""
    rng = np.random.default_rng(3)
    m, n, r, c = 400, 10, 4, 2
    basis_rows = rng.normal(size=(c, r, n)) * np.logspace(0, 2, n)  # rows of A lie in span(basis_rows[c]^T)
    a = np.einsum("mrc,crn->mnc", rng.normal(size=(m, r, c)), basis_rows)
    b = rng.normal(size=(m, c))
    w = rng.uniform(0.2, 1.0, size=m)
    back = basis_rows  # (C, r, n)
    wmat = np.stack([np.linalg.pinv(back[k]) for k in range(c)])  # (C, n, r): back[k] @ wmat[k] = I_r
    full = _stream(a, b, w)
    red = StreamedQR(r, c)
    for start in range(0, m, 128):
        red.add(a[start : start + 128], b[start : start + 128], w[start : start + 128], basis=wmat)
    lifted = red.lifted(back)
    for solver in ("joint", "tikhonov", "paper"):
        ref = solve(full, solver, bands=np.arange(n) // 4)
        got = solve(lifted, solver, bands=np.arange(n) // 4)
        assert got.rank.tolist() == ref.rank.tolist() == [r] * c
        np.testing.assert_allclose(got.residual, ref.residual, rtol=1e-8)
        for k in range(c):
            fitted = a[:, :, k] @ got.x[:, k]
            np.testing.assert_allclose(fitted, a[:, :, k] @ ref.x[:, k], rtol=0, atol=1e-8 * np.abs(fitted).max())
    sw = np.sqrt(w)
    for k in range(c):  # joint = dense minimum-norm least squares of the column-equilibrated system
        ad, bd = a[:, :, k] * sw[:, None], b[:, k] * sw
        d = np.linalg.norm(ad, axis=0)
        y = np.linalg.lstsq(ad / d, bd, rcond=1e-9)[0]
        np.testing.assert_allclose(solve(lifted, "joint").x[:, k], y / d, rtol=1e-7, atol=1e-9 * np.abs(y / d).max())


def test_streamed_factor_is_the_dense_householder_factor():
    """The ``tpqrt`` updates give the triangular factor of the whole weighted ``[A | b]`` (numpy's dense QR,
    up to the sign of each row), whatever the block sizes."""
    a, b, w, _ = _problem(m=700, n=15, c=2)
    qr = _stream(a, b, w, sizes=(1, 5, 333, 40))
    for c in range(2):
        ad, bd = _dense(a, b, w, c)
        ref = np.linalg.qr(np.column_stack([ad, bd]), mode="r")
        got = qr._r[c] * (np.sign(np.diag(ref)) * np.sign(np.diag(qr._r[c])))[:, None]
        np.testing.assert_allclose(got, ref, rtol=0, atol=1e-12 * np.abs(ref).max())
    assert qr.rows == np.count_nonzero(w)


def test_probe_solution_is_the_damped_least_squares_solution():
    """Oracle: numpy's lstsq of the explicitly stacked ``[A / d; mu I] y = [b; 0]`` (dense, SVD-based)."""
    from brdfrig.fit.solvers import PROBE_DAMPING, probe_solution

    a, b, w, _ = _problem(n=10, c=2)
    a[:, 7, :] = 2.0 * a[:, 3, :]  # rank-deficient: only the damping makes the answer unique
    x = probe_solution(_stream(a, b, w))
    for c in range(2):
        ad, bd = _dense(a, b, w, c)
        d = np.linalg.norm(ad, axis=0)
        mu = PROBE_DAMPING * np.sqrt(ad.shape[1])
        y = np.linalg.lstsq(np.vstack([ad / d, mu * np.eye(10)]), np.concatenate([bd, np.zeros(10)]), rcond=None)[0]
        np.testing.assert_allclose(x[:, c], y / d, rtol=0, atol=1e-7 * np.abs(y / d).max())


@pytest.mark.parametrize("singular", [False, True])
def test_tikhonov_reports_the_condition_number_of_the_regularised_system(singular):
    """``cond_regularised`` is the 2-norm condition number of the stacked ``[A / d; lam I]`` actually solved
    (numpy SVD of the explicit matrix), finite where the data system's is inf; other solvers report None."""
    rng = np.random.default_rng(5)
    m, n = 300, 8
    t = np.linspace(0, 1, m)
    a = np.stack([t**k for k in range(n)], axis=1)[:, :, None]
    if singular:
        a[:, 5, 0] = 3.0 * a[:, 2, 0]
    b = a[:, :3, 0].sum(axis=1, keepdims=True) + 1e-3 * rng.normal(size=(m, 1))
    qr = _stream(a, b, np.ones(m))
    tik = solve(qr, "tikhonov", lam_min=1e-4)
    ad = a[:, :, 0] / np.linalg.norm(a[:, :, 0], axis=0)
    lam = tik.lam[0] * np.linalg.svd(ad, compute_uv=False)[0]
    s = np.linalg.svd(np.vstack([ad, lam * np.eye(n)]), compute_uv=False)
    print(f"singular={singular}: data cond {tik.cond[0]:.3g}, regularised {tik.cond_regularised[0]:.6g}, oracle {s[0] / s[-1]:.6g}")
    assert tik.cond_regularised[0] == pytest.approx(s[0] / s[-1], rel=1e-9)
    assert tik.cond_regularised[0] <= math.sqrt(1 + 1e8) * (1 + 1e-9)  # lam >= 1e-4 s_max
    assert np.isinf(tik.cond[0]) == singular
    assert solve(qr, "joint").cond_regularised is None and solve(qr, "paper", bands=np.arange(n)).cond_regularised is None
