"""Real RAW path: DNG written with tifffile, decoded by rawpy (LibRaw), metadata read by OpenImageIO."""

from __future__ import annotations

import numpy as np
import pytest

from brdfrig.hdr.dng import CFA_PATTERNS, write_dng
from brdfrig.hdr.raw import Exposure, decode_raw, read_exposure, read_frame

WHITE = 16383
BLACK = (512.0, 520.0, 508.0, 515.0)  # per position of the 2x2 block


def _mosaic(rgb: np.ndarray, pattern: str, black, white: int) -> np.ndarray:
    """Bayer mosaic of a [0, 1] linear RGB image in raw units (the test's own forward model)."""
    h, w, _ = rgb.shape
    cfa = np.empty((h, w))
    for pos, colour in enumerate(CFA_PATTERNS[pattern]):
        i, j = divmod(pos, 2)
        cfa[i::2, j::2] = black[pos] + rgb[i::2, j::2, colour] * (white - black[pos])
    return np.clip(np.round(cfa), 0, white).astype(np.uint16)


def _smooth_scene(h: int, w: int) -> np.ndarray:
    y, x = np.mgrid[0:h, 0:w] / max(h, w)
    return np.stack([0.15 + 0.5 * x, 0.3 + 0.4 * y, 0.6 - 0.3 * x * y], axis=-1)


@pytest.mark.parametrize("pattern", ["RGGB", "BGGR", "GRBG"])
def test_dng_decodes_to_expected_linear_values_within_1_percent(tmp_path, pattern):
    rng = np.random.default_rng(0)
    truth = _smooth_scene(48, 64)
    cfa = _mosaic(truth, pattern, BLACK, WHITE)
    path = write_dng(tmp_path / "frame.dng", cfa, pattern=pattern, black_level=BLACK, white_level=WHITE,
                     exposure_time_s=1 / 125, f_number=5.6, iso=200, as_shot_neutral=(0.5, 1.0, 0.7))
    rgb = decode_raw(path)
    assert rgb.shape == (48, 64, 3) and rgb.dtype == np.float32
    inner = (slice(2, -2), slice(2, -2))  # demosaicing borders
    rel = np.abs(rgb[inner] / truth[inner] - 1)
    assert rel.max() < 0.01, rel.max()
    # Exact linearity: scaling the signal scales the decoded value (no auto-brightness, no gamma).
    half = _mosaic(truth * 0.5, pattern, BLACK, WHITE)
    rgb_half = decode_raw(write_dng(tmp_path / "half.dng", half, pattern=pattern, black_level=BLACK,
                                    white_level=WHITE, exposure_time_s=1 / 250, f_number=5.6, iso=200))
    ratio = rgb_half[inner] / rgb[inner]
    assert np.abs(ratio - 0.5).max() < 0.002


def test_saturated_sensor_decodes_to_one(tmp_path):
    cfa = np.full((32, 32), WHITE, np.uint16)
    rgb = decode_raw(write_dng(tmp_path / "sat.dng", cfa, black_level=BLACK, white_level=WHITE,
                               exposure_time_s=1.0, f_number=8, iso=100))
    assert np.allclose(rgb, 1.0, atol=2e-3)  # LibRaw scales by white minus the common black


def test_exposure_metadata_read_through_openimageio(tmp_path):
    cfa = np.full((32, 32), 1000, np.uint16)
    path = write_dng(tmp_path / "a.dng", cfa, exposure_time_s=1 / 125, f_number=5.6, iso=400)
    exp = read_exposure(path)
    assert isinstance(exp, Exposure)
    assert exp.time_s == pytest.approx(1 / 125, rel=1e-6)
    assert exp.f_number == pytest.approx(5.6, rel=1e-6)
    assert exp.iso == 400
    image, linear = read_frame(path)
    assert linear and image.shape == (32, 32, 3)


def test_missing_exposure_time_is_a_clear_error(tmp_path):
    import tifffile

    path = tmp_path / "plain.tif"
    tifffile.imwrite(path, np.zeros((8, 8, 3), np.uint16))
    with pytest.raises(ValueError, match=r"plain\.tif.*no exposure time"):
        read_exposure(path)


@pytest.mark.parametrize("keep", [0.5, 0.05])
def test_truncated_raw_is_a_clear_error(tmp_path, keep):
    cfa = np.full((64, 64), 3000, np.uint16)
    good = write_dng(tmp_path / "good.dng", cfa, exposure_time_s=0.01, f_number=4, iso=100)
    data = good.read_bytes()
    bad = tmp_path / "cut.dng"
    bad.write_bytes(data[: int(len(data) * keep)])
    with pytest.raises(ValueError, match=r"cut\.dng"):
        decode_raw(bad)


def test_corrupt_raw_is_a_clear_error(tmp_path):
    bad = tmp_path / "noise.dng"
    bad.write_bytes(np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8).tobytes())
    with pytest.raises(ValueError, match=r"noise\.dng"):
        decode_raw(bad)
    with pytest.raises(FileNotFoundError, match="missing.dng"):
        decode_raw(tmp_path / "missing.dng")


def test_write_dng_rejects_bad_input_and_leaves_nothing(tmp_path):
    target = tmp_path / "x.dng"
    with pytest.raises(ValueError, match="uint16"):
        write_dng(target, np.zeros((32, 32)), exposure_time_s=1, f_number=2, iso=100)
    with pytest.raises(ValueError, match="exposure_time_s"):
        write_dng(target, np.zeros((32, 32), np.uint16), exposure_time_s=0, f_number=2, iso=100)
    with pytest.raises(ValueError, match="even"):
        write_dng(target, np.zeros((33, 32), np.uint16), exposure_time_s=1, f_number=2, iso=100)
    assert list(tmp_path.iterdir()) == []
