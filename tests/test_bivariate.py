"""The bivariate model: a BRDF that is a function of (theta_h, theta_d) is recovered from one image and relights.

Oracle: the ground-truth renderer of tabulated BRDFs (:func:`brdfrig.fit.groundtruth.render_tabulated`,
MERL grid, trilinear lookup), independent of the bivariate model's own kernels.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from brdfrig.fit.bivariate import BivariateBRDF, fit_bivariate
from brdfrig.fit.brdf import FittedBRDF, brdf_from_dict
from brdfrig.fit.metrics import relative_rms
from brdfrig.fit.scene import Scene


def _sphere_normals(size: int, max_radius: float = 0.95) -> np.ndarray:
    y, x = np.mgrid[0:size, 0:size] + 0.5
    dx, dy = (x - size / 2) / (size / 2), (size / 2 - y) / (size / 2)
    inside = dx**2 + dy**2 < max_radius**2
    return np.stack([dx[inside], dy[inside], np.sqrt(1 - dx[inside] ** 2 - dy[inside] ** 2)], axis=1)


def _probe(path, rows: int):
    from brdfrig.evaluate.probes import box_downsample
    from brdfrig.hdr.exr import read_image
    from brdfrig.lighting import environment_from_latlong

    return environment_from_latlong(box_downsample(np.asarray(read_image(path), dtype=np.float64), rows))


def _bivariate_truth(th, td, albedo, alpha, f0):
    """Lambertian + GGX distribution of theta_h times Schlick's Fresnel of theta_d (1/sr), per channel."""
    c2 = np.cos(th)[..., None] ** 2
    a2 = np.asarray(alpha) ** 2
    ndf = a2 / (math.pi * (c2 * (a2 - 1) + 1) ** 2)
    fresnel = np.asarray(f0) + (1 - np.asarray(f0)) * (1 - np.cos(td)[..., None]) ** 5
    return np.asarray(albedo) / math.pi + 0.25 * ndf * fresnel


def _tabulated(fn):
    from brdfrig.fit.measured import TabulatedBRDF, merl_grid

    th, td, _ = merl_grid()
    table = fn(th[:, None], td[None, :])  # (90, 90, C)
    return TabulatedBRDF(np.repeat(table[:, :, None, :], 180, axis=2))


def _fit(env, normals, observed, **kw):
    return fit_bivariate([Scene(env, normals, observed, np.ones(len(normals)))], progress=False, **kw)


@pytest.fixture(scope="module")
def envs():
    from conftest import probe_paths

    paths = probe_paths()
    if not paths:
        pytest.skip("../shared/data/probes is absent")
    return _probe(paths[1], 32), _probe(paths[2], 32)  # grace, pisa at 64 x 32


def test_lambertian_is_recovered_exactly(envs):
    from brdfrig.fit.analytic import Lambertian
    from brdfrig.fit.groundtruth import render_tabulated

    fit_env, test_env = envs
    normals = _sphere_normals(48)
    truth = _tabulated(lambda th, td: np.broadcast_to(np.array([0.6, 0.4, 0.2]) / math.pi, np.broadcast(th, td).shape + (3,)))
    brdf, report = _fit(fit_env, normals, render_tabulated(truth, normals, fit_env))
    assert isinstance(brdf, FittedBRDF) and brdf.model == "bivariate"
    # a constant lies in the regulariser's null space: recovered up to the two quadratures' difference
    # (the oracle's 20-degree cone split 12 x 12 and trilinear lookup vs the fit's 10-degree cone split 8 x 8)
    np.testing.assert_allclose(brdf.table, np.broadcast_to((np.array([0.6, 0.4, 0.2]) / math.pi)[:, None, None], brdf.table.shape), rtol=1e-2)  # measured 0.44%
    err = relative_rms(brdf.predict(test_env, normals), render_tabulated(truth, normals, test_env))
    assert err < 2e-3
    # and the table's own renderer agrees with the analytic Lambertian's (cell-centre quadrature)
    assert relative_rms(brdf.predict(test_env, normals), Lambertian([0.6, 0.4, 0.2]).predict(test_env, normals)) < 1e-3


