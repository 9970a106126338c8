"""``fit_brdf``: fit a BRDF to sphere images under measured lighting, choosing a model that relights.

Pipeline (``docs/MATH.md``):

1. Pixels and lighting (:mod:`brdfrig.fit.stream`): usable pixels within the limb margin
   (:data:`DEFAULT_MAX_THETA_DEG`), every exclusion counted; each scene's lighting in SH.
2. Identifiability from the lighting alone (:mod:`brdfrig.fit.identifiability`): bands without lighting
   energy are dropped from every model (reported), and ``full`` is only a candidate of ``auto`` at band
   limits the scenes separate.
3. Held-out pixels: a random :data:`HELDOUT_FRACTION` of the pixels (at most :data:`HELDOUT_MAX`) never
   enter a fit; they drive the stopping rule of the streamed linear models and each candidate's
   held-out error is reported.
4. Candidates (:data:`brdfrig.fit.registry.REGISTRY`): the linear SH models share one streamed QR factor
   per model (:func:`brdfrig.fit.stream.stream_model`) across solvers and priors; single-model fits
   (``microfacet``, ...) get the training pixels of each scene.
5. Relighting estimate of every candidate under other lighting (:mod:`brdfrig.fit.relight`):
   leave-one-scene-out with two or more scenes, the rotated-lighting spread with one.  The tables' blend
   (:mod:`brdfrig.fit.blend`) is then weighted by their one-image estimates, or stacked on their
   leave-one-scene-out predictions.  ``auto`` (and the blend) compare candidates (weigh the tables) on
   interleaved folds and, with more scenes than folds, report the chosen fit's estimate from folds of
   consecutive scenes (``"arcs"``), where a blend ``auto`` chose gives way to its best part if that part
   relights the arcs better than the blend with weights stacked on the other arcs; another requested
   model's estimate is the arcs'.  One-image fits also
   keep ``bivariate+measured``'s tables re-solved on resampled references (its report's ``resampled_tables``),
   several-scene fits the chosen table's (a blend's parts') refits on the folds its estimate came from
   (``fold_tables``, ``fold_spread``): :func:`brdfrig.fit.relight.lighting_estimate` turns them into an estimate
   for a given lighting.
6. Judgement and choice (:mod:`brdfrig.fit.select`): determinacy, finite non-negative predicted
   radiance, plausibility; from one image ``auto`` keeps a parametric family where it holds against a
   flexible table (held-out errors above the pixel noise, :mod:`brdfrig.fit.noise`), else takes the
   tables' blend; with several
   scenes it picks by the relighting estimate.  The report is a
   :class:`brdfrig.fit.report.FitReport`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from threadpoolctl import threadpool_limits

from brdfrig.errors import InputError
from brdfrig.fit.bivariate import RESAMPLES
from brdfrig.fit.blend import PARTS, BlendBRDF, blend_estimate, inverse_variance_weights, nested_stacking, stacked_weights
from brdfrig.fit.brdf import FittedBRDF
from brdfrig.fit.metrics import relative_rms, relative_spread
from brdfrig.fit.identifiability import THETA_MAX_DEG, Identifiability, analyse_lighting
from brdfrig.fit.models import make_linear_brdf, plausibility, project_to_full
from brdfrig.fit.noise import scenes_noise
from brdfrig.fit.references import shipped
from brdfrig.fit.registry import MODELS, PARAMETRIC, PRIOR_OF, REGISTRY, RICHNESS, SOLVERS, single_fit
from brdfrig.fit.relight import (LOSO_MAX_FOLDS, SPREAD, LosoPredictions, across_lightings, estimate_pixels,
                                 fold_predictions, loso_predictions, other_lightings, predict_held, predict_under, spread_estimates)
from brdfrig.fit.report import Candidate, FitReport, RelightEstimate
from brdfrig.fit.scene import Scene
from brdfrig.fit.select import choose, fit_warnings, judge, radiance_problem
from brdfrig.fit.stream import (
    BLOCK_ROWS, STOP_TOL, FitData, StageClock, Stream, gather_pixels, project_lighting,
    solve_stream, stream_model,
)
from brdfrig.fit.system import ModelSpec

__all__ = ["FitResult", "fit_brdf", "MODELS", "RICHNESS", "SOLVERS", "DEFAULT_MAX_THETA_DEG", "STOP_TOL"]

DEFAULT_MAX_THETA_DEG = THETA_MAX_DEG
HELDOUT_FRACTION = 0.1
HELDOUT_MAX = 2000
PRIOR_LAM_MIN = {True: 1e-2, False: 1e-1}
"""``full+prior``: smallest Tikhonov lambda, relative to the largest singular value of the
column-equilibrated system, keyed by whether the identifiability analysis calls ``full`` determined
at this band limit.  Directions the lighting excites less than this fraction of the best-excited one
stay (mostly) at the prior.  Without a floor GCV, whose score with m ~ 1e4-1e6 rows is essentially
the residual, picks lambda ~ 1e-12 on one scene: the fit image's SH truncation error, amplified
along barely excited directions, relights at 2e5 relative error.  Measured (GGX alpha 0.3 sphere,
48 px, l = p = 6, grace -> pisa, priors: microfacet / lobe / a wrong GGX): one scene, floor 0.1:
0.61% / 3.5% / 7.7% vs 0.42% / 3.6% / 8.5% for the prior's own projection onto ``full`` (0.01:
1.2% / 3.4% / 7.7%); twelve scenes, floor 0.01: 0.97% / 0.93% / 1.35% vs 2.7% for plain ``full``
(0.1: 0.55% / 2.3% / 6.2%: too strong once the data determine the model)."""
LOSO_MAX_CANDIDATES = 4
"""With several scenes, the leave-one-scene-out estimate refits (per fold) the requested model or, for
``auto``, the admissible candidates with the smallest held-out errors, at most this many (the others get
no estimate and are not chosen), and the blend's parts (:data:`brdfrig.fit.blend.PARTS`) where a blend is wanted."""
REFERENCES = tuple(m for m in RICHNESS if REGISTRY[m].kind == "single" or m in ("diffuse", "lobe"))
"""Candidates a one-scene fit of a requested model is compared with for its relighting estimate
(the models one image determines)."""
BLEND = "bivariate+blend"
"""The model built from the other candidates' estimates (:mod:`brdfrig.fit.blend`)."""


