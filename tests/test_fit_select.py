"""Model selection that predicts relighting: leave-one-scene-out vs held-out pixels, the rotated-lighting
spread estimate, and the fit report's round trip through the BRDF file.

Oracles: the brute-force ground-truth renderer (relighting under pisa, a lighting no estimate sees) and
predictions built with known, independent errors.
"""

from __future__ import annotations

import json
import math
from types import SimpleNamespace

import numpy as np
import pytest

from brdfrig.fit.rotation import axis_rotation
from brdfrig.fit.analytic import GGX, Lambertian, OrenNayar
from brdfrig.fit.brdffile import jsonable, load_brdf, save_brdf
from brdfrig.fit.fitter import BLEND, _blend_or_part, fit_brdf
from brdfrig.fit.relight import ACROSS, SPREAD_CALIBRATION, LosoPredictions, across_lightings, loso_folds, other_lightings, predict_under, spread_estimates
from brdfrig.fit.report import Candidate, FitReport, RelightEstimate, format_report
from brdfrig.fit.select import choose, radiance_problem
from test_fit_scenes import GGX_MATERIAL, make_scenes, probes, relight_error, rotations, sphere  # noqa: F401


def test_loso_picks_the_model_that_relights_where_heldout_pixels_pick_the_wrong_one(probes):
    """Two scenes (grace, grace turned 90 degrees), GGX sphere, l = p = 3.  ``full`` reproduces held-out
    pixels of the same lighting better than ``lobe`` (measured 0.026 vs 0.030) but relights under pisa at
    123% against 2.6%; the estimate (leave-one-scene-out with the rotated-lighting spread) sees it (measured
    1460 vs 0.048)."""
    fit_env, test_env = probes
    normals, weights = sphere(32)
    truth = GGX(**GGX_MATERIAL)
    scenes = make_scenes(truth, [fit_env, fit_env.rotated(axis_rotation("y", 90))], normals, weights)
    fits = {m: fit_brdf(scenes, model=m, lmax=3, pmax=3, progress=False, estimate=True) for m in ("lobe", "full")}
    held = {m: r.report.chosen.heldout_relative_rms for m, r in fits.items()}
    loso = {m: r.report.relight.value for m, r in fits.items()}
    true = {m: relight_error(r.brdf, truth, test_env, normals) for m, r in fits.items()}
    print(f"held-out {held}, estimated {loso}, relit under pisa {true}")
    assert all(r.report.relight.method == ACROSS for r in fits.values())
    assert held["full"] < held["lobe"]  # the same-lighting criterion prefers full ...
    assert true["full"] > 10 * true["lobe"]  # ... which relights far worse
    assert loso["full"] > 10 * loso["lobe"]  # the relighting criterion sees it
    # the choice itself: both marked determined so that only the criterion decides
    cands = {m: Candidate(m, heldout_relative_rms=held[m], determined=True, full_rank=True,
                          plausibility={"plausible": True}, relight=fits[m].report.relight) for m in ("lobe", "full")}
    assert choose(cands)[0] == "lobe"
    for c in cands.values():
        c.relight = None
    assert choose(cands)[0] == "full"  # held-out fallback: the wrong model
    # the estimate is a relighting error: within a factor 2 of pisa's for the model that relights
    assert 0.5 <= loso["lobe"] / true["lobe"] <= 2.0


def _with_errors(sizes: dict[str, float], seed: int) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """A seeded truth (5 lightings, 2000 pixels, RGB) and, per name, the truth plus an independent Gaussian
    error of relative RMS exactly ``sizes[name]``."""
    rng = np.random.default_rng(seed)
    truth = rng.uniform(0.5, 1.5, size=(5, 2000, 3))
    scale = math.sqrt(float(np.mean(np.sum(truth**2, axis=(1, 2)))))
    preds = {}
    for m, e in sizes.items():
        noise = rng.standard_normal(truth.shape)
        preds[m] = truth + e * scale * noise / math.sqrt(float(np.mean(np.sum(noise**2, axis=(1, 2)))))
    return truth, preds


