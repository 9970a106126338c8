"""``fit_brdf``: fit a BRDF to sphere images under measured lighting, choosing a model the data determine.

Pipeline (``docs/MATH.md``):

1. Pixels: only finite pixels with positive weight whose normal lies within
   :data:`DEFAULT_MAX_THETA_DEG` of the view direction are used (the default
   limb margin: beyond it pixels are grazing, anti-aliased against the
   background in real and rendered images, and the design is badly
   conditioned); every exclusion is counted in the report.
2. Lighting: each scene's environment is projected onto SH once
   (``brdfrig.fit.shproject``); the rotated lighting ``L'(n)`` is computed once per
   pixel block for all colour channels, and every solver works from the same
   streamed QR factor (:mod:`brdfrig.fit.solvers`).
3. Identifiability from the lighting alone (:mod:`brdfrig.fit.identifiability`):
   bands without lighting energy are dropped from every model (reported), and
   ``full`` is only a candidate of ``auto`` at band limits the scenes separate.
4. Stopping rule (pixels beyond what changes the answer are skipped): pixels
   of all scenes are visited in one random order, in blocks of
   :data:`BLOCK_ROWS`; once at least ``3 n`` rows are in, a cheap, slightly
   damped least-squares solution (:func:`brdfrig.fit.solvers.probe_solution`, a Cholesky
   solve of the damped normal equations from the QR factor instead of an SVD) is recomputed
   after every block and its predicted radiance on the held-out pixels
   compared with the previous one; the stream stops when that relative
   change stays below ``tol`` (default :data:`STOP_TOL`) for two consecutive blocks.
   The resulting QR factor is shared by every solver and prior on the same model.
   A model the lighting analysis finds rank-deficient (``full`` from few scenes) is streamed in a
   basis of its design's row space found on the first block (QR of r < n columns, e.g. 146 of 285
   for one scene at l = p = 8), with every later block checked to lie in it (else the stream
   restarts unreduced); the factor is lifted back to the n unknowns, so every
   solver and the reported rank and condition number see the same system (report: ``reduced_stream``);
   the stopping rule's probe is solved in the reduced coordinates.

   Speed (``python -m benchmarks.bench_fit_speed``; 512x512 three-channel spheres, ``full`` at l = p = 8,
   joint solver, 2-core machine shared with other jobs): one scene folds 10 blocks (20480 rows), twelve
   scenes 39 blocks (79872 rows), and the time goes to the QR updates (LAPACK ``tpqrt``, each channel on
   its own thread), design assembly (numba kernel over the rotated lighting), the probes and the fixed
   stages; ``report["stage_seconds"]`` (:data:`STAGES`) has the breakdown of every fit.  Measured there:
   sphericart's OpenMP threads, woken for every SH evaluation, made each call on a block's pixels of
   one scene take ~10 ms (4.6 s of a twelve-scene fit): the design evaluates the SH once per block
   (:func:`brdfrig.fit.system.design_rows`).  Limiting those threads instead (threadpoolctl) corrupted memory
   once numba's own OpenMP runtime (microfacet fit) ran in the same process.  QR-updating in a
   worker while assembling the next block saved nothing (GIL waits) and was dropped.

5. Held-out check: a random :data:`HELDOUT_FRACTION` of the pixels (at most
   :data:`HELDOUT_MAX` of them) never enter a fit; each candidate's weighted
   relative RMS error on them is reported.  ``auto`` keeps only candidates the
   identifiability analysis calls determined *and* whose pixel system reached
   full rank (and, when any is, physically plausible: :func:`brdfrig.fit.models.plausibility`), and picks the richest (order :data:`RICHNESS`) whose held-out
   error is within :data:`SELECT_RTOL` of the best.
"""

from __future__ import annotations

import math
import time
from contextlib import contextmanager
from dataclasses import dataclass

import numba
import numpy as np
from threadpoolctl import threadpool_limits
from tqdm import tqdm

