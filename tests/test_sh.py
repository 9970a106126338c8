"""Real SH evaluation (brdfrig.fit.sh): orthonormality, peer agreement, high degree, bad input."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import sph_harm_y

from brdfrig.fit.sh import SPHERICART_MAX_LMAX, num_coeffs, sh_degree, sh_eval, sh_index


def random_dirs(n: int, seed: int = 0) -> np.ndarray:
    d = np.random.default_rng(seed).normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def gauss_legendre_grid(lmax: int) -> tuple[np.ndarray, np.ndarray]:
    """Directions and weights exact for products of two band-<=lmax SH (degree 2 lmax)."""
    x, wx = np.polynomial.legendre.leggauss(lmax + 1)
    nphi = 2 * lmax + 2
    phi = 2 * np.pi * np.arange(nphi) / nphi
    st = np.sqrt(1 - x * x)
    d = np.stack(
        [st[:, None] * np.cos(phi), st[:, None] * np.sin(phi), np.broadcast_to(x[:, None], (x.size, nphi))], -1
    )
    return d.reshape(-1, 3), np.repeat(wx, nphi) * (2 * np.pi / nphi)


def real_from_complex(l: int, m: int, dirs: np.ndarray) -> np.ndarray:
    """Y_lm of brdfrig.fit.sh from scipy's complex SH (Condon-Shortley phase included there).

    Y_l0 = Y_l^0;  Y_lm = sqrt(2) (-1)^m Re Y_l^m;  Y_l,-m = sqrt(2) (-1)^m Im Y_l^m  (m > 0).
    """
    theta = np.arccos(np.clip(dirs[:, 2], -1, 1))
    phi = np.arctan2(dirs[:, 1], dirs[:, 0])
    c = sph_harm_y(l, abs(m), theta, phi)
    if m == 0:
        return c.real
    return np.sqrt(2) * (-1) ** abs(m) * (c.real if m > 0 else c.imag)


def test_index_helpers():
    assert num_coeffs(0) == 1 and num_coeffs(7) == 64
    assert sh_index(0, 0) == 0 and sh_index(1, -1) == 1 and sh_index(2, 2) == 8
    assert sh_degree(49) == 6
    with pytest.raises(ValueError, match="coeffs"):
        sh_degree(50)


def test_orthonormal_by_gauss_legendre_quadrature_to_l60():
    lmax = 60
    d, w = gauss_legendre_grid(lmax)
    y = sh_eval(d, lmax)
    gram = (y * w[:, None]).T @ y
    assert np.abs(gram - np.eye(num_coeffs(lmax))).max() <= 1e-12


@pytest.mark.parametrize("lmax", [0, 1, 5, 30])
def test_matches_scipy_with_explicit_real_map(lmax):
    d = np.concatenate([random_dirs(200), [[0, 0, 1.0], [0, 0, -1.0], [1.0, 0, 0]]])
    y = sh_eval(d, lmax)
    err = max(
        np.abs(y[:, sh_index(l, m)] - real_from_complex(l, m, d)).max()
        for l in range(lmax + 1)
        for m in range(-l, l + 1)
    )
    assert err <= 1e-12


def test_matches_pyshtools_orthonormal_real_without_condon_shortley():
    pyshtools = pytest.importorskip("pyshtools")
    lmax = 30
    d = random_dirs(20, seed=1)
    theta, phi = np.arccos(d[:, 2]), np.arctan2(d[:, 1], d[:, 0])
    y = sh_eval(d, lmax)
    err = 0.0
    for k in range(d.shape[0]):
        # [0, l, m]: cos(m phi) terms -> our (l, m); [1, l, m]: sin(m phi) terms -> our (l, -m)
        ref = pyshtools.expand.spharm(lmax, theta[k], phi[k], kind="real", degrees=False, normalization="ortho", csphase=1)
        for l in range(lmax + 1):
            m = np.arange(l + 1)
            err = max(err, np.abs(y[k, sh_index(l, m)] - ref[0, l, : l + 1]).max())
            if l:
                err = max(err, np.abs(y[k, sh_index(l, -m[1:])] - ref[1, l, 1 : l + 1]).max())
    assert err <= 1e-12


def test_phase_convention_low_order_closed_forms():
    d = random_dirs(50)
    x, y, z = d.T
    c1 = np.sqrt(3 / (4 * np.pi))
    out = sh_eval(d, 2)
    np.testing.assert_allclose(out[:, 0], 0.5 / np.sqrt(np.pi), atol=1e-15)
    np.testing.assert_allclose(out[:, 1:4], c1 * np.stack([y, z, x], -1), atol=1e-14)  # m = -1, 0, 1: +y, z, +x
    np.testing.assert_allclose(out[:, 4], 0.5 * np.sqrt(15 / np.pi) * x * y, atol=1e-14)
    np.testing.assert_allclose(out[:, 8], 0.25 * np.sqrt(15 / np.pi) * (x * x - y * y), atol=1e-14)


def test_high_degree_path_matches_scipy_where_sphericart_fails():
    # equatorial directions at the highest orders: where sphericart 2.0.4 returns zeros from l = 87 on
    phi = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    zs = np.array([-0.013, 0.0, 0.4])
    d = np.stack([np.sqrt(1 - zs[:, None] ** 2) * np.cos(phi), np.sqrt(1 - zs[:, None] ** 2) * np.sin(phi),
                  np.broadcast_to(zs[:, None], (3, 40))], -1).reshape(-1, 3)
    d = np.concatenate([d, random_dirs(60, seed=3)])
    lmax = 120
    y = sh_eval(d, lmax)
    for l in (81, 87, 100, 120):
        for m in (0, 1, -7, l // 2, -(l - 1), l):
            assert np.abs(y[:, sh_index(l, m)] - real_from_complex(l, m, d)).max() <= 1e-11, (l, m)


def test_both_evaluation_paths_agree_at_the_switch():
    d = random_dirs(300, seed=5)
    low = sh_eval(d, SPHERICART_MAX_LMAX)
    high = sh_eval(d, SPHERICART_MAX_LMAX + 1)[:, : low.shape[1]]
    assert np.abs(low - high).max() <= 1e-12


def test_shapes_and_empty_input():
    d = random_dirs(12).reshape(3, 4, 3)
    assert sh_eval(d, 3).shape == (3, 4, 16)
    assert sh_eval(np.zeros((0, 3)), 2).shape == (0, 9)


@pytest.mark.parametrize("lmax", [-1, 201, 2.5, True, "3"])
def test_bad_lmax(lmax):
    with pytest.raises(ValueError, match="lmax"):
        sh_eval(random_dirs(3), lmax)


@pytest.mark.parametrize(
    "dirs",
    [np.array([[1.0, 1.0, 0.0]]), np.array([[np.nan, 0, 1.0]]), np.zeros((4, 2)), np.array([[0, 0, 1.001]])],
)
def test_bad_dirs(dirs):
    with pytest.raises(ValueError, match="dirs"):
        sh_eval(dirs, 2)
