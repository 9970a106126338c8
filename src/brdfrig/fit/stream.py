"""Pixels, lighting and the streamed QR factor of the linear models, with the stopping rule.

- Pixels (:func:`gather_pixels`): only finite pixels with positive weight whose normal lies within the
  limb margin (``max_theta_deg`` from the view direction) are used; every exclusion is counted.
- Lighting (:func:`project_lighting`): each scene's environment is projected onto SH once; the rotated
  lighting ``L'(n)`` is computed once per pixel block for all colour channels
  (:func:`brdfrig.fit.system.design_rows`), and every solver works from the same streamed QR factor
  (:mod:`brdfrig.fit.solvers`).
- Stopping rule (:func:`stream_model`): pixels of all scenes are visited in one random order, in blocks
  of :data:`BLOCK_ROWS`; once at least ``3 n`` rows are in, a cheap, slightly damped least-squares
  solution (:func:`brdfrig.fit.solvers.probe_solution`, a Cholesky solve of the damped normal equations
  from the QR factor) is recomputed after every block and its predicted radiance on the held-out pixels
  compared with the previous one; the stream stops when that relative change stays below ``tol``
  (default :data:`STOP_TOL`) for two consecutive blocks.  The factor is shared by every solver and
  prior on the same model.
- Reduced stream: a model the lighting analysis finds rank-deficient (``full`` from few scenes) is
  streamed in a basis of its design's row space found on the first block (QR of r < n columns, e.g. 146
  of 285 for one scene at l = p = 8), every later block checked to lie in it (else the stream restarts
  unreduced); the factor is lifted back to the n unknowns, so every solver and the reported rank and
  condition number see the same system; the stopping rule's probe is solved in the reduced coordinates.

Speed: ``python -m benchmarks.bench_fit_speed``; the time of every fit per stage is in
``FitReport.stage_seconds`` (:data:`STAGES`).
"""

from __future__ import annotations

import dataclasses
import math
import time
from contextlib import contextmanager
from dataclasses import dataclass

import numba
import numpy as np
from tqdm import tqdm

from brdfrig.errors import InputError
from brdfrig.fit.metrics import relative_rms
from brdfrig.fit.report import PixelCounts, SystemStats
from brdfrig.fit.scene import Scene
from brdfrig.fit.shproject import project_environment
from brdfrig.fit.solvers import StreamedQR, numerical_rank, probe_solution, solve
from brdfrig.fit.system import ModelSpec, design_rows

__all__ = [
    "STOP_TOL", "BLOCK_ROWS", "STAGES", "StageClock", "Pool", "FitData", "Stream",
    "gather_pixels", "project_lighting", "stream_model", "solve_stream",
]

STOP_TOL = 1e-3
"""Stopping-rule tolerance: relative change of the held-out prediction from one block to the next.
Measured on the 512x512 headline (``full``, l = p = 8): one scene stops after 10 blocks (changes
8e-3, 4e-3, 2.4e-3, 2.2e-3, 1.4e-3, 1.2e-3, 1.2e-3, 9.7e-4, 7.7e-4); twelve scenes after 39 blocks,
the change hovering at 0.7e-3 to 1.8e-3 from 36k rows on (its noise, not its trend, sets the cost)."""
BLOCK_ROWS = 2048
"""Pixels per block of the stream.  Also the stopping rule's step: the change it measures grows with
the block, so a different block size is a different rule (and a different answer)."""
REDUCE_RTOL = 1e-13
"""Singular values of the first block's column-equilibrated factor above this fraction of the largest span
the basis a rank-deficient model is streamed in.  One scene, ``full`` at l = p = 8 (285 unknowns): 146 of
them are above 1e-11, the rest below 2e-15 (rounding), in every block; the solvers' own threshold
(:data:`brdfrig.fit.solvers.RANK_RTOL` = 1e-9) and Tikhonov damping act far above it."""
REDUCE_MAX_FRACTION = 0.75
"""Reduce only when that rank is at most this fraction of the unknowns (QR cost ~ rows x columns^2:
above it the extra products of the reduction eat the saving)."""
REDUCE_OUTSIDE_RTOL = 1e-11
"""A later block whose (sketched, column-equilibrated) rows have more than this relative norm outside the
basis adds rank: the stream starts again unreduced."""
_SKETCH_ROWS = 8

