"""``brdfrig merge`` end to end: DNG brackets written here, exposure times from their metadata."""

from __future__ import annotations

import re

import numpy as np

from brdfrig.cli.main import main
from brdfrig.hdr.dng import write_dng
from brdfrig.hdr.exr import read_exr

BLACK, WHITE = 256, 16383
TIMES = [1 / 500, 1 / 125, 1 / 30, 1 / 8]  # nominal, as cameras label them
TRUE_TIMES = [1 / 512, 1 / 128, 1 / 32, 1 / 8]  # what the shutter did: exactly 2 stops apart


def scene(h=64, w=96):
    """Radiance (full scale per second) over ~1e4:1: a horizontal ramp in log, a colour tint per channel."""
    x = np.linspace(0, 1, w)[None, :, None]
    y = np.linspace(0, 1, h)[:, None, None]
    return 0.06 * 10 ** (4 * x) * (1 + 0.2 * y) * np.array([1.0, 0.8, 0.6])


def write_bracket(directory, radiance, times, rng, true_times=None):
    paths = []
    for k, (t, t_true) in enumerate(zip(times, true_times or times)):
        signal = np.clip(radiance * t_true, 0, 1.2)
        electrons = rng.poisson(signal * 20000) + rng.normal(0, 5, signal.shape)
        raw = BLACK + np.clip(electrons / 20000, 0, None) * (WHITE - BLACK)
        cfa = np.empty(raw.shape[:2])
        cfa[0::2, 0::2] = raw[0::2, 0::2, 0]
        cfa[0::2, 1::2] = raw[0::2, 1::2, 1]
        cfa[1::2, 0::2] = raw[1::2, 0::2, 1]
        cfa[1::2, 1::2] = raw[1::2, 1::2, 2]
        cfa = np.clip(np.round(cfa), 0, WHITE).astype(np.uint16)
        paths.append(write_dng(directory / f"f{k}.dng", cfa, black_level=BLACK, white_level=WHITE,
                               exposure_time_s=t, f_number=8.0, iso=100))
    return paths


def test_merge_dng_bracket_from_metadata(tmp_path, capsys):
    truth = scene()
    files = write_bracket(tmp_path, truth, TIMES, np.random.default_rng(0), TRUE_TIMES)
    out = tmp_path / "hdr.exr"
    assert main(["merge", *map(str, files), "-o", str(out)]) == 0
    assert "merged 4 frames" in capsys.readouterr().out
    rgb, extra, attrs = read_exr(out)
    assert rgb.shape == (64, 96, 3) and extra["variance"].shape == (64, 96, 3) and "flags" in extra
    assert attrs["times_source"] == "metadata" and attrs["source_files"] == [str(f.resolve()) for f in files]
    # Standard attributes: radiance per second (a 1 s exposure) at the first frame's f-number and ISO.
    assert (attrs["expTime"], attrs["aperture"], attrs["isoSpeed"]) == (1.0, 8.0, 100.0)
    assert np.allclose(attrs["nominal_times_s"], TIMES, rtol=1e-6)
    # The rounded labels were detected: re-estimated ratios are the shutter's true 4x steps.
    used = np.array(attrs["times_s"])
    assert np.allclose(used[1:] / used[:-1], 4.0, rtol=0.01)
    inner = (slice(2, -2), slice(2, -2))
    ratio = rgb[inner] / truth[inner]
    # Within 1% up to one global scale (the absolute exposure is only known through the labels: <= 2.5% off).
    assert abs(np.median(ratio) - 1) < 0.025
    rel = np.abs(ratio / np.median(ratio) - 1)
    # Tails: above 1500 electrons in the longest frame (the dark quarter of the ramp is shot-noise limited).
    assert np.median(rel) < 0.01 and np.percentile(rel[:, 24:], 95) < 0.03
    # Trusting the labels leaves steps of 4% between the exposures' ranges.
    assert main(["merge", *map(str, files), "--no-reestimate", "-o", str(tmp_path / "naive.exr")]) == 0
    naive = read_exr(tmp_path / "naive.exr")[0][inner] / truth[inner]
    assert np.percentile(np.abs(naive / np.median(naive) - 1)[:, 24:], 95) > 0.03


