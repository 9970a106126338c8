"""Camera RGB -> Rec.709 / ACEScg from a DNG's own colour metadata, on a simulated camera of known colour matrix.

The oracle is the test's own forward model: patches of known linear Rec.709 reflectance under D65 are
turned into XYZ by colour-science's BT.709 matrix, then into camera RGB by the camera's matrix ``MC``,
mosaicked and written as a DNG whose ColorMatrix1 and AsShotNeutral describe that camera.
"""

from __future__ import annotations

import numpy as np
import pytest

from brdfrig.hdr.colour import camera_to_space, chromaticities, convert, read_camera_colour
from brdfrig.hdr.dng import CFA_PATTERNS, write_dng
from brdfrig.hdr.raw import decode_raw

colour = pytest.importorskip("colour")

MC = np.array([[0.9, 0.3, -0.15], [-0.2, 1.1, 0.1], [0.05, -0.1, 0.8]])  # XYZ -> camera native RGB
PATCHES = {"grey": (0.18, 0.18, 0.18), "orange": (0.6, 0.3, 0.1), "blue": (0.1, 0.35, 0.7), "white": (0.9, 0.9, 0.9)}


def _shot(tmp_path):
    bt709 = colour.RGB_COLOURSPACES["ITU-R BT.709"]
    white_cam = MC @ (bt709.matrix_RGB_to_XYZ @ np.ones(3))
    scale = 0.8 / white_cam.max()  # the white patch sits below saturation
    tiles = [np.broadcast_to(MC @ (bt709.matrix_RGB_to_XYZ @ np.array(v)) * scale, (32, 32, 3)) for v in PATCHES.values()]
    cam = np.concatenate(tiles, axis=1)
    cfa = np.empty(cam.shape[:2])
    for pos, c in enumerate(CFA_PATTERNS["RGGB"]):
        i, j = divmod(pos, 2)
        cfa[i::2, j::2] = cam[i::2, j::2, c] * 16383
    cm = MC / white_cam.max()  # DNG normalisation: the illuminant's white (Y = 1) maps to a maximum of 1
    path = write_dng(tmp_path / "patches.dng", np.round(cfa).astype(np.uint16), white_level=16383, color_matrix=cm,
                     as_shot_neutral=white_cam / white_cam.max(), exposure_time_s=0.01, f_number=8, iso=100)
    return path


def _patch(img, k):
    return img[8:24, 32 * k + 8:32 * k + 24].reshape(-1, 3).mean(axis=0)


def test_grey_reads_grey_and_colours_read_their_reflectance_in_rec709(tmp_path):
    path = _shot(tmp_path)
    cam = read_camera_colour(path)
    np.testing.assert_allclose(cam.color_matrix / cam.color_matrix.max(), MC / MC.max(), rtol=1e-3, atol=1e-4)
    rgb = convert(decode_raw(path), camera_to_space(cam, "rec709"))
    grey = _patch(rgb, 0)
    assert np.ptp(grey) / grey.mean() < 0.01  # channel ratio within 1%
    ref = grey / 0.18  # the white of the scene, from the grey card
    for k, (name, want) in enumerate(PATCHES.items()):
        np.testing.assert_allclose(_patch(rgb, k) / ref, want, rtol=0.01, err_msg=name)


def test_acescg_is_rec709_through_colour_sciences_own_conversion(tmp_path):
    path = _shot(tmp_path)
    cam = read_camera_colour(path)
    img = decode_raw(path)
    rec709 = convert(img, camera_to_space(cam, "rec709"))
    aces = convert(img, camera_to_space(cam, "acescg"))
    peer = colour.RGB_to_RGB(rec709.astype(np.float64), "ITU-R BT.709", "ACEScg", chromatic_adaptation_transform="Bradford")
    np.testing.assert_allclose(_patch(aces, 1), _patch(peer, 1), rtol=2e-3)
    assert chromaticities("rec709")[:2] == pytest.approx((0.64, 0.33)) and chromaticities("camera") is None