def test_bivariate_lobe_relights_under_another_probe(envs):
    from brdfrig.fit.groundtruth import render_tabulated

    fit_env, test_env = envs
    normals = _sphere_normals(48)
    fn = lambda th, td: _bivariate_truth(th, td, [0.5, 0.35, 0.2], [0.2, 0.25, 0.3], [0.04, 0.05, 0.06])  # noqa: E731
    truth = _tabulated(fn)
    observed = render_tabulated(truth, normals, fit_env)
    noisy = observed * (1 + 0.01 * np.random.default_rng(0).standard_normal(observed.shape))
    brdf, report = _fit(fit_env, normals, noisy, max_pixels=1000)
    err = relative_rms(brdf.predict(test_env, normals), render_tabulated(truth, normals, test_env))
    assert err < 0.01, err  # measured 0.44% (1% noise; grace -> pisa at 64 x 32)
    # constraints: non-negative everywhere, non-increasing in theta_h when the monotone table was kept
    assert np.all(brdf.tables >= 0) and np.all(np.isfinite(brdf.tables))
    if report["monotone"]:
        assert np.all(np.diff(brdf.tables, axis=2) <= 1e-12)
    grazing = brdf.evaluate(np.radians(89.9), np.radians(89.9), math.pi)
    assert np.all(np.isfinite(grazing)) and np.all(grazing >= 0)
    # identifiability report: shapes, and the cells no light of the scene reaches are flagged as filled
    obs = np.asarray(report["observation"])
    filled = np.asarray(report["filled_by_regulariser"])
    assert obs.shape == (3, report["nh"], report["nd"]) and filled.shape == (report["nh"], report["nd"])
    assert filled.any() and (~filled).any()
    assert report["observed_fraction"] == pytest.approx(float((~filled).mean()))


def test_round_trip_and_bad_tables():
    rng = np.random.default_rng(1)
    brdf = BivariateBRDF(rng.uniform(0, 1, (3, 5, 4)), rng.uniform(0, 1, (3, 5, 4)))
    back = brdf_from_dict(brdf.to_dict())
    assert isinstance(back, BivariateBRDF)
    ti, to, dp = rng.uniform(0, math.pi / 2, (3, 50))
    np.testing.assert_array_equal(back.evaluate(ti, to, dp), brdf.evaluate(ti, to, dp))
    # a file without a cross table (no phi_d dependence) reads as one whose cross table equals the table
    plain = brdf_from_dict({"model": "bivariate", "nh": 5, "nd": 4, "table": brdf.table.tolist()})
    np.testing.assert_array_equal(plain.cross, brdf.table)
    with pytest.raises(ValueError, match="negative"):
        BivariateBRDF(-np.ones((1, 3, 3)))
    with pytest.raises(ValueError, match="cross table has 1 negative"):
        BivariateBRDF(np.ones((1, 3, 3)), np.where(np.eye(3) * np.arange(3) == 1, -1.0, 1.0)[None])
    with pytest.raises(ValueError, match="non-finite"):
        BivariateBRDF(np.full((1, 3, 3), np.nan))
    with pytest.raises(ValueError, match="cross table has shape"):
        BivariateBRDF(np.ones((1, 3, 3)), np.ones((1, 3, 4)))
    with pytest.raises(ValueError, match="shape"):
        brdf_from_dict({"model": "bivariate", "nh": 4, "nd": 4, "table": np.ones((3, 5, 4)).tolist()})