from brdfrig.fit.brdf import FittedBRDF
from brdfrig.fit.identifiability import THETA_MAX_DEG, analyse_lighting
from brdfrig.fit.microfacet import fit_microfacet
from brdfrig.fit.models import make_linear_brdf, plausibility, project_to_full
from brdfrig.fit.scene import Scene
from brdfrig.fit.shproject import project_environment
from brdfrig.fit.solvers import SOLVERS, StreamedQR, numerical_rank, probe_solution, solve
from brdfrig.fit.system import ModelSpec, design_rows

__all__ = ["FitResult", "fit_brdf", "MODELS", "RICHNESS", "DEFAULT_MAX_THETA_DEG", "STOP_TOL"]

RICHNESS = ("diffuse", "lobe", "microfacet", "full", "full+prior")
MODELS = ("auto",) + RICHNESS
DEFAULT_MAX_THETA_DEG = THETA_MAX_DEG
STOP_TOL = 1e-3
"""Stopping-rule tolerance: relative change of the held-out prediction from one block to the next.
Measured on the 512x512 headline (``full``, l = p = 8): one scene stops after 10 blocks (changes
8e-3, 4e-3, 2.4e-3, 2.2e-3, 1.4e-3, 1.2e-3, 1.2e-3, 9.7e-4, 7.7e-4); twelve scenes after 39 blocks,
the change hovering at 0.7e-3 to 1.8e-3 from 36k rows on (its noise, not its trend, sets the cost)."""
BLOCK_ROWS = 2048
"""Pixels per block of the stream.  Also the stopping rule's step: the change it measures grows with
the block, so a different block size is a different rule (and a different answer)."""
HELDOUT_FRACTION = 0.1
HELDOUT_MAX = 2000
SELECT_RTOL = 0.02
PRIOR_LAM_MIN = {True: 1e-2, False: 1e-1}
"""``full+prior``: smallest Tikhonov lambda, relative to the largest singular value of the
column-equilibrated system, keyed by whether the identifiability analysis calls ``full`` determined
at this band limit.  Directions the lighting excites less than this fraction of the best-excited one
stay (mostly) at the prior.  Without a floor GCV, whose score with m ~ 1e4-1e6 rows is essentially
the residual, picked lambda ~ 1e-12 on one scene: the fit image's SH truncation error, amplified
along barely excited directions, relit at 2e5 relative error.  Measured (GGX alpha 0.3 sphere,
48 px, l = p = 6, grace -> pisa, priors: microfacet / lobe / a wrong GGX): one scene, floor 0.1:
0.61% / 3.5% / 7.7% vs 0.42% / 3.6% / 8.5% for the prior's own projection onto ``full`` (0.01:
1.2% / 3.4% / 7.7%); twelve scenes, floor 0.01: 0.97% / 0.93% / 1.35% vs 2.7% for plain ``full``
(0.1: 0.55% / 2.3% / 6.2%: too strong once the data determine the model)."""
COND_WARN = 1e6
"""Condition number (column-equilibrated) above which the report warns that weakly determined
directions may relight badly under other lighting.  For the ``tikhonov`` solver (and ``full+prior``)
the condition number judged is that of the regularised system solved (report key
``condition_number_regularised``, :attr:`brdfrig.fit.solvers.Solution.cond_regularised`): a fit the prior
keeps well determined does not warn."""


STAGES = ("gather", "lighting", "identifiability", "design", "qr", "probe", "solve", "other")
"""Stages of :func:`fit_brdf` timed in ``report["stage_seconds"]``: pixel gathering, lighting projection,
identifiability analysis, design assembly (rotated lighting and outgoing SH, held-out rows included),
QR updates (with the reduced-basis SVD and checks), stopping-rule probes, final solves, and the rest
(microfacet fits, priors, plausibility)."""


class _StageClock:
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
class FitResult:
    """A fitted BRDF and its JSON-able report (identifiability, rank, condition, residuals, choice)."""

    brdf: FittedBRDF
    report: dict


@dataclass
class _Pool:
    """Usable pixels of all scenes, flattened."""

    scene: np.ndarray  # (N,) int
    normals: np.ndarray  # (N, 3)
    radiance: np.ndarray  # (N, C)
    weights: np.ndarray  # (N,)


