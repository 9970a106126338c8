"""``brdfrig refit --batch``: many stored sessions refit as Dask tasks, recorded once each in the catalogue.

Sessions come from the simulated bench (the quick demo's plan, two scenes, a reduced frame);
the cluster is real: a ``LocalCluster`` of worker processes, and a separately started
``dask scheduler`` + ``dask worker`` on localhost.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from brdfrig.cli.demo import DEMO_CONFIG, _quick
from brdfrig.fit.brdffile import load_brdf
from brdfrig.session.config import load_session_config, session_config_from_dict
from brdfrig.session.library import Library

pytest.importorskip("dask.distributed")

N_SESSIONS = 4
N_KILLED = 20
"""Sessions of the worker-kill test (the issue's 20); the other tests use the first N_SESSIONS."""
PRESET = ["--model", "diffuse", "--lmax", "3"]
BATCH = [*PRESET, "--no-figures"]
"""Batch refits skip the figures and HTML report (the single refit they are compared with draws them)."""


@pytest.fixture(scope="module")
def stored(tmp_path_factory):
    """A directory of N_KILLED small simulated sessions (two seeds, copied), none fitted yet."""
    from brdfrig.devices import open_rig
    from brdfrig.session.runner import run_session

    root = tmp_path_factory.mktemp("sessions")
    base = json.loads(json.dumps(_quick(load_session_config(DEMO_CONFIG)).to_dict()))  # TOML-like lists
    made = []
    for seed in (1, 2):
        doc = {"session": {"name": f"sim-{seed}"}, "rig": {**base["rig"], "sim": {**base["rig"]["sim"], "seed": seed}},
               "plan": {**{k: v for k, v in base["plan"].items() if v is not None and k not in ("probe_rotations", "scenes")},
                        "scene_angles": [0.0, 90.0]},
               "fit": base["fit"]}
        out = root / f"s{seed}"
        run_session(session_config_from_dict(doc, "test"), out, rig_factory=open_rig, prompt=None, progress=False)
        made.append(out)
    for k in range(N_KILLED - len(made)):
        shutil.copytree(made[k % len(made)], root / f"t{k:02d}")  # after s1, s2 in name order
    return root


def _brdfrig(*args, env=None, timeout=300):
    return subprocess.run([sys.executable, "-m", "brdfrig", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, env=env)


def _fresh(stored, tmp_path, count: int = N_SESSIONS) -> Path:
    """A copy of the first ``count`` stored sessions."""
    dst = tmp_path / "root"
    for session in sorted(stored.iterdir())[:count]:
        shutil.copytree(session, dst / session.name)
    return dst


def _numbers(obj) -> list[float]:
    """Every number in a JSON value, in order (the fitted BRDF's parameters)."""
    if isinstance(obj, dict):
        return [v for k in sorted(obj) for v in _numbers(obj[k])]
    if isinstance(obj, list):
        return [v for item in obj for v in _numbers(item)]
    return [float(obj)] if isinstance(obj, (int, float)) and not isinstance(obj, bool) else []


def _coefficients(path: Path) -> np.ndarray:
    brdf, _ = load_brdf(path)
    return np.array(_numbers(brdf.to_dict()))


def _check_batch(root: Path, lib_path: Path, count: int = N_SESSIONS) -> None:
    """Each session: exactly one committed fit, no staging left, one catalogue row per sample."""
    sessions = sorted(p.parent for p in root.rglob("session.json"))
    assert len(sessions) == count
    for s in sessions:
        assert [p.name for p in (s / "results").iterdir()] == ["fit-001"], s
    with Library(lib_path) as lib:
        fits = lib.fits()
        assert lib.integrity_check() == "ok"
    assert len(fits) == 2 * count  # two samples each, none twice
    assert len({(f.results_dir, f.sample) for f in fits}) == len(fits)


def test_batch_on_a_local_cluster_equals_single_refits(stored, tmp_path):
    root = _fresh(stored, tmp_path)
    lib = tmp_path / "lib.sqlite"
    r = _brdfrig("refit", "--batch", root, "--workers", "2", "--library", lib, "--no-progress", *BATCH)
    assert r.returncode == 0, r.stderr
    assert f"{N_SESSIONS} session(s) refit, 0 failed" in r.stdout
    _check_batch(root, lib)
    alone = tmp_path / "alone"
    shutil.copytree(stored / "s1", alone)
    r = _brdfrig("refit", alone, "--library", lib, "--no-progress", *PRESET)
    assert r.returncode == 0, r.stderr
    drawn = sorted(p.name for p in (alone / "results" / "fit-001").iterdir() if p.suffix in (".png", ".html"))
    assert drawn == ["glossy.png", "matte.png", "report.html"]
    assert not [p for p in (root / "s1" / "results" / "fit-001").iterdir() if p.suffix in (".png", ".html")]
    for sample in ("matte", "glossy"):
        a = _coefficients(alone / "results" / "fit-001" / f"{sample}.brdf.json")
        b = _coefficients(root / "s1" / "results" / "fit-001" / f"{sample}.brdf.json")
        np.testing.assert_allclose(b, a, rtol=1e-10, atol=1e-14)


def _workers_of(pid: int) -> list[int]:
    import psutil

    return [c.pid for c in psutil.Process(pid).children(recursive=True)
            if any("distributed" in part or "spawn_main" in part for part in c.cmdline())]


def test_a_killed_worker_costs_nothing(stored, tmp_path):
    import psutil

    root = _fresh(stored, tmp_path, N_KILLED)
    lib = tmp_path / "lib.sqlite"
    p = subprocess.Popen([sys.executable, "-m", "brdfrig", "refit", "--batch", str(root), "--workers", "2",
                          "--library", str(lib), "--no-progress", *BATCH],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    killed = None
    deadline = time.monotonic() + 120
    while killed is None and time.monotonic() < deadline and p.poll() is None:
        staging = list(root.glob("*/results/.staging-*"))
        if staging:  # a fit is under way: kill the worker process doing it
            pid = int(staging[0].name.split("-")[1])
            if psutil.pid_exists(pid):
                os.kill(pid, signal.SIGKILL)
                killed = pid
        time.sleep(0.05)
    out, err = p.communicate(timeout=300)
    assert killed is not None, "no fit was seen under way"
    assert p.returncode == 0, err
    _check_batch(root, lib, N_KILLED)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_batch_on_a_separately_started_scheduler(stored, tmp_path):
    root = _fresh(stored, tmp_path)
    lib = tmp_path / "lib.sqlite"
    port = _free_port()
    dask = [sys.executable, "-m", "distributed.cli"]
    address = f"tcp://127.0.0.1:{port}"
    procs = [subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1",
                               "--port", str(port), "--no-dashboard"], stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)]
    try:
        procs.append(subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_worker", address, "--nworkers", "2",
                                       "--nthreads", "1", "--no-dashboard"], stdout=subprocess.DEVNULL,
                                      stderr=subprocess.DEVNULL))
        r = _brdfrig("refit", "--batch", root, "--scheduler", address, "--library", lib, "--no-progress", *BATCH)
        assert r.returncode == 0, r.stderr
        _check_batch(root, lib)
    finally:
        for proc in reversed(procs):
            proc.terminate()
        for proc in procs:
            proc.wait(30)