def test_evaluate_matches_node_values_and_reciprocity():
    from brdfrig.fit.measured import rusinkiewicz_directions

    table, cross = np.random.default_rng(2).uniform(0, 1, (2, 2, 9, 5))
    brdf = BivariateBRDF(table, cross)
    # at a node: theta_h = (a / 8)^2 * 90 deg, theta_d = b / 4 * 90 deg; in the plane of incidence wi, wo lie at
    # theta_h +- theta_d from the normal (same side: delta_phi = 0; opposite sides: pi)
    a, b = 3, 2
    th, td = (a / 8) ** 2 * math.pi / 2, b / 4 * math.pi / 2
    ti, to = th + td, abs(th - td)
    dphi = 0.0 if th >= td else math.pi
    np.testing.assert_allclose(brdf.evaluate(ti, to, dphi), table[:, a, b], rtol=1e-9)
    # Rusinkiewicz's phi_d = 90 deg (wi across the plane of n and h) is the cross table, 45 deg their mean
    for phi_d, want in ((math.pi / 2, cross[:, a, b]), (math.pi / 4, 0.5 * (table[:, a, b] + cross[:, a, b]))):
        wi, wo = rusinkiewicz_directions(th, td, phi_d)
        got = brdf.evaluate(np.arccos(wi[2]), np.arccos(wo[2]), np.arctan2(wo[1], wo[0]) - np.arctan2(wi[1], wi[0]))
        np.testing.assert_allclose(got, want, rtol=1e-9)
    ti, to, dp = np.random.default_rng(3).uniform(0, math.pi / 2, (3, 20))
    np.testing.assert_allclose(brdf.evaluate(ti, to, dp), brdf.evaluate(to, ti, dp), rtol=1e-12)


def test_project_to_nodes_of_a_table_and_a_lambertian():
    from brdfrig.fit.analytic import Lambertian
    from brdfrig.fit.bivariate import project_to_nodes, theta_d_nodes, theta_h_nodes

    tables = np.random.default_rng(4).uniform(0, 1, (2, 2, 9, 5))
    tables[1, :, 0] = tables[0, :, 0]  # isotropy: at theta_h = 0 (and theta_d = 0) phi_d is undefined
    tables[1, :, :, 0] = tables[0, :, :, 0]
    got = project_to_nodes(BivariateBRDF(*tables), 9, 5)
    # where theta_h + theta_d < 90 deg every phi_d keeps wi and wo above the horizon: both tables come back
    # exactly; beyond, only phi_d near 90 deg is seen and the node takes the mean of what is (finite, >= 0)
    th, td = np.meshgrid(np.degrees(theta_h_nodes(9)), np.degrees(theta_d_nodes(5)), indexing="ij")
    seen = th + td < 90.0
    assert got.shape == (2, 2, 9, 5) and 20 <= seen.sum() < 45
    np.testing.assert_allclose(got[:, :, seen], tables[:, :, seen], rtol=1e-9)
    assert np.all(np.isfinite(got)) and np.all(got >= 0)
    lam = project_to_nodes(Lambertian([0.6, 0.3, 0.1]), 24, 8)
    np.testing.assert_allclose(lam, np.broadcast_to((np.array([0.6, 0.3, 0.1]) / math.pi)[:, None, None], lam.shape), rtol=1e-12)


def test_prior_fills_the_nodes_the_lighting_leaves_unobserved(envs):
    """Data of a lobe BRDF, prior = that BRDF: the table stays at the prior's nodes (zero residual and zero
    deviation penalty are both reached there, up to the two quadratures' difference); a wrong prior (half the
    truth) is overruled by the image: the fit relights far better than the prior alone."""
    from brdfrig.fit.bivariate import project_to_nodes
    from brdfrig.fit.groundtruth import render_tabulated

    fit_env, test_env = envs
    normals = _sphere_normals(48)
    fn = lambda th, td: _bivariate_truth(th, td, [0.5, 0.35, 0.2], [0.3, 0.35, 0.4], [0.04, 0.05, 0.06])  # noqa: E731
    th_n, td_n = np.meshgrid(*(np.radians(np.array(v)) for v in (
        np.linspace(0, 1, 24) ** 2 * 90, np.linspace(0, 90, 8))), indexing="ij")
    exact = BivariateBRDF(np.moveaxis(fn(th_n, td_n), -1, 0))
    nodes = project_to_nodes(exact, 24, 8)
    observed = render_tabulated(_tabulated(fn), normals, fit_env)
    brdf, report = _fit(fit_env, normals, observed, prior=exact, max_pixels=1000)
    assert report["prior"] == "bivariate" and report["determined"]
    assert not np.all(report["observed"])  # some nodes are left to the prior
    deviation = np.abs(brdf.tables - nodes) / nodes
    assert np.median(deviation) < 0.01  # measured 0.39% (largest 2.7%)
    reference = render_tabulated(_tabulated(fn), normals, test_env)
    assert relative_rms(brdf.predict(test_env, normals), reference) < 3e-3  # measured 0.044%
    half = BivariateBRDF(0.5 * exact.table)
    corrected, _ = _fit(fit_env, normals, observed, prior=half, max_pixels=1000)
    err_prior = relative_rms(half.predict(test_env, normals), reference)
    err_fit = relative_rms(corrected.predict(test_env, normals), reference)
    assert err_prior > 0.45 and err_fit < 0.01, (err_prior, err_fit)  # measured 50% -> 0.12%


