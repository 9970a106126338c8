"""Least-squares solvers of the linear BRDF models, on a streamed QR factor.

The weighted system ``sqrt(w) * A x = sqrt(w) * b`` (one per colour channel,
``A`` of shape (m, n) with m up to millions of pixels) is never held in
memory: :class:`StreamedQR` folds pixel blocks into the triangular factor of
the augmented matrix ``[A | b]`` (``R`` (n, n), ``z = Q^T b`` and the norm of
the residual outside the column space), i.e. a streamed Householder QR
(LAPACK ``geqrf`` via numpy, batched over channels).  Every solver starts from
that factor, so rotations and design rows are computed once for all solvers.

Solvers (``docs/MATH.md`` pitfalls 4-5):

``paper``     the seed's band-by-band normal equations (one block Gauss-Seidel
              sweep over bands, each band solved against the residual of the
              previous ones) -- the baseline.  Its Gram matrix is ``R^T R`` (= ``A^T A``);
              its reported condition number is that of the whole (column-equilibrated)
              Gram matrix ``A^T A`` it works from, i.e. the square of ``joint``'s, not
              of the per-band blocks (1 by construction for one-unknown bands).
``joint``     all bands at once from the SVD of the column-equilibrated ``R``:
              truncated (minimum-norm) where the numerical rank is below n.
``tikhonov``  ``min |A x - b|^2 + lam^2 |D (x - x0)|^2`` with ``D`` the column norms
              of ``A`` and ``lam`` minimising generalised cross-validation (GCV)
              over ``[lam_min, 1] * s_max`` (``lam_min`` = 1e-12 unless given).
              With millions of pixel rows GCV ~ residual / rows^2 and, on
              noise-free data, picks the smallest lambda on its grid; a prior
              fit (``full+prior``) therefore passes a floor (``lam_min``) so
              that directions excited below that fraction of the strongest one
              stay at the prior instead of amplifying model error.

All accept a prior ``x0``: they then solve for ``x - x0`` against ``b - A x0``,
so directions the data do not determine stay at the prior.  Rank and
condition number are returned with every solution; ``tikhonov`` also returns
the condition number of the regularised system it solves, ``[Rs; lam I]``
(:attr:`Solution.cond_regularised`).
"""

from __future__ import annotations

import functools
import math
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import scipy.linalg
from scipy.linalg.lapack import dtpqrt as _tpqrt

__all__ = ["RANK_RTOL", "TPQRT_NB", "LAM_GRID_MIN", "PROBE_DAMPING", "probe_solution", "SOLVERS", "StreamedQR", "Solution", "solve", "numerical_rank"]

RANK_RTOL = 1e-9
"""Singular values below ``RANK_RTOL * s_max`` of the column-equilibrated system count as zero."""

from brdfrig.fit.registry import SOLVERS  # noqa: E402  (the one list of names)


def numerical_rank(singular_values: np.ndarray, rtol: float = RANK_RTOL) -> int:
    """Number of singular values above ``rtol`` times the largest (0 for an all-zero matrix)."""
    s = np.asarray(singular_values)
    if s.size == 0 or not np.isfinite(s[0]) or s[0] <= 0:
        return 0
    return int(np.count_nonzero(s > rtol * s[0]))


TPQRT_NB = 32
"""Block size of LAPACK ``tpqrt`` in :meth:`StreamedQR.add` (measured, 2048 x 287 blocks: 16 -> 11.6 ms,
32 -> 12.9 ms, 64 -> 15.5 ms, 128 -> 21.1 ms; ``geqrf`` of the stacked matrix 27 ms)."""


@functools.cache
def _channel_pool() -> ThreadPoolExecutor:
    """Worker threads for per-channel QR updates (one per core, at most 4)."""
    return ThreadPoolExecutor(max_workers=max(1, min(4, os.cpu_count() or 1)), thread_name_prefix="brdfrig-qr")


