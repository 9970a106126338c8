"""Measured-materials benchmark: the harness's oracle (exact family relights at ~0), its render cache, the CLI."""

from __future__ import annotations

import base64
import html
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from brdfrig.evaluate.measured import Material, make_cache, relight_case, render_truth, CaseSetup
from brdfrig.fit.analytic import GGX, Lambertian
from brdfrig.fit.groundtruth import render_groundtruth
from brdfrig.hdr.sphere import sphere_pixels

SHARED = Path(__file__).resolve().parents[2] / "shared"
PROBES = SHARED / "data" / "probes"
MEASURED = SHARED / "data" / "measured"
GGX_TRUTH = GGX(alpha=0.3, f0=0.04, diffuse=(0.6, 0.4, 0.2))
SMALL = dict(size=24, env_rows=16)


@pytest.fixture
def probes():
    if not all((PROBES / f"{n}.hdr").is_file() for n in ("grace", "ennis", "pisa")):
        pytest.skip("../shared/data/probes is absent")
    return PROBES


def _rms(a, b, w):
    return float(np.sqrt(np.sum(w[:, None] * (a - b) ** 2) / np.sum(w[:, None] * b**2)))


def test_exact_family_relights_at_zero_and_error_is_the_relative_rms(probes, tmp_path):
    """Oracle: GGX rendered, fitted by the microfacet model (which contains GGX): ~0 relighting error;
    the harness's error equals a relative RMS recomputed here from an independent render."""
    case = relight_case(GGX_TRUTH, "microfacet", **SMALL, cache_dir=tmp_path, probe_dir=probes)
    assert set(case.errors) == {"ennis", "pisa"} and case.chosen_model == "microfacet" and case.fit_seconds > 0
    assert max(case.errors.values()) < 2e-3, case.errors
    # one model fitted alone reports no estimate, for any lighting, and says so for each
    assert case.estimate is None and case.lighting_estimates == {"ennis": None, "pisa": None}
    details = case.lighting_estimate_details
    assert set(details) == {"ennis", "pisa"} and all(d.startswith("none: not estimated") for d in details.values())
    # the harness's number for a model that cannot fit GGX (Lambertian-only): the same relative RMS by hand
    setup = CaseSetup(SMALL["size"], relight_probes=("ennis",), env_rows=SMALL["env_rows"], probe_dir=probes)
    truth = render_truth(Material("ggx", brdf=GGX_TRUTH), setup, make_cache(tmp_path))
    from brdfrig.evaluate.measured import fit_and_relight

    diffuse = fit_and_relight(truth, "diffuse")
    px = sphere_pixels((24, 24), (12.0, 12.0, 12.0))
    seen = px.weights > 0
    env = truth.relight["ennis"][0]
    reference = render_groundtruth(GGX_TRUTH, px.normals[seen], env)
    assert diffuse.errors["ennis"] == pytest.approx(_rms(diffuse.relit["ennis"], reference, px.weights[seen]), rel=1e-9)
    assert diffuse.errors["ennis"] > 0.02  # a highlight the diffuse model cannot hold: the harness sees it


def test_noise_and_turned_scenes(probes, tmp_path):
    """Twelve turned scenes are renders under the fit probe turned 30 k degrees about +y; 1% noise is seeded."""
    from brdfrig.evaluate.measured import noisy_scenes
    from brdfrig.fit.rotation import axis_rotation

    setup = CaseSetup(16, relight_probes=("ennis",), env_rows=8, scenes=3, probe_dir=probes)
    brdf = Lambertian(albedo=(0.8, 0.5, 0.2))
    truth = render_truth(Material("lambert", brdf=brdf), setup, make_cache(tmp_path))
    assert len(truth.scenes) == 3
    turned = truth.scenes[0].env.rotated(axis_rotation("y", 60.0))
    np.testing.assert_allclose(truth.scenes[2].env.dirs, turned.dirs, atol=1e-12)
    np.testing.assert_array_equal(truth.scenes[2].radiance, render_groundtruth(brdf, truth.normals, turned))
    a, b = noisy_scenes(truth.scenes, 0.01, seed=3), noisy_scenes(truth.scenes, 0.01, seed=3)
    np.testing.assert_array_equal(a[1].radiance, b[1].radiance)
    rel = a[0].radiance / truth.scenes[0].radiance - 1
    assert 0.008 < np.std(rel) < 0.012 and abs(np.mean(rel)) < 0.002


