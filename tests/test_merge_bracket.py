"""One merge path: ``brdfrig merge`` and the session pipeline give the same radiance for the same files."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

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


FW_TIFF, RN_TIFF = 20000.0, 5.0
TIFF_TIMES = 2.0 ** np.arange(-6, 1)  # 7 exposures, 1 stop apart


def smooth_scene(h=150, w=200, seed=0):
    """Smooth radiance over ~1e4:1 (a log ramp and blobs), full scale per second, tinted per channel."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w] / max(h, w)
    log_x = np.log(3e-3) + np.log(1e4) * 0.8 * x / x.max()
    for _ in range(6):
        cy, cx, s, a = rng.uniform(0, 1), rng.uniform(0, 1), rng.uniform(0.05, 0.2), rng.uniform(-1.5, 1.5)
        log_x = log_x + a * np.exp(-((y - cy) ** 2 + (x - cx) ** 2) / (2 * s * s))
    return np.exp(log_x)[:, :, None] * np.array([1.0, 0.8, 0.6])


def write_tiff_bracket(directory, truth, gamma=1.0, times=TIFF_TIMES, seed=1):
    """16-bit TIFFs of a sensor whose pixels are measured independently (shot + read noise), code = value^(1/gamma)."""
    import tifffile

    rng = np.random.default_rng(seed)
    paths = []
    for k, t in enumerate(times):
        e = rng.poisson(np.minimum(truth * t, 4.0) * FW_TIFF) + rng.normal(0, RN_TIFF, truth.shape)
        paths.append(directory / f"f{k}.tif")
        tifffile.imwrite(paths[-1], np.round(np.clip(e / FW_TIFF, 0, 1) ** (1 / gamma) * 65535).astype(np.uint16))
    return paths


def merge_cli(paths, out, *extra, times=TIFF_TIMES):
    from brdfrig.cli.main import main

    args = ["merge", *map(str, paths), "--times", ",".join(map(str, times)), "--full-well", str(FW_TIFF),
            "--read-noise", str(RN_TIFF), "-o", str(out), *extra]
    assert main(args) == 0
    return read_exr(out)


def test_linear_tiff_bracket_is_merged_as_linear_with_clip_radius_0_by_default(tmp_path, capsys):
    truth = smooth_scene()
    paths = write_tiff_bracket(tmp_path, truth)
    rgb, _, attrs = merge_cli(paths, tmp_path / "auto.exr")
    printed = capsys.readouterr().out
    assert attrs["response"] == "linear" and "linear within its uncertainty" in attrs["response_reason"]
    assert attrs["clip_radius_px"] == 0 and "measured independently" in attrs["clip_radius_reason"]
    assert "response: linear" in printed and "clip radius 0 px" in printed
    best, _, _ = merge_cli(paths, tmp_path / "best.exr", "--response", "linear", "--clip-radius", "0")
    assert np.array_equal(rgb, best)  # the defaults are the noise-optimal settings for these frames
    rel = np.abs(rgb / truth - 1)
    # Median error of the noise-optimal merge: 1.1% on this scene (the dark end of the ramp has ~60 electrons at 1 s).
    assert np.median(rel) < 0.013
    # A forced recovered curve costs accuracy (its noise): still within 20% of the linear merge's median error.
    forced, _, attrs = merge_cli(paths, tmp_path / "rec.exr", "--response", "recover", "--clip-radius", "0")
    assert attrs["response"] == "recover"
    assert np.median(np.abs(forced / truth - 1)) < 1.2 * np.median(rel)


def test_gamma_tiff_bracket_is_linearised_by_the_recovered_response(tmp_path):
    truth = smooth_scene(seed=2)
    paths = write_tiff_bracket(tmp_path, truth, gamma=2.2)
    rgb, extra, attrs = merge_cli(paths, tmp_path / "g.exr")
    assert attrs["response"] == "recover" and "not linear" in attrs["response_reason"]
    ok = extra["flags"] == 0
    ratio = rgb[ok] / truth[np.broadcast_to(ok[:, :, None], truth.shape)].reshape(-1, 3)
    # Up to the curve's overall scale (full scale = 1 by construction: exact here); the noise-optimal merge with the
    # true response has a median error of 1.14% on this scene.
    assert abs(np.median(ratio) - 1) < 0.01
    assert np.median(np.abs(ratio / np.median(ratio) - 1)) < 0.0125


def test_two_frame_16_bit_bracket_recovers_or_says_what_to_do(tmp_path):
    from brdfrig.errors import InputError
    from brdfrig.hdr.raw import read_frame
    from brdfrig.hdr.response import recover_response

    truth = smooth_scene(seed=3)
    times = [1 / 8, 1 / 2]
    paths = write_tiff_bracket(tmp_path, truth, gamma=2.2, times=times)
    rgb, extra, attrs = merge_cli(paths, tmp_path / "two.exr", times=times)  # default sample count: enough
    assert attrs["response"] == "recover"
    ok = (extra["flags"] == 0)[:, :, None] & (truth * times[0] > 0.05) & (truth * times[1] < 0.9)
    ratio = rgb[ok] / truth[ok]
    assert np.median(np.abs(ratio / np.median(ratio) - 1)) < 0.02
    frames = [read_frame(p)[0] for p in paths]
    with pytest.raises(InputError, match=r"n_samples \* \(K - 1\) = 600 must exceed levels = 1024: .*"
                                         r"shoot more frames, or give --response linear"):
        recover_response(frames, times, n_samples=600)


