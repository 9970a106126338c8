"""``brdfrig demo --quick`` end to end in a real subprocess, from a NON-editable install of the package.

The wheel is built from the checkout and installed (without dependencies, which the test
environment has) into a private directory; the demo then runs from an unrelated working
directory, so it finds its configuration as package data, not through the source tree.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """Environment variables that make ``python -m brdfrig`` import a wheel-installed copy."""
    base = tmp_path_factory.mktemp("install")
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q"]
    subprocess.run([*pip, "wheel", "--no-deps", "-w", str(base / "wheel"), str(ROOT)], check=True,
                   capture_output=True, timeout=600)
    (wheel,) = (base / "wheel").glob("brdfrig-*.whl")
    subprocess.run([*pip, "install", "--no-deps", "--target", str(base / "site"), str(wheel)], check=True,
                   capture_output=True, timeout=600)
    return {**os.environ, "PYTHONPATH": str(base / "site")}


def test_installed_copy_is_used_and_reports_its_version(installed, tmp_path):
    code = "import brdfrig, sys; print(brdfrig.__file__); print(brdfrig.__version__)"
    r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=installed, capture_output=True, text=True)
    where, version = r.stdout.split()
    assert Path(where).is_relative_to(installed["PYTHONPATH"]) and not Path(where).is_relative_to(ROOT)
    r = subprocess.run([sys.executable, "-m", "brdfrig", "--version"], cwd=tmp_path, env=installed,
                       capture_output=True, text=True)
    assert r.returncode == 0 and r.stdout.strip() == f"brdfrig {version}" and version != "0+unknown"


def test_quick_demo_runs_end_to_end(installed, tmp_path):
    out = tmp_path / "demo"
    r = subprocess.run([sys.executable, "-m", "brdfrig", "demo", "--quick", "--dir", str(out), "--no-progress"],
                       cwd=tmp_path, env=installed, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    # a fresh install has no compiled kernels: the first computing command says it compiles them
    assert "compiling numerical kernels (numba) once" in r.stderr
    assert "identifiability:" in r.stdout and "session complete" not in r.stderr
    rows = dict(re.findall(r"^\s+(matte|glossy)\s+\w+\s+\S+\s+([\d.]+)%", r.stdout, re.M))
    assert set(rows) == {"matte", "glossy"}, r.stdout
    # reduced session (half-size frame, 4 scenes, lobe model at lmax 4): looser than the full demo's 2% / 8%
    assert float(rows["matte"]) < 4.0 and float(rows["glossy"]) < 10.0

    from brdfrig.session.store import SessionStore
    from brdfrig.fit.brdffile import load_brdf

    store = SessionStore.open(out)
    assert store.verify().passed and store.journal()[-1]["event"] == "fit"
    results = out / "results" / "fit-001"
    for name in ("matte", "glossy"):
        brdf, report = load_brdf(results / f"{name}.brdf.json")
        assert brdf.model == "lobe"
        assert (results / f"{name}.png").read_bytes()[:4] == b"\x89PNG"
        assert str(results / f"{name}.png") in r.stdout
    # stats.json holds the numbers printed: the relighting table (to its printed 0.01%) and the merge counts
    import json

    stats = json.loads((results / "stats.json").read_text())
    table = {row["name"]: row for row in stats["demo"]["relighting_heldout"]}
    for name, printed in rows.items():
        assert abs(100 * table[name]["error"] - float(printed)) <= 0.005 + 1e-9 and table[name]["model"] == "lobe"
    merged, cached = map(int, re.search(r"merged (\d+) brackets \((\d+) reused", r.stdout).groups())
    assert (stats["merged"], stats["merged_from_cache"]) == (merged, cached) and merged > 0
    assert stats["demo"]["captured_files"] == int(re.search(r"captured (\d+) files", r.stdout).group(1))
