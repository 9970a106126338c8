"""The ``bivariate+blend`` model: the tables averaged with inverse-variance weights (one image) or stacked
on leave-one-scene-out predictions (several scenes).

Oracles: closed forms (inverse-variance weights; a blend of constant tables is the Lambertian of the
weighted albedo, rendered analytically; stacking weights of an exact convex combination), a brute-force
search over the simplex, each part's own prediction, and the ground-truth renderer of tabulated BRDFs.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from brdfrig.fit.bivariate import BivariateBRDF
from brdfrig.fit.blend import BlendBRDF, inverse_variance_weights, nested_stacking, stacked_weights
from brdfrig.fit.brdf import FittedBRDF, brdf_from_dict
from brdfrig.fit.metrics import relative_rms, relative_spread
from brdfrig.fit.scene import Scene
from test_bivariate import _bivariate_truth, _sphere_normals, _tabulated, envs  # noqa: F401 - envs: the fixture (grace, pisa at 64 x 32)


def test_inverse_variance_weights():
    w = inverse_variance_weights([0.1, 0.2, 0.4])
    assert w == pytest.approx(np.array([16.0, 4.0, 1.0]) / 21.0, rel=1e-12)
    for bad in ([], [0.1, 0.0], [0.1, -0.2], [0.1, math.nan], [0.1, math.inf]):
        with pytest.raises(ValueError, match="finite positive"):
            inverse_variance_weights(bad)


def _stack_cost(a, preds, target, w) -> float:
    return float(np.sum(w[:, None] * (sum(x * p for x, p in zip(a, preds)) - target) ** 2))


def test_stacked_weights():
    """An exact convex combination is recovered (1e-9); a target outside the parts' hull gets the nearest
    vertex; random predictions: no point of a 0.01 grid over the simplex does better (brute force)."""
    rng = np.random.default_rng(7)
    preds = [rng.random((50, 3)) for _ in range(3)]
    w = rng.random(50)
    assert stacked_weights(preds, 0.2 * preds[0] + 0.5 * preds[1] + 0.3 * preds[2], w) == pytest.approx([0.2, 0.5, 0.3], abs=1e-9)
    assert stacked_weights(preds, preds[1] + 0.5 * (preds[1] - preds[0]), w) == pytest.approx([0.0, 1.0, 0.0], abs=1e-9)
    target = rng.random((50, 3))
    a = stacked_weights(preds, target, w)
    assert np.all(a >= 0) and a.sum() == pytest.approx(1.0, abs=1e-12)
    grid = [(i / 100, j / 100, 1 - (i + j) / 100) for i in range(101) for j in range(101 - i)]
    assert _stack_cost(a, preds, target, w) <= min(_stack_cost(g, preds, target, w) for g in grid) + 1e-12
    with pytest.raises(ValueError, match="two or more finite"):
        stacked_weights([preds[0]], target, w)
    with pytest.raises(ValueError, match="two or more finite"):
        stacked_weights([preds[0], np.full((50, 3), math.nan)], target, w)


def test_nested_stacking():
    """Each fold gets the weights of the other folds: a target that is one convex combination everywhere is
    predicted exactly (1e-9); a target that is part 0 on fold 0 and part 1 elsewhere is predicted as part 1
    on fold 0 (the other folds' weights (0, 1), 1e-9); one fold is refused."""
    rng = np.random.default_rng(11)
    preds = [rng.random((60, 3)) for _ in range(2)]
    w = rng.random(60)
    fold = np.repeat([0, 1, 2], 20)
    mix = 0.3 * preds[0] + 0.7 * preds[1]
    assert np.abs(nested_stacking(preds, mix, w, fold) - mix).max() < 1e-9
    target = np.where((fold == 0)[:, None], preds[0], preds[1])
    assert np.abs(nested_stacking(preds, target, w, fold)[:20] - preds[1][:20]).max() < 1e-9
    with pytest.raises(ValueError, match="two or more folds"):
        nested_stacking(preds, mix, w, np.zeros(60, dtype=int))


def _lambertian_table(albedo, nh: int, nd: int) -> BivariateBRDF:
    return BivariateBRDF(np.broadcast_to((np.asarray(albedo) / math.pi)[:, None, None], (3, nh, nd)))


def test_blend_of_constant_tables_is_the_lambertian_of_the_weighted_albedo(envs):
    """Parts on two grids (24 x 8, 32 x 12): ``evaluate`` is the weighted albedo / pi (1e-12), ``predict`` the
    analytic Lambertian's (1e-3, cell-centre quadrature), and in :func:`predict_under` beside its own parts
    the blend equals its parts' weighted sum and each part its own prediction (1e-12)."""
    from brdfrig.fit.analytic import Lambertian
    from brdfrig.fit.relight import predict_under

    _, env = envs
    normals = _sphere_normals(24)
    a, b = np.array([0.6, 0.4, 0.2]), np.array([0.1, 0.3, 0.5])
    parts = [_lambertian_table(a, 24, 8), _lambertian_table(b, 32, 12)]
    blend = BlendBRDF(parts, [0.25, 0.75])
    assert isinstance(blend, FittedBRDF) and blend.channels == 3
    albedo = 0.25 * a + 0.75 * b
    rho = blend.evaluate(np.array([0.2, 1.0]), np.array([0.5, 0.3]), np.array([0.0, 2.0]))
    assert np.allclose(rho, albedo / math.pi, rtol=1e-12)
    assert relative_rms(blend.predict(env, normals), Lambertian(albedo).predict(env, normals)) < 1e-3
    other = BivariateBRDF(np.random.default_rng(4).random((3, 24, 8)))
    together = predict_under({"blend": blend, "part": parts[0], "other": other}, [env], normals)
    assert relative_rms(together["blend"][0], 0.25 * parts[0].predict(env, normals) + 0.75 * parts[1].predict(env, normals)) < 1e-12
    assert relative_rms(together["part"][0], parts[0].predict(env, normals)) < 1e-12
    assert relative_rms(together["other"][0], other.predict(env, normals)) < 1e-12


def test_held_out_pixels_predicted_together_as_each_alone(envs):
    """``relight.predict_held``: held-out pixels of two scenes, each under its own lighting, for two tables (one
    pass per scene), their blend and an analytic BRDF: each the same as its own ``predict`` to 1e-12 relative (a
    lighting and pixels seen again are predicted from their kept design: the same sums in another order)."""
    from brdfrig.fit.analytic import GGX
    from brdfrig.fit.relight import predict_held
    from brdfrig.fit.stream import STOP_TOL, FitData, StageClock, gather_pixels, project_lighting

    normals = _sphere_normals(16)
    rng = np.random.default_rng(5)
    tables = [BivariateBRDF(rng.random((3, 24, 8))), BivariateBRDF(rng.random((3, 32, 12)))]
    brdfs = {"a": tables[0], "b": tables[1], "blend": BlendBRDF(tables, [0.3, 0.7]),
             "ggx": GGX(alpha=0.2, f0=0.04, diffuse=(0.5, 0.4, 0.3))}
    scenes = [Scene(env, normals, np.ones((len(normals), 3)), np.ones(len(normals))) for env in envs]
    pool, _ = gather_pixels(scenes, 80.0)
    held = np.sort(rng.permutation(len(pool.weights))[:40])
    data = FitData(scenes, pool, project_lighting(scenes, 2), np.arange(0), held, StageClock(), False, STOP_TOL)
    together = predict_held(data, brdfs)
    assert set(np.unique(pool.scene[held])) == {0, 1}
    for name, brdf in brdfs.items():
        alone = np.empty((len(held), 3))
        for k, scene in enumerate(scenes):
            rows = pool.scene[held] == k
            alone[rows] = brdf.predict(scene.env, pool.normals[held[rows]])
        np.testing.assert_allclose(together[name], alone, rtol=1e-12, atol=0, err_msg=name)


def test_round_trip_and_bad_blends():
    rng = np.random.default_rng(5)
    blend = BlendBRDF([BivariateBRDF(rng.random((3, 24, 8))), BivariateBRDF(rng.random((3, 32, 12)), rng.random((3, 32, 12)))],
                      [0.4, 0.6])
    back = brdf_from_dict(json.loads(json.dumps(blend.to_dict())))
    angles = (np.linspace(0, 1.4, 7), np.linspace(1.3, 0.1, 7), np.linspace(0, 3, 7))
    assert isinstance(back, BlendBRDF) and np.array_equal(back.evaluate(*angles), blend.evaluate(*angles))
    part = blend.parts[0]
    for parts, weights, match in (([part, part], [0.5, 0.6], "summing to 1"), ([part], [1.0, 0.0], "summing to 1"),
                                  ([part, part], [1.5, -0.5], "summing to 1"), ([], [], "one or more"),
                                  ([part, BivariateBRDF(np.ones((1, 24, 8)))], [0.5, 0.5], "channel")):
        with pytest.raises(ValueError, match=match):
            BlendBRDF(parts, weights)
    bad = blend.to_dict() | {"parts": [{"model": "diffuse"}]}
    with pytest.raises(ValueError, match="bivariate"):
        brdf_from_dict(bad)


def test_fitter_blends_the_tables_by_their_estimates(envs):
    """One image of a BRDF outside the parametric families (Lambertian + GGX distribution x Schlick Fresnel,
    tabulated, rendered by the ground truth): ``auto`` returns the blend of the three tables, weighted by the
    inverse squares of their relighting estimates; under another probe it relights as their weighted sum
    does, within 1% of the truth.  Several scenes: the blend is refused when asked for by name."""
    from brdfrig.fit.fitter import fit_brdf
    from brdfrig.fit.groundtruth import render_tabulated

    fit_env, test_env = envs
    normals = _sphere_normals(40)
    truth = _tabulated(lambda th, td: _bivariate_truth(th, td, [0.5, 0.3, 0.2], [0.15, 0.2, 0.25], 0.04))
    scene = Scene(fit_env, normals, render_tabulated(truth, normals, fit_env), np.ones(len(normals)))
    result = fit_brdf([scene], progress=False)
    report = result.report
    assert report.chosen_model == "bivariate+blend" and isinstance(result.brdf, BlendBRDF)
    cand = report.candidates["bivariate+blend"]
    parts = list(cand.fit_report["parts"])
    assert parts == ["bivariate", "bivariate+prior", "bivariate+measured"]
    estimates = [report.candidates[m].relight.value for m in parts]
    assert result.brdf.weights == pytest.approx(inverse_variance_weights(estimates), rel=1e-12)
    assert cand.relight.value == min(estimates)
    reference = render_tabulated(truth, normals, test_env)
    relit = [result.brdfs[m].predict(test_env, normals) for m in parts]
    blended = sum(w * p for w, p in zip(result.brdf.weights, relit))
    assert relative_rms(result.brdf.predict(test_env, normals), blended) < 1e-12
    assert relative_rms(blended, reference) < 0.01  # measured 0.63% (the parts: 0.47, 0.35, 2.35%)


def test_several_scenes_stack_the_tables_on_leave_one_scene_out_predictions(envs):
    """Two scenes (the probe and the probe turned 90 degrees) of the BRDF above: ``bivariate+blend`` stacks the
    tables on their leave-one-scene-out predictions, so its estimate on those folds is at most each part's
    (the simplex holds every part), and it relights under the other probe within 1% of the truth."""
    from brdfrig.fit.fitter import fit_brdf
    from brdfrig.fit.groundtruth import render_tabulated

    fit_env, test_env = envs
    normals = _sphere_normals(32)
    truth = _tabulated(lambda th, td: _bivariate_truth(th, td, [0.5, 0.3, 0.2], [0.15, 0.2, 0.25], 0.04))
    turned_env = fit_env.rotated(np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]]))
    scenes = [Scene(e, normals, render_tabulated(truth, normals, e), np.ones(len(normals))) for e in (fit_env, turned_env)]
    result = fit_brdf(scenes, model="bivariate+blend", progress=False)
    report = result.report
    assert report.chosen_model == "bivariate+blend" and isinstance(result.brdf, BlendBRDF)
    cand = report.candidates["bivariate+blend"]
    parts = list(cand.fit_report["parts"])
    assert parts == ["bivariate", "bivariate+prior", "bivariate+measured"]
    assert np.all(result.brdf.weights >= 0) and result.brdf.weights.sum() == pytest.approx(1.0, abs=1e-12)
    assert cand.relight.method == "leave-one-scene-out and rotated-lighting spread" and "weights stacked" in cand.relight.detail
    assert cand.relight.value <= min(report.candidates[m].relight.value for m in parts) + 1e-12
    relit = relative_rms(result.brdf.predict(test_env, normals), render_tabulated(truth, normals, test_env))
    print(f"weights {result.brdf.weights}, estimate {cand.relight.value:.4f}, relit {relit:.4f}")
    assert relit < 0.01
    # the parts' refits on the two folds, kept for an estimate under a given lighting: each fold's blend of them
    # (BlendBRDF.predict) spreads under the other probe by s, so the estimate is sqrt(c d) of c = e s / (sqrt(2) s0)
    # and d = s sqrt(2)
    from brdfrig.fit.relight import FOLDS_FOR_LIGHTING, lighting_estimate

    folds = [report.candidates[m].fit_report["fold_tables"] for m in parts]
    assert all(t.shape[:3] == (2, 3, 2) for t in folds) and cand.fit_report["fold_spread"] > 0
    blends = [BlendBRDF([BivariateBRDF(t[f][:, 0], t[f][:, 1]) for t in folds], result.brdf.weights) for f in range(2)]
    s = relative_spread(np.stack([b.predict(test_env, normals) for b in blends]), np.ones(len(normals)))
    est = lighting_estimate(report.to_dict(), test_env, normals, np.ones(len(normals)))
    assert est.method == FOLDS_FOR_LIGHTING
    c = cand.relight.value * s / (math.sqrt(2) * cand.fit_report["fold_spread"])
    assert est.value == pytest.approx(math.sqrt(c * s * math.sqrt(2)), rel=1e-6)