STAGES = ("gather", "lighting", "noise", "identifiability", "design", "qr", "probe", "solve", "other")
"""Timed stages of a fit: pixel gathering, lighting projection, pixel-noise estimate, identifiability
analysis, design assembly (rotated lighting and outgoing SH, held-out rows included), QR updates (with the
reduced-basis SVD and checks), stopping-rule probes, final solves, and the rest (single-model fits, priors,
plausibility, relighting estimates)."""


class StageClock:
    """Wall-clock seconds spent per stage (:data:`STAGES`); ``with clock("qr"): ...`` adds to one."""

    def __init__(self) -> None:
        self.seconds = dict.fromkeys(STAGES, 0.0)
        self._t0 = time.perf_counter()

    @contextmanager
    def __call__(self, stage: str):
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[stage] += time.perf_counter() - t0

    def report(self) -> dict:
        """Seconds per stage; ``other`` is the total minus the timed stages."""
        out = dict(self.seconds)
        out["other"] = max(time.perf_counter() - self._t0 - sum(v for k, v in out.items() if k != "other"), 0.0)
        return out


@dataclass
class Pool:
    """Usable pixels of all scenes, flattened, in scene order."""

    scene: np.ndarray  # (N,) int
    normals: np.ndarray  # (N, 3)
    radiance: np.ndarray  # (N, C)
    weights: np.ndarray  # (N,)


@dataclass
class FitData:
    """What every candidate fit of one ``fit_brdf`` call shares.

    Attributes
    ----------
    scenes : list of Scene
        The caller's scenes (their environments light the predictions).
    pool : Pool
        Their usable pixels.
    coeffs : list of (n_sh, C) arrays
        Each scene's lighting in SH.
    train, held : int arrays
        Pool indices of the pixels fitted (stream order) and held out (sorted).
    clock : StageClock
    progress : bool
        tqdm bars on stderr.
    tol : float
        Stopping-rule tolerance.
    """

    scenes: list[Scene]
    pool: Pool
    coeffs: list[np.ndarray]
    train: np.ndarray
    held: np.ndarray
    clock: StageClock
    progress: bool
    tol: float = STOP_TOL

    def with_split(self, train: np.ndarray, held: np.ndarray) -> "FitData":
        """The same data with another train / held-out split (e.g. a left-out scene)."""
        return dataclasses.replace(self, train=train, held=held)

    def train_scenes(self) -> list[Scene]:
        """One Scene per input scene holding only its training pixels (the single-model fits' input)."""
        p = self.pool
        rows = [self.train[p.scene[self.train] == k] for k in range(len(self.scenes))]
        return [Scene(s.env, p.normals[r], p.radiance[r], p.weights[r]) for s, r in zip(self.scenes, rows) if len(r)]


@numba.njit(cache=True, nogil=True)
def _classify(normals, radiance, weights, cos_max):  # pragma: no cover - compiled
    """Per pixel: 0 usable, 1 weight not a positive number, 2 a non-finite normal or radiance, 3 normal
    beyond the limb margin (``n_z < cos_max``), in one pass."""
    out = np.empty(weights.shape[0], np.int8)
    for i in range(weights.shape[0]):
        w = weights[i]
        if not (np.isfinite(w) and w > 0):
            out[i] = 1
            continue
        finite = np.isfinite(normals[i, 0]) and np.isfinite(normals[i, 1]) and np.isfinite(normals[i, 2])
        for c in range(radiance.shape[1]):
            finite = finite and np.isfinite(radiance[i, c])
        out[i] = 2 if not finite else (3 if normals[i, 2] < cos_max else 0)
    return out


