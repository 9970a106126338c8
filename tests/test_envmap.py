"""Environment-image geometry (brdfrig.hdr.envmap): directions, solid angles, inverse maps, sampling."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad

from brdfrig.hdr.envmap import (
    angular_directions,
    latlong_directions,
    latlong_pixels,
    mirrorball_directions,
    mirrorball_pixels,
    sample_latlong,
)

FOUR_PI = 4 * np.pi


def random_dirs(n: int, seed: int = 0) -> np.ndarray:
    d = np.random.default_rng(seed).normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


# ----------------------------------------------------------------------------- lat-long


@pytest.mark.parametrize("hw", [(1, 1), (2, 3), (128, 256), (256, 512), (101, 37)])
def test_latlong_solid_angles_sum_to_4pi(hw):
    _, sa = latlong_directions(*hw)
    assert abs(sa.sum() - FOUR_PI) <= 1e-6 * FOUR_PI
    assert sa.shape == hw and sa.min() > 0


def test_latlong_convention_openexr():
    h, w = 4, 8
    d, _ = latlong_directions(h, w)
    # MATH.md: u=(col+.5)/W, t=(row+.5)/H, lam=-2 pi (u-.5), phi=-pi (t-.5)
    i, j = 1, 6
    lam, phi = -2 * np.pi * ((j + 0.5) / w - 0.5), -np.pi * ((i + 0.5) / h - 0.5)
    np.testing.assert_allclose(d[i, j], [np.sin(lam) * np.cos(phi), np.sin(phi), np.cos(lam) * np.cos(phi)], atol=1e-15)
    big, _ = latlong_directions(64, 128)
    assert big[31:33, 63:65, 2].min() > 0.99  # image centre looks at +z
    assert big[0, :, 1].min() > 0.99  # top row is +y
    assert big[32, 96, 0] < -0.99 and big[32, 32, 0] > 0.99  # columns right of centre: -x (lam < 0)
    assert np.abs(np.linalg.norm(big, axis=-1) - 1).max() <= 1e-15


def test_latlong_solid_angle_is_the_pixel_integral():
    h, w = 9, 5
    _, sa = latlong_directions(h, w)
    for i in range(h):
        top, bottom = np.pi / 2 - i * np.pi / h, np.pi / 2 - (i + 1) * np.pi / h
        exact = (2 * np.pi / w) * quad(np.cos, bottom, top)[0]
        assert abs(sa[i, 0] - exact) <= 1e-14


def test_latlong_pixels_inverts_directions():
    h, w = 32, 64
    d, _ = latlong_directions(h, w)
    x, y = latlong_pixels(d, h, w)
    assert np.abs(x - (np.arange(w) + 0.5)[None, :]).max() <= 1e-10
    assert np.abs(y - (np.arange(h) + 0.5)[:, None]).max() <= 1e-10
    xs, ys = latlong_pixels(random_dirs(500), h, w)
    assert xs.min() >= 0 and xs.max() < w and ys.min() >= 0 and ys.max() <= h


def test_sample_latlong_bilinear_with_wrap():
    rng = np.random.default_rng(1)
    h, w = 16, 32
    img = rng.normal(size=(h, w, 2))
    d, _ = latlong_directions(h, w)
    np.testing.assert_allclose(sample_latlong(img, d), img, atol=1e-13)
    # across the seam: x = 0.2 lies between column W-1 (centre -0.5 after wrap) and column 0 (0.5)
    i = 5
    t = (i + 0.5) / h
    for x, expect in ((0.2, 0.3 * img[i, -1] + 0.7 * img[i, 0]), (w - 0.1, 0.6 * img[i, -1] + 0.4 * img[i, 0])):
        lam, phi = -2 * np.pi * (x / w - 0.5), -np.pi * (t - 0.5)
        dirs = np.array([np.sin(lam) * np.cos(phi), np.sin(phi), np.cos(lam) * np.cos(phi)])
        np.testing.assert_allclose(sample_latlong(img, dirs), expect, atol=1e-12)
    # between rows, and clamped above the first row's centre
    x = 10.5
    for y, expect in ((3.25, 0.75 * img[3, 10] + 0.25 * img[2, 10]), (0.2, img[0, 10])):
        lam, phi = -2 * np.pi * (x / w - 0.5), -np.pi * (y / h - 0.5)
        dirs = np.array([np.sin(lam) * np.cos(phi), np.sin(phi), np.cos(lam) * np.cos(phi)])
        np.testing.assert_allclose(sample_latlong(img, dirs), expect, atol=1e-12)
    assert sample_latlong(img[..., 0], d[:2, :3]).shape == (2, 3, 1)


# ----------------------------------------------------------------------------- mirror ball


@pytest.mark.parametrize("circle", [(60.3, 50.7, 40.2), (100.0, 100.0, 99.5), (8.0, 9.0, 5.0)])
def test_mirrorball_solid_angles_sum_to_4pi(circle):
    _, sa, inside = mirrorball_directions((210, 210), circle)
    assert abs(sa.sum() - FOUR_PI) <= 1e-6 * FOUR_PI
    assert np.array_equal(inside, sa > 0)


def test_mirrorball_solid_angle_matches_supersampled_coverage():
    cx, cy, r = 20.3, 18.6, 12.7
    _, sa, _ = mirrorball_directions((40, 40), (cx, cy, r))
    n = 200  # brute force: fraction of n x n sub-pixel centres inside the disc
    off = (np.arange(n) + 0.5) / n
    for i, j in [(18, 20), (6, 20), (18, 8), (9, 11), (30, 29), (5, 20)]:
        xs, ys = j + off[None, :], i + off[:, None]
        frac = np.mean((xs - cx) ** 2 + (ys - cy) ** 2 < r * r)
        assert abs(sa[i, j] - 4 / r**2 * frac) <= 4 / r**2 * 2e-3


def test_mirrorball_reflection_and_constant_jacobian():
    cx, cy, r = 50.0, 40.0, 30.0
    d, sa, inside = mirrorball_directions((80, 100), (cx, cy, r))
    e, nz = 0.5 / 30, np.sqrt(1 - 2 * (0.5 / 30) ** 2)  # pixel (39, 49): offset (-e, +e), w = 2 nz n - v
    np.testing.assert_allclose(d[39, 49], [-2 * nz * e, 2 * nz * e, 2 * nz * nz - 1], atol=1e-12)
    # independent check of the 4/r^2 sr per pixel: numerical Jacobian |dw/dx x dw/dy| of the reflection map
    rng = np.random.default_rng(2)

    def w_of(x, y):
        dx, dy = (x - cx) / r, (cy - y) / r
        nz = np.sqrt(1 - dx * dx - dy * dy)
        n = np.stack([dx, dy, nz], -1)
        return 2 * nz[..., None] * n - np.array([0, 0, 1.0])

    rho = 0.95 * np.sqrt(rng.uniform(size=50))
    ang = rng.uniform(0, 2 * np.pi, 50)
    x, y = cx + r * rho * np.cos(ang), cy - r * rho * np.sin(ang)
    e = 1e-5
    jac = np.linalg.norm(np.cross((w_of(x + e, y) - w_of(x - e, y)) / (2 * e), (w_of(x, y + e) - w_of(x, y - e)) / (2 * e)), axis=-1)
    np.testing.assert_allclose(jac, 4 / r**2, rtol=1e-6)
    np.testing.assert_allclose(sa[40, 30:70], 4 / r**2, rtol=1e-12)  # fully covered pixels
    assert not inside[40, 85] and sa[40, 85] == 0


def test_mirrorball_pixels_inverts_directions():
    circle = (50.2, 40.7, 30.3)
    d, _, inside = mirrorball_directions((80, 100), circle)
    x, y = mirrorball_pixels(d, circle)
    rows, cols = np.nonzero(inside)
    centre_in = np.hypot(cols + 0.5 - circle[0], rows + 0.5 - circle[1]) < circle[2] - 0.5
    assert np.abs(x[rows, cols][centre_in] - (cols[centre_in] + 0.5)).max() <= 1e-8
    assert np.abs(y[rows, cols][centre_in] - (rows[centre_in] + 0.5)).max() <= 1e-8
    # +z (towards the camera) is seen at the centre; -z on the rim, never NaN
    bx, by = mirrorball_pixels(np.array([[0, 0, 1.0], [0, 0, -1.0]]), circle)
    np.testing.assert_allclose([bx[0], by[0]], circle[:2], atol=1e-12)
    assert abs(np.hypot(bx[1] - circle[0], by[1] - circle[1]) - circle[2]) <= 1e-9


# ----------------------------------------------------------------------------- angular map


@pytest.mark.parametrize("size", [64, 255, 256])
def test_angular_solid_angles_sum_to_4pi(size):
    d, sa, inside = angular_directions(size)
    assert abs(sa.sum() - FOUR_PI) <= 1e-6 * FOUR_PI
    assert np.abs(np.linalg.norm(d, axis=-1) - 1).max() <= 1e-14
    assert np.array_equal(inside, sa > 0)


def test_angular_geometry():
    size = 128
    d, sa, _ = angular_directions(size)
    assert d[63:65, 63:65, 2].min() > 0.999  # centre looks at +z
    assert d[64, 126, 2] < -0.9 and d[64, 126, 0] > 0  # right rim: behind, tilted to +x
    assert d[1, 64, 2] < -0.9 and d[1, 64, 1] > 0  # top rim: behind, tilted to +y
    # interior pixel: (pi/R)^2 sin(theta)/theta at the centre (the density is smooth there)
    i, j = 40, 70
    rho = np.hypot(j + 0.5 - 64, 64 - i - 0.5) / 64
    assert abs(sa[i, j] - (np.pi / 64) ** 2 * np.sin(np.pi * rho) / (np.pi * rho)) <= 1e-4 * sa[i, j]


# ----------------------------------------------------------------------------- bad input


def test_bad_input_names_the_argument():
    with pytest.raises(ValueError, match="height"):
        latlong_directions(0, 4)
    with pytest.raises(ValueError, match="width"):
        latlong_directions(4, 0)
    with pytest.raises(ValueError, match="dirs"):
        latlong_pixels([[1.0, 1.0, 1.0]], 4, 8)
    with pytest.raises(ValueError, match="image"):
        sample_latlong(np.zeros((0, 4, 3)), [[0, 0, 1.0]])
    with pytest.raises(ValueError, match="circle"):
        mirrorball_directions((10, 10), (5, 5, 0))
    with pytest.raises(ValueError, match="shape"):
        mirrorball_directions((0, 10), (5, 5, 3))
    with pytest.raises(ValueError, match="dirs"):
        mirrorball_pixels([[np.nan, 0, 1.0]], (5, 5, 3))
    with pytest.raises(ValueError, match="size"):
        angular_directions(0)
