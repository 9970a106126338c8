"""EXR round trips (OpenEXR), Radiance .hdr reading (OpenImageIO), corrupt files, atomic writes."""

from __future__ import annotations

import numpy as np
import pytest

from brdfrig.hdr.exr import read_exr, read_image, write_exr


def test_round_trip_with_extra_channels_and_attributes(tmp_path):
    rng = np.random.default_rng(0)
    rgb = (rng.random((12, 20, 3)) * 1e4).astype(np.float32)
    var = rng.random((12, 20, 3)).astype(np.float32)
    mask = (rng.random((12, 20)) > 0.5).astype(np.float32)
    attrs = {"circle": [10.5, 6.25, 4.0], "times": [0.001, 0.01], "source": "a.dng"}
    write_exr(tmp_path / "a.exr", rgb, {"variance": var, "mask": mask}, attrs)
    back, extra, meta = read_exr(tmp_path / "a.exr")
    assert back.dtype == np.float32 and np.array_equal(back, rgb)
    assert np.array_equal(extra["variance"], var) and np.array_equal(extra["mask"], mask)
    for key, value in attrs.items():
        assert meta[key] == value
    assert "tool_version" in meta


def test_half_precision_and_single_channel(tmp_path):
    img = np.linspace(0.01, 100, 60, dtype=np.float32).reshape(6, 10)
    write_exr(tmp_path / "y.exr", img, half=True)
    back = read_image(tmp_path / "y.exr")
    assert back.shape == (6, 10, 1)
    assert np.abs(back[:, :, 0] / img - 1).max() < 1e-3  # half: 11-bit mantissa


def test_latlong_flag_is_the_standard_envmap_attribute(tmp_path):
    import OpenEXR

    write_exr(tmp_path / "env.exr", np.ones((4, 8, 3), np.float32), latlong=True)
    with OpenEXR.File(str(tmp_path / "env.exr"), header_only=True) as f:
        assert f.header()["envmap"] == OpenEXR.ENVMAP_LATLONG


def test_radiance_hdr_read_through_openimageio(tmp_path):
    import OpenImageIO as oiio

    truth = (np.random.default_rng(1).random((8, 16, 3)) * 50 + 0.1).astype(np.float32)
    out = oiio.ImageOutput.create(str(tmp_path / "p.hdr"))
    out.open(str(tmp_path / "p.hdr"), oiio.ImageSpec(16, 8, 3, oiio.FLOAT))
    out.write_image(truth)
    out.close()
    back = read_image(tmp_path / "p.hdr")
    assert back.shape == truth.shape
    # RGBE: 8-bit mantissas sharing the exponent of the largest channel of the pixel.
    assert np.all(np.abs(back - truth) <= truth.max(axis=2, keepdims=True) / 128)


def test_real_probes_read(real_probes):
    for path in real_probes:
        img = read_image(path)
        assert img.shape == (128, 256, 3) and np.all(img >= 0) and img.max() > 0


@pytest.mark.parametrize("suffix", [".exr", ".hdr"])
def test_truncated_and_corrupt_files_are_clear_errors(tmp_path, suffix):
    import OpenImageIO as oiio

    good = tmp_path / f"good{suffix}"
    img = np.random.default_rng(2).random((64, 64, 3)).astype(np.float32) + 0.1
    if suffix == ".exr":
        write_exr(good, img)
    else:
        out = oiio.ImageOutput.create(str(good))
        out.open(str(good), oiio.ImageSpec(64, 64, 3, oiio.FLOAT))
        out.write_image(img)
        out.close()
    data = good.read_bytes()
    cut = tmp_path / f"cut{suffix}"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match=f"cut\\{suffix}"):
        read_image(cut)
    junk = tmp_path / f"junk{suffix}"
    junk.write_bytes(b"#?RADIANCE\n" + bytes(range(256)) if suffix == ".hdr" else b"\x76\x2f\x31\x01junk")
    with pytest.raises(ValueError, match=f"junk\\{suffix}"):
        read_image(junk)


def test_nan_pixels_are_rejected_naming_the_file(tmp_path):
    img = np.ones((4, 4, 3), np.float32)
    img[2, 1, 0] = np.nan
    write_exr(tmp_path / "nan.exr", img, allow_nonfinite=True)
    with pytest.raises(ValueError, match=r"nan\.exr.*NaN/inf.*row 2, col 1"):
        read_image(tmp_path / "nan.exr")
    assert np.isnan(read_image(tmp_path / "nan.exr", allow_nonfinite=True)[2, 1, 0])