def _checked_arrays(k: int, s: Scene) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n = np.asarray(s.normals, dtype=np.float64)
    b = np.asarray(s.radiance, dtype=np.float64)
    w = np.asarray(s.weights, dtype=np.float64)
    if b.ndim != 2 or n.shape != (b.shape[0], 3) or w.shape != (b.shape[0],):
        raise ValueError(f"scene {k}: normals (N,3), radiance (N,C) and weights (N,) disagree: {n.shape}, {b.shape}, {w.shape}")
    env_c = np.asarray(s.env.radiance).shape[1]
    if b.shape[1] != env_c:
        raise ValueError(f"scene {k}: image has {b.shape[1]} channels but its lighting has {env_c}")
    return n, b, w


def gather_pixels(scenes: list[Scene], max_theta_deg: float) -> tuple[Pool, PixelCounts]:
    """The usable pixels of all scenes (module docstring) and the count of each exclusion.

    Raises
    ------
    ValueError
        No scene, inconsistent arrays or channel counts, or no usable pixel.
    """
    if not scenes:
        raise ValueError("fit_brdf needs at least one scene")
    arrays, keeps = [], []
    cos_max = math.cos(math.radians(max_theta_deg))
    tally = np.zeros(4, dtype=np.int64)  # usable, weight_zero, non_finite, beyond_limb_margin
    for k, s in enumerate(scenes):
        n, b, w = _checked_arrays(k, s)
        if arrays and b.shape[1] != arrays[0][1].shape[1]:
            raise ValueError(f"scene {k}: {b.shape[1]} channels, scene 0 has {arrays[0][1].shape[1]}")
        code = _classify(n, b, w, cos_max)
        tally += np.bincount(code, minlength=4)
        arrays.append((n, b, w))
        keeps.append(code == 0)
    counts = PixelCounts(int(tally.sum()), int(tally[1]), int(tally[2]), int(tally[3]), int(tally[0]))
    if counts.used == 0:
        raise InputError(f"no usable pixel: {dataclasses.asdict(counts)}")
    total, channels = counts.used, arrays[0][1].shape[1]
    pool = Pool(np.empty(total, dtype=np.int64), np.empty((total, 3)), np.empty((total, channels)), np.empty(total))
    start = 0
    for k, ((n, b, w), keep) in enumerate(zip(arrays, keeps)):
        stop = start + int(np.count_nonzero(keep))
        pool.scene[start:stop] = k
        np.compress(keep, n, axis=0, out=pool.normals[start:stop])
        np.compress(keep, b, axis=0, out=pool.radiance[start:stop])
        np.compress(keep, w, axis=0, out=pool.weights[start:stop])
        start = stop
    return pool, counts


def project_lighting(scenes: list[Scene], lmax: int) -> list[np.ndarray]:
    """Each scene's lighting in real SH up to band ``lmax``; ValueError if a map cannot carry it or is not finite."""
    coeffs = []
    for k, s in enumerate(scenes):
        seen = int(np.count_nonzero(np.asarray(s.env.solid_angle) > 0))
        if (lmax + 1) ** 2 > seen / 2:
            raise InputError(
                f"scene {k}: lmax={lmax} needs at least {2 * (lmax + 1) ** 2} seen lighting samples, the environment has {seen}"
            )
        c = project_environment(s.env, lmax)
        if not np.all(np.isfinite(c)):
            raise InputError(f"scene {k}: the lighting contains NaN or inf")
        coeffs.append(c)
    return coeffs


def _design(spec: ModelSpec, data: FitData, idx: np.ndarray) -> np.ndarray:
    """Design rows (len(idx), n, C) of pool pixels ``idx`` (sorted: the pool is in scene order, so each scene
    is one run), laid out by :func:`brdfrig.fit.system.design_rows` (each channel's rows one Fortran-ordered matrix)."""
    return design_rows(spec, data.coeffs, data.pool.scene[idx], data.pool.normals[idx])


