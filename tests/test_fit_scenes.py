"""Scenes for the fitter tests (real probes, small spheres, ground truth) and checks of the linear models' forward model.

Helpers are imported by the other ``test_fit*`` modules.  Oracles: the
brute-force renderer ``brdfrig.fit.groundtruth.render_groundtruth`` and the
Ramamoorthi-Hanrahan irradiance coefficients ``A_l`` (MATH.md).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from brdfrig.fit.analytic import GGX, Lambertian
from brdfrig.fit.rotation import axis_rotation
from brdfrig.fit.groundtruth import render_groundtruth
from brdfrig.fit.models import DiffuseBRDF, FullBRDF, project_to_full
from brdfrig.fit.scene import Environment, Scene
from brdfrig.fit.system import ModelSpec
from brdfrig.hdr.envmap import latlong_directions
from brdfrig.hdr.exr import read_image
from brdfrig.hdr.sphere import sphere_pixels

GGX_MATERIAL = dict(alpha=0.3, f0=[0.04, 0.04, 0.04], diffuse=[0.5, 0.4, 0.3])
ALBEDO = np.array([0.6, 0.5, 0.3])


def irradiance_coefficient(l: int) -> float:
    """``A_l`` of max(cos, 0) (Ramamoorthi & Hanrahan 2001, eq. 8): pi, 2pi/3, pi/4, 0, -pi/24, ..."""
    if l == 1:
        return 2 * math.pi / 3
    if l % 2:
        return 0.0
    return 2 * math.pi * (-1) ** (l // 2 + 1) / ((l + 2) * (l - 1)) * math.factorial(l) / (2**l * math.factorial(l // 2) ** 2)


def probe_environment(path, rows: int = 32) -> Environment:
    """A real lat-long probe box-filtered to ``rows`` x ``2 rows`` (MATH.md geometry)."""
    img = np.asarray(read_image(path), dtype=np.float64)
    h, w, c = img.shape
    img = img.reshape(rows, h // rows, 2 * rows, w // (2 * rows), c).mean(axis=(1, 3))
    dirs, solid = latlong_directions(rows, 2 * rows)
    return Environment(dirs.reshape(-1, 3), img.reshape(-1, c), solid.reshape(-1))


def sphere(size: int) -> tuple[np.ndarray, np.ndarray]:
    """Normals and weights of the pixels of a centred sphere image of ``size`` px (radius size/2)."""
    px = sphere_pixels((size, size), (size / 2, size / 2, size / 2))
    keep = px.weights > 0
    return px.normals[keep], px.weights[keep]


def rotations(env: Environment, count: int) -> list[Environment]:
    """``env`` turned about the vertical axis in 30 degree steps."""
    return [env.rotated(axis_rotation("y", 30 * k)) for k in range(count)]


def make_scenes(brdf, envs, normals, weights, noise: float = 0.0, seed: int = 0) -> list[Scene]:
    """Ground-truth sphere images (optionally with relative Gaussian noise) under each environment."""
    rng = np.random.default_rng(seed)
    out = []
    for env in envs:
        img = render_groundtruth(brdf, normals, env)
        img = img * (1.0 + noise * rng.normal(size=img.shape))
        out.append(Scene(env, normals, img, weights))
    return out


def relight_error(brdf, truth_brdf, env: Environment, normals: np.ndarray, max_theta_deg: float = 80.0, _cache={}) -> float:
    """Relative RMS error of ``brdf.predict`` against the ground truth, within the fitter's limb margin.

    The ground-truth rendering is memoised per (truth BRDF, environment, normals) object triple.
    """
    sel = normals[:, 2] >= math.cos(math.radians(max_theta_deg))
    key = (id(truth_brdf), id(env), id(normals), max_theta_deg)
    if key not in _cache:
        _cache[key] = (truth_brdf, env, normals, render_groundtruth(truth_brdf, normals[sel], env))
    truth = _cache[key][3]
    pred = brdf.predict(env, normals[sel])
    return float(np.sqrt(np.sum((pred - truth) ** 2) / np.sum(truth**2)))


@pytest.fixture
def probes(real_probes):
    """(fit map, relight map) as 64x32 environments: grace for fitting, pisa for relighting."""
    by_name = {p.stem: p for p in real_probes}
    return probe_environment(by_name["grace"]), probe_environment(by_name["pisa"])


def test_diffuse_model_with_irradiance_coefficients_matches_brute_force(probes):
    """Forward model of ``diffuse``: a_l = (a/pi) A_l reproduces a Lambertian sphere rendered by quadrature."""
    env, _ = probes
    normals, _ = sphere(64)
    assert [irradiance_coefficient(l) for l in range(5)] == pytest.approx([math.pi, 2 * math.pi / 3, math.pi / 4, 0, -math.pi / 24])
    truth = render_groundtruth(Lambertian(ALBEDO), normals, env)
    errs = {}
    for lmax in (8, 16):
        x = np.outer([irradiance_coefficient(l) for l in range(lmax + 1)], ALBEDO / math.pi)
        model = DiffuseBRDF(ModelSpec("diffuse", lmax), x)
        pred = model.predict(env, normals)
        errs[lmax] = np.sqrt(np.sum((pred - truth) ** 2) / np.sum(truth**2))
        np.testing.assert_allclose(model.albedo, ALBEDO, rtol=1e-12)
    # truncation of the clamped cosine: ~1% at l = 8 under this sharp map, converging with l
    assert errs[8] < 0.02 and errs[16] < 0.006 and errs[16] < errs[8] / 2, errs


def test_full_projection_of_lambertian_evaluates_to_albedo_over_pi():
    spec = ModelSpec("full", 8, 8)
    full = FullBRDF(spec, project_to_full(Lambertian(ALBEDO), spec))
    theta = np.radians([10.0, 30.0, 50.0])
    rho = full.evaluate(theta[:, None], theta[None, :], np.pi / 3)
    # truncation ripple of max(cos, 0) at l = 8, divided by cos theta_i
    np.testing.assert_allclose(rho, np.broadcast_to(ALBEDO / math.pi, rho.shape), rtol=0.03)


def test_full_projection_of_ggx_relights_like_the_ground_truth(probes):
    """The tau basis (l = p = 8) written from an analytic GGX by quadrature relights it to a few percent."""
    _, env = probes
    normals, _ = sphere(48)
    truth = GGX(**GGX_MATERIAL)
    spec = ModelSpec("full", 8, 8)
    full = FullBRDF(spec, project_to_full(truth, spec))
    err = relight_error(full, truth, env, normals)
    assert err < 0.04, err
