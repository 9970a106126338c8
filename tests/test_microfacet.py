"""The microfacet model: identifiable from one image, relights under another real probe, recovers alpha."""

from __future__ import annotations

import math

import numpy as np
import pytest

from brdfrig.fit.analytic import GGX, Lambertian
from brdfrig.fit.brdf import FittedBRDF, brdf_from_dict
from brdfrig.fit.groundtruth import render_groundtruth
from brdfrig.fit.microfacet import MicrofacetBRDF, coarsen_environment, fit_microfacet
from brdfrig.fit.models import DiffuseBRDF
from brdfrig.fit.scene import Environment, Scene
from brdfrig.fit.system import ModelSpec


def _sphere_normals(size: int, max_radius: float = 0.95) -> np.ndarray:
    """Normals of the pixels of a size x size sphere image (MATH.md convention) within max_radius of the centre."""
    y, x = np.mgrid[0:size, 0:size] + 0.5
    dx, dy = (x - size / 2) / (size / 2), (size / 2 - y) / (size / 2)
    inside = dx**2 + dy**2 < max_radius**2
    return np.stack([dx[inside], dy[inside], np.sqrt(1 - dx[inside] ** 2 - dy[inside] ** 2)], axis=1)


def _probe_env(path, factor: int) -> Environment:
    """A real lat-long probe box-downsampled by ``factor`` (A's lat-long geometry, B's reader)."""
    from brdfrig.hdr.envmap import latlong_directions
    from brdfrig.hdr.exr import read_image

    img = np.asarray(read_image(path), dtype=np.float64)
    h, w = img.shape[0] // factor, img.shape[1] // factor
    img = img[: h * factor, : w * factor].reshape(h, factor, w, factor, -1).mean(axis=(1, 3))
    dirs, omega = latlong_directions(h, w)
    return Environment(dirs.reshape(-1, 3), img.reshape(-1, img.shape[-1]), omega.ravel())


def _relative_rms(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((a - b) ** 2) / np.mean(b**2)))


def _fit_one(env, normals, observed, **kw):
    return fit_microfacet([Scene(env, normals, observed, np.ones(len(normals)))], progress=False, **kw)


def test_one_real_probe_fit_recovers_per_channel_parameters_and_relights(real_probes):
    # Per-channel roughness over an Oren-Nayar (rough diffuse) base, 1% noise: fit under grace, relight under pisa.
    fit_env = _probe_env(real_probes[1], 2)  # 128 x 64
    test_env = _probe_env(real_probes[2], 2)
    normals = _sphere_normals(64)
    truth = GGX([0.2, 0.3, 0.45], [0.04, 0.05, 0.03], [0.6, 0.4, 0.2], diffuse_sigma=0.5)
    observed = render_groundtruth(truth, normals, fit_env)
    noisy = observed * (1 + 0.01 * np.random.default_rng(0).standard_normal(observed.shape))
    brdf, report = _fit_one(fit_env, normals, noisy)
    assert isinstance(brdf, FittedBRDF) and brdf.model == "microfacet"
    np.testing.assert_allclose(report["alpha"], [0.2, 0.3, 0.45], rtol=0.05)  # measured within 2.3%
    np.testing.assert_allclose(report["diffuse_albedo"], [0.6, 0.4, 0.2], rtol=0.03)  # within 0.5%
    np.testing.assert_allclose(report["diffuse_sigma"], 0.5, atol=0.05)  # within 0.012 rad
    np.testing.assert_allclose(report["f0"], [0.04, 0.05, 0.03], rtol=0.1)
    assert report["determined"] and not any(report["alpha_at_bound"])
    assert not report["series_check"]["kept"] and brdf.series is None  # off by default (fit_microfacet's docstring)
    err = _relative_rms(brdf.predict(test_env, normals), render_groundtruth(truth, normals, test_env))
    assert err < 0.01  # measured 0.09%
    back = brdf_from_dict(brdf.to_dict())
    assert isinstance(back, MicrofacetBRDF)
    np.testing.assert_array_equal(back.evaluate(0.3, 0.5, 2.0), brdf.evaluate(0.3, 0.5, 2.0))


