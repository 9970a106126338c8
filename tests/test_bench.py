"""``brdfrig bench``: the quick run end to end (subprocess), its timing rule, Pareto front, JSON and render cache."""

from __future__ import annotations

import html
import json
import math
import re
import statistics
import subprocess
import sys

import numpy as np
import pytest

from brdfrig.cli.bench import CachedGroundTruth
from brdfrig.fit.analytic import GGX
from brdfrig.evaluate.bench import (
    FAST_S,
    FULL,
    MODELS,
    QUICK,
    SOLVERS,
    BenchResult,
    BenchRow,
    pareto_front,
    plan_cases,
    result_from_json,
    rows_to_json,
    time_runs,
)
from brdfrig.fit.groundtruth import render_groundtruth
from brdfrig.fit.scene import Environment


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    """``brdfrig bench --quick`` (a subprocess): (its output directory, its stdout)."""
    out = tmp_path_factory.mktemp("bench") / "bench"
    proc = subprocess.run(
        [sys.executable, "-m", "brdfrig", "bench", "--quick", "--no-progress", "--out", str(out)],
        capture_output=True, text=True, timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]  # its run time is a benchmark figure, not a test
    return out, proc.stdout


def test_bench_quick_cli(quick_run):
    out, text = quick_run
    assert "lighting = " in text and ("real probes" in text or "procedural" in text)
    # one table row per (linear model, solver, band limit), full+prior once per band limit, one microfacet row
    table = text.split("Solver comparison")[0]
    num = r"[\d.]+(?:e[+-]\d+)?"
    for model in ("diffuse", "lobe", "full"):
        for solver in SOLVERS:
            for l in QUICK.lmax_values:
                assert re.search(rf"^{re.escape(model)}\s+{solver}\s+{l}\s+1\s+{num}\s+\d+\s+{num}\s", table, re.M), (model, solver, l)
    for l in QUICK.lmax_values:
        assert re.search(rf"^full\+prior\s+tikhonov\s+{l}\s+1\s+{num}\s+\d+\s", table, re.M)
    assert re.search(rf"^microfacet\s+-\s+-\s+1\s+{num}\s+\d+\s", table, re.M)
    assert "Headline timings" in text and re.search(rf"full l=p={QUICK.headline_lmax}, joint solver,\s+1 scene", text)
    written = (out / "bench.png", out / "bench.json", out / "report.html")
    assert f"wrote {written[0].resolve()}, {written[1].resolve()} and {written[2].resolve()}" in text
    assert (out / "bench.png").stat().st_size > 10_000
    assert not list(out.glob(".*tmp*"))  # no partial files left

    data = json.loads((out / "bench.json").read_text())
    got = [(r["model"], r["solver"], r["lmax"], r["scenes"]) for r in data["rows"]]
    assert got == plan_cases(QUICK)  # every case of the quick plan, in table order
    assert len(got) == 3 * 3 * len(QUICK.lmax_values) + len(QUICK.lmax_values) + 1
    assert {r["model"] for r in data["rows"]} == set(MODELS)
    for r in data["rows"]:
        times = r["times"]
        assert all(t > 0 for t in times) and r["seconds"] == statistics.median(times), r
        # the timing rule: a case under FAST_S gets QUICK.runs fits; none gets more
        assert len(times) == QUICK.runs if times[0] < FAST_S else 1 <= len(times) <= QUICK.runs, r
        assert math.isfinite(r["relight_error"]) and r["relight_error"] >= 0
    # the truth is a GGX material: the microfacet model relights it far better than a Lambertian-only model
    err = {(r["model"], r["solver"], r["lmax"]): r["relight_error"] for r in data["rows"]}
    assert err[("microfacet", "-", 0)] < 0.02
    assert min(err[("diffuse", s, l)] for s in SOLVERS for l in QUICK.lmax_values) > 5 * err[("microfacet", "-", 0)]
    head = data["headline"]
    assert head["size"] == QUICK.headline_size and len(head["times_by_scenes"]["1"]) == QUICK.runs
    assert head["seconds_by_scenes"]["1"] == statistics.median(head["times_by_scenes"]["1"]) > 0
    assert set(data["phases_seconds"]) == {"ground truth", "warm-up", "table fits", "headline"}
    # the JSON round-trips through BenchResult
    assert rows_to_json(result_from_json(data)) == data
    # the ground truth was rendered once per lighting (fit, test, warm-up sphere) and cached
    assert len(list((out / "gt-cache").glob("gt-*.npy"))) == 3
    assert "ground truth: 3 rendered, 0 from" in text



def test_bench_report_renders_in_chromium(quick_run, browser):
    """report.html holds the Pareto figure and every printed table, and a browser draws it (not a blank page)."""
    out, text = quick_run
    pixels, dom = browser(out / "report.html")
    assert np.mean(np.any(pixels < 0.9, axis=-1)) > 0.02  # the figure and the tables ink 4.5% of this window
    assert np.mean(np.ptp(pixels, axis=-1) > 0.15) > 3e-4  # the figure's coloured markers (0.13%; text is grey)
    assert dom.count("<img") == 1 and "Pareto" in dom
    for heading in ("Time against error", "Solvers", "Headline timings", "Where the time went"):
        assert f"<h2>{heading}</h2>" in dom
    table = text.split("Solver comparison")[0].strip().splitlines()[-1]  # the table's last row, as printed
    assert html.escape(table) in dom