class StreamedQR:
    """Triangular factor of ``[sqrt(w) A | sqrt(w) b]`` accumulated over pixel blocks.

    Parameters
    ----------
    n : int
        Number of unknowns.
    channels : int
        Number of colour channels C (one independent system each).
    """

    def __init__(self, n: int, channels: int) -> None:
        self.n = n
        self.channels = channels
        self._r = np.zeros((channels, n + 1, n + 1))
        self.rows = 0

    def add(self, design: np.ndarray, radiance: np.ndarray, weights: np.ndarray, basis: np.ndarray | None = None) -> None:
        """Fold a block in: design (nb, n, C), radiance (nb, C), weights (nb,) >= 0.

        With ``basis`` (C, n', n) the design given is (nb, n', C) and channel c's rows
        ``design[:, :, c] @ basis[c]`` are folded in (a reduced basis, computed on the channel's thread).

        The update is LAPACK's triangular-pentagonal QR ``tpqrt`` of ``[R; sqrt(w) [A | b]]``, which
        skips the zeros under ``R`` and needs no stacked copy: measured 2.1x faster than ``geqrf`` on
        the stacked matrix (``scipy.linalg.qr``) for 2048-row blocks of 287 columns, single-threaded
        (block size :data:`TPQRT_NB`).  The channels are independent systems: each is updated on its
        own thread (scipy's LAPACK wrappers release the GIL; measured ~1.8x on two idle cores with
        ``geqrf``), where a second BLAS thread inside one factorisation made it slower.
        """
        nb = design.shape[0]
        if nb == 0:
            return
        sw = np.sqrt(np.asarray(weights, dtype=np.float64))
        k = self.n + 1

        def update(c: int) -> np.ndarray:
            block = np.empty((nb, k), order="F")  # sqrt(w) [A | b], column-major as LAPACK wants it
            rows = design[:, :, c] if basis is None else design[:, :, c] @ basis[c]
            np.multiply(rows, sw[:, None], out=block[:, : self.n])
            np.multiply(radiance[:, c], sw, out=block[:, self.n])
            r, _, _, info = _tpqrt(0, min(TPQRT_NB, k), np.asfortranarray(self._r[c]), block, overwrite_a=1, overwrite_b=1)
            if info != 0:
                raise RuntimeError(f"LAPACK tpqrt failed (info={info})")
            return r

        if self.channels == 1:
            self._r = update(0)[None]
        else:
            self._r = np.stack(list(_channel_pool().map(update, range(self.channels))))
        self.rows += int(np.count_nonzero(sw))

    def lifted(self, back: np.ndarray) -> StreamedQR:
        """The system of ``A`` (n columns) from this factor of a reduced design ``A W`` (r columns).

        Exact when ``A = (A W) back``, i.e. the rows of ``A`` lie in the span ``back`` (C, r, n) maps
        ``W``'s coordinates onto (:func:`brdfrig.fit.fitter.fit_brdf` streams rank-deficient models so): the
        returned factor ``R back`` (rows r.. zero) has the same ``R^T R = A^T A``, ``R^T z = A^T b``
        and residual outside the column space, which is all the solvers use.
        """
        channels, k, n = back.shape
        if channels != self.channels or k != self.n:
            raise ValueError(f"back has shape {back.shape}, expected ({self.channels}, {self.n}, n)")
        out = StreamedQR(n, channels)
        out._r[:, :k, :n] = np.matmul(self.r, back)
        out._r[:, :k, n] = self.z
        out._r[:, n, n] = self._r[:, k, k]
        out.rows = self.rows
        return out

    @property
    def r(self) -> np.ndarray:
        """(C, n, n) factor ``R`` of ``sqrt(w) A`` (``R^T R = A^T A``; upper triangular unless :meth:`lifted`)."""
        return self._r[:, : self.n, : self.n]

    @property
    def z(self) -> np.ndarray:
        """(C, n) ``Q^T sqrt(w) b``."""
        return self._r[:, : self.n, self.n]

    @property
    def residual_outside(self) -> np.ndarray:
        """(C,) squared norm of the part of ``sqrt(w) b`` outside the column space of ``A``."""
        return self._r[:, self.n, self.n] ** 2