@pytest.mark.parametrize("n, split, expected", [
    (2, "arcs", [[0], [1]]),
    (3, "arcs", [[0], [1], [2]]),
    (3, "interleaved", [[0], [1], [2]]),
    (7, "arcs", [[0, 1], [2, 3], [4, 5, 6]]),
    (7, "interleaved", [[0, 3, 6], [1, 4], [2, 5]]),
    (12, "arcs", [[0, 1, 2, 3], [4, 5, 6, 7], [8, 9, 10, 11]]),
    (12, "interleaved", [[0, 3, 6, 9], [1, 4, 7, 10], [2, 5, 8, 11]]),
])
def test_loso_folds(n, split, expected):
    """Arcs leave out runs of consecutive turns (twelve turns: arcs of four), interleaved folds every third turn."""
    assert [f.tolist() for f in loso_folds(n, split)] == expected


def test_loso_folds_refuse_an_unknown_split():
    with pytest.raises(ValueError, match="unknown leave-one-scene-out split 'blocks'"):
        loso_folds(12, "blocks")


def test_auto_reports_the_chosen_fit_on_arcs_after_choosing_on_interleaved_folds(probes):
    """Four turned scenes of a GGX sphere: the candidates' estimates come from interleaved folds, the report's from
    arcs (a second leave-one-scene-out pass of the chosen model), and both are within 2x of the relighting error
    under pisa (the ground-truth renderer)."""
    fit_env, test_env = probes
    normals, weights = sphere(16)
    truth = GGX(**GGX_MATERIAL)
    scenes = make_scenes(truth, rotations(fit_env, 4), normals, weights)
    res = fit_brdf(scenes, model="auto", lmax=3, pmax=3, progress=False)
    chosen = res.report.candidates[res.report.chosen_model].relight
    reported = res.report.relight
    true = relight_error(res.brdf, truth, test_env, normals)
    print(f"{res.report.chosen_model}: interleaved {chosen.value:.4g}, arcs {reported.value:.4g}, relit under pisa {true:.4g}")
    assert chosen.method == reported.method == ACROSS
    assert "scene k in fold k mod 3" in chosen.detail and "3 runs of consecutive scenes" in reported.detail
    assert reported.value != chosen.value
    for value in (chosen.value, reported.value):
        assert 0.5 * true <= value <= 2.0 * true


def _arcs_pass(biases: dict[str, tuple]) -> LosoPredictions:
    """An arcs pass of three folds of 20 pixels: part m predicts the radiance times ``1 + biases[m][f]`` on fold f."""
    target = np.random.default_rng(5).random((60, 3)) + 0.5
    fold = np.repeat([0, 1, 2], 20)
    preds = {m: target * (1.0 + np.asarray(b)[fold])[:, None] for m, b in biases.items()}
    return LosoPredictions(target, np.ones(60), preds, "3 arcs", np.arange(60), fold, {})


def test_a_chosen_blend_gives_way_to_a_part_that_relights_the_arcs_better():
    """Part a is 5% high on every arc, part b 5% low on the last two arcs and 50% high on the first.  Stacked on
    the last two arcs the weights are (1/2, 1/2), which predict the first arc 27.5% high, so the blend's
    out-of-sample error exceeds a's 5% and a replaces it, with a's arcs error as its estimate (1e-12).  With
    b 5% low everywhere the blend (1/2, 1/2) is exact out of sample and stays, its estimate untouched."""
    fitter = SimpleNamespace(entries={BLEND: SimpleNamespace(fit_report={"parts": {"a": 0.5, "b": 0.5}})}, spread={})
    before = RelightEstimate(0.01, ACROSS, "interleaved")
    chosen, est, reason = _blend_or_part(fitter, _arcs_pass({"a": (0.05,) * 3, "b": (0.5, -0.05, -0.05)}), before, "r")
    print(reason)
    assert chosen == "a" and est.value == pytest.approx(0.05, rel=1e-12) and "replaced by its part a" in reason
    chosen, est, reason = _blend_or_part(fitter, _arcs_pass({"a": (0.05,) * 3, "b": (-0.05,) * 3}), before, "r")
    print(reason)
    assert chosen == BLEND and est is before and "kept against its best part" in reason