def test_tilted_scenes_light_from_other_elevations(probes, tmp_path):
    """The tilts arrangement: the fit probe, then the probe tilted 45, -45 and 90 degrees about +x (a rotation
    built here by scipy, to 1e-12); a fifth tilted scene or an unknown arrangement is refused by name."""
    from scipy.spatial.transform import Rotation

    from brdfrig.errors import InputError
    from brdfrig.evaluate.measured import scene_label

    setup = CaseSetup(16, relight_probes=("ennis",), env_rows=8, scenes=4, probe_dir=probes, arrangement="tilts")
    brdf = Lambertian(albedo=(0.8, 0.5, 0.2))
    truth = render_truth(Material("lambert", brdf=brdf), setup, make_cache(tmp_path))
    first = truth.scenes[0].env
    for scene, deg in zip(truth.scenes[1:], (45.0, -45.0, 90.0)):
        rot = Rotation.from_euler("x", deg, degrees=True).as_matrix()
        np.testing.assert_allclose(scene.env.dirs, first.dirs @ rot.T, atol=1e-12)
        np.testing.assert_allclose(scene.radiance, render_groundtruth(brdf, truth.normals, first.rotated(rot)),
                                   rtol=1e-9, atol=1e-12)
    # a 90 degree tilt moves the zenith to the horizon: the sphere's top now sees what its front saw
    assert np.abs(truth.scenes[3].radiance - truth.scenes[0].radiance).max() > 0.05 * truth.scenes[0].radiance.max()
    with pytest.raises(InputError, match="1..4 for tilts"):
        CaseSetup(16, scenes=5, arrangement="tilts")
    with pytest.raises(InputError, match="arrangement"):
        CaseSetup(16, scenes=2, arrangement="twists")
    assert [scene_label(1, "tilts"), scene_label(4, "tilts"), scene_label(12)] == ["1 scene", "4 tilted scenes",
                                                                                  "12 turned scenes"]


def test_a_turned_relight_probe_is_the_probe_rotated(probes, tmp_path):
    """``grace@y180`` is grace turned 180 degrees about +y (scipy's rotation, to 1e-12): the light of each direction
    ``d`` arrives from ``R d`` (a permutation of the cells here, turned samples for a tilt), and its truth is the
    ground truth under that rotation; a malformed turn is refused naming the probe and the form."""
    from scipy.spatial.transform import Rotation

    from brdfrig.errors import InputError
    from brdfrig.evaluate.probes import probe_environment

    plain = probe_environment("grace", 8, probes)
    for degrees in (90.0, 180.0):
        turned = probe_environment(f"grace@y{degrees:g}", 8, probes)
        turn = Rotation.from_euler("y", degrees, degrees=True).as_matrix()
        match = np.argmax(turned.dirs @ (plain.dirs @ turn.T).T, axis=1)  # the plain sample whose light each turned one has
        np.testing.assert_allclose(turned.dirs, plain.dirs[match] @ turn.T, atol=1e-12)
        np.testing.assert_array_equal(turned.radiance, plain.radiance[match])
        assert np.array_equal(np.sort(match), np.arange(len(match)))
    rot = Rotation.from_euler("y", 180.0, degrees=True).as_matrix()
    tilted = probe_environment("grace@x-45.5", 8, probes)
    np.testing.assert_allclose(tilted.dirs, plain.dirs @ Rotation.from_euler("x", -45.5, degrees=True).as_matrix().T,
                               atol=1e-12)
    brdf = GGX_TRUTH
    setup = CaseSetup(16, relight_probes=("ennis", "grace@y180"), env_rows=8, probe_dir=probes)
    truth = render_truth(Material("ggx", brdf=brdf), setup, make_cache(tmp_path))
    _, reference = truth.relight["grace@y180"]
    np.testing.assert_allclose(reference, render_groundtruth(brdf, truth.normals, plain.rotated(rot)), rtol=1e-9, atol=1e-12)
    assert np.abs(reference - truth.scenes[0].radiance).max() > 0.05 * reference.max()
    with pytest.raises(InputError, match=r"'grace@w90' not found .*NAME@AXISDEGREES"):
        probe_environment("grace@w90", 8, probes)