def test_fitter_regularises_bivariate_toward_the_best_parametric_candidate(envs):
    """``bivariate+prior`` in ``fit_brdf``: the prior is the parametric candidate with the smallest held-out
    error; a sphere of a dielectric BRDF (one of those families) relights about as well as the table of that
    BRDF's own node values (oracle: the BRDF's render under the other probe)."""
    from brdfrig.fit.fitter import fit_brdf
    from brdfrig.fit.pbr import DielectricBRDF
    from brdfrig.fit.registry import PARAMETRIC

    fit_env, test_env = envs
    normals = _sphere_normals(40)
    truth = DielectricBRDF(base_color=[0.5, 0.3, 0.2], specular_weight=1.0, specular_roughness=0.5, specular_ior=1.5)
    scene = Scene(fit_env, normals, truth.predict(fit_env, normals), np.ones(len(normals)))
    result = fit_brdf([scene], model="bivariate+prior", progress=False)
    cands = result.report.candidates
    prior = cands["bivariate+prior"].prior
    held = {m: cands[m].heldout_relative_rms for m in PARAMETRIC if cands[m].heldout_relative_rms is not None}
    assert prior == min(held, key=held.get)
    assert result.report.to_dict()["candidates"]["bivariate+prior"]["fit_report"]["prior"] == result.brdfs[prior].model
    reference = truth.predict(test_env, normals)
    err = relative_rms(result.brdf.predict(test_env, normals), reference)
    # the table cannot do much better than the truth's own node values (two phi_d terms, bilinear between nodes)
    from brdfrig.fit.bivariate import project_to_nodes

    floor = relative_rms(BivariateBRDF(*project_to_nodes(truth, 24, 8)).predict(test_env, normals), reference)
    assert err < floor + 0.002, (err, floor)  # measured 2.24% against the node values' 2.57%


def test_phi_d_dependence_is_recovered(envs):
    """A BRDF ``P cos^2 phi_d + Q sin^2 phi_d`` (MERL grid, rendered by the tabulated ground truth): the fit
    recovers its ``phi_d`` term from one image and relights far better than the truth's own ``phi_d``-mean node
    values (the table a ``phi_d``-free fit aims at)."""
    from brdfrig.fit.bivariate import project_to_nodes
    from brdfrig.fit.groundtruth import render_tabulated
    from brdfrig.fit.measured import TabulatedBRDF, merl_grid

    fit_env, test_env = envs
    normals = _sphere_normals(48)
    th, td, pd = merl_grid()
    th, td, pd = th[:, None, None, None], td[None, :, None, None], pd[None, None, :, None]
    albedo = np.array([0.5, 0.35, 0.2])
    bend = np.sin(td) ** 2 * np.sin(2 * np.minimum(th, math.pi / 4)) ** 2  # 0 where phi_d is undefined
    lobe = _bivariate_truth(th[..., 0], td[..., 0], 0.0, [0.3, 0.35, 0.4], 0.04)
    inplane = albedo / math.pi * (1 + 0.9 * bend) + lobe
    cross = albedo / math.pi * (1 - 0.6 * bend) + lobe
    truth = TabulatedBRDF(inplane * np.cos(pd) ** 2 + cross * np.sin(pd) ** 2)
    brdf, _ = _fit(fit_env, normals, render_tabulated(truth, normals, fit_env), max_pixels=1000)
    reference = render_tabulated(truth, normals, test_env)
    err = relative_rms(brdf.predict(test_env, normals), reference)
    mean_nodes = project_to_nodes(truth, 24, 8).mean(axis=0)
    floor = relative_rms(BivariateBRDF(mean_nodes).predict(test_env, normals), reference)
    assert err < 0.015 and err < 0.3 * floor, (err, floor)  # measured 0.50% against the mean nodes' 4.98%