def test_several_scenes_add_the_spread_to_leave_one_scene_out_in_quadrature():
    """``across_lightings``: 3% and 4% give 5% (a 3-4-5 triangle), named by both methods with both values; a
    missing spread or leave-one-scene-out value leaves the leave-one-scene-out estimate as it is."""
    loso = RelightEstimate(0.03, "leave-one-scene-out", "3 folds")
    both = across_lightings(loso, RelightEstimate(0.04, "rotated-lighting spread", "5 turned copies"))
    assert both.value == pytest.approx(0.05, rel=1e-12) and both.method == ACROSS
    assert "l = 0.03 (leave-one-scene-out: 3 folds)" in both.detail and "s = 0.04 (rotated-lighting spread" in both.detail
    assert across_lightings(loso, None) is loso
    assert across_lightings(loso, RelightEstimate(None, "rotated-lighting spread", "")) is loso
    missing = RelightEstimate(None, "leave-one-scene-out", "a refit failed")
    assert across_lightings(missing, RelightEstimate(0.04, "rotated-lighting spread", "")) is missing


def test_spread_split_recovers_independent_errors():
    """Predictions = truth + independent errors of known size (2%, 4%, 8%, 20%): the pairwise split
    recovers each within 15% (no truth given); a parametric candidate that reproduces the held-out
    pixels best is the anchor and the others' estimates are their distances to it."""
    sizes = {"diffuse": 0.2, "lobe": 0.08, "bivariate": 0.04, "full": 0.02}
    truth, preds = _with_errors(sizes, seed=3)
    weights = np.ones(truth.shape[1])
    held = dict.fromkeys(sizes, 0.001)
    est = spread_estimates(preds, weights, held)
    for m, e in sizes.items():
        print(f"{m}: true {e}, estimate {est[m].value:.4f}")
        assert est[m].value == pytest.approx(e, rel=0.15), m
    preds["microfacet"] = truth.copy()
    anchored = spread_estimates(preds, weights, held | {"microfacet": 1e-4})
    assert "microfacet" in anchored["lobe"].detail
    assert anchored["microfacet"].value == pytest.approx(1e-4)
    for m, e in sizes.items():
        assert anchored[m].value == pytest.approx(e, rel=0.1), m


def test_table_estimate_is_the_calibrated_spread():
    """The table's one-image estimate is ``c s^b`` of its spread ``s`` (:data:`SPREAD_CALIBRATION`): with
    independent errors of 2%, 8%, 20% and 9% (the table), the table's estimate is 0.25 sqrt(0.09) = 0.075
    within 8% (the spread itself is within 15% of 0.09), the others stay their spreads, and a held-out
    error above the spread is calibrated in its place; only the table's detail names the lighting its calibration
    speaks of."""
    c, b = SPREAD_CALIBRATION["bivariate+prior"]
    assert (c, b) == (0.25, 0.5)
    sizes = {"diffuse": 0.2, "lobe": 0.08, "full": 0.02, "bivariate+prior": 0.09}
    _, preds = _with_errors(sizes, seed=5)
    est = spread_estimates(preds, np.ones(2000), dict.fromkeys(sizes, 0.001))
    assert est["bivariate+prior"].value == pytest.approx(0.075, rel=0.08)
    assert "calibrated against measured materials relit under ennis" in est["bivariate+prior"].detail
    assert "calibrated" not in est["lobe"].detail
    assert est["lobe"].value == pytest.approx(0.08, rel=0.15)
    floored = spread_estimates(preds, np.ones(2000), dict.fromkeys(sizes, 0.001) | {"bivariate+prior": 0.12})
    assert floored["bivariate+prior"].value == pytest.approx(0.25 * math.sqrt(0.12))