@dataclass
class FitResult:
    """A fitted BRDF, its report, and every candidate fitted on all the pixels (``brdfs``, by model name)."""

    brdf: FittedBRDF
    report: FitReport
    brdfs: dict[str, FittedBRDF] = field(default_factory=dict)


class _Candidates:
    """Fits candidates on one :class:`~brdfrig.fit.stream.FitData`, one pixel stream per model spec."""

    def __init__(self, data: FitData, ident: Identifiability, lmax: int, pmax: int, solver: str, required: str | None = None,
                 reference_tables=None, prior_family: str | None = None, judged: tuple[str, ...] | None = None,
                 resamples: int = 0) -> None:
        """``required``: the model asked for (its fit errors propagate; another candidate's failure only skips it);
        ``reference_tables``: those of ``bivariate+measured`` (None: :func:`brdfrig.fit.references.shipped`);
        ``resamples``: its bootstrap resamples of the references (:func:`brdfrig.fit.bivariate.fit_bivariate`);
        ``prior_family``: the parametric family to try first as a table's prior (:meth:`_parametric_prior`);
        ``judged``: the single-model fits whose held-out pixels are predicted (None: all; a fold's refits need only
        the parametric families', to choose a prior)."""
        self.data, self.ident, self.lmax, self.pmax, self.solver = data, ident, lmax, pmax, solver
        self.required = required
        self.reference_tables = reference_tables
        self.prior_family = prior_family
        self.judged = judged
        self.resamples = resamples
        self.bands = tuple(ident.observable_bands)
        self.streams: dict[ModelSpec, Stream] = {}
        self.brdfs: dict[str, FittedBRDF] = {}
        self.entries: dict[str, Candidate] = {}
        self.held_preds: dict[str, np.ndarray] = {}
        self.loso: LosoPredictions | None = None
        self.spread: dict[str, RelightEstimate] = {}

    def fit(self, name: str, full_lmax: int, auto: bool) -> Candidate:
        """Fit ``name`` (``full`` and ``full+prior`` at band limit ``full_lmax``, skipped where it is < 0, or < 1 for ``auto``)."""
        if name in self.entries:
            return self.entries[name]
        kind = REGISTRY[name].kind
        if kind == "single":
            try:
                cand = self._single(name, self._parametric_prior(full_lmax, auto) if REGISTRY[name].prior_parametric else None)
            except (ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
                if name == self.required:
                    raise
                cand = Candidate(name, skipped=f"fit failed: {exc}")
        elif name in ("diffuse", "lobe"):
            cand = self._linear(name, name, self.lmax, self.solver)
        elif full_lmax < 0 or (auto and full_lmax < 1):
            cand = Candidate(name, skipped="the lighting separates no full-model band limit >= 1 (needs >= 2 differing scenes)")
        elif kind == "linear":
            cand = self._linear("full", name, full_lmax, self.solver)
        else:  # prior: Tikhonov toward the best identifiable fit
            prior = PRIOR_OF[name]
            self.fit(prior, full_lmax, auto)
            cand = self._linear("full", name, full_lmax, "tikhonov", self.brdfs.get(prior))
            cand.prior = prior
        self.entries[name] = cand
        return cand

    def _linear(self, kind: str, name: str, spec_lmax: int, solver: str, prior: FittedBRDF | None = None) -> Candidate:
        t0 = time.perf_counter()
        spec = ModelSpec(kind, spec_lmax, self.pmax, bands=tuple(b for b in self.bands if b <= spec_lmax))
        if spec not in self.streams:
            # Reduce the stream where the lighting analysis already found the design rank-deficient
            # (the first block decides; the hint spares full-rank models its SVD).
            entry = self.ident.models.get(kind, {}) if spec_lmax == self.lmax else {}
            self.streams[spec] = stream_model(spec, self.data, name, entry.get("rank"))
        x0 = lam_min = None
        if prior is not None:
            x0 = project_to_full(prior, spec)
            lam_min = PRIOR_LAM_MIN[spec_lmax <= self.ident.full_lmax_determined]
        st = self.streams[spec]
        x, stats, held_err = solve_stream(st, self.data, solver, x0, lam_min)
        self.brdfs[name] = make_linear_brdf(spec, x)
        check = radiance_problem(np.einsum("inc,nc->ic", st.heldout_design, x), "held-out pixels") if len(self.data.held) else None
        return Candidate(name, heldout_relative_rms=held_err, full_rank=stats.full_rank, system=stats,
                         radiance_check=check, seconds=st.seconds + time.perf_counter() - t0)

    def _parametric_prior(self, full_lmax: int, auto: bool) -> str:
        """Fit every parametric family (:data:`PARAMETRIC`); the one with the smallest held-out error and
        finite, non-negative held-out radiance.  With ``prior_family`` set (a leave-one-scene-out fold takes the
        family chosen on all the data) that family alone, unless its fit fails that test."""
        for families in ((self.prior_family,) if self.prior_family else (), PARAMETRIC):
            for m in families:
                self.fit(m, full_lmax, auto)
            usable = {m: self.entries[m].heldout_relative_rms for m in families
                      if m in self.brdfs and self.entries[m].radiance_check is None}
            if usable:
                return min(usable, key=lambda m: math.inf if usable[m] is None else usable[m])
        raise ValueError("no parametric fit to take as the prior")

    def _single(self, name: str, prior: str | None = None) -> Candidate:
        """A single-model fit on the training pixels of each scene (limb margin applied, held-out pixels kept
        out); ``prior``: the candidate passed to it as ``prior=``."""
        t0 = time.perf_counter()
        data = self.data
        extra = {} if prior is None else {"prior": self.brdfs[prior]}
        if REGISTRY[name].prior_references:
            extra["references"] = self.reference_tables if self.reference_tables is not None else shipped()
            extra["resamples"] = self.resamples
        brdf, rep = single_fit(name)(data.train_scenes(), lmax=self.lmax, bands=self.bands, progress=data.progress, **extra)
        self.brdfs[name] = brdf
        held_err, check = self._held_out(name, brdf) if self.judged is None or name in self.judged else (None, None)
        return Candidate(name, heldout_relative_rms=held_err, full_rank=bool(rep["determined"]), fit_report=rep,
                         radiance_check=check, seconds=time.perf_counter() - t0, prior=prior)

    def _held_out(self, name: str, brdf: FittedBRDF, pred: np.ndarray | None = None) -> tuple[float | None, str | None]:
        """(held-out error, radiance problem) of a fit; its held-out prediction (``pred``, else predicted) is kept."""
        data = self.data
        if not len(data.held):
            return None, None
        pred = predict_held(data, {name: brdf})[name] if pred is None else pred
        self.held_preds[name] = pred
        held_err = None
        if np.all(np.isfinite(pred)):
            held_err = relative_rms(pred, data.pool.radiance[data.held], data.pool.weights[data.held])
        return held_err, radiance_problem(pred, "held-out pixels")

    def blend(self) -> Candidate:
        """:data:`BLEND` from the tables already fitted and estimated (:mod:`brdfrig.fit.blend`): from one image
        their inverse-variance average, with several scenes their stacking on the leave-one-scene-out
        predictions (``self.loso``); skipped with fewer than two such tables."""
        t0 = time.perf_counter()
        ok = [m for m in PARTS if m in self.brdfs and self.entries[m].radiance_check is None]
        if self.loso is not None:
            parts = [m for m in ok if m in self.loso.preds]
        else:
            parts = [m for m in ok if self.entries[m].relight is not None and self.entries[m].relight.value is not None
                     and math.isfinite(self.entries[m].relight.value) and self.entries[m].relight.value > 0]
        if len(parts) < 2:
            cand = Candidate(BLEND, skipped=f"fewer than two table fits with a relighting estimate ({parts})")
        else:
            errors = [self.entries[m].relight.value for m in parts]
            if self.loso is None:
                weights = inverse_variance_weights(errors)
            else:
                preds = [self.loso.preds[m] for m in parts]
                weights = stacked_weights(preds, self.loso.target, self.loso.weights)
            brdf = self.brdfs[BLEND] = BlendBRDF([self.brdfs[m] for m in parts], weights)
            if self.loso is None:
                relight = RelightEstimate(blend_estimate(errors), self.entries[parts[0]].relight.method,
                                          "the smallest of the parts' estimates")
            else:
                spreads = [self.spread[m].value for m in parts if m in self.spread]
                if len(spreads) == len(parts):
                    self.spread[BLEND] = RelightEstimate(blend_estimate(spreads), SPREAD, "the smallest of the parts' spreads")
                relight = self.loso.estimate(brdf.combine(preds))
                relight.detail += "; the weights stacked on these folds"
                relight = across_lightings(relight, self.spread.get(BLEND))
            relight.detail += " (weights: " + ", ".join(f"{m} {w:.3f}" for m, w in zip(parts, weights)) + ")"
            pred = brdf.combine([self.held_preds[m] for m in parts]) if all(m in self.held_preds for m in parts) else None
            held_err, check = self._held_out(BLEND, brdf, pred)
            cand = Candidate(BLEND, heldout_relative_rms=held_err, full_rank=True, radiance_check=check, relight=relight,
                             fit_report={"parts": dict(zip(parts, weights.tolist())), "estimates": dict(zip(parts, errors))},
                             seconds=sum(self.entries[m].seconds for m in parts) + time.perf_counter() - t0)
        if cand.skipped and self.required == BLEND:
            raise InputError(f"{BLEND}: {cand.skipped}")
        self.entries[BLEND] = cand
        return cand


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
    estimate: bool | None = None,
    reference_tables=None,
) -> FitResult:
    """Fit a BRDF to one or more scenes.

    Parameters
    ----------
    scenes : list of Scene
        Each: lighting (``Environment``) and the sphere's pixels (normals, radiance, weights).
    model : str
        One of :data:`MODELS`.  ``full+prior`` is ``full`` solved by Tikhonov (GCV, lambda >=
        :data:`PRIOR_LAM_MIN`, larger where identifiability calls ``full`` undetermined) toward the
        projection of the ``microfacet`` fit.  ``full`` alone is solved as asked even when undetermined
        (minimum norm; the report says so); ``auto`` never picks an undetermined model.
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
    estimate : bool or None
        Estimate the relighting error (:mod:`brdfrig.fit.relight`; None: only for ``auto``, whose
        choice depends on it).  A requested model is then also compared with :data:`REFERENCES` (one
        scene) or refitted per fold (several scenes), at the cost of those fits.
    reference_tables : brdfrig.fit.references.ReferenceTables, optional
        The measured materials ``bivariate+measured`` combines (default: the shipped set,
        :func:`brdfrig.fit.references.shipped`); a benchmark passes the set without its own material.

    Returns
    -------
    FitResult
        The report also holds ``seconds`` (wall clock) and ``stage_seconds`` (per
        :data:`brdfrig.fit.stream.STAGES`).
    """
    if model not in MODELS:
        raise ValueError(f"unknown model {model!r}; expected one of {MODELS}")
    if solver not in SOLVERS:
        raise ValueError(f"unknown solver {solver!r}; expected one of {SOLVERS}")
    if lmax < 0 or pmax < 0:
        raise ValueError(f"band limits must be >= 0 (lmax={lmax}, pmax={pmax})")
    # The blocks are small (a few thousand x a few hundred): multithreaded BLAS only
    # adds contention (measured 15-30x slower QR on a loaded 2-core machine).
    with threadpool_limits(limits=1, user_api="blas"):
        return _fit_brdf(scenes, model, lmax, pmax, solver, progress, max_theta_deg, tol, seed,
                         bool(estimate) or model in ("auto", BLEND), reference_tables)


