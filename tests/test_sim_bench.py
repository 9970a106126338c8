"""Simulated bench: lighting, probe, samples and turntable semantics against independent oracles."""

from __future__ import annotations

import math

import numpy as np
import pytest

from brdfrig.fit.groundtruth import render_groundtruth
from brdfrig.fit.rotation import axis_rotation
from brdfrig.sim.bench import BACKDROP, SimBench, procedural_environment


@pytest.fixture(scope="module")
def bench():
    return SimBench(scale=0.5, carries="rig", env_height=32, probe_env_height=128)


def probe_offsets(bench, shrink=0.9):
    cx, cy, r = bench.probe_circle
    h, w = bench.frame_shape
    rows, cols = np.mgrid[0:h, 0:w]
    dx, dy = (cols + 0.5 - cx) / r, (cy - rows - 0.5) / r
    inside = dx**2 + dy**2 < shrink**2
    n = np.stack([dx, dy, np.sqrt(np.clip(1 - dx**2 - dy**2, 0, None))], -1)
    return rows[inside], cols[inside], n[inside]


def test_geometry_and_environment(bench):
    assert bench.frame_shape == (120, 320)
    assert bench.probe_circle == (57.5, 60.0, 45.0)
    env = bench.environment(0.0)
    assert env.solid_angle.sum() == pytest.approx(4 * math.pi, rel=1e-9)
    assert np.all(env.radiance > 0)
    # the sun is the brightest direction and dominates the energy; the floor is dimmer than the sky
    sun = env.dirs[np.argmax(env.radiance[:, 1])]
    assert sun[1] > 0.4
    up, down = env.dirs[:, 1] > 0.3, env.dirs[:, 1] < -0.3
    assert np.median(env.radiance[up, 2]) > 2 * np.median(env.radiance[down, 2])


def test_probe_reflects_the_environment_with_albedo_and_blemishes(bench):
    rows, cols, n = probe_offsets(bench)
    img = bench.radiance(0.0)
    v = np.array([0.0, 0.0, 1.0])
    r = 2 * (n @ v)[:, None] * n - v
    oracle = bench.probe_albedo * procedural_environment(r)  # the function itself, no map lookup
    factor = bench.blemish_factor(n)
    clean = factor > 0.999
    ratio = img[rows, cols][clean] / oracle[clean]
    assert np.median(ratio) == pytest.approx(1.0, abs=0.01)
    assert np.percentile(np.abs(ratio - 1), 75) < 0.03  # bilinear lookup in a 256 x 128 map
    assert (~clean).sum() > 20  # blemishes are visible ...
    dark = img[rows, cols][factor < 0.5] / oracle[factor < 0.5]
    assert np.median(dark) < 0.6  # ... and dark
    assert np.all(img[0, :] == np.float32(BACKDROP))


def test_rig_rotation_turns_the_room_about_plus_y(bench):
    """Oracle by hand: Ry(90 deg) takes +z to +x, so at 90 deg the ball's centre mirrors the room's +x."""
    cx, cy, r = bench.probe_circle
    i, j = int(cy), int(cx)
    n = np.array([[(j + 0.5 - cx) / r, (cy - i - 0.5) / r, 0.0]])
    n[0, 2] = math.sqrt(1 - n[0, 0] ** 2 - n[0, 1] ** 2)
    refl = 2 * n[0, 2] * n[0] - np.array([0, 0, 1.0])
    expected = bench.probe_albedo * procedural_environment(axis_rotation("y", 90.0) @ refl) * bench.blemish_factor(n)[0]
    assert np.allclose(axis_rotation("y", 90.0) @ [0, 0, 1.0], [1, 0, 0])
    np.testing.assert_allclose(bench.radiance(90.0)[i, j], expected, rtol=0.02)
    # with the rig turning, the blemishes ride with the camera: the probe/env ratio is the same at every angle
    rows, cols, nn = probe_offsets(bench)
    v = np.array([0.0, 0.0, 1.0])
    rr = 2 * (nn @ v)[:, None] * nn - v
    for angle in (0.0, 90.0):
        ratio = bench.radiance(angle)[rows, cols, 1] / procedural_environment(rr @ axis_rotation("y", angle).T)[:, 1]
        assert np.median(np.abs(ratio / (bench.probe_albedo * bench.blemish_factor(nn)) - 1)) < 0.01


def test_samples_carried_table_moves_blemishes_only():
    b = SimBench(scale=0.5, carries="samples", env_height=16)
    a, c = b.radiance(0.0), b.radiance(40.0)
    for cx, cy, r in b.sample_circles.values():  # isotropic spheres, fixed room: identical images
        sl = np.s_[int(cy - r / 2):int(cy + r / 2), int(cx - r / 2):int(cx + r / 2)]
        np.testing.assert_array_equal(a[sl], c[sl])
    rows, cols, n = probe_offsets(b)
    moved = np.abs(a[rows, cols, 1] / c[rows, cols, 1] - 1) > 0.05
    expected = np.abs(b.blemish_factor(n) / b.blemish_factor(n @ axis_rotation("y", 40.0)) - 1) > 0.05
    assert moved.sum() > 20
    assert np.mean(moved == expected) > 0.98


def test_sample_rendering_matches_brute_force_quadrature(bench):
    """Node-grid rendering + cubic interpolation vs C2's quadrature at every pixel, and a numpy Lambertian oracle."""
    env = bench.environment(30.0)
    img = bench.radiance(30.0)
    for name, (cx, cy, r) in bench.sample_circles.items():
        px = bench._sample_pixels[name]
        n = np.asarray(px.normals)
        keep = np.hypot(n[:, 0], n[:, 1]) < 0.95
        sel = np.flatnonzero(keep)[::7]
        exact = render_groundtruth(bench.true_brdf(name), n[sel], env)
        got = img[px.rows[sel], px.cols[sel]]
        rel = np.sqrt(np.mean((got - exact) ** 2) / np.mean(exact**2))
        print(f"{name}: interpolation rel rms {rel:.5f}")
        assert rel < 0.005
    # independent oracle for the matte sphere: B = albedo/pi * sum L max(n.w, 0) dOmega (plain numpy)
    px = bench._sample_pixels["matte"]
    sel = np.flatnonzero(np.hypot(px.normals[:, 0], px.normals[:, 1]) < 0.95)[::50]
    n = np.asarray(px.normals)[sel]
    irr = (np.clip(n @ env.dirs.T, 0, None) * env.solid_angle) @ env.radiance
    oracle = bench.true_brdf("matte").albedo / math.pi * irr
    np.testing.assert_allclose(img[px.rows[sel], px.cols[sel]], oracle, rtol=0.01)


def test_heldout_lighting_differs_and_truth_is_exposed(bench):
    held = bench.heldout_environment()
    assert held.solid_angle.sum() == pytest.approx(4 * math.pi)
    base = bench.environment(0.0)
    assert np.abs(held.radiance - base.radiance).mean() > 0.1 * base.radiance.mean()
    assert type(bench.true_brdf("matte")).__name__ == "Lambertian"
    with pytest.raises(ValueError, match="no sample named"):
        bench.true_brdf("chrome")


@pytest.mark.parametrize("kwargs, name", [({"carries": "table"}, "carries"), ({"scale": 0}, "scale"),
                                          ({"probe_albedo": 1.2}, "probe_albedo"), ({"env_height": 2}, "env_height")])
def test_bad_bench_settings_are_named(kwargs, name):
    with pytest.raises(ValueError, match=name):
        SimBench(**kwargs)
