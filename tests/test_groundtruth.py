"""Ground-truth renderer against closed forms, scipy quadrature and (as an independent peer) the SH irradiance formula."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import integrate

from brdfrig.fit.analytic import GGX, BlinnPhong, Lambertian
from brdfrig.fit.groundtruth import render_groundtruth
from brdfrig.fit.scene import Environment


def _frame(n: np.ndarray) -> np.ndarray:
    """Orthonormal basis (3, 3) whose third column is ``n``."""
    a = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    t = np.cross(n, a)
    t /= np.linalg.norm(t)
    return np.stack([t, np.cross(n, t), n], axis=1)


def _hemisphere_rule(n: np.ndarray, n_mu: int = 24, n_phi: int = 48) -> tuple[np.ndarray, np.ndarray]:
    """Quadrature on the whole sphere with its equator on the horizon of ``n``.

    Gauss-Legendre in mu = cos(theta) on [0, 1] and on [-1, 0], uniform in phi: exact for
    polynomials of degree < 2 n_mu in mu times trigonometric polynomials of degree < n_phi
    in phi, hence for max(n.w, 0) times a low-degree polynomial of w.
    """
    x, w = np.polynomial.legendre.leggauss(n_mu)
    mu = np.concatenate([(x + 1) / 2, (x - 1) / 2])
    wmu = np.concatenate([w / 2, w / 2])
    phi = (np.arange(n_phi) + 0.5) * 2 * np.pi / n_phi
    M, P = np.meshgrid(mu, phi, indexing="ij")
    s = np.sqrt(1 - M**2)
    local = np.stack([s * np.cos(P), s * np.sin(P), M], -1).reshape(-1, 3)
    omega = (wmu[:, None] * np.full(n_phi, 2 * np.pi / n_phi)[None, :]).ravel()
    return local @ _frame(n).T, omega


def _normals(n: int, seed: int = 0) -> np.ndarray:
    v = np.random.default_rng(seed).normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2]) + 0.05
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def test_constant_environment_lambertian_is_exact():
    albedo = np.array([0.2, 0.5, 0.9])
    for n in _normals(5):
        dirs, omega = _hemisphere_rule(n)
        env = Environment(dirs, np.full((len(dirs), 3), 2.5), omega)
        got = render_groundtruth(Lambertian(albedo), n[None], env)
        np.testing.assert_allclose(got[0], 2.5 * albedo, rtol=1e-13)


def test_band2_lighting_matches_irradiance_closed_form():
    # L(w) = c0 + c1.w + Q(w) with Q traceless quadratic (pure band 2). Ramamoorthi-Hanrahan:
    # irradiance E(n) = pi c0 + (2 pi / 3) c1.n + (pi / 4) Q(n); Lambertian B = albedo E / pi.
    c1 = np.array([0.3, -0.2, 0.5])
    lighting = lambda w: 1.0 + w @ c1 + 0.4 * w[..., 0] * w[..., 1] + 0.25 * (3 * w[..., 2] ** 2 - 1)
    for n in _normals(6, seed=1):
        dirs, omega = _hemisphere_rule(n)
        env = Environment(dirs, lighting(dirs)[:, None], omega)
        got = render_groundtruth(Lambertian(0.7), n[None], env)[0, 0]
        quad = 0.4 * n[0] * n[1] + 0.25 * (3 * n[2] ** 2 - 1)
        expected = 0.7 / math.pi * (math.pi + 2 * math.pi / 3 * (c1 @ n) + math.pi / 4 * quad)
        assert got == pytest.approx(expected, rel=1e-12)


@pytest.mark.parametrize("model,theta_o", [(GGX(0.3, 1.0, 0.0), 0.6), (BlinnPhong(0.1, 0.8, 30.0), 1.1)])
def test_white_furnace_matches_scipy(model, theta_o):
    # Under constant unit radiance B(n) is the directional albedo at theta_o = angle(n, v).
    n = np.array([math.sin(theta_o), 0.0, math.cos(theta_o)])
    dirs, omega = _hemisphere_rule(n, n_mu=96, n_phi=192)
    env = Environment(dirs, np.ones((len(dirs), 1)), omega)
    got = render_groundtruth(model, n[None], env)[0, 0]
    f = lambda x: model.evaluate(x[:, 0], theta_o, x[:, 1])[:, 0] * np.cos(x[:, 0]) * np.sin(x[:, 0])
    expected = integrate.cubature(f, [0.0, 0.0], [math.pi / 2, 2 * math.pi], rtol=1e-9, atol=1e-9).estimate
    assert got == pytest.approx(expected, rel=1e-6)


def test_away_facing_and_unseen_samples_and_channels():
    dirs, omega = _hemisphere_rule(np.array([0.0, 0.0, 1.0]))
    rad = np.ones((len(dirs), 3))
    rad[0] = 1e30  # unseen sample (zero solid angle) must not contribute
    omega = omega.copy()
    omega[0] = 0.0
    env = Environment(dirs, rad, omega)
    out = render_groundtruth(GGX(0.3, 0.04, 0.5), np.array([[0.0, 0.0, 1.0], [0.0, 0.6, -0.8]]), env)
    assert out.shape == (2, 3) and np.all(np.isfinite(out)) and out[0, 0] < 1 and np.all(out[1] == 0)
    with pytest.raises(ValueError, match="channels"):
        render_groundtruth(GGX(0.3, 0.04, [0.5, 0.5]), np.array([[0.0, 0.0, 1.0]]), env)


def test_real_probe_lambertian_matches_sh_irradiance(real_probes):
    # Independent peer: A's SH projection + the Ramamoorthi-Hanrahan A_l of the clamped cosine.
    from brdfrig.fit.sh import sh_eval
    from brdfrig.fit.shproject import project_environment
    from brdfrig.hdr.envmap import latlong_directions
    from brdfrig.hdr.exr import read_image

    img = np.asarray(read_image(real_probes[0]), dtype=np.float64)
    h, w = img.shape[0] // 4, img.shape[1] // 4
    img = img.reshape(h, 4, w, 4, -1).mean(axis=(1, 3))  # box-downsample to 64x32
    dirs, omega = latlong_directions(h, w)
    env = Environment(dirs.reshape(-1, 3), img.reshape(-1, img.shape[-1]), omega.ravel())
    normals = _normals(200, seed=2)
    got = render_groundtruth(Lambertian(0.8), normals, env)

    lmax = 24
    coeffs = project_environment(env, lmax)  # (ncoef, C)
    a_l = np.zeros(lmax + 1)
    a_l[0], a_l[1] = math.pi, 2 * math.pi / 3
    for l in range(2, lmax + 1, 2):  # R-H 2001 eq. 8 (odd l > 1 vanish)
        a_l[l] = 2 * math.pi * (-1) ** (l // 2 - 1) / ((l + 2) * (l - 1)) * math.comb(l, l // 2) / 2**l
    band = np.concatenate([[l] * (2 * l + 1) for l in range(lmax + 1)])
    expected = 0.8 / math.pi * sh_eval(normals, lmax) @ (a_l[band, None] * coeffs)
    rel = np.sqrt(np.mean((got - expected) ** 2) / np.mean(expected**2))
    assert rel < 1e-3  # measured 1.7e-4 (64x32 map, lmax 24)


def test_ggx_basis_recombines_to_the_ggx_render():
    from brdfrig.fit.columns import render_ggx_basis

    dirs, omega = _hemisphere_rule(np.array([0.0, 0.0, 1.0]), n_mu=12, n_phi=24)
    rad = 1.0 + np.abs(dirs) @ np.array([[1.0, 0.2], [0.5, 2.0], [0.1, 0.3]])
    env = Environment(dirs, rad, omega)
    normals = _normals(40, seed=4)
    basis = render_ggx_basis(0.2, normals, env)
    model = GGX(0.2, [0.04, 0.9], [0.5, 0.1], f90=[1.0, 0.7])
    combined = np.einsum("ncb,cb->nc", basis, np.stack([model.f0, model.f90], axis=1))
    combined += render_groundtruth(Lambertian(model.diffuse), normals, env)
    np.testing.assert_allclose(combined, render_groundtruth(model, normals, env), rtol=1e-12)
