"""One merge path: ``brdfrig merge`` and the session pipeline give the same radiance for the same files."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from brdfrig.hdr.exr import read_exr
from brdfrig.session.pipeline import merge_files
from brdfrig.sim.bench import SimBench
from brdfrig.sim.camera import SimulatedCamera

FULL_WELL, READ_NOISE = 4000.0, 4.0  # a session config's [rig.camera] noise model, not the merge defaults


@pytest.fixture(scope="module")
def dng_bracket(tmp_path_factory):
    """A simulated camera's DNG bracket with the ISO changed between frames (effective time = t * ISO / 100)."""
    bench = SimBench(scale=0.5, env_height=32)
    cam = SimulatedCamera(bench, full_well_e=FULL_WELL, read_noise_e=READ_NOISE, seed=4)
    directory = tmp_path_factory.mktemp("bracket")
    paths = []
    for t, iso in [(1 / 250, 100), (1 / 125, 200), (1 / 15, 100), (1 / 4, 200), (1.0, 100)]:
        cam.set_exposure(t, iso, 8.0)
        paths.append(cam.capture(directory))
    return bench, paths


def test_merge_command_and_session_pipeline_give_identical_radiance(dng_bracket, tmp_path):
    bench, paths = dng_bracket
    out = tmp_path / "hdr.exr"
    run = subprocess.run([sys.executable, "-m", "brdfrig.cli.main", "merge", *map(str, paths), "-o", str(out),
                          "--full-well", str(FULL_WELL), "--read-noise", str(READ_NOISE)],
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    rgb, _, attrs = read_exr(out)
    session = merge_files(paths, FULL_WELL, READ_NOISE)
    # The EXR stores float32: the same float32 array, bit for bit.
    assert rgb.dtype == session.radiance.dtype == np.float32
    assert np.array_equal(rgb, session.radiance)
    # Both used the ISO-scaled effective times (the raw shutter times would put the ISO 200 frames 2x too bright).
    assert attrs["response"] == "linear" and attrs["clip_radius_px"] == 1
    truth = bench.radiance(0.0)
    ok = session.usable.all(axis=2)
    sim = SimulatedCamera(bench)
    sim.set_exposure(1.0, 100, 8.0)
    expect = sim.expected_value(truth)  # frame units per second at ISO 100, f/8
    ratio = session.radiance[ok] / expect[ok]
    assert abs(np.median(ratio) - 1) < 0.01