def test_a_relight_probe_lit_as_a_fit_scene_is_refused():
    """Relighting under a fit scene's own lighting measures reproduction: refused naming the probe and the scene
    (grace turned 180 is the 7th of twelve turns, grace itself the first of any setup, -45 degrees the 3rd tilt);
    the same turns where no scene shows them, another probe, or another fit probe are accepted."""
    from brdfrig.errors import InputError

    for kwargs, probe, scene in (({"scenes": 12}, "grace@y180", 7), ({"scenes": 12}, "grace@y-180", 7),
                                 ({"scenes": 2}, "grace@y30", 2), ({}, "grace", 1),
                                 ({"scenes": 3, "arrangement": "tilts"}, "grace@x-45", 3)):
        with pytest.raises(InputError, match=rf"relight probe '{probe}' is the lighting of fit scene {scene} of"):
            CaseSetup(16, relight_probes=("ennis", probe), **kwargs)
    for kwargs, probe in (({"scenes": 12}, "grace@y15"), ({"scenes": 12}, "grace@x90"), ({}, "grace@y180"),
                          ({"scenes": 2, "arrangement": "tilts"}, "grace@x-45"), ({"scenes": 12}, "ennis@y180"),
                          ({"scenes": 12, "fit_probe": "pisa"}, "grace@y180")):
        assert CaseSetup(16, relight_probes=(probe,), **kwargs).relight_probes == (probe,)


def test_cache_returns_the_same_array_and_rerenders_a_damaged_file(probes, tmp_path):
    setup = CaseSetup(16, relight_probes=("ennis",), env_rows=8, probe_dir=probes)
    material = Material("ggx", brdf=GGX_TRUTH)
    cache = make_cache(tmp_path)
    first = render_truth(material, setup, cache)
    assert (cache.misses, cache.hits) == (2, 0) and len(list(tmp_path.glob("gt-*.npy"))) == 2
    again = render_truth(material, setup, cache)
    assert (cache.misses, cache.hits) == (2, 2)
    np.testing.assert_array_equal(again.scenes[0].radiance, first.scenes[0].radiance)
    np.testing.assert_array_equal(again.relight["ennis"][1], first.relight["ennis"][1])
    for f in tmp_path.glob("gt-*.npy"):
        f.write_bytes(f.read_bytes()[:40])  # truncated
    third = render_truth(material, setup, cache)
    assert (cache.misses, cache.hits) == (4, 2)
    np.testing.assert_array_equal(third.scenes[0].radiance, first.scenes[0].radiance)
    # another material is another key
    render_truth(Material("ggx2", brdf=GGX(alpha=0.31, f0=0.04, diffuse=(0.6, 0.4, 0.2))), setup, cache)
    assert cache.misses == 6


