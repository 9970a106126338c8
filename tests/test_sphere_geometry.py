"""Sphere pixels (brdfrig.hdr.sphere): selection, normals, limb and partial-pixel weights."""

from __future__ import annotations

import numpy as np
import pytest

from brdfrig.hdr.sphere import DEFAULT_LIMB_MARGIN_PX, sphere_pixels


def corners_inside(rows, cols, cx, cy, r):
    """Brute force: all four corners of each pixel square inside the circle."""
    out = np.ones(rows.shape, bool)
    for a in (0, 1):
        for b in (0, 1):
            out &= (cols + a - cx) ** 2 + (rows + b - cy) ** 2 <= r * r
    return out


def test_normals_follow_the_image_convention():
    px = sphere_pixels((10, 10), (5.0, 5.0, 5.0))
    k = np.nonzero((px.rows == 4) & (px.cols == 5))[0][0]  # centre (5.5, 4.5): offset (+0.1, +0.1)
    np.testing.assert_allclose(px.normals[k], [0.1, 0.1, np.sqrt(0.98)], atol=1e-15)
    assert np.abs(np.linalg.norm(px.normals, axis=1) - 1).max() <= 1e-15
    assert px.normals[:, 2].min() > 0


def test_selection_and_weights_against_brute_force():
    shape, (cx, cy, r) = (60, 70), (33.3, 29.8, 21.7)
    px = sphere_pixels(shape, (cx, cy, r), margin_px=0.0)
    rows, cols = np.mgrid[0:60, 0:70]
    centre_in = (cols + 0.5 - cx) ** 2 + (rows + 0.5 - cy) ** 2 < r * r
    assert px.rows.size == centre_in.sum()
    assert np.all(centre_in[px.rows, px.cols])
    np.testing.assert_array_equal(px.weights, corners_inside(px.rows, px.cols, cx, cy, r).astype(float))
    assert 0 < (px.weights == 0).sum() < px.rows.size  # the rim ring is out, the rest in


def test_limb_margin():
    cx, cy, r = 40.0, 40.0, 30.0
    px = sphere_pixels((80, 80), (cx, cy, r))
    dist = r - np.hypot(px.cols + 0.5 - cx, px.rows + 0.5 - cy)
    assert DEFAULT_LIMB_MARGIN_PX > 0
    assert np.all(px.weights[dist < DEFAULT_LIMB_MARGIN_PX] == 0)
    assert np.all(px.weights[dist >= DEFAULT_LIMB_MARGIN_PX + 1] == 1)
    wide = sphere_pixels((80, 80), (cx, cy, r), margin_px=10)
    assert wide.weights.sum() < px.weights.sum()
    np.testing.assert_array_equal(wide.weights[dist >= 10.0], 1.0)


def test_circle_partly_outside_the_image():
    px = sphere_pixels((20, 30), (2.0, 10.0, 8.0), margin_px=0)
    assert px.cols.min() >= 0 and px.rows.min() >= 0 and px.rows.max() < 20
    assert px.rows.size < np.pi * 64 * 0.75


@pytest.mark.parametrize(
    "args, name",
    [(((0, 5), (1, 1, 1)), "shape"), (((5, 5), (1, 1, -1)), "circle"), (((5, 5), (1, np.nan, 1)), "circle"),
     (((5, 5), (1, 1, 1), -1.0), "margin_px")],
)
def test_bad_input(args, name):
    with pytest.raises(ValueError, match=name):
        sphere_pixels(*args)