def test_demosaic_radius_from_noise_correlation(dng_bracket, tmp_path):
    from brdfrig.hdr.demosaic import demosaic_radius
    from brdfrig.hdr.raw import decode_raw, read_frame

    _, paths = dng_bracket
    times = [1 / 250, 1 / 125 * 2, 1 / 15, 1 / 4 * 2, 1.0]  # effective (ISO 200 frames count double)
    dng = demosaic_radius([decode_raw(p) for p in paths], times)
    assert dng.radius == 1 and dng.correlation[0] > 0.3  # bilinear: neighbours share samples
    tiffs = write_tiff_bracket(tmp_path, smooth_scene(seed=4))
    ind = demosaic_radius([read_frame(p)[0] for p in tiffs], TIFF_TIMES)
    assert ind.radius == 0 and np.all(np.abs(ind.correlation) < 0.03)


def test_streamed_merge_equals_the_in_memory_merge_and_holds_no_whole_frame(tmp_path):
    import tracemalloc

    from brdfrig.hdr.frames import ImageFileFrame
    from brdfrig.hdr.merge import merge_bracket
    from brdfrig.hdr.raw import read_frame

    truth = smooth_scene(300, 400, seed=5)
    paths = write_tiff_bracket(tmp_path, truth)
    kwargs = dict(clip_radius=1, full_well=FW_TIFF, read_noise=RN_TIFF)
    whole = merge_bracket([read_frame(p)[0] for p in paths], TIFF_TIMES, tile_rows=10**6, **kwargs)
    for rows in (7, 256):
        streamed = merge_bracket([ImageFileFrame(p) for p in paths], TIFF_TIMES, tile_rows=rows, **kwargs)
        # Same samples (uint16 / 65535 in the kernel vs float32 from the reader): equal to float32 rounding.
        np.testing.assert_allclose(streamed.radiance, whole.radiance, rtol=2e-6)
        assert np.array_equal(streamed.flags, whole.flags)
        np.testing.assert_allclose(streamed.times, whole.times, rtol=1e-9)
    sources = [ImageFileFrame(p) for p in paths]
    samples = truth.size
    tracemalloc.start()
    merge_bracket(sources, TIFF_TIMES, tile_rows=32, reestimate_times=False, **kwargs)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    # Outputs: 9 bytes per sample (radiance, variance float32, flags uint8), the saturation count's mask 1, bands of
    # 32 rows of 7 frames ~2 here (measured 12.8 in all); the 7 frames held whole would add 14 (uint16) or 28 (float32).
    assert peak < 18 * samples, peak / samples


def test_align_leaves_an_unshifted_bracket_alone(tmp_path):
    import cv2

    from brdfrig.hdr.bracket import MergePolicy, merge_files as merge_bracket_files
    from brdfrig.hdr.raw import read_frame

    paths = write_tiff_bracket(tmp_path, smooth_scene(300, 400))
    frames = [read_frame(p)[0] for p in paths]
    grey8 = [(np.clip(f.mean(axis=2), 0, 1) ** (1 / 2.2) * 255).astype(np.uint8) for f in frames]
    mtb = cv2.createAlignMTB(max_bits=3)  # what align_frames uses for 300 rows
    bitmap_shifts = [tuple(mtb.calculateShift(grey8[3], g)) for g in grey8]
    assert any(s != (0, 0) for s in bitmap_shifts)  # the bitmaps alone report shifts of this unshifted bracket
    policy = MergePolicy(full_well=FW_TIFF, read_noise=RN_TIFF)
    aligned = merge_bracket_files(paths, MergePolicy(full_well=FW_TIFF, read_noise=RN_TIFF, align=True),
                                  times=TIFF_TIMES)
    # A shift that does not bring the frames closer is dropped: no shift, no border without data, the same radiance.
    assert aligned.merge.shifts.tolist() == [[0, 0]] * len(paths) and aligned.no_data == 0
    plain = merge_bracket_files(paths, policy, times=TIFF_TIMES).merge.radiance
    np.testing.assert_allclose(aligned.merge.radiance, plain, rtol=2e-6)  # aligned frames are read whole (float32)


DNG_SHIFTS = [(0, 0), (2, -3), (5, 1), (-1, 4), (3, 3)]  # (dy, dx) where each frame's window starts in the scene
DNG_TIMES = [1 / 64, 1 / 16, 1 / 4, 1.0, 4.0]