def _wanted(model: str, n_scenes: int, estimate: bool) -> tuple[str, ...]:
    """Candidates to fit: all for ``auto``; the requested one, plus the one-image references when its
    one-scene estimate needs them."""
    if model == "auto":
        return RICHNESS
    extra = REFERENCES if estimate and n_scenes == 1 else ()
    if model == BLEND:
        extra += PARTS
    return tuple(m for m in RICHNESS if m == model or m in extra)


def _analyse(data: FitData, scenes_in: list[int], lmax: int, pmax: int, wanted, max_theta_deg: float) -> Identifiability:
    kinds = tuple(k for k in ("diffuse", "lobe", "full") if any(w.startswith(k) for w in wanted))
    with data.clock("identifiability"):
        return analyse_lighting([data.coeffs[k] for k in scenes_in], lmax, pmax, models=kinds, theta_max_deg=max_theta_deg)


def _fit_brdf(scenes, model, lmax, pmax, solver, progress, max_theta_deg, tol, seed, estimate, reference_tables) -> FitResult:
    t0 = time.perf_counter()
    clock = StageClock()
    with clock("gather"):
        pool, counts = gather_pixels(scenes, max_theta_deg)
    with clock("lighting"):
        coeffs = project_lighting(scenes, lmax)
    noise = None
    if model == "auto" and len(scenes) == 1:  # only the one-image choice uses it
        with clock("noise"):
            usable = pool.weights > 0
            noise = scenes_noise(pool.scene[usable], pool.normals[usable], pool.radiance[usable])
    order = np.random.default_rng(seed).permutation(len(pool.weights))
    n_held = min(int(HELDOUT_FRACTION * len(order)), HELDOUT_MAX)
    data = FitData(scenes, pool, coeffs, order[n_held:], np.sort(order[:n_held]), clock, progress, tol)
    wanted = _wanted(model, len(scenes), estimate)
    ident = _analyse(data, list(range(len(scenes))), lmax, pmax, wanted, max_theta_deg)
    if not ident.observable_bands:
        raise InputError("the lighting has no energy in any band: nothing can be measured")

    full_lmax = lmax if model != "auto" else min(lmax, ident.full_lmax_determined)
    fitter = _Candidates(data, ident, lmax, pmax, solver, None if model == "auto" else model, reference_tables,
                         resamples=RESAMPLES if estimate and len(scenes) == 1 else 0)
    for name in wanted:
        if name != BLEND:
            fitter.fit(name, full_lmax, model == "auto")
    cands = fitter.entries
    _judge(fitter, ident, list(cands))
    prior_family = next((c.prior for m, c in cands.items() if REGISTRY[m].prior_parametric and c.prior), None)
    settings = (lmax, pmax, solver, full_lmax, max_theta_deg, reference_tables, prior_family)
    if estimate:
        _estimate(data, fitter, model, settings, PARTS if BLEND in wanted else ())
    if BLEND in wanted:  # built from the other candidates' estimates
        fitter.blend()
        _judge(fitter, ident, [BLEND])

    if model == "auto":
        chosen, reason, selection = choose(cands, noise, one_image=len(scenes) == 1)
    else:
        chosen, selection = model, "requested"
        reason = "requested" + ("" if cands[model].determined else " (WARNING: not determined by these data; see identifiability)")
    if chosen not in fitter.brdfs:
        raise ValueError(f"model {chosen!r} could not be fitted: {cands[chosen].to_dict()}")
    relight = cands[chosen].relight or RelightEstimate(None, "none", "not estimated (estimate=False)")
    folds = fitter.loso
    if estimate and model in ("auto", BLEND) and len(scenes) > LOSO_MAX_FOLDS:  # the two splits differ
        with data.clock("other"):
            relight, folds = _arcs_estimate(data, fitter, chosen, settings, model == "auto")
            if model == "auto" and chosen == BLEND:
                chosen, relight, reason = _blend_or_part(fitter, folds, relight, reason)
    if folds is not None:
        with data.clock("other"):
            _keep_folds(fitter, data, chosen, folds)
    report = FitReport(
        chosen_model=chosen, reason=reason, requested_model=model, solver=solver, lmax=lmax, pmax=pmax,
        n_scenes=len(scenes), pixels=counts, limb_margin_max_theta_deg=max_theta_deg, heldout_pixels=int(len(data.held)),
        stopping_rule=(f"random pixel blocks of {BLOCK_ROWS}; stop when the held-out prediction changes by < {tol:g} "
                       "(relative) for two consecutive blocks"),
        unobservable_bands=ident.unobservable_bands, identifiability=ident.to_dict(),
        identifiability_summary=ident.summary(), candidates=cands, selection=selection,
        relight=relight,
        pixel_noise=noise, warnings=fit_warnings(cands[chosen], ident, counts),
    )
    report.seconds, report.stage_seconds = time.perf_counter() - t0, clock.report()
    return FitResult(brdf=fitter.brdfs[chosen], report=report, brdfs=dict(fitter.brdfs))