def test_tables_of_different_grids_predicted_together_equal_each_alone(envs):
    """One pass over the quadrature samples serves several tables (24 x 8, 32 x 12, a phi_d-dependent one): each
    prediction equals the table's own to 1e-12 relative, and the constant table's equals the analytic
    Lambertian's (cell-centre quadrature) to 1e-3."""
    from brdfrig.fit.analytic import Lambertian
    from brdfrig.fit.bivariate import predict_tables

    _, test_env = envs
    normals = _sphere_normals(24)
    rng = np.random.default_rng(3)
    lambertian = BivariateBRDF(np.broadcast_to((np.array([0.6, 0.4, 0.2]) / math.pi)[:, None, None], (3, 32, 12)))
    brdfs = [BivariateBRDF(rng.random((3, 24, 8))), lambertian, BivariateBRDF(rng.random((3, 24, 8)), rng.random((3, 24, 8)))]
    together = predict_tables(brdfs, test_env, normals)
    for brdf, pred in zip(brdfs, together):
        alone = predict_tables([brdf], test_env, normals)[0]
        assert pred.shape == (len(normals), 3) and relative_rms(pred, alone) < 1e-12
    assert relative_rms(together[1], Lambertian([0.6, 0.4, 0.2]).predict(test_env, normals)) < 1e-3
    assert predict_tables([], test_env, normals) == []


def test_a_lighting_and_pixels_seen_again_are_predicted_from_their_kept_design(envs, monkeypatch):
    """The same lighting, pixels and grid seen a second time keep their design, and later predictions come from
    it: equal to the quadrature pass of the first sight to 1e-12 relative (tables of two grids in one call, in
    either order), the constant table equal to the analytic Lambertian to 1e-3.  Other pixels or another
    lighting are not served from it.  A budget too small for any design keeps none, and one that holds only the
    24 x 8 design keeps it (the larger 32 x 12 one is rendered, not built, so it flushes nothing); neither
    changes a prediction."""
    from brdfrig.fit import bivariate
    from brdfrig.fit.memo import RenderMemo
    from brdfrig.fit.analytic import Lambertian

    fit_env, test_env = envs
    normals = _sphere_normals(24)
    rng = np.random.default_rng(4)
    albedo = np.array([0.6, 0.4, 0.2])
    lambertian = BivariateBRDF(np.broadcast_to((albedo / math.pi)[:, None, None], (3, 32, 12)))
    brdfs = [BivariateBRDF(rng.random((3, 24, 8))), lambertian, BivariateBRDF(rng.random((3, 24, 8)), rng.random((3, 24, 8)))]
    small = len(normals) * 2 * 24 * 8 * 3 * 8  # bytes of the 24 x 8 design on these pixels
    for budget, kept, kept_after in ((bivariate.DESIGN_CACHE_BYTES, 2, 4), (0, 0, 0), (small, 1, 1)):
        monkeypatch.setattr(bivariate, "_DESIGNS", RenderMemo(budget, second_sight=True))
        first = bivariate.predict_tables(brdfs, test_env, normals)
        assert len(bivariate._DESIGNS) == 0
        second = bivariate.predict_tables(brdfs, test_env, normals)
        assert len(bivariate._DESIGNS) == kept
        third = bivariate.predict_tables(brdfs[::-1], test_env, normals)[::-1]
        for a, b, c in zip(first, second, third):
            assert relative_rms(b, a) < 1e-12 and relative_rms(c, a) < 1e-12
        assert relative_rms(third[1], Lambertian(albedo).predict(test_env, normals)) < 1e-3
        for env, pixels in ((test_env, normals[::2]), (fit_env, normals)):
            for _ in range(3):
                other = bivariate.predict_tables([lambertian], env, pixels)[0]
                assert relative_rms(other, Lambertian(albedo).predict(env, pixels)) < 1e-3
        assert len(bivariate._DESIGNS) == kept_after
