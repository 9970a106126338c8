"""Response recovery (Debevec & Malik) for non-linear 8/16-bit brackets, against the truth and OpenCV."""

from __future__ import annotations

import numpy as np

from brdfrig.hdr.merge import merge_bracket
from brdfrig.hdr.response import linearize, recover_response

TIMES = 2.0 ** np.arange(-3, 4)  # 7 exposures, 1 stop apart


def camera(e):
    """The test's non-linear camera: sRGB-like 1/2.2 power response, clipped."""
    return np.clip(e, 0, 1) ** (1 / 2.2)


def scene(seed=0, h=120, w=160):
    return np.exp(np.random.default_rng(seed).uniform(np.log(1e-3), 0, (h, w, 3)))


def test_16_bit_response_matches_the_true_curve():
    x = scene()
    frames = [np.round(camera(x * t) * 65535) / 65535 for t in TIMES]
    curve = recover_response(frames, TIMES)
    sel = (curve.codes > 0.05) & (curve.codes < 0.95)
    truth = curve.codes[sel] ** 2.2
    assert np.abs(curve.linear[sel] / truth[:, None] - 1).max() < 0.005


def test_8_bit_response_agrees_with_opencv_calibrate_debevec():
    import cv2

    x = scene(seed=1)
    frames8 = [np.round(camera(x * t) * 255).astype(np.uint8) for t in TIMES]
    ours = recover_response([f / 255.0 for f in frames8], TIMES, levels=256, n_samples=200)
    peer = cv2.createCalibrateDebevec(samples=200).process(frames8, TIMES.astype(np.float32))[:, 0, :]
    peer = peer / peer[-1]
    sel = slice(13, 243)  # codes 0.05 .. 0.95
    assert np.abs(ours.linear[sel] / peer[sel] - 1).max() < 0.03
    truth = ours.codes[sel] ** 2.2
    assert np.abs(ours.linear[sel] / truth[:, None] - 1).max() < 0.03


def test_linearised_nonlinear_bracket_merges_to_the_radiance():
    x = scene(seed=2)
    frames = [np.round(camera(x * t) * 65535) / 65535 for t in TIMES]
    curve = recover_response(frames, TIMES)
    linear = [linearize(f, curve) for f in frames]
    res = merge_bracket(linear, TIMES, reestimate_times=False)
    ok = res.flags == 0
    ratio = res.radiance[ok] / x[ok]
    # Up to the curve's unknown overall scale (fixed by full scale = 1), within 1%.
    assert abs(np.median(ratio) - 1) < 0.01
    assert np.percentile(np.abs(ratio / np.median(ratio) - 1), 99) < 0.01
