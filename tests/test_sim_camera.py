"""Simulated camera: real files that hdr/ decodes and merges back to the bench's known radiance."""

from __future__ import annotations

import numpy as np
import pytest

from brdfrig.hdr.merge import merge_bracket
from brdfrig.hdr.raw import decode_raw, read_exposure, read_frame
from brdfrig.rig.camera import Camera
from brdfrig.sim.grbl import GrblSimulator
from brdfrig.sim.bench import SimBench
from brdfrig.sim.camera import SimulatedCamera
from brdfrig.rig.turntable import GrblTurntable

FULL_WELL, READ_NOISE = 4000.0, 4.0


@pytest.fixture(scope="module")
def bench():
    return SimBench(scale=0.5, env_height=32)


def disc(shape, circle, shrink_px):
    cx, cy, r = circle
    rows, cols = np.mgrid[0:shape[0], 0:shape[1]]
    return (cols + 0.5 - cx) ** 2 + (rows + 0.5 - cy) ** 2 < (r - shrink_px) ** 2


def test_dng_bracket_merges_to_the_known_radiance_within_noise(bench, tmp_path):
    cam = SimulatedCamera(bench, full_well_e=FULL_WELL, read_noise_e=READ_NOISE, seed=1)
    assert isinstance(cam, Camera)
    times = [4.0, 0.5, 1 / 16, 1 / 128, 1 / 1024, 1 / 8192]
    frames = []
    for t in times:
        cam.set_exposure(t, 100, 8.0)
        path = cam.capture(tmp_path)
        exp = read_exposure(path)
        assert (exp.time_s, exp.f_number, exp.iso) == pytest.approx((t, 8.0, 100.0), rel=1e-6)
        frames.append(decode_raw(path))
    # the simulator's times are exact, so the nominal times are used (no re-estimation from overlap)
    merged = merge_bracket(frames, times, full_well=FULL_WELL, read_noise=READ_NOISE, reestimate_times=False)
    truth = bench.radiance(0.0)
    for name, circle in bench.sample_circles.items():
        inside = disc(truth.shape, circle, 3)  # away from the limb (demosaicing mixes in the backdrop)
        rel = merged.radiance[inside] / truth[inside] - 1
        z = (merged.radiance[inside] - truth[inside]) / np.sqrt(merged.variance[inside])
        print(f"{name}: median rel {np.median(rel, 0)}, rms rel {np.sqrt(np.mean(rel**2, 0))}, std z {z.std(0)}")
        assert np.all(np.abs(np.median(rel, axis=0)) < 0.005)  # unbiased
        assert np.all(z.std(axis=0) < 1.3)  # scatter no larger than the merge's own noise estimate
        assert np.all(np.abs(z.mean(axis=0)) < 0.1)
    back = disc(truth.shape, (truth.shape[1] / 2, 4.0, 1.5), 0) | (np.arange(truth.shape[0])[:, None] < 3)
    assert np.median(merged.radiance[back]) == pytest.approx(0.01, rel=0.05)  # the velvet backdrop


def test_camera_sees_the_physical_angle_not_the_drivers_belief(tmp_path):
    bench = SimBench(scale=0.25, env_height=8)
    # the virtual clock (tick_s): homing and motion advance per status report, never with the machine's load
    with GrblSimulator(steps_per_degree=80, backlash_deg=0.5, max_rate_deg_s=1e5, homing_time_s=0.002, tick_s=0.001) as sim:
        # a driver told there is no backlash: coming down, it believes 20.0 while the table rests at 20.5
        with GrblTurntable(sim.port, 115200, 80, 0.0, poll_interval_s=0.001) as table:
            table.home()
            table.move_to(30.0)
            assert table.move_to(20.0) == 20.0
            cam = SimulatedCamera(bench, sim)
            cam.set_exposure(0.01, 100, 8)
            cam.capture(tmp_path)
    assert cam.last_angle_deg == pytest.approx(20.5)


def test_noise_is_deterministic_per_seed(bench, tmp_path):
    def shot(seed, sub):
        d = tmp_path / sub
        d.mkdir()
        cam = SimulatedCamera(bench, seed=seed)
        cam.set_exposure(0.1, 100, 8)
        return decode_raw(cam.capture(d))

    a, b, c = shot(5, "a"), shot(5, "b"), shot(6, "c")
    np.testing.assert_array_equal(a, b)
    assert np.abs(a - c).max() > 0


def test_begin_shot_makes_the_noise_a_function_of_the_shot_key(bench, tmp_path):
    # the session runner calls begin_shot(key) before each capture: a shot's noise must not depend on
    # how many captures came before it (a resumed session rewrites the same files)
    cam = SimulatedCamera(bench, seed=5)
    cam.set_exposure(0.1, 100, 8)
    frames = {}
    for k, key in enumerate(["s0-a0-t0", "s0-a0-t1", "s0-a0-t0"]):
        d = tmp_path / str(k)
        d.mkdir()
        cam.begin_shot(key)
        frames[k] = decode_raw(cam.capture(d))
    np.testing.assert_array_equal(frames[0], frames[2])
    assert np.abs(frames[0] - frames[1]).max() > 0
    # the interface's default is a no-op (real cameras have no noise to seed)
    assert Camera.begin_shot(object(), "s0-a0-t0") is None


def test_iso_and_aperture_scale_the_signal(bench, tmp_path):
    cam = SimulatedCamera(bench, read_noise_e=0.0, full_well_e=1e7)  # almost noiseless
    cam.set_exposure(0.05, 100, 8)
    base = decode_raw(cam.capture(tmp_path))
    cam.set_exposure(0.05, 200, 5.6)
    brighter = decode_raw(cam.capture(tmp_path))
    inside = disc(base.shape, bench.sample_circles["matte"], 3)
    ratio = np.median(brighter[inside] / base[inside])
    assert ratio == pytest.approx(2.0 * (8 / 5.6) ** 2, rel=0.01)


def test_tiff_with_nonlinear_response(bench, tmp_path):
    cam = SimulatedCamera(bench, file_format="tiff", response_gamma=2.2, read_noise_e=0.0, full_well_e=1e7)
    cam.set_exposure(0.02, 100, 8)
    path = cam.capture(tmp_path)
    assert path.suffix == ".tif"
    exp = read_exposure(path)
    assert (exp.time_s, exp.f_number, exp.iso) == pytest.approx((0.02, 8.0, 100.0), rel=1e-6)
    frame, linear = read_frame(path)
    assert not linear
    truth = bench.radiance(0.0)
    inside = disc(truth.shape, bench.sample_circles["glossy"], 3)
    np.testing.assert_allclose(frame[inside] ** 2.2, np.clip(truth[inside] * 0.02, 0, 1), rtol=0.01, atol=1e-4)


def test_bad_exposure_and_settings_are_named(bench, tmp_path):
    cam = SimulatedCamera(bench)
    with pytest.raises(ValueError, match="set_exposure"):
        cam.capture(tmp_path)
    with pytest.raises(ValueError, match="exposure time"):
        cam.set_exposure(0, 100, 8)
    with pytest.raises(ValueError, match="response_gamma"):
        SimulatedCamera(bench, response_gamma=2.2)
    with pytest.raises(ValueError, match="table_state"):
        SimulatedCamera(bench, table_state=object())
    cam.set_exposure(0.1, 100, 8)
    with pytest.raises(OSError, match="not a directory"):
        cam.capture(tmp_path / "missing")