def test_cli_two_materials_writes_table_pngs_and_json(probes, tmp_path, capsys):
    if not (MEASURED / "rgl").is_dir():
        pytest.skip("../shared/data/measured is absent")
    from brdfrig.cli.main import main
    from brdfrig.evaluate.measured_report import format_table, result_from_json

    out = tmp_path / "out"
    argv = ["bench", "--measured", "--materials", "rgl/acrylic_felt_green,nielsen/cardboard", "--models", "auto,diffuse",
            "--size", "16", "--env-rows", "16", "--relight-probes", "ennis", "--scenes", "1", "--noise", "0", "--no-progress", "--no-warm-up",
            "--out", str(out)]
    assert main(argv) == 0
    text = capsys.readouterr().out
    num = r"\d+\.\d\d"
    assert re.search(rf"^rgl/acrylic_felt_green\s+{num}\s+{num}\s+\S+", text, re.M), text
    assert re.search(rf"^nielsen/cardboard\*\s+{num}\s+{num}\s+\S+", text, re.M), text
    assert re.search(rf"^\s+1\s+0\s+tuning\s+auto\s+1\s+{num}\s+{num}\s+{num}", text, re.M), text
    assert re.search(rf"^\s+1\s+0\s+held-out\s+diffuse\s+1\s+{num}", text, re.M), text
    for name in ("errors.png", "worst.png", "estimates.png"):
        assert (out / name).stat().st_size > 5_000
    data = json.loads((out / "measured.json").read_text())
    assert len(data["cases"]) == 4 and not any(c["failure"] for c in data["cases"])
    assert {c["material"] for c in data["cases"] if c["held_out"]} == {"nielsen/cardboard"}
    assert all(np.isfinite(c["errors"]["ennis"]) and c["errors"]["ennis"] >= 0 for c in data["cases"])
    # the table's numbers are the JSON's
    auto = next(c for c in data["cases"] if c["material"] == "nielsen/cardboard" and c["model"] == "auto")
    assert re.search(rf"^nielsen/cardboard\*\s+{100 * auto['errors']['ennis']:.2f}\s", text, re.M)
    # report.html: one self-contained page with the three figures and the printed table
    page = (out / "report.html").read_text()
    images = re.findall(r'src="data:image/png;base64,([^"]+)"', page)
    assert len(images) == 3 and all(base64.b64decode(b)[:8] == b"\x89PNG\r\n\x1a\n" for b in images)
    assert "src=\"http" not in page and "<script" not in page
    assert html.escape(format_table(result_from_json(data))) in page
    # the JSON read back prints the same table
    assert format_table(result_from_json(data)) in text
    # every fit is kept as a BRDF file with its report: read back and relit under ennis it gives the recorded
    # error, and auto's report gives the recorded estimate for that lighting
    _check_kept_fits(out, data, probes)
    rendered = tmp_path / "kept.exr"
    assert main(["render", str(out / auto["fit_file"]), "--lighting", str(probes / "ennis.hdr"), "--size", "16",
                 "-o", str(rendered)]) == 0
    capsys.readouterr()
    assert rendered.stat().st_size > 0
    # a second run, on two Dask worker processes, reads every ground truth from the cache and fits (diffuse
    # alone) to the same numbers as this process did
    assert main([a if a != "auto,diffuse" else "diffuse" for a in argv] + ["--workers", "2"]) == 0
    text = capsys.readouterr().out
    assert "0 rendered, 4 from the cache" in text and "summed over 2 worker processes" in text
    again = json.loads((out / "measured.json").read_text())
    assert again["workers"] == 2 and again["phases_seconds"]["CPU, all threads"] > 0
    first = {c["material"]: c["errors"]["ennis"] for c in data["cases"] if c["model"] == "diffuse"}
    assert {c["material"]: c["errors"]["ennis"] for c in again["cases"]} == first


def _check_kept_fits(out: Path, data: dict, probes: Path) -> None:
    """Each case of ``data`` (a 16 px, 16-row run relit under ennis) names its BRDF file under ``out/fits``; the
    file, read back and relit, reproduces the recorded error (and auto's the recorded estimate) to 1e-9."""
    from brdfrig.evaluate.measured import find_materials
    from brdfrig.fit.brdffile import load_brdf
    from brdfrig.fit.relight import lighting_estimate

    setup = CaseSetup(size=16, env_rows=16, relight_probes=("ennis",), probe_dir=probes)
    for case in data["cases"]:
        assert case["fit_file"].startswith(f"fits/{case['material']}/{case['model']}-1scene-noise0")
        truth = render_truth(find_materials([case["material"]])[0], setup, make_cache(out / "gt-cache"))
        env, reference = truth.relight["ennis"]
        brdf, report = load_brdf(out / case["fit_file"])
        assert _rms(brdf.predict(env, truth.normals), reference, truth.weights) == pytest.approx(case["errors"]["ennis"], rel=1e-9)
        if case["model"] == "auto":
            estimate = lighting_estimate(report, env, truth.normals, truth.weights).value
            assert estimate == pytest.approx(case["lighting_estimates"]["ennis"], rel=1e-9)