def _judge(fitter: _Candidates, ident: Identifiability, names: list[str]) -> None:
    """Determinacy and plausibility of the candidates ``names``."""
    for name in names:
        judge(fitter.entries[name], ident)
        if name in fitter.brdfs:
            fitter.entries[name].plausibility = plausibility(fitter.brdfs[name])


def _estimate(data: FitData, fitter: _Candidates, model: str, settings: tuple, parts: tuple) -> None:
    """Check every fitted candidate's radiance under other lightings and set its ``relight`` estimate.

    With several scenes the leave-one-scene-out pass also refits ``parts`` (a blend's) and is kept as
    ``fitter.loso``, and the spreads as ``fitter.spread``; each estimate combines the two
    (:func:`~brdfrig.fit.relight.across_lightings`)."""
    cands = fitter.entries
    with data.clock("other"):
        envs = other_lightings(data.scenes[0].env)
        normals, weights = estimate_pixels(data)
        preds = {}
        for m, pred in predict_under(fitter.brdfs, envs, normals).items():
            cands[m].radiance_check = cands[m].radiance_check or radiance_problem(pred, "other lightings")
            if np.all(np.isfinite(pred)):
                preds[m] = pred
        spread = spread_estimates(preds, weights, {m: cands[m].heldout_relative_rms for m in preds})
        if len(data.scenes) >= 2:
            names = [m for m in fitter.brdfs if model == m or (cands[m].determined and cands[m].radiance_check is None)]
            names = sorted(names, key=lambda m: (m != model, cands[m].heldout_relative_rms or 0.0))[:LOSO_MAX_CANDIDATES]
            names += [m for m in parts if m in fitter.brdfs and m not in names]
            # auto and the blend choose on one split (candidate, weights) and report on the other
            split = "interleaved" if model in ("auto", BLEND) else "arcs"
            fitter.loso = _loso(data, names, settings, model == "auto", split)
            fitter.spread = spread
            estimates = {m: across_lightings(e, spread.get(m)) for m, e in fitter.loso.estimates(names).items()}
        else:
            estimates = spread
    for m, est in estimates.items():
        cands[m].relight = est


