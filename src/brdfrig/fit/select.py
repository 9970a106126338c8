"""Judging the candidate fits of ``fit_brdf``: determinacy, admissibility, the choice of ``auto``, warnings.

- Determinacy (:func:`judge`): from the lighting alone (identifiability analysis) and from the pixels
  (the linear system reached full rank; a single-model fit's own ``determined``).
- Radiance check: every candidate's predicted radiance (held-out pixels and the relighting estimate's
  other lightings) must be finite and non-negative (:func:`radiance_problem`).
- Choice (:func:`choose`): ``auto`` keeps the determined candidates, of those the ones whose radiance
  check passed and of those the physically plausible ones (each filter applied when it leaves any:
  :func:`brdfrig.fit.models.plausibility`).  From one image it asks whether a parametric family holds
  (:func:`family_holds`): the family with the smallest held-out error is kept when that error, above
  the image's pixel noise, is at most :data:`FAMILY_HOLDS` times the flexible table's
  (:data:`YARDSTICK`) plus :data:`NOISE_TOL` times the noise; otherwise the first of :data:`TABLES` admitted.  With several scenes (or without those candidates) it
  picks the one with the smallest estimated relighting error (:mod:`brdfrig.fit.relight`); of those
  within :data:`SELECT_RTOL` of it, the one with the smallest held-out error.  Without any estimate it
  picks the richest (order :data:`brdfrig.fit.registry.RICHNESS`) whose held-out error (same lighting)
  is within :data:`SELECT_RTOL` of the best.
"""

from __future__ import annotations

import math

import numpy as np

from brdfrig.fit.identifiability import Identifiability
from brdfrig.fit.registry import PARAMETRIC, REGISTRY, RICHNESS
from brdfrig.fit.report import Candidate, PixelCounts

__all__ = ["SELECT_RTOL", "FAMILY_HOLDS", "NOISE_TOL", "YARDSTICK", "TABLES", "COND_WARN", "NEGATIVE_RTOL", "judge", "radiance_problem",
           "excess_error", "family_holds", "choose", "fit_warnings"]

SELECT_RTOL = 0.02
"""``auto`` picks the richest candidate whose score is within this fraction of the best."""
FAMILY_HOLDS = 0.5
"""From one image a parametric family is kept when its held-out error above the noise is at most this
fraction of the table's (docs/DESIGN.md, History: the one-image choice of ``auto``)."""
NOISE_TOL = 0.3
"""... plus this fraction of the pixel noise: two fits that both reproduce the held-out pixels to the noise
tie, and the family is kept."""
YARDSTICK = "bivariate+prior"
"""The flexible fit a parametric family's held-out error is weighed against from one image (docs/DESIGN.md,
History: the one-image choice of ``auto``)."""
TABLES = ("bivariate+blend", "bivariate+measured")
"""The data-driven candidates ``auto`` takes from one image when no family holds, in order of preference
(:data:`YARDSTICK` where neither is admitted): the tables' inverse-variance blend (docs/DESIGN.md, History:
blending the one-image tables), else the measured-prior table.  Neither is the yardstick: the measured-prior
table reproduces an image of a family's own BRDF so closely (a dielectric: 0.099% held out against the
family's 0.061%) that the family would not hold (docs/DESIGN.md, History: reference tables)."""
COND_WARN = 1e6
"""Condition number (column-equilibrated) above which the report warns that weakly determined
directions may relight badly under other lighting.  For the ``tikhonov`` solver (and ``full+prior``)
the condition number judged is that of the regularised system solved
(:attr:`brdfrig.fit.report.SystemStats.condition_number_regularised`): a fit the prior keeps well
determined does not warn."""
NEGATIVE_RTOL = 1e-3
"""Predicted radiance below ``-NEGATIVE_RTOL`` times the mean absolute prediction counts as negative."""


def judge(cand: Candidate, ident: Identifiability) -> None:
    """Set ``cand.determined`` from the lighting analysis and the achieved rank."""
    if not cand.fitted:
        cand.determined = False
        return
    kind = REGISTRY[cand.name].kind
    if kind == "linear" and cand.name != "full":
        det = ident.determined(cand.name)
    elif kind in ("linear", "prior"):  # full, and full+prior (the prior only regularises)
        det = cand.system.lmax <= ident.full_lmax_determined
    else:
        det = True  # single-model fits: a few parameters; their own report's "determined" is full_rank
    cand.determined = bool(det and cand.full_rank)


def radiance_problem(pred: np.ndarray, where: str) -> str | None:
    """None if ``pred`` is finite and non-negative (within :data:`NEGATIVE_RTOL`), else what is wrong."""
    pred = np.asarray(pred)
    bad = int(np.count_nonzero(~np.isfinite(pred)))
    if bad:
        return f"{bad} non-finite predicted radiance value(s) ({where})"
    scale = float(np.mean(np.abs(pred))) if pred.size else 0.0
    neg = int(np.count_nonzero(pred < -NEGATIVE_RTOL * scale))
    if neg:
        return f"{neg} of {pred.size} predicted radiance values negative ({where}, down to {float(pred.min()):.3g})"
    return None


def _admissible(cands: dict[str, Candidate]) -> list[str]:
    ok = [m for m in RICHNESS if m in cands and cands[m].fitted and cands[m].determined]
    # Prefer fits whose predicted radiance is finite and non-negative, then physically plausible ones
    # (an implausible fit extrapolates outside what the lighting measured).
    ok = [m for m in ok if cands[m].radiance_check is None] or ok
    return [m for m in ok if cands[m].plausibility["plausible"]] or ok


def _richest_within(names: list[str], score: dict[str, float]) -> tuple[str, float]:
    best = min(score[m] for m in names)
    return [m for m in names if score[m] <= best * (1 + SELECT_RTOL) + 1e-12][-1], best