def shifted_dng_bracket(directory, h=1024, w=200, seed=3):
    """5 RGGB DNGs (14-bit, seeded noise) of one scene, each frame a window of it moved by ``DNG_SHIFTS``."""
    import cv2

    from brdfrig.hdr.dng import write_dng

    rng = np.random.default_rng(seed)
    coarse = np.exp(rng.normal(0, 1.5, (h // 8 + 4, w // 8 + 4, 3))).astype(np.float32)
    scene = cv2.resize(coarse, ((w // 8 + 4) * 8, (h // 8 + 4) * 8), interpolation=cv2.INTER_CUBIC).clip(1e-3)
    black, white, paths = 256, 16383, []
    for k, (t, (dy, dx)) in enumerate(zip(DNG_TIMES, DNG_SHIFTS)):
        raw = black + np.clip(scene[16 + dy:16 + dy + h, 16 + dx:16 + dx + w] * t * 0.3, 0, 1) * (white - black)
        cfa = np.empty((h, w))
        for (y, x), c in zip(((0, 0), (0, 1), (1, 0), (1, 1)), (0, 1, 1, 2)):
            cfa[y::2, x::2] = raw[y::2, x::2, c]
        cfa = np.round(np.clip(cfa + rng.normal(0, 6, cfa.shape), 0, white)).astype(np.uint16)
        paths.append(write_dng(directory / f"f{k}.dng", cfa, black_level=black, white_level=white,
                               exposure_time_s=t, f_number=8.0, iso=100))
    return paths


def _shift_whole(frame, dx, dy):
    """A whole frame moved by (dx, dy) pixels, NaN where nothing was shifted in (the oracle of the streamed shift)."""
    h, w = frame.shape[:2]
    out = np.full(frame.shape, np.nan, np.float32)
    out[max(0, dy):h + min(0, dy), max(0, dx):w + min(0, dx)] = frame[max(0, -dy):h - max(0, dy),
                                                                      max(0, -dx):w - max(0, dx)]
    return out


@pytest.mark.filterwarnings("ignore::brdfrig.hdr.merge.SaturationWarning")
def test_raw_bracket_streamed_one_decoded_frame_at_a_time_is_bit_identical(tmp_path):
    """merge_files on DNGs (decoded one at a time, served by bands; --align by bands) equals the merge of the
    whole decoded frames (aligned whole by the known shifts) bit for bit, and holds no whole decoded frame."""
    import tracemalloc

    from brdfrig.hdr.bracket import MergePolicy, merge_files as merge_bracket_files
    from brdfrig.hdr.frames import ArrayFrame
    from brdfrig.hdr.merge import merge_bracket
    from brdfrig.hdr.raw import decode_raw

    paths = shifted_dng_bracket(tmp_path)
    whole = [decode_raw(p) for p in paths]
    kwargs = dict(clip_radius=1, full_well=MergePolicy.full_well, read_noise=MergePolicy.read_noise)
    for align in (False, True):
        streamed = merge_bracket_files(paths, MergePolicy(align=align)).merge
        frames = whole
        if align:  # the shifts that move each window onto the median-exposure one (frame 2); frame 4 is too bright
            ref_dy, ref_dx = DNG_SHIFTS[2]
            assert [tuple(s) for s in streamed.shifts[:4]] == [(dx - ref_dx, dy - ref_dy)
                                                                for dy, dx in DNG_SHIFTS[:4]]
            frames = [ArrayFrame(_shift_whole(f, dx, dy), str(p), 1.0) for f, p, (dx, dy) in
                      zip(whole, paths, streamed.shifts)]  # a source: arrays with NaN are refused
        expected = merge_bracket(frames, DNG_TIMES, **kwargs)
        expected.radiance[~np.isfinite(expected.radiance)] = 0.0  # no data after alignment: 0, as merge_files
        expected.variance[~np.isfinite(expected.variance)] = 0.0
        for key in ("radiance", "variance", "flags", "times"):
            assert np.array_equal(getattr(streamed, key), getattr(expected, key)), (align, key)
    del frames, whole, expected
    for align in (False, True):
        tracemalloc.start()
        merge_bracket_files(paths, MergePolicy(align=align, reestimate_times=False))
        peak = tracemalloc.get_traced_memory()[1] / streamed.radiance.size
        tracemalloc.stop()
        # outputs 9 bytes per sample, one decoded frame 2 (uint16), bands of 256 of the 1024 rows ~5 (measured
        # 17-18); the 5 decoded frames held whole would add 20 (float32), aligned copies of them 20 more
        assert peak < 24, (align, peak)


def test_no_room_for_a_decoded_raw_frame_says_where(tmp_path, monkeypatch, capsys):
    """The decoded copy of a raw frame goes to $TMPDIR; a full one (here /dev/full) is one line naming it, exit 2."""
    import tempfile

    from brdfrig.cli.main import main

    if not Path("/dev/full").exists():
        pytest.skip("no /dev/full")
    paths = shifted_dng_bracket(tmp_path, h=64, w=64)
    monkeypatch.setattr(tempfile, "TemporaryFile", lambda **_kw: open("/dev/full", "w+b"))
    out = tmp_path / "hdr.exr"
    assert main(["merge", *map(str, paths), "-o", str(out)]) == 2
    assert capsys.readouterr().err == (f"brdfrig merge: error: disk full while decoding {paths[0]} into "
                                       f"{tempfile.gettempdir()} (0 MB per raw frame): free some space there or "
                                       "set TMPDIR to a disk with room\n")
    assert not out.exists()