@dataclass
class Solution:
    """Result of one solve.

    Attributes
    ----------
    x : (n, C) float64
        Unknowns per channel.
    rank : (C,) int
        Numerical rank used (column-equilibrated, :data:`RANK_RTOL`).
    cond : (C,) float
        2-norm condition number of the column-equilibrated system (inf if singular);
        for ``paper`` that of the column-equilibrated normal-equation matrix ``A^T A`` (inf if singular).
    residual : (C,) float
        Weighted residual sum of squares ``|sqrt(w)(A x - b)|^2``.
    lam : (C,) float or None
        Tikhonov parameter (relative to the largest singular value) chosen by GCV.
    cond_regularised : (C,) float or None
        ``tikhonov`` only: 2-norm condition number of the regularised system actually solved,
        ``[Rs; lam I]`` (``Rs`` column-equilibrated, ``lam`` absolute):
        ``sqrt((s_max^2 + lam^2) / (s_min^2 + lam^2))``, finite even where ``cond`` is inf
        (inf only for an all-zero system).
    """

    solver: str
    x: np.ndarray
    rank: np.ndarray
    cond: np.ndarray
    residual: np.ndarray
    lam: np.ndarray | None = None
    cond_regularised: np.ndarray | None = None


def _equilibrate(r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Column norms ``d`` of ``r`` (zero columns get 1) and ``r / d``."""
    d = np.linalg.norm(r, axis=0)
    d = np.where(d > 0, d, 1.0)
    return r / d, d


def _residual(r: np.ndarray, z: np.ndarray, outside: float, x: np.ndarray) -> float:
    return float(np.sum((r @ x - z) ** 2) + outside)


def _joint(r: np.ndarray, z: np.ndarray, rtol: float) -> tuple[np.ndarray, int, float]:
    rs, d = _equilibrate(r)
    u, s, vt = np.linalg.svd(rs)
    k = numerical_rank(s, rtol)
    y = vt[:k].T @ ((u[:, :k].T @ z) / s[:k]) if k else np.zeros(r.shape[1])
    cond = s[0] / s[-1] if k == len(s) else np.inf
    return y / d, k, float(cond)


LAM_GRID_MIN = 1e-12
"""Smallest Tikhonov lambda (relative to the largest singular value) GCV considers by default."""


def _tikhonov(
    r: np.ndarray, z: np.ndarray, outside: float, rows: int, rtol: float, lam_min: float = LAM_GRID_MIN
) -> tuple[np.ndarray, int, float, float, float]:
    """(x, rank, condition number, lambda relative to s_max, condition number of ``[Rs; lam I]``)."""
    rs, d = _equilibrate(r)
    u, s, vt = np.linalg.svd(rs)
    k = numerical_rank(s, rtol)
    cond = s[0] / s[-1] if k == len(s) else np.inf
    if k == 0:
        return np.zeros(r.shape[1]), 0, float(cond), 0.0, np.inf
    beta = u.T @ z
    s2 = s * s
    lo = math.log10(min(max(lam_min, LAM_GRID_MIN), 1.0))
    grid = s[0] * np.logspace(lo, 0, max(2, int(round(-10 * lo)) + 1))
    best, best_lam = np.inf, grid[0]
    for lam in grid:
        f = s2 / (s2 + lam * lam)
        res = outside + np.sum(((1.0 - f) * beta) ** 2)
        dof = max(rows - np.sum(f), 1.0)
        g = res / (dof * dof)
        if g < best:
            best, best_lam = g, lam
    f = s / (s2 + best_lam * best_lam)
    y = vt.T @ (f * beta)
    cond_reg = math.sqrt((s2[0] + best_lam**2) / (s2[-1] + best_lam**2))
    return y / d, k, float(cond), float(best_lam / s[0]), cond_reg


def _paper(r: np.ndarray, z: np.ndarray, bands: np.ndarray, rtol: float) -> tuple[np.ndarray, int, float]:
    gram = r.T @ r
    rhs = r.T @ z
    x = np.zeros(r.shape[1])
    done = np.zeros(r.shape[1], dtype=bool)
    for l in np.unique(bands):
        idx = np.flatnonzero(bands == l)
        g = gram[np.ix_(idx, idx)]
        b = rhs[idx] - gram[np.ix_(idx, np.flatnonzero(done))] @ x[done]
        # The seed inverts A_l^T A_l; lstsq gives the same answer when it is
        # invertible and a finite one when a band is singular (no NaN/inf).
        x[idx] = np.linalg.lstsq(g, b, rcond=None)[0]
        done[idx] = True
    # Rank and condition of the normal equations the sweep works from (equilibrated A^T A = Rs^T Rs).
    s = np.linalg.svd(_equilibrate(r)[0], compute_uv=False) ** 2
    rank = numerical_rank(s, rtol * rtol)
    cond = s[0] / s[-1] if rank == len(s) else np.inf
    return x, rank, float(cond)


PROBE_DAMPING = 1e-5
"""Damping of :func:`probe_solution`, relative to the largest possible singular value of the
column-equilibrated system (``sqrt(n)``)."""


def probe_solution(qr: StreamedQR) -> np.ndarray:
    """A cheap, slightly damped least-squares solution (n, C) for monitoring a stream (not a final answer).

    Solves ``(Rs^T Rs + mu^2 I) y = Rs^T z``, ``x = y / d`` (``Rs = R / d`` column-equilibrated,
    ``mu = PROBE_DAMPING * sqrt(n)``) by a Cholesky factorisation of the normal equations:
    O(n^3) per channel with a small constant, several times cheaper than the SVD the
    final solvers use (measured 1.7 ms per channel at n = 285, against 3.5 ms for the general
    LU solve used before).  The damping keeps the normal-equation matrix's
    condition number below ``1 / PROBE_DAMPING^2`` = 1e10 (Cholesky cannot break down), so
    rank-deficient systems give a finite answer whose fitted values (and predictions in the span of
    the data) converge with the exact ones; the stopping rule of :func:`brdfrig.fit.fitter.fit_brdf`
    compares such predictions.
    """
    n = qr.n
    out = np.zeros((n, qr.channels))
    diag = np.arange(n)
    for c in range(qr.channels):
        r, z = qr.r[c], qr.z[c]
        d = np.linalg.norm(r, axis=0)
        d = np.where(d > 0, d, 1.0)
        rs = r / d
        gram = rs.T @ rs
        gram[diag, diag] += (PROBE_DAMPING**2) * n
        factor = scipy.linalg.cho_factor(gram, overwrite_a=True, check_finite=False)
        out[:, c] = scipy.linalg.cho_solve(factor, rs.T @ z, check_finite=False) / d
    return out


def solve(
    qr: StreamedQR,
    solver: str = "joint",
    *,
    bands: np.ndarray | None = None,
    x0: np.ndarray | None = None,
    rtol: float = RANK_RTOL,
    lam_min: float = LAM_GRID_MIN,
) -> Solution:
    """Solve every channel of a streamed system.

    Parameters
    ----------
    qr : StreamedQR
        The accumulated system.
    solver : {"paper", "joint", "tikhonov"}
    bands : (n,) int, optional
        Lighting band of each unknown (``ModelSpec.column_band``); required by ``paper``.
    x0 : (n, C) float64, optional
        Prior; the solvers solve for ``x - x0``.
    rtol : float
        Relative singular-value threshold of the numerical rank.
    lam_min : float
        ``tikhonov`` only: smallest lambda (relative to the largest singular value of the
        column-equilibrated system) GCV may choose.
    """
    if solver not in SOLVERS:
        raise ValueError(f"unknown solver {solver!r}; expected one of {SOLVERS}")
    if solver == "paper" and bands is None:
        raise ValueError("the 'paper' solver needs the band of every unknown")
    n, nc = qr.n, qr.channels
    x = np.zeros((n, nc))
    rank = np.zeros(nc, dtype=np.int64)
    cond = np.zeros(nc)
    resid = np.zeros(nc)
    lam = np.zeros(nc) if solver == "tikhonov" else None
    cond_reg = np.zeros(nc) if solver == "tikhonov" else None
    for c in range(nc):
        r, z, outside = qr.r[c], qr.z[c], qr.residual_outside[c]
        prior = np.zeros(n) if x0 is None else x0[:, c]
        zc = z - r @ prior
        if solver == "joint":
            dx, rank[c], cond[c] = _joint(r, zc, rtol)
        elif solver == "tikhonov":
            dx, rank[c], cond[c], lam[c], cond_reg[c] = _tikhonov(r, zc, outside, qr.rows, rtol, lam_min)
        else:
            dx, rank[c], cond[c] = _paper(r, zc, np.asarray(bands), rtol)
        x[:, c] = prior + dx
        resid[c] = _residual(r, z, outside, x[:, c])
    return Solution(solver=solver, x=x, rank=rank, cond=cond, residual=resid, lam=lam, cond_regularised=cond_reg)