def test_sh_series_captures_a_diffuse_term_the_base_cannot(real_probes):
    # The truth adds a diffuse term radially symmetric about the normal in bands 1-2 (rendered through SH,
    # which is how that term is defined): the check pixels keep the series and it is recovered.
    fit_env = _probe_env(real_probes[1], 2)
    test_env = _probe_env(real_probes[2], 2)
    normals = _sphere_normals(64)
    truth = GGX([0.2, 0.3, 0.45], [0.04, 0.05, 0.03], [0.6, 0.4, 0.2])
    extra = DiffuseBRDF(ModelSpec("diffuse", 2, bands=(1, 2)), np.array([[0.1, 0.06, 0.03], [0.08, 0.05, 0.02]]))
    observed = render_groundtruth(truth, normals, fit_env) + extra.predict(fit_env, normals)
    noisy = observed * (1 + 0.01 * np.random.default_rng(0).standard_normal(observed.shape))
    brdf, report = _fit_one(fit_env, normals, noisy, lmax=4, series=True)
    check = report["series_check"]
    assert check["kept"] and check["check_relative_rms"]["with_series"] < 0.2 * check["check_relative_rms"]["base_only"]
    np.testing.assert_allclose(brdf.series.x[:2], extra.x, rtol=0.05, atol=2e-3)  # measured within 1%
    np.testing.assert_allclose(brdf.series.x[2:], 0.0, atol=3e-3)
    np.testing.assert_allclose(report["alpha"], [0.2, 0.3, 0.45], rtol=0.05)
    relit = brdf.predict(test_env, normals)
    err = _relative_rms(relit, render_groundtruth(truth, normals, test_env) + extra.predict(test_env, normals))
    assert err < 0.01  # measured 0.14% (11% without the series)


