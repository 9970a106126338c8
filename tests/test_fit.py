"""fit_brdf on real probes against the brute-force ground truth: accuracy, model choice, solvers (stability and the
streamed pixel path: test_fit_stability.py).

Fit under grace (or its rotations about the vertical axis), relight under pisa,
both box-filtered to 64x32; spheres of 48-96 px; errors are relative RMS
within the fitter's limb margin (``test_fit_scenes.relight_error``).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import pytest

from brdfrig.fit.analytic import GGX, Lambertian
from brdfrig.fit.fitter import fit_brdf
from brdfrig.fit.scene import Environment, Scene
from test_fit_scenes import ALBEDO, GGX_MATERIAL, make_scenes, probes, relight_error, rotations, sphere  # noqa: F401


class _OneScene(NamedTuple):
    fit_env: Environment
    test_env: Environment
    normals: np.ndarray
    weights: np.ndarray
    truth: object
    scenes: list[Scene]


def _one_scene(probes, size: int, truth, noise: float = 0.0) -> _OneScene:
    """``truth`` rendered on a ``size`` px sphere under the fit map (one scene, relative noise ``noise``, seed 0)."""
    fit_env, test_env = probes
    normals, weights = sphere(size)
    return _OneScene(fit_env, test_env, normals, weights, truth, make_scenes(truth, [fit_env], normals, weights, noise=noise))


def _determined_choice(result):
    chosen = result.report.chosen_model
    assert result.report.chosen.determined, result.report.chosen
    return chosen


@pytest.mark.parametrize("noise", [0.0, 0.01])
def test_one_scene_lambertian_relights_within_half_percent(probes, noise):
    _, test_env, normals, _, truth, scenes = _one_scene(probes, 96, Lambertian(ALBEDO), noise)
    # l = 12: at l = 8 truncating the clamped cosine alone costs ~0.5% under this sharp map (test_fit_scenes)
    res = fit_brdf(scenes, model="diffuse", lmax=12, progress=False)
    err = relight_error(res.brdf, truth, test_env, normals)
    print(f"lambertian 1 scene noise={noise}: diffuse relight {err:.4%}, albedo {res.brdf.albedo}")
    assert err <= 0.005
    np.testing.assert_allclose(res.brdf.albedo, ALBEDO, rtol=0.005)
    auto = fit_brdf(scenes, lmax=12, pmax=4, progress=False)
    err_auto = relight_error(auto.brdf, truth, test_env, normals)
    print(f"  auto -> {auto.report.chosen_model}: relight {err_auto:.4%}")
    assert _determined_choice(auto) != "full"
    assert err_auto <= 0.005


@pytest.mark.parametrize("noise", [0.0, 0.01])
def test_one_scene_ggx_relights_within_eight_percent(probes, noise):
    # 48 px: auto makes the same choice (microfacet) as at 96 px and relights at <= 0.1% either way (a third faster)
    _, test_env, normals, _, truth, scenes = _one_scene(probes, 48, GGX(**GGX_MATERIAL), noise)
    auto = fit_brdf(scenes, lmax=8, pmax=8, progress=False)
    chosen = _determined_choice(auto)
    assert chosen not in ("full", "full+prior")
    assert auto.report.identifiability["models"]["full"]["determined"] is False
    err = relight_error(auto.brdf, truth, test_env, normals)
    lobe = fit_brdf(scenes, model="lobe", lmax=8, progress=False)
    err_lobe = relight_error(lobe.brdf, truth, test_env, normals)
    print(f"ggx 1 scene noise={noise}: auto -> {chosen} relight {err:.4%}; lobe {err_lobe:.4%}")
    assert err <= 0.08


_TWELVE: dict = {}


@pytest.mark.parametrize("noise", [0.0, 0.01])
def test_twelve_scenes_ggx_full_model_relights_within_three_percent(probes, noise):
    fit_env, test_env = probes
    if not _TWELVE:  # the noise-free ground truth, rendered once for both cases
        normals, weights = sphere(48)
        truth = GGX(**GGX_MATERIAL)
        _TWELVE.update(normals=normals, weights=weights, truth=truth, clean=make_scenes(truth, rotations(fit_env, 12), normals, weights))
    normals, truth = _TWELVE["normals"], _TWELVE["truth"]
    rng = np.random.default_rng(1)
    scenes = [Scene(s.env, s.normals, s.radiance * (1 + noise * rng.normal(size=s.radiance.shape)), s.weights) for s in _TWELVE["clean"]]
    res = fit_brdf(scenes, model="full", lmax=8, pmax=8, progress=False)
    assert res.report.identifiability["models"]["full"]["determined"]
    assert res.report.candidates["full"].determined
    err = relight_error(res.brdf, truth, test_env, normals)
    print(f"ggx 12 scenes noise={noise}: full relight {err:.4%}")
    assert err <= 0.03
    if noise:
        prior = fit_brdf(scenes, model="full+prior", lmax=8, pmax=8, progress=False)
        err_prior = relight_error(prior.brdf, truth, test_env, normals)
        print(f"  full+prior (toward {prior.report.candidates['full+prior'].prior}) relight {err_prior:.4%}")
        assert err_prior <= 0.03
        assert err_prior <= 1.05 * err  # the prior does not cost accuracy once the data determine the model


@pytest.mark.parametrize("noise", [0.0, 0.01])
def test_one_scene_full_plus_prior_relights_no_worse_than_its_prior(probes, noise):
    # One scene leaves most tau directions undetermined; full+prior must keep them at the prior
    # (GCV alone picked lambda ~ 1e-12 here and relit at ~1e5 relative error).  Oracle: the
    # ground-truth renderer; reference: the prior itself written on the same full basis
    # (project_to_full), the best the full model at this band limit can do with the prior alone.
    from brdfrig.fit.models import make_linear_brdf, project_to_full

    _, test_env, normals, _, truth, scenes = _one_scene(probes, 48, GGX(**GGX_MATERIAL), noise)
    res = fit_brdf(scenes, model="full+prior", lmax=6, pmax=6, progress=False)
    info = res.report.candidates["full+prior"]
    assert info.prior == "microfacet"
    prior = fit_brdf(scenes, model=info.prior, progress=False).brdf
    prior_full = make_linear_brdf(res.brdf.spec, project_to_full(prior, res.brdf.spec))
    err = relight_error(res.brdf, truth, test_env, normals)
    err_prior = relight_error(prior_full, truth, test_env, normals)
    plain = relight_error(fit_brdf(scenes, model="full", lmax=6, pmax=6, progress=False).brdf, truth, test_env, normals)
    print(f"ggx 1 scene noise={noise}: full+prior relight {err:.4%}, its prior on the full basis {err_prior:.4%}, plain full {plain:.3g}")
    assert plain > 0.5  # the case is the hard one: the plain full fit relights wildly
    assert err <= 1.5 * err_prior


def test_joint_and_tikhonov_at_least_as_accurate_as_paper(probes):
    fit_env, test_env, normals, weights, truth, one = _one_scene(probes, 48, GGX(**GGX_MATERIAL))
    many = make_scenes(truth, rotations(fit_env, 5), normals, weights)
    table = []
    cases = [("diffuse", one, l) for l in range(1, 9)] + [("lobe", one, l) for l in range(1, 9)]
    cases += [("full", many, l) for l in (1, 2, 3, 4)]
    for model, scenes, lmax in cases:
        errs = {
            s: relight_error(fit_brdf(scenes, model=model, lmax=lmax, pmax=lmax, solver=s, progress=False).brdf, truth, test_env, normals)
            for s in ("paper", "joint", "tikhonov")
        }
        table.append((model, len(scenes), lmax, errs))
    print("\nmodel   scenes l=p   paper    joint    tikhonov")
    for model, n, lmax, e in table:
        print(f"{model:8s}{n:5d}{lmax:5d}  {e['paper']:.4f}  {e['joint']:.4f}  {e['tikhonov']:.4f}")
    for model, n, lmax, e in table:
        # At l = 1 no solver is within 12% (the model cannot represent the material) and which
        # biased answer relights better is luck; from l = 2 on the joint solves win by 2-8x.
        if lmax >= 2:
            assert min(e["joint"], e["tikhonov"]) <= e["paper"] * 1.001 + 1e-6, (model, lmax, e)