def _keep_folds(fitter: _Candidates, data: FitData, chosen: str, loso: LosoPredictions) -> None:
    """The chosen table (or each part of the chosen blend) refitted on every fold of the leave-one-scene-out pass
    that gave its estimate: the refits' node values (``fold_tables``) in its report, and their spread over the
    left-out pixels (``fold_spread``) in the chosen model's (a blend's parts combined with its weights), for
    :func:`~brdfrig.fit.relight.lighting_estimate`.  Nothing for a model without table refits on every fold."""
    names, combine = _parts(fitter, chosen)
    preds = {m: p for m in names if (p := fold_predictions(data, loso, m)) is not None}
    if len(preds) < len(names):
        return
    for m in names:
        fitter.entries[m].fit_report["fold_tables"] = np.stack([np.moveaxis(b.tables, 0, 1) for b in loso.brdfs[m]])
    fitter.entries[chosen].fit_report["fold_spread"] = relative_spread(combine([preds[m] for m in names]), loso.weights)


def _parts(fitter: _Candidates, chosen: str) -> tuple[list[str], Callable[[list[np.ndarray]], np.ndarray]]:
    """The models refitted for ``chosen`` (a blend's parts, else itself) and how their predictions combine into its."""
    if chosen == BLEND:
        return list(fitter.entries[BLEND].fit_report["parts"]), fitter.brdfs[BLEND].combine
    return [chosen], lambda preds: preds[0]


