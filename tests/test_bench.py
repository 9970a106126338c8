"""Smoke test of ``brdfrig bench --quick`` through a real subprocess, plus the Pareto-front rule."""

from __future__ import annotations

import json
import re
import subprocess
import sys

from fit.bench import MODELS, QUICK, SOLVERS, BenchRow, pareto_front


def test_bench_quick_cli(tmp_path):
    out = tmp_path / "bench"
    proc = subprocess.run(
        [sys.executable, "-m", "capture", "bench", "--quick", "--no-progress", "--out", str(out)],
        capture_output=True, text=True, timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    text = proc.stdout
    assert "lighting = " in text and ("real probes" in text or "procedural" in text)
    # one table row per (linear model, solver, band limit), full+prior once per band limit, one microfacet row
    table = text.split("Solver comparison")[0]
    for model in ("diffuse", "lobe", "full"):
        for solver in SOLVERS:
            for l in QUICK.lmax_values:
                assert re.search(rf"^{re.escape(model)}\s+{solver}\s+{l}\s+1\s+[\d.]+\s+[\d.]+", table, re.M), (model, solver, l)
    for l in QUICK.lmax_values:
        assert re.search(rf"^full\+prior\s+tikhonov\s+{l}\s", table, re.M)
    assert re.search(r"^microfacet\s+-\s+-\s+1\s", table, re.M)
    assert "Headline timings" in text and re.search(rf"full l=p={QUICK.headline_lmax}, joint solver,\s+1 scene", text)
    assert (out / "bench.png").stat().st_size > 10_000
    data = json.loads((out / "bench.json").read_text())
    assert len(data["rows"]) == 3 * 3 * len(QUICK.lmax_values) + len(QUICK.lmax_values) + 1
    assert {r["model"] for r in data["rows"]} == set(MODELS)
    assert not list(out.glob(".*tmp*"))  # no partial files left


def test_pareto_front():
    rows = [BenchRow("m", "s", 1, 1, t, e, None, None) for t, e in [(1, 0.5), (2, 0.6), (3, 0.1), (0.5, 0.9), (4, 0.1)]]
    assert [(r.seconds, r.relight_error) for r in pareto_front(rows)] == [(0.5, 0.9), (1, 0.5), (3, 0.1)]
