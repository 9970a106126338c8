"""Crash safety: SIGKILL a real session process at 20 random points; each resume completes and matches.

Each trial starts a child process (from a clean forkserver) that runs a tiny simulated session (GRBL
simulator on a pty, simulated camera), kills it with SIGKILL after a random
number of journal records plus a random delay (so kills land inside file
writes, manifest rewrites and table moves too), then resumes it in another
child that must complete.  The final manifest must verify, every shot must be
byte-identical to an uninterrupted run's (the simulated sensor's noise is a
function of the shot, not of the order of captures), and the fitted BRDF must
equal the uninterrupted run's.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from brdfrig.session.config import load_session_config
from brdfrig.session.store import SessionStore

PLAN = """
[session]
name = "tiny"
[rig]
carries = "rig"
[rig.turntable]
backend = "sim"
speed_deg_s = 720.0
[rig.camera]
backend = "sim"
full_well_e = 20000.0
read_noise_e = 5.0
[rig.sim]
scale = 0.25
env_height = 16
probe_env_height = 32
blemishes = 0
[plan]
scene_angles = [0.0, 180.0]
exposure = [0.004, 0.064]
[plan.probe]
circle = [28.75, 30.0, 22.5]
albedo = 0.6
[[plan.samples]]
name = "matte"
circle = [80.0, 30.0, 22.5]
[fit]
model = "diffuse"
lmax = 2
pmax = 2
"""

TRIALS = 20


def _child(plan: str, out: str, resume: bool) -> None:
    """Body of a session process: run or resume, quietly; exit status 0 on completion."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 1)
    os.dup2(devnull, 2)
    code = 1
    try:
        from brdfrig.devices import open_rig
        from brdfrig.session.runner import resume_session, run_session

        if resume:
            status, _ = resume_session(out, rig_factory=open_rig, prompt=None, progress=False)
        else:
            status, _ = run_session(load_session_config(plan), out, rig_factory=open_rig, prompt=None, progress=False)
        code = 0 if status == "complete" else 3
    finally:
        os._exit(code)


# Session processes come from a forkserver started clean, not forked from pytest: numba's OpenMP layer
# raises SIGTERM in a child forked from a process that already ran a parallel kernel (earlier tests do).
_CHILD_MODULES = ["brdfrig.session.pipeline", "brdfrig.session.runner", "brdfrig.devices", "brdfrig.hdr.dng", "brdfrig.hdr.raw", "brdfrig.sim.grbl",
                  "brdfrig.sim.camera", "brdfrig.rig.turntable"]
_CTX = multiprocessing.get_context("forkserver")
_CTX.set_forkserver_preload(_CHILD_MODULES)


def _start(plan: Path, out: Path, resume: bool):
    p = _CTX.Process(target=_child, args=(str(plan), str(out), resume))
    p.start()
    return p


def _journal_records(out: Path) -> int:
    try:
        return (out / "journal.jsonl").read_bytes().count(b"\n")
    except OSError:
        return 0


def _shots(store: SessionStore) -> dict[str, str]:
    return {e["key"]: e["sha256"] for e in store.files.values() if e.get("kind") == "exposure"}


def _fit(out: Path) -> dict:
    from brdfrig.session.pipeline import run_pipeline

    result = run_pipeline(out, progress=False, echo=lambda text: None, figures=False)
    return {s.name: s.brdf.to_dict() for s in result.samples}


@pytest.mark.skipif(sys.platform != "linux", reason="needs a forkserver and ptys")
def test_sigkill_at_random_points_then_resume(tmp_path):
    plan = tmp_path / "tiny.toml"
    plan.write_text(PLAN)
    ref = tmp_path / "ref"
    p = _start(plan, ref, resume=False)
    p.join(120)
    assert p.exitcode == 0
    ref_store = SessionStore.open(ref)
    ref_shots = _shots(ref_store)
    assert len(ref_shots) == 4
    n_records = _journal_records(ref)
    rng = np.random.default_rng(20261122)
    landed = {"before the session existed": 0, "mid-session": 0, "after completion": 0}
    fits = []
    for trial in range(TRIALS):
        out = tmp_path / f"k{trial:02d}"
        target = int(rng.integers(0, n_records))
        delay = float(rng.uniform(0.0, 0.05))
        p = _start(plan, out, resume=False)
        deadline = time.monotonic() + 60
        while _journal_records(out) < target and p.is_alive() and time.monotonic() < deadline:
            time.sleep(0.002)
        time.sleep(delay)
        try:
            os.kill(p.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass  # it already finished (a forkserver child is reaped by the server, not by us)
        p.join(10)
        if not (out / "session.json").exists():
            landed["before the session existed"] += 1
            assert not out.exists() or not any(out.iterdir())
            p = _start(plan, out, resume=False)  # nothing to resume: run again (the directory must be usable)
        else:
            stop = [r for r in SessionStore.open(out).journal() if r["event"] == "stop"]
            landed["after completion" if stop else "mid-session"] += 1
            p = _start(plan, out, resume=True)
        p.join(120)
        assert p.exitcode == 0, f"trial {trial}: resume did not complete"
        store = SessionStore.open(out)
        check = store.verify()
        assert check.passed, f"trial {trial}: {check.describe()}"
        assert _shots(store) == ref_shots, f"trial {trial}: shots differ from the uninterrupted run"
        fits.append(out)
    assert landed["mid-session"] >= TRIALS // 2, landed
    ref_fit = _fit(ref)
    for out in fits:
        assert _fit(out) == ref_fit, f"{out.name}: fitted BRDF differs from the uninterrupted run"
