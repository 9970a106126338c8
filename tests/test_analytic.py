"""Analytic BRDFs against closed forms and scipy quadrature (independent of the ground-truth renderer)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import integrate
from scipy.spatial.transform import Rotation

from brdfrig.fit.analytic import GGX, BlinnPhong, Lambertian, OrenNayar, ggx_ndf, smith_lambda
from brdfrig.fit.brdf import brdf_from_dict


def _unit(rng: np.random.Generator, n: int, upper: bool = False) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    if upper:
        v[:, 2] = np.abs(v[:, 2])
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _directional_albedo(brdf, theta_o: float, tol: float = 1e-8) -> float:
    """int rho(wi, wo) cos(theta_i) dwi over the upper hemisphere (channel 0), scipy adaptive cubature."""

    def f(x):
        return brdf.evaluate(x[:, 0], theta_o, x[:, 1])[:, 0] * np.cos(x[:, 0]) * np.sin(x[:, 0])

    res = integrate.cubature(f, [0.0, 0.0], [math.pi / 2, 2 * math.pi], rtol=tol, atol=tol)
    assert res.status == "converged"
    return float(res.estimate)


@pytest.mark.parametrize("alpha", [0.05, 0.3, 1.0])
def test_ggx_ndf_is_normalised(alpha):
    # int D(h) (n.h) dw_h = 1 over the hemisphere (Walter et al. 2007, eq. 4).
    val = integrate.quad(lambda t: ggx_ndf(math.cos(t), alpha) * math.cos(t) * math.sin(t) * 2 * math.pi,
                         0, math.pi / 2, epsabs=1e-12, epsrel=1e-12, limit=200)[0]
    assert val == pytest.approx(1.0, abs=1e-8)


@pytest.mark.parametrize("alpha,theta_o", [(0.3, 1.0), (0.8, 0.4)])
def test_smith_lambda_weak_white_furnace(alpha, theta_o):
    # Heitz 2014, sec. 7.2: int_{sphere} D(h) G1(wo) / (4 cos_o) dwi = 1 with G1 = 1 / (1 + Lambda(wo)).
    wo = np.array([math.sin(theta_o), 0.0, math.cos(theta_o)])
    g1 = 1.0 / (1.0 + smith_lambda(wo[2], alpha))

    def f(phi, t):
        wi = np.array([math.sin(t) * math.cos(phi), math.sin(t) * math.sin(phi), math.cos(t)])
        h = wi + wo
        h /= np.linalg.norm(h)
        return ggx_ndf(h[2], alpha) * g1 / (4 * wo[2]) * math.sin(t)

    val = integrate.dblquad(f, 0.0, math.pi, 0.0, 2 * math.pi, epsabs=1e-7, epsrel=1e-7)[0]
    assert val == pytest.approx(1.0, abs=1e-4)


def test_ggx_mirror_configuration_closed_form():
    # wi, wo mirror images about n (delta_phi = pi): h = n, D = 1/(pi a^2), cos_d = cos(theta).
    alpha, f0, diffuse, theta = 0.3, 0.04, 0.5, math.radians(60)
    lam = 0.5 * (math.sqrt(1 + alpha**2 * math.tan(theta) ** 2) - 1)
    fresnel = f0 + (1 - f0) * (1 - math.cos(theta)) ** 5
    expected = diffuse / math.pi + fresnel / (math.pi * alpha**2) / (1 + 2 * lam) / (4 * math.cos(theta) ** 2)
    got = GGX(alpha, f0, diffuse).evaluate(theta, theta, math.pi)
    assert got.shape == (1,)
    assert got[0] == pytest.approx(expected, rel=1e-12)
    # normal incidence: F = f0, G2 = 1
    assert GGX(alpha, f0, diffuse).evaluate(0.0, 0.0, 0.0)[0] == pytest.approx(
        diffuse / math.pi + f0 / (4 * math.pi * alpha**2), rel=1e-12)


def test_blinn_phong_closed_form_and_normalisation():
    b = BlinnPhong(diffuse=0.2, specular=0.5, exponent=40.0)
    # mirror configuration: n.h = 1
    assert b.evaluate(0.7, 0.7, math.pi)[0] == pytest.approx(0.2 / math.pi + 0.5 * 48 / (8 * math.pi), rel=1e-12)
    # Lobe albedo at normal incidence, closed form: with wo = n, n.h = cos(theta_i / 2); substituting
    # x = cos(theta_i / 2) gives (e+8) * [2 x^(e+4)/(e+4) - x^(e+2)/(e+2)] from x = 1/sqrt(2) to 1.
    for e in [10.0, 100.0]:
        prim = lambda x: 2 * x ** (e + 4) / (e + 4) - x ** (e + 2) / (e + 2)
        expected = (e + 8) * (prim(1.0) - prim(math.sqrt(0.5)))
        assert _directional_albedo(BlinnPhong(0.0, 1.0, e), 0.0) == pytest.approx(expected, rel=1e-6)


@pytest.mark.parametrize("alpha", [0.1, 0.5])
@pytest.mark.parametrize("theta_o", [0.0, 1.2])
def test_ggx_white_furnace(alpha, theta_o):
    # f0 = f90 = 1, no diffuse: the lobe alone may lose energy (single scattering) but never create it.
    a = _directional_albedo(GGX(alpha, 1.0, 0.0), theta_o)
    assert a <= 1.0 + 1e-6
    # the fraction of D's projected mass whose mirror direction stays above the horizon bounds
    # the albedo from above at normal incidence: P(theta_h < 45 deg) = 1 / (1 + alpha^2).
    if theta_o == 0.0:
        assert a <= 1.0 / (1.0 + alpha**2) + 1e-6
        assert a >= 0.8 / (1.0 + alpha**2)


def test_reciprocity_and_horizon():
    rng = np.random.default_rng(1)
    wi, wo, n = _unit(rng, 500), _unit(rng, 500), _unit(rng, 500)
    models = [Lambertian([0.2, 0.6]), BlinnPhong([0.1, 0.3], 0.7, [20.0, 5.0]), GGX([0.2, 0.6], 0.04, [0.3, 0.1]),
              OrenNayar([0.5, 0.3], [0.3, 1.0]), GGX(0.3, 0.04, 0.5, diffuse_sigma=[0.0, 0.5])]
    for m in models:
        a, b = m.rho(wi, wo, n), m.rho(wo, wi, n)
        assert a.shape == (500, 2)
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=0)
        below = (np.einsum("ij,ij->i", wi, n) <= 0) | (np.einsum("ij,ij->i", wo, n) <= 0)
        assert np.all(a[below] == 0) and np.all(a[~below] > 0)


def test_evaluate_matches_rho_and_isotropy():
    rng = np.random.default_rng(2)
    ti, to, dp = rng.uniform(0, 1.5, 50), rng.uniform(0, 1.5, 50), rng.uniform(-math.pi, math.pi, 50)
    wi = np.stack([np.sin(ti), np.zeros_like(ti), np.cos(ti)], 1)  # phi_i = 0
    wo = np.stack([np.sin(to) * np.cos(dp), np.sin(to) * np.sin(dp), np.cos(to)], 1)  # phi_o = dp
    n = np.tile([0.0, 0.0, 1.0], (50, 1))
    R = Rotation.random(random_state=3).as_matrix()
    m = GGX(0.25, [0.04, 0.9], 0.2)
    ev = m.evaluate(ti, to, dp)
    np.testing.assert_allclose(ev, m.rho(wi, wo, n), rtol=1e-12)
    np.testing.assert_allclose(ev, m.rho(wi @ R.T, wo @ R.T, n @ R.T), rtol=1e-9)
    assert m.evaluate(np.zeros((4, 3)), 0.5, 0.0).shape == (4, 3, 2)


def test_oren_nayar_matches_its_angular_form():
    # Oren & Nayar 1994, eq. 30, written with the angles (alpha = max, beta = min of the polar angles);
    # the kernel uses a cosine rewrite of it.
    rng = np.random.default_rng(4)
    ti, to, dp = rng.uniform(0, 1.5, 200), rng.uniform(0, 1.5, 200), rng.uniform(-math.pi, math.pi, 200)
    albedo, sigma = 0.7, 0.4
    a = 1 - 0.5 * sigma**2 / (sigma**2 + 0.33)
    b = 0.45 * sigma**2 / (sigma**2 + 0.09)
    expected = albedo / math.pi * (a + b * np.maximum(0, np.cos(dp)) * np.sin(np.maximum(ti, to)) * np.tan(np.minimum(ti, to)))
    np.testing.assert_allclose(OrenNayar(albedo, sigma).evaluate(ti, to, dp)[:, 0], expected, rtol=1e-12)
    np.testing.assert_array_equal(OrenNayar(albedo, 0.0).evaluate(ti, to, dp), Lambertian(albedo).evaluate(ti, to, dp))
    # the GGX base is the same Oren-Nayar term
    np.testing.assert_allclose(GGX(0.3, 0.0, albedo, f90=0.0, diffuse_sigma=sigma).evaluate(ti, to, dp)[:, 0], expected, rtol=1e-12)


def test_dict_roundtrip_and_validation():
    for m in [Lambertian(0.5), BlinnPhong([0.1, 0.2, 0.3], 0.5, 30), GGX(0.3, 0.04, [0.2, 0.4, 0.6], f90=0.8),
              OrenNayar([0.5, 0.4], 0.3), GGX(0.3, 0.04, 0.5, diffuse_sigma=0.2)]:
        back = brdf_from_dict(m.to_dict())
        assert type(back) is type(m) and back.channels == m.channels
        np.testing.assert_array_equal(back.kernel_params(), m.kernel_params())
    with pytest.raises(ValueError, match="alpha"):
        GGX(-0.1, 0.04, 0.5)
    with pytest.raises(ValueError, match="channel count"):
        GGX([0.1, 0.2], 0.04, [0.5, 0.5, 0.5])
    with pytest.raises(ValueError, match="albedo"):
        Lambertian(float("nan"))