@dataclass
class Stream:
    """A model's streamed system: QR factor, held-out design, and how much of the pixel stream it took.

    ``reduced_columns``: None, or the number of columns r < n of the basis the design was streamed in
    (the factor ``qr`` is then :meth:`brdfrig.fit.solvers.StreamedQR.lifted` back to the n unknowns).
    """

    spec: ModelSpec
    qr: StreamedQR
    heldout_design: np.ndarray
    consumed: int
    converged: bool
    seconds: float
    reduced_columns: int | None = None


@dataclass
class _Basis:
    """Per channel c: ``w[c]`` (n, r) spans the rows of the design, ``null[c]`` (n, n - r) the rest, and
    ``back[c]`` (r, n) maps coordinates back (``A = (A w[c]) back[c]`` for rows in the span)."""

    w: np.ndarray  # (C, n, r)
    null: list[np.ndarray]
    back: np.ndarray  # (C, r, n)


def _reduced_basis(qr: StreamedQR) -> _Basis | None:
    """Bases of the row space of the accumulated factor, or None when it is (nearly) of full rank.

    From the SVD of the column-equilibrated ``R = Rs diag(d)``, ``Rs = U S V^T`` with r singular values
    above :data:`REDUCE_RTOL`: ``w = diag(1/d) V[:, :r]``, ``null = diag(1/d) V[:, r:]``,
    ``back = V[:, :r]^T diag(d)``.  None unless every channel has the same r <= :data:`REDUCE_MAX_FRACTION` n.
    """
    w, null, back, ranks = [], [], [], set()
    for c in range(qr.channels):
        r = qr.r[c]
        d = np.linalg.norm(r, axis=0)
        d = np.where(d > 0, d, 1.0)
        _, s, vt = np.linalg.svd(r / d)
        k = numerical_rank(s, REDUCE_RTOL)
        ranks.add(k)
        w.append(vt[:k].T / d[:, None])
        null.append(vt[k:].T / d[:, None])
        back.append(vt[:k] * d[None, :])
    k = ranks.pop() if len(ranks) == 1 else 0
    if k == 0 or k > REDUCE_MAX_FRACTION * qr.n:
        return None
    return _Basis(np.stack(w), null, np.stack(back))


def _outside(design: np.ndarray, sw: np.ndarray, basis: _Basis, rng: np.random.Generator) -> float:
    """Largest relative norm, over channels, of a Gaussian sketch of weighted rows outside the basis.

    ``design @ null[c]`` are the coordinates of the column-equilibrated rows outside the row space.  The
    sketch combines all rows of the block with :data:`_SKETCH_ROWS` sets of Gaussian weights: a pixel
    population that adds rank shows up with probability 1.
    """
    g = rng.standard_normal((_SKETCH_ROWS, design.shape[0])) * sw
    worst = 0.0
    for c in range(design.shape[2]):
        s = g @ design[:, :, c]  # (k, n)
        inside, out = np.linalg.norm(s @ basis.w[c]), np.linalg.norm(s @ basis.null[c])
        worst = max(worst, out / max(math.hypot(inside, out), 1e-300))
    return worst