def _loso(data: FitData, names: list[str], settings: tuple, auto: bool, split: str) -> LosoPredictions:
    """Leave-one-scene-out predictions of ``names`` on the folds of ``split``, each fold refitted by :func:`_refit`."""
    return loso_predictions(data, names, lambda fold, ms: _refit(fold, ms, settings, auto), split)


def _arcs_estimate(data: FitData, fitter: _Candidates, chosen: str, settings: tuple, auto: bool) -> tuple[RelightEstimate, LosoPredictions]:
    """Estimate of ``chosen`` from the ``"arcs"`` split (a blend's parts refitted and combined with the blend's
    weights) and its spread (:func:`~brdfrig.fit.relight.across_lightings`), and the arcs pass."""
    names, combine = _parts(fitter, chosen)
    run = _loso(data, names, settings, auto, "arcs")
    missing = any(m not in run.preds for m in names)
    return across_lightings(run.estimate(None if missing else combine([run.preds[m] for m in names])), fitter.spread.get(chosen)), run


def _blend_or_part(fitter: _Candidates, run: LosoPredictions, relight: RelightEstimate,
                   reason: str) -> tuple[str, RelightEstimate, str]:
    """``auto``'s chosen blend against its own parts on the arcs pass ``run``: ``(chosen, its estimate, reason)``.

    The blend's weights were stacked on the interleaved folds, so its error there is in sample.  Here the part
    with the smallest leave-one-scene-out error replaces the blend when that error is below the blend's with
    weights stacked on the other arcs (:func:`~brdfrig.fit.blend.nested_stacking`): both out of sample."""
    names = list(fitter.entries[BLEND].fit_report["parts"])
    if any(m not in run.preds for m in names):
        return BLEND, relight, reason
    nested = run.estimate(nested_stacking([run.preds[m] for m in names], run.target, run.weights, run.fold)).value
    if nested is None:  # no radiance in the left-out pixels
        return BLEND, relight, reason
    own = run.estimates(names)
    part = min(names, key=lambda m: own[m].value)
    versus = f"{part} {own[part].value:.4g} against the blend {nested:.4g} (weights stacked on the other arcs)"
    if own[part].value >= nested:
        return BLEND, relight, f"{reason}; kept against its best part on the arcs folds: {versus}"
    estimate = across_lightings(own[part], fitter.spread.get(part))
    return part, estimate, f"{reason}; replaced by its part {part}, better on the arcs folds: {versus}"


def _refit(fold: FitData, names: list[str], settings: tuple, auto: bool) -> dict[str, FittedBRDF]:
    """Fit ``names`` on a fold's training pixels (the fold's own identifiability); their BRDFs."""
    lmax, pmax, solver, full_lmax, max_theta_deg, reference_tables, prior_family = settings
    present = sorted(set(np.unique(fold.pool.scene[fold.train]).tolist()))
    quiet = fold.with_split(fold.train, fold.held)
    quiet.progress = False
    ident = _analyse(quiet, present, lmax, pmax, names, max_theta_deg)
    sub = _Candidates(quiet, ident, lmax, pmax, solver, reference_tables=reference_tables, prior_family=prior_family,
                      judged=PARAMETRIC)
    for m in names:
        sub.fit(m, full_lmax, auto)
    return {m: b for m, b in sub.brdfs.items() if m in names}
