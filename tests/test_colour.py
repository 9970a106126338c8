"""Camera RGB -> Rec.709 / ACEScg from a DNG's own colour metadata, on a simulated camera of known colour matrix.

The oracle is the forward model of the ``colour_chart`` fixture (tests/conftest.py): patches of known linear
Rec.709 reflectance under D65 turned into XYZ by colour-science's BT.709 matrix, then into camera RGB by the
camera's matrix, mosaicked and written as a DNG whose ColorMatrix1 and AsShotNeutral describe that camera.
"""

from __future__ import annotations

import numpy as np
import pytest

from brdfrig.hdr.colour import camera_to_space, chromaticities, convert, read_camera_colour
from brdfrig.hdr.raw import decode_raw

colour = pytest.importorskip("colour")


def test_grey_reads_grey_and_colours_read_their_reflectance_in_rec709(tmp_path, colour_chart):
    path = colour_chart.write(tmp_path / "patches.dng")
    cam = read_camera_colour(path)
    mc = np.array(colour_chart.mc)
    np.testing.assert_allclose(cam.color_matrix / cam.color_matrix.max(), mc / mc.max(), rtol=1e-3, atol=1e-4)
    rgb = convert(decode_raw(path), camera_to_space(cam, "rec709"))
    grey = colour_chart.patch(rgb, 0)
    assert np.ptp(grey) / grey.mean() < 0.01  # channel ratio within 1%
    ref = grey / 0.18  # the white of the scene, from the grey card
    for k, (name, want) in enumerate(colour_chart.patches.items()):
        np.testing.assert_allclose(colour_chart.patch(rgb, k) / ref, want, rtol=0.01, err_msg=name)


def test_acescg_is_rec709_through_colour_sciences_own_conversion(tmp_path, colour_chart):
    path = colour_chart.write(tmp_path / "patches.dng")
    cam = read_camera_colour(path)
    img = decode_raw(path)
    rec709 = convert(img, camera_to_space(cam, "rec709"))
    aces = convert(img, camera_to_space(cam, "acescg"))
    peer = colour.RGB_to_RGB(rec709.astype(np.float64), "ITU-R BT.709", "ACEScg", chromatic_adaptation_transform="Bradford")
    np.testing.assert_allclose(colour_chart.patch(aces, 1), colour_chart.patch(peer, 1), rtol=2e-3)
    assert chromaticities("rec709")[:2] == pytest.approx((0.64, 0.33)) and chromaticities("camera") is None


def test_merge_colour_space_rec709_grey_card_reads_grey(tmp_path, colour_chart, capsys):
    """A DNG bracket through ``brdfrig merge --colour-space rec709``: grey grey, patches at their reflectance."""
    from brdfrig.cli.main import main
    from brdfrig.hdr.exr import read_exr

    files = [colour_chart.write(tmp_path / f"f{k}.dng", exposure=e, exposure_time_s=0.01 * e)
             for k, e in enumerate((0.25, 1.0, 4.0))]  # the longest frame clips the white and orange patches
    out = tmp_path / "hdr.exr"
    assert main(["merge", *map(str, files), "-o", str(out), "--colour-space", "rec709"]) == 0
    assert "colour space rec709" in capsys.readouterr().out
    rgb, extra, attrs = read_exr(out)
    assert attrs["colour_space"] == "rec709" and np.shape(attrs["colour_matrix"]) == (3, 3)
    assert attrs["chromaticities"] == pytest.approx((0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290), abs=1e-4)
    grey = colour_chart.patch(rgb, 0)
    assert np.ptp(grey) / grey.mean() < 0.01  # channel ratio within 1%
    for k, (name, want) in enumerate(colour_chart.patches.items()):
        np.testing.assert_allclose(colour_chart.patch(rgb, k) / (grey / 0.18), want, rtol=0.01, err_msg=name)
    # camera (the default) keeps camera RGB: the same bracket, unconverted, is not grey and has no chromaticities
    assert main(["merge", *map(str, files), "-o", str(tmp_path / "cam.exr")]) == 0
    cam, _, cam_attrs = read_exr(tmp_path / "cam.exr")
    assert cam_attrs["colour_space"] == "camera" and "chromaticities" not in cam_attrs
    assert np.ptp(colour_chart.patch(cam, 0)) / colour_chart.patch(cam, 0).mean() > 0.05


def test_colour_space_of_tiff_frames_is_refused(tmp_path):
    from brdfrig.errors import InputError
    from brdfrig.hdr.bracket import MergePolicy, merge_files

    with pytest.raises(InputError, match=r"a\.tif: colour space 'rec709' needs raw frames"):
        merge_files([tmp_path / "a.tif", tmp_path / "b.tif"], MergePolicy(colour_space="rec709"), times=[1, 2])