def test_spread_estimate_within_factor_two_on_synthetic_materials(probes):
    """Candidate BRDFs with errors of different kinds (a sharper lobe, no lobe, a rough base, a wrong base
    colour) of a GGX sphere fitted under grace: the spread estimate, made without the truth, is within a
    factor 2 of each one's true relighting error under the estimate's own other lightings (grace turned;
    ground truth by brute-force quadrature; measured ratios 0.83-1.47).  Under pisa the true errors differ
    from those by up to 3.2x (printed), which bounds how well any one estimate can predict one lighting.
    The split assumes independent errors: a sharper and a broader lobe (opposite errors) are split
    wrongly (measured 0.093 and 0.0 for true 0.058 and 0.07)."""
    from brdfrig.fit.groundtruth import render_groundtruth

    fit_env, test_env = probes
    normals, weights = sphere(32)
    truth = GGX(alpha=0.3, f0=0.04, diffuse=[0.5, 0.4, 0.3])
    cands = {
        "microfacet": GGX(alpha=0.2, f0=0.04, diffuse=[0.5, 0.4, 0.3]),
        "diffuse": Lambertian([0.55, 0.45, 0.35]),
        "bivariate": OrenNayar([0.45, 0.35, 0.25], sigma=0.5),
        "lobe": GGX(alpha=0.3, f0=0.06, diffuse=[0.44, 0.42, 0.33]),
    }
    envs = other_lightings(fit_env)
    preds = predict_under(cands, envs, normals)
    est = spread_estimates(preds, weights, dict.fromkeys(cands, None))
    ref = np.stack([render_groundtruth(truth, normals, e) for e in envs])
    energy = np.einsum("lnc,n->l", ref**2, weights)
    for m, b in cands.items():
        proxy = math.sqrt(float(np.mean(np.einsum("lnc,n->l", (preds[m] - ref) ** 2, weights) / energy)))
        pisa = relight_error(b, truth, test_env, normals)
        print(f"{m}: estimate {est[m].value:.4f}, true under the turned lightings {proxy:.4f}, under pisa {pisa:.4f}")
        assert 0.5 <= est[m].value / proxy <= 2.0, m


def test_radiance_check():
    assert radiance_problem(np.ones((4, 3)), "x") is None
    assert radiance_problem(np.array([[1.0, -1e-6, 1.0]]), "x") is None  # rounding below NEGATIVE_RTOL
    assert "negative" in radiance_problem(np.array([[1.0, -0.1, 1.0]]), "other lightings")
    assert "non-finite" in radiance_problem(np.array([[1.0, np.nan, 1.0]]), "x")


def test_report_round_trip_through_brdf_file_and_json(probes, tmp_path):
    fit_env, _ = probes
    normals, weights = sphere(24)
    scenes = make_scenes(Lambertian([0.6, 0.5, 0.3]), [fit_env], normals, weights)
    res = fit_brdf(scenes, model="diffuse", lmax=3, progress=False)
    rep = res.report
    assert isinstance(rep, FitReport) and rep.relight.value is None  # requested model, estimate not asked for
    rep.relight = rep.chosen.relight = RelightEstimate(0.0123, "rotated-lighting spread", "a test")
    path = save_brdf(tmp_path / "d.brdf.json", res.brdf, rep)
    _, stored = load_brdf(path)
    back = FitReport.from_dict(stored)
    assert back.to_dict() == json.loads(json.dumps(jsonable(rep)))
    assert back.relight == rep.relight and back.chosen.system == rep.chosen.system
    assert back.pixels == rep.pixels and back.candidates["diffuse"].system.rank == rep.chosen.system.rank
    assert stored["relight"] == {"value": 0.0123, "method": "rotated-lighting spread", "detail": "a test"}
    text = "\n".join(format_report(back))
    assert "estimated relighting error under other lighting: 1.23%" in text
    with pytest.raises(ValueError, match="not a fit report"):
        FitReport.from_dict({"chosen_model": "diffuse"})