def test_lambertian_sphere_gives_no_lobe():
    # A single directional-ish light plus ambient: the fit must put nothing into the lobe.
    rng = np.random.default_rng(1)
    dirs = rng.normal(size=(4000, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    rad = 0.2 + 5.0 * np.maximum(dirs @ np.array([0.5, 0.6, 0.62]), 0) ** 8
    env = Environment(dirs, rad[:, None], np.full(4000, 4 * math.pi / 4000))
    normals = _sphere_normals(32)
    observed = render_groundtruth(Lambertian(0.7), normals, env)
    brdf, report = _fit_one(env, normals, observed, env_rows=24)
    assert report["diffuse_albedo"][0] == pytest.approx(0.7, rel=0.02)
    assert report["lobe_fraction"][0] < 0.01 and report["diffuse_sigma"][0] < 0.1
    relit = brdf.predict(env, normals)
    assert _relative_rms(relit, observed) < 0.01


def test_coarsen_environment_preserves_energy_and_first_moment():
    rng = np.random.default_rng(2)
    dirs = rng.normal(size=(5000, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    rad = rng.uniform(0, 3, size=(5000, 2))
    omega = rng.uniform(0, 1e-3, 5000)
    omega[:10] = 0
    env = Environment(dirs, rad, omega)
    c = coarsen_environment(env, 8)
    assert len(c.solid_angle) <= 128
    np.testing.assert_allclose(c.solid_angle.sum(), omega.sum(), rtol=1e-12)
    np.testing.assert_allclose((c.radiance * c.solid_angle[:, None]).sum(0), (rad * omega[:, None]).sum(0), rtol=1e-12)


def test_bad_input():
    env = Environment(np.array([[0.0, 0.0, 1.0]]), np.ones((1, 3)), np.ones(1))
    n = np.array([[0.0, 0.0, 1.0]])
    with pytest.raises(ValueError, match="channel"):
        fit_microfacet([Scene(env, n, np.ones((1, 1)), np.ones(1))], progress=False)
    with pytest.raises(ValueError, match="positive weight"):
        fit_microfacet([Scene(env, n, np.ones((1, 3)), np.zeros(1))], progress=False)
    with pytest.raises(ValueError, match="non-finite"):
        fit_microfacet([Scene(env, n, np.full((1, 3), np.nan), np.ones(1))], progress=False)
    with pytest.raises(ValueError, match="at least one scene"):
        fit_microfacet([], progress=False)
    with pytest.raises(ValueError, match="lmax"):
        fit_microfacet([Scene(env, n, np.ones((1, 3)), np.ones(1))], lmax=-1, progress=False)


def test_black_image_and_single_bright_pixel_are_finite():
    rng = np.random.default_rng(3)
    dirs = rng.normal(size=(2000, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    rad = np.zeros((2000, 3))
    rad[np.argmax(dirs @ np.array([0.3, 0.4, 0.866]))] = 1e6  # one bright sample, 1e6 dynamic range vs black
    env = Environment(dirs, rad, np.full(2000, 4 * math.pi / 2000))
    normals = _sphere_normals(24)
    truth = GGX(0.3, 0.04, 0.5)
    for observed in (np.zeros((len(normals), 3)), render_groundtruth(truth, normals, env)):
        brdf, report = _fit_one(env, normals, observed, env_rows=24)
        params = brdf.analytic.kernel_params()
        assert np.all(np.isfinite(params)) and math.isfinite(report["relative_rms_residual"])
    assert np.all(np.abs(brdf.predict(env, normals) - observed) <= 0.05 * observed.max())


def test_relighting_on_binned_lighting_matches_the_full_map(real_probes):
    # predict() bins a 256 x 128 map to 63 rows for alpha = 0.1; the ground truth sums over every pixel.
    env = _probe_env(real_probes[2], 1)
    normals = _sphere_normals(40)
    analytic = GGX(0.1, 0.04, 0.5, diffuse_sigma=0.3)
    got = MicrofacetBRDF(analytic).predict(env, normals)
    assert _relative_rms(got, render_groundtruth(analytic, normals, env)) < 5e-4  # measured 1.7e-4 on a 128 px sphere


def test_roughplastic_like_sphere_keeps_fresnel_physical_and_no_series(real_probes):
    # A GGX dielectric coating over a coloured base (brdfrig.fit.pbr, Mitsuba roughplastic's layering): outside
    # the microfacet family.  The grazing reflectance stays in [f0, 1] (free, it went to 1.32 on Mitsuba's
    # roughplastic), nothing goes into an SH series, rho stays bounded at grazing and the sphere relights.
    from brdfrig.fit.pbr import DielectricBRDF

    fit_env = _probe_env(real_probes[1], 4)  # 64 x 32
    test_env = _probe_env(real_probes[2], 4)
    normals = _sphere_normals(32)
    truth = DielectricBRDF([0.6, 0.3, 0.1], 0.0, 1.0, math.sqrt(0.2), 1.49)
    brdf, report = _fit_one(fit_env, normals, truth.predict(fit_env, normals))
    f0, f90 = np.array(report["f0"]), np.array(report["f90"])
    assert np.all((0 <= f0) & (f0 <= f90) & (f90 <= 1.0))
    assert brdf.series is None and report["series_bands"] == []
    grazing = brdf.evaluate(math.radians(89.9), np.radians([0.0, 30.0, 60.0]), 0.0)
    assert np.all(np.isfinite(grazing)) and np.all(grazing >= 0) and np.all(grazing < 0.5)
    relit = brdf.predict(test_env, normals)
    assert np.all(relit >= 0)
    assert _relative_rms(relit, truth.predict(test_env, normals)) < 0.06  # measured 3.5% at 96 px / 128 x 64