def _best_reproducing_within(names: list[str], score: dict[str, float], cands: dict[str, Candidate]) -> tuple[str, float]:
    """Among the candidates within :data:`SELECT_RTOL` of the best score, the one with the smallest held-out error."""
    best = min(score[m] for m in names)
    near = [m for m in names if score[m] <= best * (1 + SELECT_RTOL) + 1e-12]
    return min(near, key=lambda m: (cands[m].heldout_relative_rms is None, cands[m].heldout_relative_rms or 0.0)), best


def excess_error(heldout: float, noise: float | None) -> float:
    """The part of a relative held-out error the pixel noise does not explain: ``sqrt(max(h^2 - nu^2, 0))``."""
    return math.sqrt(max(heldout**2 - (noise or 0.0) ** 2, 0.0))


def family_holds(cands: dict[str, Candidate], names: list[str], noise: float | None) -> tuple[str, str] | None:
    """One image: the best parametric family if it holds against :data:`YARDSTICK`, else the first of :data:`TABLES`
    in ``names``, with the reason.

    The noise is capped at the smaller of the two held-out errors (held-out pixels are not fitted, so no
    fit's error is below the noise; a larger ``noise`` is shading the estimate took for noise, as on
    near-mirror materials).  None when ``names`` (the admissible candidates) hold no parametric family
    or no yardstick with held-out errors.
    """
    held = {m: cands[m].heldout_relative_rms for m in names if cands[m].heldout_relative_rms is not None}
    families = [m for m in PARAMETRIC if m in held]
    if YARDSTICK not in held or not families:
        return None
    family = min(families, key=held.get)
    noise = min(noise or 0.0, held[family], held[YARDSTICK])
    e_family, e_table = excess_error(held[family], noise), excess_error(held[YARDSTICK], noise)
    above = f"held-out error above the pixel noise ({noise:.3g})"
    if e_family <= FAMILY_HOLDS * e_table + NOISE_TOL * noise:
        return family, f"the family holds: {above} {e_family:.4g} vs {YARDSTICK}'s {e_table:.4g}"
    return (next((m for m in TABLES if m in names), YARDSTICK),
            f"no family holds: {above} {e_table:.4g} for {YARDSTICK}, {e_family:.4g} for the best family ({family})")


def choose(cands: dict[str, Candidate], noise: float | None = None, one_image: bool = False) -> tuple[str, str, str]:
    """``auto``'s choice: ``(model, reason, criterion)`` (module docstring).

    ``noise``: the relative pixel noise of the image (:mod:`brdfrig.fit.noise`); ``one_image``: the fit
    has one scene, so :func:`family_holds` decides.
    """
    ok = _admissible(cands)
    if not ok:
        return "diffuse", "no candidate is determined by these data; fell back to diffuse (minimum norm)", "none"
    held = family_holds(cands, ok, noise) if one_image else None
    if held is not None:
        return held[0], held[1], "family holds"
    rated = [m for m in ok if cands[m].relight is not None and cands[m].relight.value is not None]
    if rated:
        score = {m: cands[m].relight.value for m in rated}
        chosen, best = _best_reproducing_within(rated, score, cands)
        method = cands[chosen].relight.method
        return chosen, (f"smallest estimated relighting error ({method}): {score[chosen]:.4g}"
                        + ("" if score[chosen] == best else f", within {SELECT_RTOL:.0%} of the best {best:.4g}")), method
    held = [m for m in ok if cands[m].heldout_relative_rms is not None]
    if not held:
        return ok[-1], "richest admissible candidate (no held-out pixels, no relighting estimate)", "richness"
    score = {m: cands[m].heldout_relative_rms for m in held}
    chosen, best = _richest_within(held, score)
    return chosen, (f"richest admissible model with held-out error (same lighting) within {SELECT_RTOL:.0%} of the best "
                    f"({score[chosen]:.4g} vs {best:.4g}); no relighting estimate"), "held-out pixels"


def fit_warnings(chosen: Candidate, ident: Identifiability, counts: PixelCounts) -> list[str]:
    """Warnings about the chosen fit: unmeasured bands, ignored pixels, conditioning, plausibility, radiance."""
    out, name, sysinfo = [], chosen.name, chosen.system
    if ident.unobservable_bands:
        out.append(f"bands {ident.unobservable_bands} have no lighting energy: not measured, left out")
    if counts.non_finite:
        out.append(f"{counts.non_finite} non-finite pixel(s) ignored")
    if sysinfo is not None:
        regularised = sysinfo.solver == "tikhonov"  # judge the system actually solved
        cond = max((sysinfo.condition_number_regularised if regularised else sysinfo.condition_number) or [0.0])
        if cond > COND_WARN:
            remedies = "fewer bands or more scenes" if regularised else "try tikhonov, fewer bands or more scenes"
            out.append(
                f"{name}: {'regularised ' if regularised else ''}condition number {cond:.3g} > {COND_WARN:g}: "
                f"directions the lighting barely excites may relight badly under other lighting ({remedies})"
            )
        if sysinfo.rows_used < 3 * sysinfo.unknowns:
            out.append(f"{name}: only {sysinfo.rows_used} pixels for {sysinfo.unknowns} unknowns")
    if chosen.plausibility is not None and not chosen.plausibility["plausible"]:
        out.append(
            f"{name}: not physically plausible ({chosen.plausibility}): the lighting did not constrain "
            "the whole BRDF; relighting under other lighting is unreliable"
        )
    if chosen.radiance_check is not None:
        out.append(f"{name}: {chosen.radiance_check}")
    if not chosen.determined:
        out.append(f"{name} is NOT determined by these data")
    return out
