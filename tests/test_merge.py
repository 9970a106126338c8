"""Exposure merging on synthetic brackets with a known radiance image."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from brdfrig.hdr.merge import (
    FLAG_DARK,
    FLAG_SATURATED,
    SaturationWarning,
    align_frames,
    clipped_neighbourhood,
    estimate_times,
    merge_bracket,
)

FULL_WELL, READ_NOISE = 20000.0, 5.0
TIMES = 2.0 ** np.arange(-6, 1)  # 7 exposures, 1 stop apart: 1/64 .. 1 s


def radiance_image(h=160, w=240, seed=0):
    """Log-uniform radiance over 1e5:1, 6e-4 .. 60 frame units per second, every pixel independent.

    At 1 s the faintest pixel collects 12 electrons (read noise 5); at 1/64 s the brightest is 0.94 of full scale.
    Not demosaiced: a clipped pixel does not bias its neighbours, so the merges below use ``clip_radius=0``
    (with 1, a third of the 1 s frame's pixels clip and almost every pixel has a clipped neighbour).
    """
    rng = np.random.default_rng(seed)
    return np.exp(rng.uniform(np.log(6e-4), np.log(60.0), (h, w, 3)))


def shoot(radiance, t, rng, dtype=np.uint16):
    """Sensor model of the test: Poisson shot noise + Gaussian read noise, clipped, quantised."""
    electrons = rng.poisson(np.minimum(radiance * t, 4.0) * FULL_WELL) + rng.normal(0, READ_NOISE, radiance.shape)
    z = np.clip(electrons / FULL_WELL, 0, 1)
    return np.round(z * 65535).astype(dtype)


def bracket(radiance, times=TIMES, seed=1):
    rng = np.random.default_rng(seed)
    return [shoot(radiance, t, rng) for t in times]


def test_merge_beats_opencv_and_variance_is_calibrated():
    import cv2

    x = radiance_image()
    frames = bracket(x)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SaturationWarning)  # a few pixels at the top may clip
        res = merge_bracket(frames, TIMES, clip_radius=0, full_well=FULL_WELL, read_noise=READ_NOISE)
    assert res.radiance.shape == x.shape and res.radiance.dtype == np.float32
    ok = res.flags == 0
    assert ok.mean() > 0.999
    rel = np.abs(res.radiance / x - 1)
    cv = cv2.createMergeDebevec().process(frames, TIMES.astype(np.float32)) / 65535.0
    rel_cv = np.abs(cv / x - 1)
    # Oracle: the true radiance; the peer: OpenCV's MergeDebevec on the same frames.
    assert np.median(rel) < 0.5 * np.median(rel_cv), (np.median(rel), np.median(rel_cv))
    assert np.mean(rel[ok]) < 0.5 * np.mean(rel_cv[ok])
    # Above the noise floor (>= 200 electrons in the longest frame) the error is Gaussian:
    # normalised residuals have unit variance (the variance image is right to 10%).
    bright = ok & (x > 0.01)
    chi2 = np.mean((res.radiance[bright] - x[bright]) ** 2 / res.variance[bright])
    assert 0.9 < chi2 < 1.1, chi2
    # No bias over the 4 decades above 6e-3 (median ratio per decade within 0.5%).
    for lo in range(-3, 1):
        sel = ok & (x >= 6 * 10.0**lo) & (x < 6 * 10.0 ** (lo + 1))
        assert abs(np.median(res.radiance[sel] / x[sel]) - 1) < 0.005


def test_noise_optimal_weights_beat_debevec_hat():
    x = radiance_image(seed=2)
    frames = bracket(x, seed=3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SaturationWarning)
        opt = merge_bracket(frames, TIMES, clip_radius=0, full_well=FULL_WELL, read_noise=READ_NOISE)
        hat = merge_bracket(frames, TIMES, clip_radius=0, weighting="debevec", full_well=FULL_WELL,
                            read_noise=READ_NOISE)
    ok = (opt.flags == 0) & (hat.flags == 0)

    def rms(res, sel):
        return np.sqrt(np.mean((res.radiance[sel] / x[sel] - 1) ** 2))

    # Better in every decade; by >= 2x near the noise floor, by >= 5% on average where shot noise dominates.
    ratios = []
    for lo in range(-4, 1):
        sel = ok & (x >= 6 * 10.0**lo) & (x < 6 * 10.0 ** (lo + 1))
        ratios.append(rms(opt, sel) / rms(hat, sel))
    print("RMS relative error, optimal / hat, per decade from 6e-4:", np.round(ratios, 3))
    assert max(ratios) < 1 and ratios[0] < 0.5 and np.mean(ratios[2:]) < 0.95
    # The hat's own variance estimate is consistent too.
    bright = ok & (x > 0.01)
    chi2 = np.mean((hat.radiance[bright] - x[bright]) ** 2 / hat.variance[bright])
    assert 0.85 < chi2 < 1.15


def test_reestimation_recovers_a_3_percent_error_in_a_nominal_time():
    x = radiance_image(seed=4)
    frames = bracket(x, seed=5)
    nominal = TIMES.copy()
    nominal[4] *= 1.03  # the camera reports 3% too long an exposure for frame 4
    est = estimate_times(frames, nominal, saturation=65535, clip_radius=0)
    assert np.abs(est / TIMES - 1).max() < 0.003, est / TIMES
    fixed = merge_bracket(frames, nominal, clip_radius=0)
    assert np.abs(fixed.times / TIMES - 1).max() < 0.003
    naive = merge_bracket(frames, nominal, clip_radius=0, reestimate_times=False)
    # Pixels whose best frame is frame 4 are 3% low without re-estimation, right with it.
    sel = (fixed.flags == 0) & (x * TIMES[4] > 0.3) & (x * TIMES[4] < 0.6)
    assert abs(np.median(naive.radiance[sel] / x[sel]) - 1) > 0.008
    assert abs(np.median(fixed.radiance[sel] / x[sel]) - 1) < 0.003


def test_consistent_times_are_kept():
    x = radiance_image(seed=6)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SaturationWarning)  # the brightest few pixels may clip at 1/64 s
        res = merge_bracket(bracket(x, seed=7), TIMES, clip_radius=0)
    assert np.array_equal(res.times, TIMES) and np.array_equal(res.nominal_times, TIMES)


def test_saturated_everywhere_warns_and_flags():
    x = radiance_image(64, 64, seed=8)
    x[:4, :4] = 500.0  # saturates even the 1/64 s frame
    frames = bracket(x, seed=9)
    with pytest.warns(SaturationWarning, match=r"48 pixel-channels .* saturated in every frame"):
        res = merge_bracket(frames, TIMES, clip_radius=0)
    assert np.all(res.flags[:4, :4] == FLAG_SATURATED)
    assert np.count_nonzero(res.flags == FLAG_SATURATED) == 48
    # A lower bound: full scale over the shortest time.
    assert np.allclose(res.radiance[:4, :4], 1.0 / TIMES[0], rtol=1e-3)


def test_black_everywhere_is_flagged_dark_and_uses_longest_exposure():
    x = radiance_image(64, 64, seed=10)
    frames = bracket(x, seed=11)
    for f in frames:
        f[10:12, 10:12] = 0  # at the black level in every frame (censored)
    frames[-1][10, 10, 0] = 0  # and one pixel-channel with signal only in the longest frame:
    frames[-1][20, 20, 1] = 30  # 30 / 65535 of full scale at 1 s, zero in every shorter frame
    for f in frames[:-1]:
        f[20, 20, 1] = 0
    with warnings.catch_warnings():
        warnings.simplefilter("error", SaturationWarning)
        res = merge_bracket(frames, TIMES, clip_radius=0)
    assert np.all(res.flags[10:12, 10:12] == FLAG_DARK)
    assert np.all(res.radiance[10:12, 10:12] == 0) and np.all(res.variance[10:12, 10:12] > 0)
    assert res.flags[20, 20, 1] == 0 and res.radiance[20, 20, 1] == pytest.approx(30 / 65535, rel=1e-4)


def test_alignment_recovers_integer_shifts():
    rng = np.random.default_rng(12)
    base = np.exp(rng.normal(0, 1.0, (48, 64)))
    from scipy.ndimage import zoom

    x = np.repeat(zoom(base, 4, order=1)[:, :, None], 3, axis=2)  # (192, 256) textured scene
    frames = []
    shifts = [(0, 0), (3, -2), (-4, 1)]
    for t, (dx, dy) in zip([0.05, 0.1, 0.2], shifts):
        frames.append(np.roll(np.clip(x * t, 0, 1), (dy, dx), axis=(0, 1)).astype(np.float32))
    aligned, found = align_frames(frames, [0.05, 0.1, 0.2])
    ref = 1  # median exposure
    for k, (dx, dy) in enumerate(shifts):
        assert tuple(found[k]) == (shifts[ref][0] - dx, shifts[ref][1] - dy)
    with pytest.warns(SaturationWarning):  # the scene's brightest spots clip even at 0.05 s
        res = merge_bracket(frames, [0.05, 0.1, 0.2], align=True)
    inner = (slice(8, -8), slice(8, -8))
    expect = np.roll(x, shifts[ref][::-1], axis=(0, 1))
    ok = res.flags[inner] == 0
    assert np.median(np.abs(res.radiance[inner][ok] / expect[inner][ok] - 1)) < 1e-3


def test_bad_brackets_are_clear_errors():
    a = np.zeros((8, 8, 3), np.float32)
    with pytest.raises(ValueError, match=r"b\.tif has size \(8, 9, 3\), a\.tif has \(8, 8, 3\)"):
        merge_bracket([a, np.zeros((8, 9, 3), np.float32)], [1, 2], names=["a.tif", "b.tif"])
    with pytest.raises(ValueError, match="1 exposure times for 2 frames"):
        merge_bracket([a, a], [1])
    with pytest.raises(ValueError, match="times are missing"):
        merge_bracket([a, a], None)
    with pytest.raises(ValueError, match=r"b\.exr: exposure time must be a positive number"):
        merge_bracket([a, a], [1, 0], names=["a.exr", "b.exr"])
    bad = a.copy()
    bad[1, 1, 1] = np.inf
    with pytest.raises(ValueError, match=r"frame 1: contains NaN/inf"):
        merge_bracket([a, bad], [1, 2])
    with pytest.raises(ValueError, match="no frames"):
        merge_bracket([], [])


def test_clipped_neighbourhood_covers_every_channel_within_the_radius():
    frame = np.full((6, 7, 3), 0.3, np.float32)
    frame[2, 3, 1] = 0.97  # green alone reaches the clip level
    frame[5, 0] = np.nan  # no data is not clipped
    expected = np.zeros((6, 7), bool)
    expected[1:4, 2:5] = True
    np.testing.assert_array_equal(clipped_neighbourhood(frame, 0.95, 1), expected)
    expected[0:5, 1:6] = True
    np.testing.assert_array_equal(clipped_neighbourhood(frame, 0.95, 2), expected)
    assert np.count_nonzero(clipped_neighbourhood(frame, 0.95, 0)) == 1
    assert not clipped_neighbourhood(frame, 0.98, 1).any()
    assert clipped_neighbourhood((np.nan_to_num(frame[:, :, 1]) * 65535).astype(np.uint16), 0.95 * 65535, 1).sum() == 9


def _decode_mosaic(path, rgb):
    """Write the RGGB mosaic of ``rgb`` (fraction of full scale, clipped at 1) as a 14-bit DNG and decode it."""
    from brdfrig.hdr.dng import write_dng
    from brdfrig.hdr.raw import decode_raw

    black, white = 256, 16383
    raw = black + np.clip(rgb, 0, 1) * (white - black)
    cfa = np.empty(raw.shape[:2])
    cfa[0::2, 0::2] = raw[0::2, 0::2, 0]
    cfa[0::2, 1::2] = raw[0::2, 1::2, 1]
    cfa[1::2, 0::2] = raw[1::2, 0::2, 1]
    cfa[1::2, 1::2] = raw[1::2, 1::2, 2]
    write_dng(path, np.round(cfa).astype(np.uint16), black_level=black, white_level=white, exposure_time_s=1.0,
              f_number=8.0, iso=100)
    return decode_raw(path)


def small_lights_bracket(directory):
    """Small lights at 16x full scale per second next to an unclipped backdrop, as demosaiced DNG frames.

    Noiseless (bias only), 14-bit.  Returns the DNG paths, their times, the decoded frames and the truth: demosaicing
    is linear, so the true demosaiced radiance is the decode of the unclipped mosaic scaled below full scale, scaled
    back up (an oracle that does not involve the merge).
    """
    h, w = 32, 40
    x = np.full((h, w, 3), 0.4) * np.array([1.0, 0.8, 0.6]) * np.linspace(0.7, 1.3, w)[None, :, None]
    x[9:11, 9:11] = 16.0  # a white 2x2 light
    x[20:23, 24:27] = [16.0, 2.0, 0.5]  # a red 3x3 light: only one channel clips
    times = [1 / 64, 1 / 16, 1 / 4, 1.0]  # the lights clip at 1/16 s and longer
    paths = [directory / f"f{k}.dng" for k in range(len(times))]
    frames = [_decode_mosaic(path, x * t) for path, t in zip(paths, times)]
    scale = 0.9 / x.max()
    truth = _decode_mosaic(directory / "truth.dng", x * scale) / scale
    return paths, times, frames, truth


def test_clipped_small_light_merges_to_the_true_radiance_with_clip_radius_1(tmp_path):
    _, times, frames, truth = small_lights_bracket(tmp_path)
    assert (frames[-1] >= 0.95).any(axis=2).sum() >= 10 and (frames[0] < 0.95).all()
    with warnings.catch_warnings():
        warnings.simplefilter("error", SaturationWarning)  # the 1/64 s frame sees every pixel unclipped
        rel = {r: np.abs(merge_bracket(frames, times, clip_radius=r).radiance / truth - 1) for r in (0, 1)}
    bad0 = rel[0] > 0.02
    print(f"max relative error: clip_radius=0 {rel[0].max():.3f} ({bad0.sum()} pixel-channels > 2%), "
          f"clip_radius=1 {rel[1].max():.5f}")
    assert rel[1].max() < 0.02
    assert rel[0].max() > 0.3 and bad0.sum() >= 20  # the demosaiced rim of the lights reads far too low


def test_merge_command_clip_radius_option(tmp_path, capsys):
    from brdfrig.cli.main import main
    from brdfrig.hdr.exr import read_exr

    paths, times, _, truth = small_lights_bracket(tmp_path)
    args = ["merge", *map(str, paths), "--times", ",".join(map(str, times))]
    for radius in (0, 1):
        out = tmp_path / f"r{radius}.exr"
        assert main([*args, "--clip-radius", str(radius), "-o", str(out)]) == 0
        rgb, _, attributes = read_exr(out)
        assert attributes["clip_radius_px"] == radius
        rel = np.abs(rgb / truth - 1).max()
        assert (rel < 0.02) if radius else (rel > 0.3), (radius, rel)
    assert main([*args, "--clip-radius", "-1", "-o", str(tmp_path / "bad.exr")]) == 2
    assert "--clip-radius: must be an integer in [0, 16], got '-1'" in capsys.readouterr().err
    assert not (tmp_path / "bad.exr").exists()


def test_any_channel_rule_survives_a_colour_matrix(tmp_path):
    # Camera TIFF/JPEG frames are demosaiced, then colour-converted: a clipped camera channel corrupts every output
    # channel of its neighbours.  Merging each channel alone applies a same-channel rule, which misses that.
    x = np.full((24, 24, 3), 0.4) * np.array([1.0, 0.8, 0.6])
    x[9:12, 9:12] = [16.0, 3.0, 1.0]  # a saturated red light: only camera red clips at 1/16 s and 1/4 s
    times = [1 / 64, 1 / 16, 1 / 4, 1.0]
    to_srgb = np.array([[1.6, -0.5, -0.1], [-0.2, 1.5, -0.3], [0.0, -0.4, 1.4]])  # a typical camera-to-sRGB matrix
    frames = [np.clip(_decode_mosaic(tmp_path / f"f{k}.dng", x * t) @ to_srgb.T, 0, 1) for k, t in enumerate(times)]
    scale = 0.9 / x.max()
    truth = _decode_mosaic(tmp_path / "truth.dng", x * scale) / scale @ to_srgb.T
    ok = np.repeat((truth > 0.05).all(axis=2, keepdims=True), 3, axis=2)  # frames clipped at 0 hold no negatives
    with warnings.catch_warnings():
        warnings.simplefilter("error", SaturationWarning)
        any_channel = merge_bracket(frames, times, clip_radius=1).radiance
        same_channel = np.concatenate(
            [merge_bracket([f[:, :, c:c + 1] for f in frames], times, clip_radius=1).radiance for c in range(3)], axis=2)
    rel_any, rel_same = np.abs(any_channel / truth - 1)[ok], np.abs(same_channel / truth - 1)[ok]
    print(f"max relative error: any channel {rel_any.max():.4f}, same channel {rel_same.max():.3f} "
          f"({np.count_nonzero(rel_same > 0.02)} pixel-channels > 2%)")
    assert rel_any.max() < 0.02
    assert rel_same.max() > 0.5 and np.count_nonzero(rel_same > 0.02) >= 5
