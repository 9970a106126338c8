"""``--json`` on fit, merge, probe and render: one JSON document on stdout holding every number the text prints.

The oracle is the command's own text output: every number it prints (paths aside) must be found in the JSON
document (as a value, x100 for percentages, or inside a string value), to the printed precision.
"""

from __future__ import annotations

import json
import re

import numpy as np

from brdfrig.cli.main import main
from brdfrig.hdr.exr import write_exr

NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")


def _numbers(doc) -> list[float]:
    """Every number in a JSON document, also those written inside its strings."""
    if isinstance(doc, dict):
        return [v for x in doc.values() for v in _numbers(x)]
    if isinstance(doc, list):
        return [v for x in doc for v in _numbers(x)]
    if isinstance(doc, bool) or doc is None:
        return []
    if isinstance(doc, (int, float)):
        return [float(doc)]
    return [float(t) for t in NUMBER.findall(str(doc))]


def _resolution(token: str) -> float:
    """Half a unit in the last printed digit of ``token``."""
    mantissa, _, exp = token.lower().partition("e")
    decimals = len(mantissa.split(".")[1]) if "." in mantissa else 0
    return 0.5 * 10.0 ** (int(exp or 0) - decimals)


def assert_json_covers_text(text: str, stdout_json: str) -> dict:
    doc = json.loads(stdout_json)  # one document and nothing else
    values = np.array(_numbers(doc))
    words = [w for w in text.split() if "/" not in w]  # paths hold digits of temporary directory names
    for token in NUMBER.findall(" ".join(words)):
        x, tol = float(token), _resolution(token) * 1.0001 + 1e-12
        found = np.any(np.abs(values - x) <= tol) or np.any(np.abs(100 * values - x) <= tol)
        assert found, f"printed {token} is not in the JSON document"
    return doc


def _both(args, capsys):
    """Run a command as text and as --json (outputs replaced); (text, json stdout)."""
    assert main(args) == 0
    text = capsys.readouterr().out
    assert main(args + ["--json"]) == 0
    return text, capsys.readouterr().out


def test_merge_json(tmp_path, colour_chart, capsys):
    files = [colour_chart.write(tmp_path / f"f{k}.dng", exposure=e, exposure_time_s=0.01 * e)
             for k, e in enumerate((0.25, 1.0, 4.0))]
    text, js = _both(["merge", *map(str, files), "-o", str(tmp_path / "hdr.exr"), "--colour-space", "rec709"], capsys)
    doc = assert_json_covers_text(text, js)
    assert doc["frames"] == 3 and doc["width"] == 128 and doc["colour_space"] == "rec709"


def _sky(tmp_path):
    rows = np.cos(np.linspace(0, np.pi, 16, endpoint=False) + np.pi / 32)
    path = tmp_path / "sky.exr"
    write_exr(path, np.broadcast_to((1.2 + rows)[:, None, None], (16, 32, 3)).astype(np.float32), latlong=True)
    return path


def test_render_json(tmp_path, capsys):
    from brdfrig.fit.analytic import Lambertian
    from brdfrig.fit.brdffile import save_brdf

    brdf = save_brdf(tmp_path / "w.brdf.json", Lambertian(np.array([0.5, 0.4, 0.3])))
    text, js = _both(["render", str(brdf), "--lighting", str(_sky(tmp_path)), "--size", "16",
                      "-o", str(tmp_path / "r.exr")], capsys)
    doc = assert_json_covers_text(text, js)
    assert doc["size"] == 16 and doc["output"] == str((tmp_path / "r.exr").resolve())


def test_probe_json(tmp_path, capsys):
    from test_probe import procedural_map, render_ball

    ball = tmp_path / "ball.exr"
    write_exr(ball, render_ball(procedural_map(16, 32), (64, 64), (32.3, 31.8, 26.0), background=0.3))
    text, js = _both(["probe", str(ball), "--albedo", "0.7", "--width", "32", "--camera-mask", "5",
                      "-o", str(tmp_path / "env.exr")], capsys)
    doc = assert_json_covers_text(text, js)
    assert doc["width"] == 32 and doc["height"] == 16 and 0 < doc["unseen_fraction"] < 1


def test_fit_json(tmp_path, capsys):
    from test_colour_space import _inputs

    env, sphere = _inputs(tmp_path)
    text, js = _both(["fit", "--scene", str(env), str(sphere), "--model", "diffuse", "--lmax", "4", "--circle",
                      "24,24,20", "--no-progress", "--no-estimate", "-o", str(tmp_path / "m.brdf.json")], capsys)
    doc = assert_json_covers_text(text, js)
    assert doc["model"] == "diffuse" and doc["colour_space"] == "rec709" and doc["report"]["pixels"]["used"] > 0
