"""``brdfrig demo --quick`` end to end in a real subprocess (the full demo is run by the coordinator)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_quick_demo_runs_end_to_end(tmp_path):
    out = tmp_path / "demo"
    r = subprocess.run([sys.executable, "-m", "capture", "demo", "--quick", "--dir", str(out), "--no-progress"],
                       cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "identifiability:" in r.stdout and "session complete" not in r.stderr
    rows = dict(re.findall(r"^\s+(matte|glossy)\s+\w+\s+\S+\s+([\d.]+)%", r.stdout, re.M))
    assert set(rows) == {"matte", "glossy"}, r.stdout
    # reduced session (half-size frame, 4 scenes, lobe model at lmax 4): looser than the full demo's 2% / 8%
    assert float(rows["matte"]) < 4.0 and float(rows["glossy"]) < 10.0

    from capture.store import SessionStore
    from fit.brdffile import load_brdf

    store = SessionStore.open(out)
    assert store.verify().passed and store.journal()[-1]["event"] == "fit"
    results = out / "results" / "fit-001"
    for name in ("matte", "glossy"):
        brdf, report = load_brdf(results / f"{name}.brdf.json")
        assert brdf.model == "lobe"
        assert (results / f"{name}.png").read_bytes()[:4] == b"\x89PNG"
        assert str(results / f"{name}.png") in r.stdout