@numba.njit(cache=True, nogil=True)
def _classify(normals, radiance, weights, cos_max):  # pragma: no cover - compiled
    """Per pixel: 0 usable, 1 weight not a positive number, 2 a non-finite normal or radiance, 3 normal
    beyond the limb margin (``n_z < cos_max``).  One pass: the numpy expression of the same masks made
    six passes and temporaries (measured 0.37 s to gather twelve 512x512 scenes, 0.1 s now)."""
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


def _gather(scenes: list[Scene], max_theta_deg: float) -> tuple[_Pool, dict]:
    if not scenes:
        raise ValueError("fit_brdf needs at least one scene")
    channels, arrays, keeps = None, [], []
    cos_max = math.cos(math.radians(max_theta_deg))
    tally = np.zeros(4, dtype=np.int64)  # usable, weight_zero, non_finite, beyond_limb_margin
    for k, s in enumerate(scenes):
        n = np.asarray(s.normals, dtype=np.float64)
        b = np.asarray(s.radiance, dtype=np.float64)
        w = np.asarray(s.weights, dtype=np.float64)
        env_c = np.asarray(s.env.radiance).shape[1]
        if b.ndim != 2 or n.shape != (b.shape[0], 3) or w.shape != (b.shape[0],):
            raise ValueError(f"scene {k}: normals (N,3), radiance (N,C) and weights (N,) disagree: {n.shape}, {b.shape}, {w.shape}")
        if b.shape[1] != env_c:
            raise ValueError(f"scene {k}: image has {b.shape[1]} channels but its lighting has {env_c}")
        if channels is None:
            channels = b.shape[1]
        elif b.shape[1] != channels:
            raise ValueError(f"scene {k}: {b.shape[1]} channels, scene 0 has {channels}")
        code = _classify(n, b, w, cos_max)
        tally += np.bincount(code, minlength=4)
        arrays.append((n, b, w))
        keeps.append(code == 0)
    counts = {"pixels": int(tally.sum()), "weight_zero": int(tally[1]), "non_finite": int(tally[2]),
              "beyond_limb_margin": int(tally[3]), "used": int(tally[0])}
    if counts["used"] == 0:
        raise ValueError(f"no usable pixel: {counts}")
    total = counts["used"]
    pool = _Pool(np.empty(total, dtype=np.int64), np.empty((total, 3)), np.empty((total, channels)), np.empty(total))
    start = 0
    for k, ((n, b, w), keep) in enumerate(zip(arrays, keeps)):
        stop = start + int(np.count_nonzero(keep))
        pool.scene[start:stop] = k
        np.compress(keep, n, axis=0, out=pool.normals[start:stop])
        np.compress(keep, b, axis=0, out=pool.radiance[start:stop])
        np.compress(keep, w, axis=0, out=pool.weights[start:stop])
        start = stop
    return pool, counts


def _lighting(scenes: list[Scene], lmax: int) -> list[np.ndarray]:
    coeffs = []
    for k, s in enumerate(scenes):
        seen = int(np.count_nonzero(np.asarray(s.env.solid_angle) > 0))
        if (lmax + 1) ** 2 > seen / 2:
            raise ValueError(
                f"scene {k}: lmax={lmax} needs at least {2 * (lmax + 1) ** 2} seen lighting samples, the environment has {seen}"
            )
        c = project_environment(s.env, lmax)
        if not np.all(np.isfinite(c)):
            raise ValueError(f"scene {k}: the lighting contains NaN or inf")
        coeffs.append(c)
    return coeffs


def _design(spec: ModelSpec, coeffs: list[np.ndarray], pool: _Pool, idx: np.ndarray) -> np.ndarray:
    """Design rows (len(idx), n, C) of pixels ``idx`` (sorted: the pool is in scene order, so each scene is one run),
    laid out by :func:`brdfrig.fit.system.design_rows` (each channel's rows one Fortran-ordered matrix)."""
    return design_rows(spec, coeffs, pool.scene[idx], pool.normals[idx])


def _rel_error(pred: np.ndarray, target: np.ndarray, weights: np.ndarray) -> float:
    """Weighted relative RMS error; 0 when prediction and target both vanish."""
    w = weights[:, None]
    den = float(np.sum(w * target**2))
    num = float(np.sum(w * (pred - target) ** 2))
    if den <= 0:
        return 0.0 if num <= 0 else math.inf
    return math.sqrt(num / den)


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


