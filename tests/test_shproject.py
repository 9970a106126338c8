"""SH projection and reconstruction (brdfrig.fit.shproject) on synthetic and real lat-long maps."""

from __future__ import annotations

import numpy as np
import pytest

from brdfrig.fit.scene import Environment
from brdfrig.fit.sh import sh_eval, sh_index
from brdfrig.fit.shproject import (
    _fejer_weights,
    project,
    project_environment,
    project_latlong,
    reconstruct,
    reconstruct_latlong,
    sh_window,
)
from brdfrig.hdr.envmap import latlong_directions

H, W = 256, 512
BASIS = [(0, 0), (1, -1), (2, 1), (5, -3), (8, 8), (12, 0), (20, -17)]
LMAX = 20


@pytest.fixture(scope="module")
def grid():
    d, sa = latlong_directions(H, W)
    return d, sa, sh_eval(d, LMAX)


@pytest.mark.parametrize("lm", BASIS)
def test_single_basis_function_round_trip_512x256(grid, lm):
    d, sa, y = grid
    k = sh_index(*lm)
    img = y[..., k]
    expect = np.zeros((LMAX + 1) ** 2)
    expect[k] = 1.0
    # general path, weights = exact pixel solid angles (a midpoint-type rule)
    dense = project(d.reshape(-1, 3), img.ravel(), sa.ravel(), LMAX)
    assert abs(dense[k] - 1) <= 1e-3 and np.abs(np.delete(dense, k)).max() <= 1e-3
    # separable lat-long path: exact for band-limited maps
    sep = project_latlong(img, LMAX)
    assert np.abs(sep - expect).max() <= 1e-12


def test_latlong_paths_use_the_hdr_envmap_convention(grid):
    d, _, _ = grid
    c = np.random.default_rng(0).normal(size=(64, 3))
    np.testing.assert_allclose(reconstruct_latlong(c, H, W), reconstruct(c, d.reshape(-1, 3)).reshape(H, W, 3), atol=1e-12)
    np.testing.assert_allclose(reconstruct_latlong(c[:, 0], 12, 20), reconstruct(c[:, 0], latlong_directions(12, 20)[0].reshape(-1, 3)).reshape(12, 20), atol=1e-12)


def test_fejer_rule_exactness():
    n = 17
    x = np.cos((np.arange(n) + 0.5) * np.pi / n)
    w = _fejer_weights(n)
    for k in range(n):  # integral_{-1}^{1} x^k dx
        assert abs(w @ x**k - (2 / (k + 1) if k % 2 == 0 else 0.0)) <= 1e-14


def test_project_ignores_unseen_samples_and_keeps_vector_shape():
    d, sa = latlong_directions(64, 128)
    d, sa = d.reshape(-1, 3), sa.ravel()
    rad = np.ones(d.shape[0])
    half = sa * (d[:, 1] > 0)
    rad_nan = np.where(half > 0, rad, np.nan)
    c = project(d, rad_nan, half, 2)
    assert c.shape == (9,)
    # hemisphere indicator: c00 = 2 pi Y00, c10 = pi sqrt(3/(4 pi)) (about +y: index of (1,-1))
    assert abs(c[0] - 2 * np.pi * 0.5 / np.sqrt(np.pi)) <= 1e-3
    assert abs(c[sh_index(1, -1)] - np.pi * np.sqrt(3 / (4 * np.pi))) <= 1e-3
    env = Environment(d, np.stack([rad, 2 * rad], -1), sa)
    ce = project_environment(env, 1)
    assert ce.shape == (4, 2)
    np.testing.assert_allclose(ce[0], [np.sqrt(4 * np.pi), 2 * np.sqrt(4 * np.pi)], rtol=1e-12)


def test_windows():
    for kind in (None, "none", "hann", "lanczos"):
        f = sh_window(10, kind)
        assert f.shape == (11,) and f[0] == 1.0 and np.all(np.diff(f) <= 0) and f[-1] > 0
    assert np.all(sh_window(10) == 1)
    np.testing.assert_allclose(sh_window(3, "hann"), [1, (1 + np.cos(np.pi / 4)) / 2, 0.5, (1 + np.cos(3 * np.pi / 4)) / 2])