def test_an_interrupted_run_resumes_to_the_numbers_of_an_uninterrupted_one(probes, tmp_path, capsys):
    """A run stopped after its first material (its checkpoint written) is continued by ``--resume``: the
    finished material is not fitted again and every number equals a run that was never stopped.  Without
    ``--resume``, or with other options, the checkpoint is refused (exit 2) and left as it was.  The resumed
    material's ``auto`` case is relit again from its BRDF file for ``worst.png``: its images reproduce the error
    the first session recorded against the cached reference (1e-9); a file that no longer reads is skipped."""
    if not (MEASURED / "rgl").is_dir():
        pytest.skip("../shared/data/measured is absent")
    from brdfrig.cli.main import main
    from brdfrig.evaluate.measured import find_materials
    from brdfrig.evaluate.measured_report import PARTIAL_JSON, write_partial
    from brdfrig.evaluate.measured_run import run_measured_benchmark

    names = ["rgl/acrylic_felt_green", "nielsen/cardboard"]
    argv = ["bench", "--measured", "--materials", ",".join(names), "--models", "auto,diffuse", "--size", "16",
            "--env-rows", "16", "--relight-probes", "ennis", "--scenes", "1", "--noise", "0", "--no-progress",
            "--no-warm-up", "--cache", str(tmp_path / "cache")]
    assert main(argv + ["--out", str(tmp_path / "whole")]) == 0
    whole = json.loads((tmp_path / "whole" / "measured.json").read_text())

    class Stop(Exception):
        pass

    def stop(result):
        write_partial(result, out)
        raise Stop

    out = tmp_path / "out"
    setup = CaseSetup(16, "grace", ("ennis",), 16, 1, probes)
    with pytest.raises(Stop):
        run_measured_benchmark(find_materials(names), ("auto", "diffuse"), setup, cache_dir=tmp_path / "cache",
                               progress=False, warm_up=False, checkpoint=stop, keep=out)
    checkpoint = (out / PARTIAL_JSON).read_bytes()
    first = {c["material"] for c in json.loads(checkpoint)["cases"]}
    assert len(first) == 1
    capsys.readouterr()
    other = [a.replace("nielsen/cardboard", "nielsen/notebook") for a in argv]
    for args, says in ((argv, "--resume"), (argv + ["--resume", "--noise", "0.01"], "noises"),
                       (argv + ["--resume", "--seed", "1"], "seed"), (other + ["--resume"], "only here: ['nielsen/notebook']")):
        assert main(args + ["--out", str(out)]) == 2
        assert says in capsys.readouterr().err
        assert (out / PARTIAL_JSON).read_bytes() == checkpoint
    assert main(argv + ["--out", str(out), "--resume"]) == 0
    printed = capsys.readouterr().out
    assert "1 material run(s) resumed from an earlier session" in printed
    assert "worst.png: 1 resumed case(s) relit" in printed
    assert not (out / PARTIAL_JSON).exists()
    resumed = json.loads((out / "measured.json").read_text())

    def numbers(run):
        return sorted((c["material"], c["model"], c["chosen_model"], c["errors"]["ennis"], c["estimate"]) for c in run["cases"])

    assert numbers(resumed) == numbers(whole) and len(resumed["cases"]) == 4
    # the resumed material's cases are the checkpoint's, with its fit times (not fitted again)
    saved = {(c["material"], c["model"]): c["fit_seconds"] for c in json.loads(checkpoint)["cases"]}
    fit_seconds = {(c["material"], c["model"]): c["fit_seconds"] for c in resumed["cases"]}
    assert {k: fit_seconds[k] for k in saved} == saved
    # worst.png's images of a resumed case, from its BRDF file and the cached reference
    from brdfrig.evaluate.measured_report import result_from_json
    from brdfrig.evaluate.measured_run import image_resumed

    def read_back():
        run = result_from_json(resumed)
        run.materials, run.setup = find_materials(names), setup
        return run

    again = read_back()
    assert image_resumed(again, out, tmp_path / "cache") == 2  # both auto cases (their files are kept)
    for case in (c for c in again.cases if c.model == "auto"):
        truth = again.truths[(1, case.material)]
        reference = truth.relight["ennis"][1]
        assert _rms(case.relit["ennis"], reference, truth.weights) == pytest.approx(case.errors["ennis"], rel=1e-9)
    again = read_back()
    (out / next(c.fit_file for c in again.cases if c.model == "auto")).write_text("{")
    assert image_resumed(again, out, tmp_path / "cache") == 1
    # nothing left to resume; a damaged checkpoint is named
    assert main(argv + ["--out", str(out), "--resume"]) == 2
    assert "holds no unfinished run" in capsys.readouterr().err
    (out / PARTIAL_JSON).write_bytes(checkpoint[: len(checkpoint) // 2])
    assert main(argv + ["--out", str(out), "--resume"]) == 2
    assert str(out / PARTIAL_JSON) in capsys.readouterr().err


@pytest.mark.parametrize("value, label", [(0.0005, "0.05%"), (0.001, "0.1%"), (0.002, "0.2%"), (0.005, "0.5%"),
                                          (0.01, "1%"), (0.2, "20%"), (1.0, "100%")])
def test_estimate_plot_ticks_keep_errors_below_one_percent(value, label):
    """The estimates plot spans 0.05-100% on log axes (LogLocator 1, 2, 5 per decade): each tick reads its own value."""
    from brdfrig.evaluate.measured_report import percent_tick

    assert percent_tick(value) == label


def test_worst_cases_come_first_and_failed_ones_last():
    """``headline_cases``: ``auto`` at the first scene count and noise level, by error under the headline probe,
    an infinite error first and a failed case (NaN) last; other models and noise levels left out."""
    from brdfrig.evaluate.measured import CaseResult, CaseSetup
    from brdfrig.evaluate.measured_report import headline_cases, worst_model
    from brdfrig.evaluate.measured_run import MeasuredResult

    def case(name, model, noise, error):
        return CaseResult(name, model, model, 1, noise, {"ennis": error, "pisa": 0.0}, 1.0, None, False)

    cases = [case("a", "auto", 0.0, 0.1), case("b", "auto", 0.0, float("nan")), case("c", "auto", 0.0, 0.3),
             case("d", "auto", 0.0, float("inf")), case("e", "auto", 0.01, 0.9), case("f", "diffuse", 0.0, 0.5)]
    result = MeasuredResult(cases, CaseSetup(relight_probes=("ennis", "pisa")), (1,), (0.0, 0.01), ("diffuse", "auto"), [])
    assert worst_model(result) == "auto"
    assert [c.material for c in headline_cases(result, "auto")] == ["d", "c", "a", "b"]


def test_cli_bad_input_exits_2(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "brdfrig", "bench", "--measured", "--materials", "nosuch",
                           "--measured-dir", str(tmp_path), "--out", str(tmp_path / "o")],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and str(tmp_path) in proc.stderr
    proc = subprocess.run([sys.executable, "-m", "brdfrig", "bench", "--measured", "--noise", "nan",
                           "--out", str(tmp_path / "o")], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and "--noise" in proc.stderr
    proc = subprocess.run([sys.executable, "-m", "brdfrig", "bench", "--measured", "--workers", "0",
                           "--out", str(tmp_path / "o")], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and "--workers" in proc.stderr
    proc = subprocess.run([sys.executable, "-m", "brdfrig", "bench", "--measured", "--arrangement", "tilts",
                           "--scenes", "1", "6", "--out", str(tmp_path / "o")], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and "1..4 for tilts" in proc.stderr and "Traceback" not in proc.stderr
    proc = subprocess.run([sys.executable, "-m", "brdfrig", "bench", "--measured", "--scenes", "1", "12",
                           "--relight-probes", "ennis,grace@y180", "--out", str(tmp_path / "o")],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and "'grace@y180' is the lighting of fit scene 7 of 12" in proc.stderr
    assert "Traceback" not in proc.stderr and not (tmp_path / "o").exists()


def _case(material: str, model: str, error: float, estimate: float | None = None, turned: float | None = None) -> dict:
    errors = {"ennis": error} | ({} if turned is None else {"grace@y180": turned})
    return {"material": material, "model": model, "chosen_model": "lobe" if model == "auto" else model, "scenes": 1,
            "noise": 0.0, "held_out": False, "errors": errors, "fit_seconds": 1.0, "estimate": estimate,
            "failure": None}


def _run(cases: list[dict], models: list[str], probes: tuple[str, ...] = ("ennis",)) -> dict:
    names = sorted({c["material"] for c in cases})
    return {"setup": {"size": 16, "fit_probe": "grace", "relight_probes": list(probes), "env_rows": 16, "scene_counts": [1],
                      "noises": [0.0], "models": models},
            "materials": [{"name": n, "path": None, "held_out": False} for n in names], "cases": cases}


def test_summary_counts_picks_only_against_models_that_ran_and_estimates_within_2x(tmp_path):
    """Three materials: auto at 1.05x, 1.2x and 0.9x of the other model's error, estimates at 1.9x, 0.4x and
    none: 2 of 3 picks within 1.1x, 1 of 2 reported estimates within 2x.  Auto alone: no pick is claimed.
    The estimates figure is written, and not when no estimate was reported."""
    from brdfrig.evaluate.measured_report import format_summary, plot_estimates, result_from_json, summarize

    cases = [_case("a", "auto", 0.105, 0.1995), _case("a", "diffuse", 0.1),
             _case("b", "auto", 0.12, 0.048), _case("b", "diffuse", 0.1),
             _case("c", "auto", 0.09), _case("c", "diffuse", 0.1)]
    both = result_from_json(_run(cases, ["auto", "diffuse"]))
    row = next(r for r in summarize(both) if r["model"] == "auto")
    assert (row["auto_within_1.1x_of_best"], row["auto_compared"]) == (2, 3)
    assert (row["estimates_within_2x"], row["estimates_reported"]) == (1, 2)
    assert "within 1.1x of best on 2/3; estimate within 2x on 1/2 reported" in format_summary(both)
    alone = result_from_json(_run([c for c in cases if c["model"] == "auto"], ["auto"]))
    text = format_summary(alone)
    assert "no other model to compare; estimate within 2x on 1/2 reported" in text and "of best" not in text
    assert plot_estimates(both, tmp_path / "e.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    none = result_from_json(_run([c | {"estimate": None} for c in cases], ["auto", "diffuse"]))
    assert plot_estimates(none, tmp_path / "n.png") is None and not (tmp_path / "n.png").exists()


def test_summary_counts_estimates_against_every_relight_probe():
    """Estimates 1%, 4% and 10% for errors 0.2%, 1% and 6% under ennis (within 2x on the third only) and 1.5%, 2.5%
    and 21% under grace turned 180 degrees (within 2x on the first two): 1 of 3 and 2 of 3."""
    from brdfrig.evaluate.measured_report import format_summary, result_from_json, summarize

    cases = [_case("a", "auto", 0.002, 0.01, 0.015), _case("b", "auto", 0.01, 0.04, 0.025),
             _case("c", "auto", 0.06, 0.10, 0.21)]
    result = result_from_json(_run(cases, ["auto"], ("ennis", "grace@y180")))
    row = next(r for r in summarize(result) if r["model"] == "auto")
    assert (row["estimates_within_2x"], row["estimates_within_2x_under"], row["estimates_reported"]) == (1, {"grace@y180": 2}, 3)
    assert "estimate within 2x on 1/3 reported, of the error under grace@y180 on 2" in format_summary(result)


def test_an_estimate_for_the_probe_counts_in_place_of_the_fit_estimate():
    """The same three materials with estimates for each lighting: ennis 0.3%, 2%, 5% (within 2x of 0.2%, 1%, 6% on
    all three; the fit's own estimate on one) and grace turned 5%, 2.5%, 9% (of 1.5%, 2.5%, 21%: the second only).
    The JSON round trip keeps them and how each was obtained."""
    from brdfrig.evaluate.measured_report import result_from_json, result_to_json, summarize

    lit = {"a": (0.003, 0.05), "b": (0.02, 0.025), "c": (0.05, 0.09)}
    cases = [_case("a", "auto", 0.002, 0.01, 0.015), _case("b", "auto", 0.01, 0.04, 0.025),
             _case("c", "auto", 0.06, 0.10, 0.21)]
    cases = [c | {"lighting_estimates": dict(zip(("ennis", "grace@y180"), lit[c["material"]])),
                  "lighting_estimate_details": {"ennis": f"how {c['material']}"}} for c in cases]
    result = result_from_json(_run(cases, ["auto"], ("ennis", "grace@y180")))
    row = next(r for r in summarize(result) if r["model"] == "auto")
    assert (row["estimates_within_2x"], row["estimates_within_2x_under"]) == (3, {"grace@y180": 1})
    again = result_from_json(result_to_json(result))
    assert [c.lighting_estimates for c in again.cases] == [c["lighting_estimates"] for c in cases]
    assert [c.lighting_estimate_details for c in again.cases] == [{"ennis": f"how {m}"} for m in "abc"]


def test_summary_noise_ratios_and_tables_against_microfacet_per_group():
    """Noise: auto's errors 2/4/10% noise-free and 2.2/4/13% with 1% noise on the same three materials: median
    ratio 4/4 = 1x, worst 13/10 = 1.3x, per material 1.1x, 1x, 1.3x (median 1.1x), only the third over 1.2x.
    Groups: the table beats microfacet on the felt (3 vs 5%), loses on the satin (6 vs 4%); the third material
    is in no group."""
    from brdfrig.evaluate.measured_report import format_summary, noise_ratios, result_from_json, table_vs_microfacet

    mats = {"rgl/acrylic_felt_x": (0.02, 0.022, 0.03, 0.05), "rgl/satin_y": (0.04, 0.04, 0.06, 0.04),
            "rgl/plastic_z": (0.10, 0.13, 0.01, 0.02)}
    cases = []
    for name, (clean, noisy, table, mf) in mats.items():
        cases += [_case(name, "auto", clean), _case(name, "auto", noisy) | {"noise": 0.01},
                  _case(name, "bivariate", table), _case(name, "microfacet", mf)]
    run = _run(cases, ["auto", "bivariate", "microfacet"])
    run["setup"]["noises"] = [0.0, 0.01]
    result = result_from_json(run)
    (row,) = noise_ratios(result)
    assert row["n"] == 3 and row["ratio"]["median"] == pytest.approx(1.0) and row["ratio"]["worst"] == pytest.approx(1.3)
    assert row["median_material_ratio"] == pytest.approx(1.1) and row["over_1.2x"] == ["rgl/plastic_z"]
    groups = {r["group"]: r for r in table_vs_microfacet(result)}
    assert set(groups) == {"felts", "satins"}
    assert (groups["felts"]["table_better"], groups["felts"]["n"]) == (1, 1)
    assert (groups["satins"]["table_better"], groups["satins"]["table_median"]) == (0, pytest.approx(0.06))
    text = format_summary(result)
    assert "median 4.00% (1.00x)" in text and "worst 13.00% (1.30x)" in text
    assert "over 1.2x on 1 (rgl/plastic_z 10.00 -> 13.00%)" in text
    assert "bivariate          felts    1 of 1   3.00 vs 5.00" in text
    assert "noise 0.01, bivariate" not in text  # only auto ran with noise: no group rows there