def test_a_fold_takes_the_prior_family_chosen_on_all_the_data(probes, monkeypatch):
    """Leave-one-scene-out refits of ``bivariate+prior`` fit the parametric family chosen on all the data, not every
    family: the same table when it is the family the fold would choose itself; the other families when that fit
    fails."""
    from brdfrig.fit import fitter
    from brdfrig.fit.registry import PARAMETRIC
    from brdfrig.fit.stream import STOP_TOL, FitData, StageClock, gather_pixels, project_lighting

    fit_env, _ = probes
    normals, weights = sphere(16)
    scenes = make_scenes(GGX(**GGX_MATERIAL), rotations(fit_env, 2), normals, weights)
    pool, _ = gather_pixels(scenes, fitter.DEFAULT_MAX_THETA_DEG)
    order = np.random.default_rng(0).permutation(len(pool.weights))
    fold = FitData(scenes, pool, project_lighting(scenes, 3), order[20:], np.sort(order[:20]), StageClock(), False, STOP_TOL)
    single_fit, fitted, failing = fitter.single_fit, [], set()

    def recording(name):
        def fit(*args, **kw):
            fitted.append((name, getattr(kw.get("prior"), "model", None)))
            if name in failing:
                raise ValueError(f"{name} made to fail")
            return single_fit(name)(*args, **kw)
        return fit

    monkeypatch.setattr(fitter, "single_fit", recording)

    def refit(family):
        fitted.clear()
        settings = (3, 3, "joint", 3, fitter.DEFAULT_MAX_THETA_DEG, None, family)
        return fitter._refit(fold, ["bivariate+prior"], settings, auto=False)["bivariate+prior"], [m for m, _ in fitted]

    own, calls = refit(None)
    chosen = fitted[-1][1]  # the family the fold chose for itself: the prior passed to the table's fit
    assert calls == [*PARAMETRIC, "bivariate+prior"] and chosen in PARAMETRIC
    for family in PARAMETRIC:
        table, calls = refit(family)
        assert calls == [family, "bivariate+prior"] and fitted[-1][1] == family
        assert np.array_equal(table.table, own.table) == (family == chosen)  # the fold's own choice: its table exactly
    failing.add(chosen)
    table, calls = refit(chosen)
    assert calls == [chosen, *(f for f in PARAMETRIC if f != chosen), "bivariate+prior"] and fitted[-1][1] != chosen


def test_a_family_with_its_ior_on_the_search_bound_is_not_determined_and_says_why(probes):
    """One image of a coating of IOR 2.6 (beyond :data:`brdfrig.fit.pbr_fit.IOR_BOUNDS`): the dielectric fit ends on
    the bound, so the candidate is not determined, the report line names the parameter, and ``auto``'s rule passes
    over it for a determined candidate even with a smaller held-out error."""
    from brdfrig.fit.pbr import DielectricBRDF

    fit_env, _ = probes
    normals, weights = sphere(24)
    scenes = make_scenes(DielectricBRDF([0.3, 0.2, 0.1], 0.2, 1.0, math.sqrt(0.05), 2.6), [fit_env], normals, weights)
    rep = fit_brdf(scenes, model="dielectric", lmax=3, progress=False).report
    cand = rep.candidates["dielectric"]
    assert cand.fit_report["specular_ior"] == pytest.approx(2.0, abs=0.01) and not cand.determined
    assert "WARNING: not determined" in rep.reason
    line = next(t for t in format_report(rep) if t.lstrip().startswith("dielectric"))
    assert line.endswith("[not determined: specular_ior on a search bound]")
    other = Candidate("bivariate+measured", heldout_relative_rms=2 * cand.heldout_relative_rms, full_rank=True,
                      determined=True, plausibility={"plausible": True})
    assert choose({"dielectric": cand, "bivariate+measured": other})[0] == "bivariate+measured"