def _dominated(r: BenchRow, rows: list[BenchRow]) -> bool:
    return any(o.seconds <= r.seconds and o.relight_error <= r.relight_error
               and (o.seconds < r.seconds or o.relight_error < r.relight_error) for o in rows)


def test_pareto_front():
    rows = [BenchRow("m", "s", 1, 1, t, e, None, None) for t, e in [(1, 0.5), (2, 0.6), (3, 0.1), (0.5, 0.9), (4, 0.1)]]
    assert [(r.seconds, r.relight_error) for r in pareto_front(rows)] == [(0.5, 0.9), (1, 0.5), (3, 0.1)]
    rng = np.random.default_rng(3)
    for _ in range(20):  # against the brute-force definition: exactly the non-dominated rows
        rows = [BenchRow("m", "s", 1, 1, float(t), float(e), None, None) for t, e in rng.lognormal(size=(40, 2))]
        front = pareto_front(rows)
        assert {id(r) for r in front} == {id(r) for r in rows if not _dominated(r, rows)}
        assert [r.seconds for r in front] == sorted(r.seconds for r in front)


def test_time_runs_rule():
    """The rule on a simulated clock: each fit advances it by exactly its cost (no real timing)."""
    now = [0.0]
    calls = []

    def fit(seconds):
        def run():
            now[0] += seconds
            calls.append(seconds)
            return len(calls)
        return run

    clock = lambda: now[0]  # noqa: E731
    times, last = time_runs(fit(0.001), 3, lambda s: False, fast_s=0.05, clock=clock)  # fast: always 3 runs
    assert times == pytest.approx([0.001] * 3) and last == 3
    asked = []
    times, _ = time_runs(fit(0.06), 3, lambda s: asked.append(s) or False, fast_s=0.05, clock=clock)  # slow, no budget
    assert times == pytest.approx([0.06]) and asked == pytest.approx([0.06])
    times, _ = time_runs(fit(0.06), 3, lambda s: True, fast_s=0.05, clock=clock)  # slow, budget allows: 3 runs
    assert times == pytest.approx([0.06] * 3)


def test_plan_covers_every_row():
    cases = plan_cases(FULL)
    assert len(cases) == len(set(cases)) == 3 * 3 * 12 * 2 + 12 * 2 + 2
    for n in (1, 12):
        for l in range(1, 13):
            for m in ("diffuse", "lobe", "full"):
                assert {s for mm, s, ll, nn in cases if (mm, ll, nn) == (m, l, n)} == set(SOLVERS)
            assert ("full+prior", "tikhonov", l, n) in cases
        assert ("microfacet", "-", 0, n) in cases


def test_result_json_round_trip():
    rows = [BenchRow("full", "joint", 3, 12, 0.2, 0.01, 22, 1e3, (0.3, 0.2, 0.1)),
            BenchRow("microfacet", "-", 0, 1, 2.5, 0.002, None, None, (2.5,))]
    result = BenchResult(rows, {1: 0.5, 12: 4.0}, 512, 8, "maps", {1: (0.5, 0.6, 0.4), 12: (4.0, 4.1, 3.9)},
                         {"table fits": 10.0}, {"qr": 3.0})
    data = json.loads(json.dumps(rows_to_json(result)))
    assert result_from_json(data) == result


def _tiny_env(seed: int) -> Environment:
    rng = np.random.default_rng(seed)
    dirs = rng.standard_normal((300, 3))
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    return Environment(dirs, rng.uniform(0, 2, (300, 3)), np.full(300, 4 * np.pi / 300))


def test_groundtruth_cache(tmp_path):
    brdf = GGX(alpha=0.3, f0=0.04, diffuse=(0.6, 0.4, 0.2))
    normals = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, -0.6, 0.8]])
    env = _tiny_env(0)
    cache = CachedGroundTruth(tmp_path / "gt")
    first = cache(brdf, normals, env)
    np.testing.assert_array_equal(first, render_groundtruth(brdf, normals, env))
    files = list((tmp_path / "gt").glob("gt-*.npy"))
    assert len(files) == 1 and (cache.misses, cache.hits) == (1, 0)
    np.testing.assert_array_equal(cache(brdf, normals, env), first)
    assert (cache.misses, cache.hits) == (1, 1)
    # any changed input is a new key: never a stale render
    brighter = Environment(env.dirs, env.radiance * 1.001, env.solid_angle)
    np.testing.assert_array_equal(cache(brdf, normals, brighter), render_groundtruth(brdf, normals, brighter))
    rougher = GGX(alpha=0.31, f0=0.04, diffuse=(0.6, 0.4, 0.2))
    np.testing.assert_array_equal(cache(rougher, normals, env), render_groundtruth(rougher, normals, env))
    np.testing.assert_array_equal(cache(brdf, normals[:2], env), first[:2])
    assert cache.misses == 4 and len(list((tmp_path / "gt").glob("gt-*.npy"))) == 4
    # a damaged cache file is rendered again, not trusted
    files[0].write_bytes(b"not a numpy file")
    np.testing.assert_array_equal(cache(brdf, normals, env), first)
    assert cache.misses == 5 and np.load(files[0]).shape == (3, 3)


@pytest.mark.parametrize("budget", ["0", "-3", "nan"])
def test_bad_budget(budget, tmp_path):
    proc = subprocess.run([sys.executable, "-m", "brdfrig", "bench", "--quick", "--budget", budget, "--out", str(tmp_path)],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and "--budget" in proc.stderr and not list(tmp_path.iterdir())
