"""Sub-pixel sphere detection on synthetic, area-antialiased images with known circles."""

from __future__ import annotations

import numpy as np
import pytest

from hdr.detect import SphereNotFoundError, detect_sphere

BACKGROUND = {"dark": 0.01, "bright": 5.0, "stand": 0.05, "highlight": 0.02}


def render(h, w, circle, case, ss=8):
    """A shaded sphere over a textured background; pixels crossed by the rim averaged over ss x ss sub-samples.

    Cases: ``dark`` / ``bright`` background, ``stand`` (a bright post under the ball, touching it),
    ``highlight`` (a third of the ball clipped at the sensor's full scale).
    """
    cx, cy, r = circle

    def shade(px, py):
        dx, dy = (px - cx) / r, (cy - py) / r
        inside = dx * dx + dy * dy < 1
        nz = np.sqrt(np.clip(1 - dx * dx - dy * dy, 0, 1))
        ball = 0.2 + 0.8 * np.clip(0.3 * dx + 0.5 * dy + 0.8 * nz, 0, None)
        if case == "highlight":
            ball = np.minimum(ball * 3, 1.0)
        bg = BACKGROUND[case] * (1 + 0.2 * np.sin(px / 37.0) * np.cos(py / 23.0))
        if case == "stand":
            bg = np.where((np.abs(px - cx) < 0.25 * r) & (py > cy), 0.6, bg)
        return np.where(inside, ball, bg)

    y, x = np.mgrid[0:h, 0:w] + 0.5
    img = shade(x, y)
    edge = np.abs(np.hypot(x - cx, y - cy) - r) < 1.5
    ey, ex = y[edge], x[edge]
    off = (np.arange(ss) + 0.5) / ss - 0.5
    img[edge] = np.mean([shade(ex + ox, ey + oy) for oy in off for ox in off], axis=0)
    return img.astype(np.float32)


@pytest.mark.parametrize("radius", [40, 100, 300, 1000])
@pytest.mark.parametrize("case", ["dark", "bright", "stand", "highlight"])
def test_circle_within_quarter_pixel(radius, case):
    rng = np.random.default_rng(radius)
    size = int(2.4 * radius) + 20
    circle = (size / 2 + rng.uniform(-5, 5), size / 2 + rng.uniform(-5, 5), radius + rng.uniform(-0.5, 0.5))
    img = render(size, size, circle, case)
    if case == "bright":
        img = np.repeat(img[:, :, None], 3, axis=2) * np.array([1.0, 0.9, 0.8], np.float32)  # colour input
    found = detect_sphere(img)
    err = np.abs(np.subtract(found, circle))
    assert err.max() <= 0.25, (found, circle)


@pytest.mark.parametrize("case", ["dark", "stand"])
def test_noisy_image_within_quarter_pixel(case):
    """Merged HDR images are noisy: 3% multiplicative noise on every pixel."""
    circle = (161.7, 150.2, 120.4)
    img = render(300, 320, circle, case)
    img *= 1 + 0.03 * np.random.default_rng(1).standard_normal(img.shape).astype(np.float32)
    assert np.abs(np.subtract(detect_sphere(img), circle)).max() <= 0.25


def test_off_centre_ball_in_a_wide_frame():
    circle = (412.3, 140.8, 90.0)
    img = render(300, 640, circle, "dark")
    assert np.abs(np.subtract(detect_sphere(img), circle)).max() <= 0.25


def test_no_sphere_is_a_clear_error():
    rng = np.random.default_rng(0)
    y, x = np.mgrid[0:200, 0:300]
    smooth = 1 + 0.5 * np.sin(x / 40.0) + 0.1 * rng.random((200, 300))
    with pytest.raises(SphereNotFoundError, match="no sphere"):
        detect_sphere(smooth)
    with pytest.raises(ValueError, match="no sphere"):
        detect_sphere(np.zeros((100, 100)))


def test_non_finite_pixels_are_rejected():
    img = render(120, 120, (60, 60, 40), "dark")
    img[3, 4] = np.nan
    with pytest.raises(ValueError, match="NaN/inf"):
        detect_sphere(img)
