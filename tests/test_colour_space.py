"""The colour space travels: merged EXR attribute -> ``brdfrig fit`` -> BRDF file -> export error record."""

from __future__ import annotations

import json

import numpy as np
import pytest

from brdfrig.cli.main import main
from brdfrig.fit.analytic import Lambertian
from brdfrig.fit.brdffile import brdf_colour_space, save_brdf
from brdfrig.hdr.exr import write_exr
from brdfrig.hdr.sphere import sphere_pixels

ALBEDO = np.array([0.5, 0.4, 0.3])


def _inputs(tmp_path, image_space="rec709", env_space="rec709"):
    """A sky brighter towards +y and a Lambertian sphere under it (ground truth), declared in the given spaces."""
    from brdfrig.fit.groundtruth import render_groundtruth
    from brdfrig.lighting import read_latlong

    env = tmp_path / "sky.exr"
    rows = np.cos(np.linspace(0, np.pi, 16, endpoint=False) + np.pi / 32)  # +y up the rows (MATH.md)
    sky = np.broadcast_to((1.2 + rows)[:, None, None], (16, 32, 3)).astype(np.float32)
    write_exr(env, sky, latlong=True, attributes={"colour_space": env_space})
    img = np.zeros((48, 48, 3), np.float32)
    px = sphere_pixels(img.shape, (24.0, 24.0, 20.0), margin_px=0.0)
    img[px.rows, px.cols] = render_groundtruth(Lambertian(ALBEDO), px.normals, read_latlong(env, 4))
    sphere = tmp_path / "sphere.exr"
    write_exr(sphere, img, attributes={"colour_space": image_space})
    return env, sphere


def test_fit_records_the_inputs_colour_space_and_export_states_it(tmp_path, capsys):
    from brdfrig.export.run import export_brdf
    from brdfrig.fit.brdffile import open_brdf

    env, sphere = _inputs(tmp_path)
    out = tmp_path / "m.brdf.json"
    assert main(["fit", "--scene", str(env), str(sphere), "--model", "diffuse", "--lmax", "4", "--circle",
                 "24,24,20", "--no-progress", "--no-estimate", "-o", str(out)]) == 0
    assert json.loads(out.read_text())["colour_space"] == "rec709" == brdf_colour_space(out)
    np.testing.assert_allclose(open_brdf(out).albedo, ALBEDO, rtol=0.01)
    res = export_brdf(open_brdf(out), "table", tmp_path / "t.csv", source=str(out), colour_space=brdf_colour_space(out),
                      step_deg=30.0)
    assert json.loads(res.record_path.read_text())["colour_space"] == "rec709"


def test_inputs_in_different_colour_spaces_are_refused(tmp_path, capsys):
    env, sphere = _inputs(tmp_path, image_space="acescg")
    assert main(["fit", "--scene", str(env), str(sphere), "--model", "diffuse", "--lmax", "4", "--circle", "24,24,20",
                 "--no-progress", "-o", str(tmp_path / "m.json")]) == 2
    err = capsys.readouterr().err
    assert "different colour spaces" in err and "sphere.exr in acescg" in err and "sky.exr in rec709" in err
    assert not (tmp_path / "m.json").exists()


def test_brdf_file_colour_space_default_old_files_and_bad_values(tmp_path):
    from brdfrig.errors import InputError

    path = save_brdf(tmp_path / "a.json", Lambertian(ALBEDO))
    assert brdf_colour_space(path) == "camera"
    doc = json.loads(path.read_text())
    del doc["colour_space"]  # a file written before the space was recorded: camera RGB
    path.write_text(json.dumps(doc))
    assert brdf_colour_space(path) == "camera"
    with pytest.raises(InputError, match=r"b\.json: unknown colour space 'srgb'"):
        save_brdf(tmp_path / "b.json", Lambertian(ALBEDO), colour_space="srgb")
    assert not (tmp_path / "b.json").exists() and brdf_colour_space(tmp_path / "x.binary") is None


def test_probe_keeps_the_captures_colour_space(tmp_path, capsys):
    from brdfrig.hdr.exr import read_exr
    from test_probe import procedural_map, render_ball

    ball = tmp_path / "ball.exr"
    write_exr(ball, render_ball(procedural_map(16, 32), (64, 64), (32.3, 31.8, 26.0), background=0.3),
              attributes={"colour_space": "acescg"})
    assert main(["probe", str(ball), "--albedo", "0.7", "--width", "32", "-o", str(tmp_path / "env.exr")]) == 0
    attrs = read_exr(tmp_path / "env.exr")[2]
    assert attrs["colour_space"] == "acescg"
    assert attrs["chromaticities"][:2] == pytest.approx((0.713, 0.293), abs=1e-3)  # ACEScg (AP1) red primary