def stream_model(spec: ModelSpec, data: FitData, label: str, expected_rank: int | None = None) -> Stream:
    """Fold random pixel blocks of ``data.train`` into the QR factor until the stopping rule holds.

    ``expected_rank``: the design's rank by the lighting analysis, if known.  When it is at most
    :data:`REDUCE_MAX_FRACTION` of the unknowns and the first block shows the design rank-deficient
    (:func:`_reduced_basis`), the rest is folded in the reduced basis (QR of r instead of n columns) and
    the factor lifted back for the stopping rule and the solvers (same system up to rounding); if a
    later block adds rank, the stream starts again unreduced.
    """
    reduce = expected_rank is not None and expected_rank <= REDUCE_MAX_FRACTION * spec.n_unknowns
    t0 = time.perf_counter()
    pool, train, held, clock, n = data.pool, data.train, data.held, data.clock, spec.n_unknowns
    with clock("design"):
        a_h = _design(spec, data, held)
    qr = StreamedQR(n, pool.radiance.shape[1])
    basis, rng = None, np.random.default_rng(0)
    prev, stable, converged, consumed = None, 0, False, 0
    blocks = range(0, len(train), BLOCK_ROWS)
    for start in tqdm(blocks, desc=f"fit {label}", unit="block", disable=not data.progress, leave=False):
        idx = np.sort(train[start : start + BLOCK_ROWS])  # row order is irrelevant to QR; sorted = one slice per scene
        with clock("design"):
            design, w = _design(spec, data, idx), pool.weights[idx]
        with clock("qr"):
            if basis is None:
                qr.add(design, pool.radiance[idx], w)
            elif _outside(design, np.sqrt(w), basis, rng) > REDUCE_OUTSIDE_RTOL:
                return stream_model(spec, data, label)
            else:
                qr.add(design, pool.radiance[idx], w, basis.w)
            consumed = start + len(idx)
            if reduce and start == 0 and qr.rows >= 3 * n:
                basis = _reduced_basis(qr)
                if basis is not None:
                    qr = StreamedQR(basis.back.shape[1], qr.channels)
                    qr.add(design, pool.radiance[idx], w, basis.w)
        if qr.rows < 3 * n or len(held) == 0:
            continue
        with clock("probe"):
            x = probe_solution(qr)  # in the reduced basis's coordinates when streaming reduced
            pred = np.einsum("inc,nc->ic", a_h, x if basis is None else np.einsum("cnr,rc->nc", basis.w, x))
        if prev is not None:
            change = np.linalg.norm(pred - prev) / max(np.linalg.norm(pred), 1e-300)
            stable = stable + 1 if change < data.tol else 0
            if stable >= 2:
                converged = True
                break
        prev = pred
    full = qr if basis is None else qr.lifted(basis.back)
    return Stream(spec, full, a_h, consumed, converged, time.perf_counter() - t0, None if basis is None else qr.n)


def solve_stream(st: Stream, data: FitData, solver: str, x0=None, lam_min=None) -> tuple[np.ndarray, SystemStats, float | None]:
    """Solve a streamed system with ``solver`` (prior ``x0``, Tikhonov floor ``lam_min``).

    Returns
    -------
    x : (n, C) unknowns
    stats : SystemStats
    heldout_relative_rms : float or None (no held-out pixels)
    """
    spec, n, pool = st.spec, st.spec.n_unknowns, data.pool
    floor = {} if lam_min is None else {"lam_min": lam_min}
    with data.clock("solve"):
        sol = solve(st.qr, solver, bands=spec.column_band, x0=x0, **floor)
    used = data.train[: st.consumed]
    energy = float(np.sum(pool.weights[used, None] * pool.radiance[used] ** 2))
    held_err = None
    if len(data.held):
        pred = np.einsum("inc,nc->ic", st.heldout_design, sol.x)
        held_err = relative_rms(pred, pool.radiance[data.held], pool.weights[data.held])
    stats = SystemStats(
        unknowns=n,
        bands=list(spec.bands),
        lmax=spec.lmax,
        pmax=spec.pmax if spec.kind == "full" else None,
        solver=solver,
        rank=sol.rank.tolist(),
        condition_number=sol.cond.tolist(),
        condition_number_regularised=None if sol.cond_regularised is None else sol.cond_regularised.tolist(),
        full_rank=bool(np.all(sol.rank == n)),
        reduced_stream=None if st.reduced_columns is None else (
            f"rows streamed in a {st.reduced_columns}-column basis of the design's row space (found on the "
            f"first block, rank at {REDUCE_RTOL:g}); rank and condition number are of the lifted {n}-unknown system"
        ),
        tikhonov_lambda_rel=None if sol.lam is None else sol.lam.tolist(),
        tikhonov_lambda_min_rel=lam_min,
        rows_used=st.qr.rows,
        rows_available=int(len(data.train)),
        stopping_rule_converged=st.converged,
        train_relative_rms=math.sqrt(float(np.sum(sol.residual)) / energy) if energy > 0 else 0.0,
    )
    return sol.x, stats, held_err