def test_merge_times_option_and_bad_input(tmp_path, capsys):
    truth = scene()
    files = write_bracket(tmp_path, truth, TIMES[:2], np.random.default_rng(1))
    out = tmp_path / "t.exr"
    assert main(["merge", *map(str, files), "--times", "0.002,0.008", "-o", str(out)]) == 0
    assert read_exr(out)[2]["times_source"] == "--times"
    good = out.read_bytes()
    # Wrong number of times.
    assert main(["merge", *map(str, files), "--times", "0.002", "-o", str(out)]) == 2
    assert "--times has 1 values for 2 files" in capsys.readouterr().err
    # Mixed sizes, naming the file.
    small = write_dng(tmp_path / "small.dng", np.full((32, 32), 3000, np.uint16), exposure_time_s=0.01,
                      f_number=8, iso=100)
    assert main(["merge", str(files[0]), str(small), "-o", str(out)]) == 2
    assert "small.dng has size 32x32" in capsys.readouterr().err
    # Truncated raw file, naming it.
    cut = tmp_path / "cut.dng"
    cut.write_bytes(files[1].read_bytes()[:3000])
    assert main(["merge", str(files[0]), str(cut), "--times", "0.002,0.008", "-o", str(out)]) == 2
    assert "cut.dng" in capsys.readouterr().err
    # Missing exposure metadata, naming the file.
    import tifffile

    plain = tmp_path / "plain.tif"
    tifffile.imwrite(plain, np.zeros((64, 96, 3), np.uint16))
    assert main(["merge", str(files[0]), str(plain), "-o", str(out)]) == 2
    assert "plain.tif: no exposure time" in capsys.readouterr().err
    # The good output was never replaced, and no temporary files were left.
    assert out.read_bytes() == good
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_merge_nonlinear_tiff_bracket(tmp_path):
    import tifffile

    truth = scene(96, 128)
    times = [1 / 64, 1 / 16, 1 / 4, 1.0]
    files = []
    for k, t in enumerate(times):
        code = np.clip(truth * t, 0, 1) ** (1 / 2.2)  # a gamma camera
        files.append(tmp_path / f"g{k}.tif")
        tifffile.imwrite(files[-1], np.round(code * 65535).astype(np.uint16))
    out = tmp_path / "g.exr"
    assert main(["merge", *map(str, files), "--times", ",".join(map(str, times)), "-o", str(out)]) == 0
    rgb, extra, attrs = read_exr(out)
    assert attrs["response"] == "recover"
    ok = extra["flags"] == 0  # the brightest columns are saturated even at 1/64 s
    assert ok.mean() > 0.7
    ratio = rgb[ok] / truth[ok]
    # Linear up to the response's overall scale: the ratio is constant over 3 decades to 2%.
    assert np.percentile(np.abs(ratio / np.median(ratio) - 1), 95) < 0.02


def test_align_borders_without_data_are_written_finite_and_flagged(tmp_path, capsys):
    """Pixels no aligned frame covers hold no data (NaN inside the merge): written as 0 with flags 2, never NaN."""
    rng = np.random.default_rng(3)
    files = []
    for k, (t, dx) in enumerate(zip(TIMES, [0, 2, -3, 1])):  # the camera moved between frames
        (tmp_path / f"s{k}").mkdir()
        files += write_bracket(tmp_path / f"s{k}", np.roll(scene(), dx, axis=1), [t], rng)
    out = tmp_path / "aligned.exr"
    assert main(["merge", *map(str, files), "--align", "-o", str(out)]) == 0
    rgb, extra, _ = read_exr(out)
    assert np.isfinite(rgb).all() and np.isfinite(extra["variance"]).all() and (rgb >= 0).all()
    note = re.search(r"note: (\d+) pixel-channel\(s\) at the frame borders have no data", capsys.readouterr().err)
    zero = rgb == 0  # the scene has no black pixel: a 0 is a pixel without data
    assert note is not None and int(note.group(1)) == int(zero.sum()) > 0
    assert np.all(extra["flags"][zero.any(axis=2)] == 2)
    assert np.all(extra["variance"][zero] == 0)
