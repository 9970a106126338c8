"""``brdfrig fit`` and ``brdfrig render`` end to end on EXR files, and their bad-input errors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from brdfrig.cli.main import main
from brdfrig.fit.analytic import Lambertian
from brdfrig.fit.brdffile import load_brdf
from brdfrig.fit.groundtruth import render_groundtruth
from brdfrig.hdr.exr import read_image, write_exr
from brdfrig.hdr.sphere import sphere_pixels
from test_fit_scenes import ALBEDO, probe_environment

SIZE = 64
IMAGE, CIRCLE = 80, (40.0, 40.0, 30.0)  # the sample photo: a sphere with a dark margin around it


def _latlong_image(env, rows=32):
    return env.radiance.reshape(rows, 2 * rows, -1).astype(np.float32)


@pytest.fixture
def files(tmp_path, real_probes):
    """EXR lighting maps (grace, pisa) and the 64 px image of a Lambertian sphere under grace."""
    by_name = {p.stem: p for p in real_probes}
    fit_env, test_env = probe_environment(by_name["grace"]), probe_environment(by_name["pisa"])
    write_exr(tmp_path / "grace.exr", _latlong_image(fit_env))
    write_exr(tmp_path / "pisa.exr", _latlong_image(test_env))
    px = sphere_pixels((IMAGE, IMAGE), CIRCLE, margin_px=0.0)
    img = np.zeros((IMAGE, IMAGE, 3), np.float32)
    img[px.rows, px.cols] = render_groundtruth(Lambertian(ALBEDO), px.normals, fit_env)
    write_exr(tmp_path / "sphere.exr", img)
    return tmp_path, test_env


def test_fit_then_render_relights_the_sphere(files, capsys):
    d, test_env = files
    out = d / "m.brdf.json"
    code = main(["fit", "--scene", str(d / "grace.exr"), str(d / "sphere.exr"), "--model", "diffuse",
                 "--lmax", "8", "--no-progress", "--no-estimate", "--figure", str(d / "fit.png"), "-o", str(out)])
    assert code == 0
    assert (d / "fit.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    text = capsys.readouterr().out
    assert "identifiability" in text and "model: diffuse" in text
    brdf, report = load_brdf(out)
    np.testing.assert_allclose(brdf.albedo, ALBEDO, rtol=0.01)
    assert report["identifiability"]["models"]["diffuse"]["determined"]

    code = main(["render", str(out), "--lighting", str(d / "pisa.exr"), "--size", str(SIZE), "-o", str(d / "r.exr")])
    assert code == 0
    rendered = read_image(d / "r.exr")
    px = sphere_pixels((SIZE, SIZE), (SIZE / 2, SIZE / 2, SIZE / 2), margin_px=0.0)
    inner = px.normals[:, 2] >= math.cos(math.radians(80))
    truth = render_groundtruth(Lambertian(ALBEDO), px.normals[inner], test_env)
    got = rendered[px.rows[inner], px.cols[inner]]
    assert np.sqrt(np.sum((got - truth) ** 2) / np.sum(truth**2)) < 0.01
    assert np.all(rendered[0, 0] == 0)


def test_fit_detects_the_circle_when_not_given(files):
    d, _ = files
    out = d / "auto.json"
    assert main(["fit", "--scene", str(d / "grace.exr"), str(d / "sphere.exr"), "--model", "diffuse",
                 "--lmax", "4", "--no-progress", "--no-estimate", "-o", str(out)]) == 0
    _, report = load_brdf(out)
    assert report["pixels"]["used"] > 0.8 * math.pi * CIRCLE[2] ** 2 * math.sin(math.radians(80)) ** 2
    cx, cy, r = report_circle = _circle(out)
    assert abs(cx - CIRCLE[0]) < 0.5 and abs(cy - CIRCLE[1]) < 0.5 and abs(r - CIRCLE[2]) < 0.5, report_circle


def _circle(path):
    import json

    return json.loads(path.read_text())["provenance"]["inputs"][0]["circle"]


def _bad(d, extra, capsys, match):
    before = set(d.iterdir())
    code = main(["fit", "--scene", str(d / "grace.exr"), str(d / extra.pop(0)), "--no-progress", "-o", str(d / "o.json"), *extra])
    assert code == 2
    assert match in capsys.readouterr().err
    assert set(d.iterdir()) == before  # no partial output


def test_bad_inputs_are_clear_errors_without_output(files, capsys):
    d, _ = files
    img = read_image(d / "sphere.exr")
    write_exr(d / "grey.exr", img[:, :, :1])
    _bad(d, ["grey.exr", "--circle", "40,40,30"], capsys, "channel")
    _bad(d, ["sphere.exr", "--circle", "60,40,30"], capsys, "outside")
    _bad(d, ["sphere.exr", "--circle", "40,40,30", "--lmax", "20"], capsys, "supports bands up to 15")
    _bad(d, ["sphere.exr", "--circle", "40,40"], capsys, "--circle")
    nan = img.copy()
    nan[30, 30] = np.nan
    write_exr(d / "nan.exr", nan, allow_nonfinite=True)
    _bad(d, ["nan.exr", "--circle", "40,40,30"], capsys, "nan.exr")


def test_fit_from_a_mirror_ball_probe(files):
    """--probe-scene: the lighting comes from a mirror-ball image (rendered here from the lat-long map)."""
    from brdfrig.hdr.envmap import mirrorball_directions, sample_latlong

    d, _ = files
    grace = read_image(d / "grace.exr")
    ball_circle = (70.0, 70.0, 60.0)
    dirs, _, inside = mirrorball_directions((140, 140), ball_circle)
    ball = np.zeros((140, 140, 3), np.float32)
    ball[inside] = sample_latlong(grace, dirs[inside])
    write_exr(d / "ball.exr", ball)
    out = d / "probe.json"
    assert main(["fit", "--probe-scene", str(d / "ball.exr"), str(d / "sphere.exr"), "--model", "diffuse",
                 "--probe-circle", "70,70,60", "--lmax", "6", "--no-progress", "--no-estimate", "-o", str(out)]) == 0
    brdf, report = load_brdf(out)
    assert report["n_scenes"] == 1
    assert report["relight"]["value"] is None and report["candidates"].keys() == {"diffuse"}  # --no-estimate: no reference fits
    # the ball's rim mask leaves a cone behind it unseen and the map is resampled: a few percent
    np.testing.assert_allclose(brdf.albedo, ALBEDO, rtol=0.05)


def test_render_estimates_the_error_for_its_lighting(files, capsys):
    """A one-image auto fit keeps bivariate+measured's resampled tables; render turns them into an estimate for the
    lighting it renders under (one that differs between lightings), printed with how it was obtained."""
    import json

    from brdfrig.fit.bivariate import RESAMPLES
    from brdfrig.fit.relight import FOR_LIGHTING

    d, _ = files
    out = d / "auto.brdf.json"
    assert main(["fit", "--scene", str(d / "grace.exr"), str(d / "sphere.exr"), "--no-progress", "-o", str(out)]) == 0
    _, report = load_brdf(out)
    tables = np.asarray(report["candidates"]["bivariate+measured"]["fit_report"]["resampled_tables"])
    assert tables.shape[:3] == (RESAMPLES, 3, 2) and np.all(tables >= 0)
    capsys.readouterr()
    estimates = {}
    for lighting in ("grace", "pisa"):
        assert main(["render", str(out), "--lighting", str(d / f"{lighting}.exr"), "--size", "32",
                     "-o", str(d / f"{lighting}-r.exr"), "--json"]) == 0
        estimates[lighting] = json.loads(capsys.readouterr().out)["relight_estimate"]
    assert all(e["method"] == FOR_LIGHTING and 0 < e["value"] < 1 for e in estimates.values()), estimates
    assert abs(math.log(estimates["grace"]["value"] / estimates["pisa"]["value"])) > 0.01, estimates
    assert main(["render", str(out), "--lighting", str(d / "pisa.exr"), "--size", "32", "-o", str(d / "p2.exr")]) == 0
    assert "estimated relighting error under this lighting: " in capsys.readouterr().out