def test_window_reduces_ringing_of_a_disc_light():
    h, w, lmax = 128, 256, 15
    d, _ = latlong_directions(h, w)
    img = (d[..., 2] > np.cos(np.radians(25))).astype(float)  # a bright disc around +z, zero elsewhere
    undershoot = {}
    for kind in ("none", "lanczos", "hann"):
        rec = reconstruct_latlong(project_latlong(img, lmax, window=kind), h, w)
        undershoot[kind] = -rec.min()
    assert undershoot["none"] > 0.05  # Gibbs ringing goes well below zero
    assert undershoot["hann"] < 0.3 * undershoot["none"]
    assert undershoot["lanczos"] < undershoot["none"]


def test_real_probes_project_and_round_trip(real_probes):
    from brdfrig.hdr.exr import read_image

    for path in real_probes:
        img = read_image(path).astype(np.float64)
        h, w, _ = img.shape
        d, sa = latlong_directions(h, w)
        errors = []
        for lmax in (4, 12, 30):
            c = project_latlong(img, lmax)
            rec = reconstruct_latlong(c, h, w)
            assert np.all(np.isfinite(rec))
            # the reconstruction is band-limited: projecting it again returns the same coefficients
            assert np.abs(project_latlong(rec, lmax) - c).max() <= 1e-10 * np.abs(c).max()
            errors.append(np.sqrt((sa[..., None] * (rec - img) ** 2).sum() / (sa[..., None] * img**2).sum()))
        assert errors[0] > errors[1] > errors[2], (path.name, errors)
        # DC term against the plain solid-angle sum (two different quadratures of the same map)
        c = project_latlong(img, 2)
        np.testing.assert_allclose(c[0], (sa[..., None] * img).sum((0, 1)) / np.sqrt(4 * np.pi), rtol=2e-3)
        # the general path on the same samples agrees up to its quadrature error
        dense = project(d.reshape(-1, 3), img.reshape(-1, 3), sa.ravel(), 8)
        assert np.abs(dense - project_latlong(img, 8)).max() <= 5e-3 * np.abs(dense).max()


def test_bad_input_names_the_argument():
    d, sa = latlong_directions(8, 16)
    d, sa = d.reshape(-1, 3), sa.ravel()
    bad = np.ones((d.shape[0], 3))
    bad[5, 1] = np.inf
    with pytest.raises(ValueError, match="radiance"):
        project(d, bad, sa, 2)
    with pytest.raises(ValueError, match="dirs"):
        project(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), 2)
    with pytest.raises(ValueError, match="dirs"):
        project(2 * d, bad, sa, 2)
    with pytest.raises(ValueError, match="solid_angle"):
        project(d, np.ones((d.shape[0], 3)), -sa, 2)
    with pytest.raises(ValueError, match="lmax"):
        project(d, np.ones((d.shape[0], 3)), sa, -1)
    with pytest.raises(ValueError, match="lmax"):
        project_latlong(np.ones((8, 16, 3)), 201)
    with pytest.raises(ValueError, match="image"):
        project_latlong(np.ones((0, 16, 3)), 2)
    img = np.ones((8, 16, 3))
    img[2, 3, 0] = np.nan
    with pytest.raises(ValueError, match="image"):
        project_latlong(img, 2)
    with pytest.raises(ValueError, match="lmax"):
        project_latlong(np.ones((8, 16, 3)), 8)  # 16 columns resolve bands up to 7
    with pytest.raises(ValueError, match="window"):
        project_latlong(np.ones((8, 16, 3)), 2, window="gauss")
    with pytest.raises(ValueError, match="coeffs"):
        reconstruct(np.ones((5, 3)), d)
    with pytest.raises(ValueError, match="width"):
        reconstruct_latlong(np.ones((4, 3)), 8, 0)