def test_failed_write_keeps_the_old_file(tmp_path):
    target = tmp_path / "keep.exr"
    write_exr(target, np.full((4, 4, 3), 2.0, np.float32))
    with pytest.raises(ValueError, match="not JSON-serialisable"):
        write_exr(target, np.zeros((4, 4, 3), np.float32), attributes={"bad": object()})
    with pytest.raises(ValueError, match="extra channel 'v'"):
        write_exr(target, np.zeros((4, 4, 3), np.float32), {"v": np.zeros((3, 3))})
    assert np.all(read_image(target) == 2.0)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.exr"]


@pytest.mark.parametrize("bad, what", [(np.nan, "NaN/inf"), (np.inf, "NaN/inf"), (1e39, "NaN/inf"),
                                       (-0.5, "negative radiance")])
def test_writer_refuses_garbage_and_writes_nothing(tmp_path, bad, what):
    """Non-finite (or beyond float32) and negative radiance never reach a file; the old file stays."""
    from brdfrig.errors import InputError

    target = tmp_path / "out.exr"
    write_exr(target, np.full((4, 4, 3), 2.0, np.float32))
    img = np.ones((4, 4, 3))
    img[1, 2, 0] = bad
    with pytest.raises(InputError, match=rf"out\.exr: refusing to write 1 {what} value\(s\) in the image .*row 1, col 2"):
        write_exr(target, img)
    var = np.ones((4, 4, 3))
    var[3, 0, 1] = np.nan
    if what == "NaN/inf":
        with pytest.raises(InputError, match=r"NaN/inf value\(s\) in channel 'variance'"):
            write_exr(target, np.ones((4, 4, 3)), {"variance": var})
    assert np.all(read_image(target) == 2.0)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.exr"]


def test_attributes_are_typed_and_standard_ones_are_openexrs_own(tmp_path):
    """Numbers are double/int attributes, strings strings, only containers JSON text (read by OpenImageIO)."""
    import OpenImageIO as oiio

    attrs = {"rim": 0.97, "count": 3, "source": "/abs/a.dng", "circle": [1.5, 2.0, 3.0], "flag": True, "none": None}
    rec709 = (0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290)
    write_exr(tmp_path / "t.exr", np.ones((4, 4, 3), np.float32), attributes=attrs,
              standard={"expTime": 0.01, "aperture": 8.0, "isoSpeed": 200.0, "chromaticities": rec709})
    spec = oiio.ImageInput.open(str(tmp_path / "t.exr")).spec()
    types = {a.name: str(a.type) for a in spec.extra_attribs}
    assert types["brdfrig:rim"] == "double" and types["brdfrig:count"] == "int"
    assert types["brdfrig:source"] == "string" and types["brdfrig:circle"] == "string"
    assert spec.getattribute("brdfrig:rim") == 0.97 and spec.getattribute("brdfrig:source") == "/abs/a.dng"
    assert spec.getattribute("ExposureTime") == pytest.approx(0.01, rel=1e-7)  # expTime, OIIO's name
    assert spec.getattribute("FNumber") == 8.0 and not any(k.startswith("brdfrig:brdfrig") for k in types)
    _, _, meta = read_exr(tmp_path / "t.exr")
    assert {k: meta[k] for k in attrs} == attrs and type(meta["rim"]) is float and type(meta["count"]) is int
    assert meta["chromaticities"] == pytest.approx(rec709, abs=1e-7) and meta["isoSpeed"] == 200.0


def test_files_of_older_brdfrig_with_json_text_attributes_still_read(tmp_path):
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage,
              "brdfrig:rim": "0.97", "brdfrig:circle": "[1, 2, 3]", "brdfrig:source": '"a.dng"'}
    with OpenEXR.File(header, {c: np.ones((2, 2), np.float32) for c in "RGB"}) as f:
        f.write(str(tmp_path / "old.exr"))
    meta = read_exr(tmp_path / "old.exr")[2]
    assert meta["rim"] == 0.97 and meta["circle"] == [1, 2, 3] and meta["source"] == "a.dng"


@pytest.mark.parametrize("kwargs, match", [({"attributes": {"brdfrig_brdf": "x"}}, "bare name"),
                                           ({"standard": {"expTime": -1.0}}, "'expTime' must be 1 finite positive"),
                                           ({"standard": {"chromaticities": (0.6, 0.3)}}, "'chromaticities' must be 8"),
                                           ({"standard": {"fNumber": 8.0}}, "unknown standard EXR attribute")])
def test_bad_attributes_are_refused_naming_the_key(tmp_path, kwargs, match):
    with pytest.raises(ValueError, match=match):
        write_exr(tmp_path / "x.exr", np.ones((2, 2, 3), np.float32), **kwargs)
    assert not (tmp_path / "x.exr").exists()