@dataclass
class _Stream:
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
    population that adds rank shows up with probability 1.  (It used to combine 512 sampled rows; the
    row gather cost more than sketching the whole block: each channel's rows are one Fortran-ordered
    matrix, see :func:`_design`.)
    """
    g = rng.standard_normal((_SKETCH_ROWS, design.shape[0])) * sw
    worst = 0.0
    for c in range(design.shape[2]):
        s = g @ design[:, :, c]  # (k, n)
        inside, out = np.linalg.norm(s @ basis.w[c]), np.linalg.norm(s @ basis.null[c])
        worst = max(worst, out / max(math.hypot(inside, out), 1e-300))
    return worst


def _stream(spec, coeffs, pool, train, held, tol, progress, label, clock, reduce=False) -> _Stream:
    """Fold random pixel blocks into the QR factor until the stopping rule holds (module docstring, step 4).

    ``reduce``: when the first block shows the design rank-deficient (:func:`_reduced_basis`), the rest
    is folded in the reduced basis (QR of r instead of n columns) and the factor lifted back for the
    stopping rule and the solvers (same system up to rounding); if a later block adds rank, the stream
    starts again unreduced.  ``clock``: a :class:`_StageClock`.

    (Folding block k on a worker thread while block k + 1's design is assembled was tried and dropped:
    on the loaded 2-core machine the main thread then waited for the GIL about as long as it saved.)
    """
    t0 = time.perf_counter()
    with clock("design"):
        a_h = _design(spec, coeffs, pool, held)
    qr = StreamedQR(spec.n_unknowns, pool.radiance.shape[1])
    basis, rng = None, np.random.default_rng(0)
    prev, stable, converged, consumed = None, 0, False, 0
    blocks = range(0, len(train), BLOCK_ROWS)
    for start in tqdm(blocks, desc=f"fit {label}", unit="block", disable=not progress, leave=False):
        idx = np.sort(train[start : start + BLOCK_ROWS])  # row order is irrelevant to QR; sorted = one slice per scene
        with clock("design"):
            design, w = _design(spec, coeffs, pool, idx), pool.weights[idx]
        with clock("qr"):
            if basis is None:
                qr.add(design, pool.radiance[idx], w)
            elif _outside(design, np.sqrt(w), basis, rng) > REDUCE_OUTSIDE_RTOL:
                return _stream(spec, coeffs, pool, train, held, tol, progress, label, clock, reduce=False)
            else:
                qr.add(design, pool.radiance[idx], w, basis.w)
            consumed = start + len(idx)
            if reduce and start == 0 and qr.rows >= 3 * spec.n_unknowns:
                basis = _reduced_basis(qr)
                if basis is not None:
                    qr = StreamedQR(basis.back.shape[1], qr.channels)
                    qr.add(design, pool.radiance[idx], w, basis.w)
        if qr.rows < 3 * spec.n_unknowns or len(held) == 0:
            continue
        with clock("probe"):
            x = probe_solution(qr)  # in the reduced basis's coordinates when streaming reduced
            pred = np.einsum("inc,nc->ic", a_h, x if basis is None else np.einsum("cnr,rc->nc", basis.w, x))
        if prev is not None:
            change = np.linalg.norm(pred - prev) / max(np.linalg.norm(pred), 1e-300)
            stable = stable + 1 if change < tol else 0
            if stable >= 2:
                converged = True
                break
        prev = pred
    full = qr if basis is None else qr.lifted(basis.back)
    return _Stream(spec, full, a_h, consumed, converged, time.perf_counter() - t0, None if basis is None else qr.n)


def _solve_stream(st: _Stream, pool, train, held, solver, x0, clock, lam_min=None) -> tuple[np.ndarray, dict]:
    """Solve a streamed system with ``solver`` (prior ``x0``, Tikhonov floor ``lam_min``); the report entry."""
    t0 = time.perf_counter()
    spec, n = st.spec, st.spec.n_unknowns
    floor = {} if lam_min is None else {"lam_min": lam_min}
    with clock("solve"):
        sol = solve(st.qr, solver, bands=spec.column_band, x0=x0, **floor)
    used = train[: st.consumed]
    energy = float(np.sum(pool.weights[used, None] * pool.radiance[used] ** 2))
    held_err = None
    if len(held):
        held_err = _rel_error(np.einsum("inc,nc->ic", st.heldout_design, sol.x), pool.radiance[held], pool.weights[held])
    info = {
        "unknowns": n,
        "bands": list(spec.bands),
        "lmax": spec.lmax,
        "pmax": spec.pmax if spec.kind == "full" else None,
        "solver": solver,
        "rank": sol.rank.tolist(),
        "condition_number": sol.cond.tolist(),
        "condition_number_regularised": None if sol.cond_regularised is None else sol.cond_regularised.tolist(),
        "full_rank": bool(np.all(sol.rank == n)),
        "reduced_stream": None if st.reduced_columns is None else (
            f"rows streamed in a {st.reduced_columns}-column basis of the design's row space (found on the "
            f"first block, rank at {REDUCE_RTOL:g}); rank and condition number are of the lifted {n}-unknown system"
        ),
        "tikhonov_lambda_rel": None if sol.lam is None else sol.lam.tolist(),
        "tikhonov_lambda_min_rel": lam_min,
        "rows_used": st.qr.rows,
        "rows_available": int(len(train)),
        "stopping_rule_converged": st.converged,
        "train_relative_rms": math.sqrt(float(np.sum(sol.residual)) / energy) if energy > 0 else 0.0,
        "heldout_relative_rms": held_err,
        "seconds": st.seconds + time.perf_counter() - t0,
    }
    return sol.x, info


def _microfacet(scenes, pool, train, held, lmax, bands, progress):
    """Fit ``microfacet`` on the training pixels of the pool (limb margin applied, held-out pixels kept out)."""
    t0 = time.perf_counter()
    mine = [train[pool.scene[train] == k] for k in range(len(scenes))]
    fit_scenes = [Scene(s.env, pool.normals[r], pool.radiance[r], pool.weights[r]) for s, r in zip(scenes, mine)]
    brdf, rep = fit_microfacet(fit_scenes, lmax=lmax, bands=bands, progress=progress)
    pred = np.empty_like(pool.radiance[held])
    for s in np.unique(pool.scene[held]):
        rows = np.flatnonzero(pool.scene[held] == s)
        pred[rows] = brdf.predict(scenes[s].env, pool.normals[held[rows]])
    info = {
        "heldout_relative_rms": _rel_error(pred, pool.radiance[held], pool.weights[held]) if len(held) else None,
        "full_rank": rep["determined"],
        "fit_report": rep,
        "seconds": time.perf_counter() - t0,
    }
    return brdf, info


def fit_brdf(
    scenes: list[Scene],
    model: str = "auto",
    lmax: int = 8,
    pmax: int = 8,
    solver: str = "joint",
    progress: bool = True,
    *,
    max_theta_deg: float = DEFAULT_MAX_THETA_DEG,
    tol: float = STOP_TOL,
    seed: int = 0,
) -> FitResult:
    """Fit a BRDF to one or more scenes.

    Parameters
    ----------
    scenes : list of Scene
        Each: lighting (``Environment``) and the sphere's pixels (normals, radiance, weights).
    model : {"auto", "diffuse", "lobe", "microfacet", "full", "full+prior"}
        ``full+prior`` is ``full`` solved by Tikhonov (GCV, lambda >= :data:`PRIOR_LAM_MIN`,
        larger where identifiability calls ``full`` undetermined) toward the projection of the ``microfacet`` fit.
        ``full`` alone is solved as asked even when undetermined (minimum norm;
        the report says so); ``auto`` never picks an undetermined model.
    lmax, pmax : int
        Lighting and outgoing band limits.
    solver : {"paper", "joint", "tikhonov"}
        Solver of the linear models (``full+prior`` always uses ``tikhonov``).
    progress : bool
        tqdm bars on stderr.
    max_theta_deg : float
        Limb margin: pixels whose normal is further than this from the view are ignored.
    tol : float
        Stopping rule tolerance (relative change of the held-out prediction).
    seed : int
        Seed of the pixel order and the held-out draw.

    Returns
    -------
    FitResult
        Its report also holds ``seconds`` (wall clock) and ``stage_seconds`` (per :data:`STAGES`).
    """
    # The blocks are small (a few thousand x a few hundred): multithreaded BLAS only
    # adds contention (measured 15-30x slower QR on a loaded 2-core machine).
    with threadpool_limits(limits=1, user_api="blas"):
        return _fit_brdf(scenes, model, lmax, pmax, solver, progress, max_theta_deg, tol, seed)


def _fit_brdf(scenes, model, lmax, pmax, solver, progress, max_theta_deg, tol, seed) -> FitResult:
    if model not in MODELS:
        raise ValueError(f"unknown model {model!r}; expected one of {MODELS}")
    if solver not in SOLVERS:
        raise ValueError(f"unknown solver {solver!r}; expected one of {SOLVERS}")
    if lmax < 0 or pmax < 0:
        raise ValueError(f"band limits must be >= 0 (lmax={lmax}, pmax={pmax})")
    t0 = time.perf_counter()
    clock = _StageClock()
    with clock("gather"):
        pool, counts = _gather(scenes, max_theta_deg)
    with clock("lighting"):
        coeffs = _lighting(scenes, lmax)
    wanted = RICHNESS if model == "auto" else (model,)
    kinds = tuple(k for k in ("diffuse", "lobe", "full") if any(w.startswith(k) for w in wanted))
    with clock("identifiability"):
        ident = analyse_lighting(coeffs, lmax, pmax, models=kinds, theta_max_deg=max_theta_deg)
    bands = tuple(ident.observable_bands)
    if not bands:
        raise ValueError("the lighting has no energy in any band: nothing can be measured")

    rng = np.random.default_rng(seed)
    order = rng.permutation(len(pool.weights))
    n_held = min(int(HELDOUT_FRACTION * len(order)), HELDOUT_MAX)
    held, train = np.sort(order[:n_held]), order[n_held:]

    candidates: dict[str, dict] = {}
    fitted: dict[str, FittedBRDF] = {}
    full_lmax = lmax if model != "auto" else min(lmax, ident.full_lmax_determined)

    streams: dict[ModelSpec, _Stream] = {}  # one pixel stream (rotations, QR) per spec, shared by solvers and priors

    def linear(kind, name, spec_lmax, x0_brdf=None, use_solver=solver):
        spec = ModelSpec(kind, spec_lmax, pmax, bands=tuple(b for b in bands if b <= spec_lmax))
        if spec not in streams:
            # Reduce the stream where the lighting analysis already found the design rank-deficient
            # (the first block decides; the hint spares full-rank models its SVD).
            entry = ident.models.get(kind, {}) if spec_lmax == lmax else {}
            reduce = entry.get("rank", spec.n_unknowns) <= REDUCE_MAX_FRACTION * spec.n_unknowns
            streams[spec] = _stream(spec, coeffs, pool, train, held, tol, progress, name, clock, reduce=reduce)
        x0, lam_min = None, None
        if x0_brdf is not None:
            x0 = project_to_full(x0_brdf, spec)
            lam_min = PRIOR_LAM_MIN[spec_lmax <= ident.full_lmax_determined]
        x, info = _solve_stream(streams[spec], pool, train, held, use_solver, x0, clock, lam_min)
        fitted[name] = make_linear_brdf(spec, x)
        candidates[name] = info

    for name in wanted:
        if name in ("diffuse", "lobe"):
            linear(name, name, lmax)
        elif name == "microfacet":
            fitted[name], candidates[name] = _microfacet(scenes, pool, train, held, lmax, bands, progress)
        elif full_lmax < 0 or (model == "auto" and full_lmax < 1):
            candidates[name] = {"skipped": "the lighting separates no full-model band limit >= 1 (needs >= 2 differing scenes)"}
        elif name == "full":
            linear("full", name, full_lmax)
        else:  # full+prior: Tikhonov toward the best identifiable fit
            if "microfacet" not in fitted:  # requested alone: fit the prior first
                fitted["microfacet"], candidates["microfacet"] = _microfacet(scenes, pool, train, held, lmax, bands, progress)
            linear("full", name, full_lmax, x0_brdf=fitted["microfacet"], use_solver="tikhonov")
            candidates[name]["prior"] = "microfacet"

    # Determinacy of each candidate: lighting (identifiability) and pixels (achieved rank).
    for name, info in candidates.items():
        if "skipped" in info:
            info["determined"] = False
            continue
        if name in ("diffuse", "lobe"):
            det = ident.determined(name)
        elif name == "full":
            det = info["lmax"] <= ident.full_lmax_determined
        elif name == "full+prior":
            det = info["lmax"] <= ident.full_lmax_determined  # the prior only regularises
        else:
            det = True  # microfacet: a few parameters, identifiable from one image
        info["determined"] = bool(det and info["full_rank"])

    for name, brdf in fitted.items():
        candidates[name]["plausibility"] = plausibility(brdf)

    if model == "auto":
        ok = [m for m in RICHNESS if m in fitted and candidates[m]["determined"] and candidates[m]["heldout_relative_rms"] is not None]
        # Prefer physically plausible fits (an implausible one extrapolates outside what the lighting measured).
        ok = [m for m in ok if candidates[m]["plausibility"]["plausible"]] or ok
        if ok:
            best = min(candidates[m]["heldout_relative_rms"] for m in ok)
            chosen = [m for m in ok if candidates[m]["heldout_relative_rms"] <= best * (1 + SELECT_RTOL) + 1e-12][-1]
            reason = (
                f"richest determined model with held-out error within {SELECT_RTOL:.0%} of the best "
                f"({candidates[chosen]['heldout_relative_rms']:.4g} vs {best:.4g})"
            )
        else:
            chosen = "diffuse"
            reason = "no candidate reached full rank on these pixels; fell back to diffuse (minimum norm)"
    else:
        chosen = model
        det = candidates[model].get("determined", False)
        reason = "requested" + ("" if det else " (WARNING: not determined by these data; see identifiability)")
    if chosen not in fitted:
        raise ValueError(f"model {chosen!r} could not be fitted: {candidates[chosen]}")

    warnings = []
    if ident.unobservable_bands:
        warnings.append(f"bands {ident.unobservable_bands} have no lighting energy: not measured, left out")
    if counts["non_finite"]:
        warnings.append(f"{counts['non_finite']} non-finite pixel(s) ignored")
    info = candidates[chosen]
    regularised = info.get("solver") == "tikhonov"  # judge the system actually solved
    cond = max(info.get("condition_number_regularised" if regularised else "condition_number") or [0.0])
    if cond > COND_WARN:
        remedies = "fewer bands or more scenes" if regularised else "try tikhonov, fewer bands or more scenes"
        warnings.append(
            f"{chosen}: {'regularised ' if regularised else ''}condition number {cond:.3g} > {COND_WARN:g}: "
            f"directions the lighting barely excites may relight badly under other lighting ({remedies})"
        )
    if chosen in fitted and not info["plausibility"]["plausible"]:
        warnings.append(
            f"{chosen}: not physically plausible ({info['plausibility']}): the lighting did not constrain "
            "the whole BRDF; relighting under other lighting is unreliable"
        )
    if "rows_used" in info and info["rows_used"] < 3 * info["unknowns"]:
        warnings.append(f"{chosen}: only {info['rows_used']} pixels for {info['unknowns']} unknowns")
    if not info.get("determined", False):
        warnings.append(f"{chosen} is NOT determined by these data")

    report = {
        "chosen_model": chosen,
        "reason": reason,
        "requested_model": model,
        "solver": solver,
        "lmax": lmax,
        "pmax": pmax,
        "n_scenes": len(scenes),
        "pixels": counts,
        "limb_margin_max_theta_deg": max_theta_deg,
        "heldout_pixels": int(len(held)),
        "stopping_rule": (
            f"random pixel blocks of {BLOCK_ROWS}; stop when the held-out prediction changes by < {tol:g} "
            "(relative) for two consecutive blocks"
        ),
        "unobservable_bands": ident.unobservable_bands,
        "identifiability": ident.to_dict(),
        "identifiability_summary": ident.summary(),
        "candidates": candidates,
        "warnings": warnings,
        "seconds": time.perf_counter() - t0,
        "stage_seconds": clock.report(),
    }
    return FitResult(brdf=fitted[chosen], report=report)
