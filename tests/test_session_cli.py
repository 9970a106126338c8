"""``brdfrig capture`` bad input through the real command line: one clear line, exit 2, nothing touched."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

PLAN = """
[rig]
carries = "samples"
[rig.turntable]
backend = "sim"
[rig.camera]
backend = "sim"
[plan]
scenes = 2
probe_rotations = ROT
exposure = [0.01]
[plan.probe]
circle = [10, 10, 5]
[[plan.samples]]
name = "a"
circle = [30, 10, 5]
"""


def brdfrig(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "brdfrig", *map(str, args)], cwd=ROOT, capture_output=True,
                          text=True, timeout=120)


def test_zero_rotations(tmp_path):
    plan = tmp_path / "plan.toml"
    plan.write_text(PLAN.replace("ROT", "[]"))
    r = brdfrig("capture", "run", plan, "--out", tmp_path / "out")
    assert r.returncode == 2
    assert r.stderr.strip() == (
        f"brdfrig capture: error: key 'probe_rotations' in [plan] of {plan} is empty: zero rotations would shoot "
        "nothing; give at least one table angle in degrees, e.g. [0] or [0, 90, 180, 270]"
    )
    assert not (tmp_path / "out").exists()


def test_existing_non_session_directory_is_left_alone(tmp_path):
    plan = tmp_path / "plan.toml"
    plan.write_text(PLAN.replace("ROT", "[0, 180]"))
    out = tmp_path / "photos"
    out.mkdir()
    (out / "keep.txt").write_text("precious")
    r = brdfrig("capture", "run", plan, "--out", out, "--yes")
    assert r.returncode == 2
    assert "is not empty and is not a brdfrig session" in r.stderr and str(out) in r.stderr
    assert [p.name for p in out.iterdir()] == ["keep.txt"] and (out / "keep.txt").read_text() == "precious"


def test_dry_run_prints_the_plan(tmp_path):
    plan = tmp_path / "plan.toml"
    plan.write_text(PLAN.replace("ROT", "[0, 90, 180, 270]"))
    r = brdfrig("capture", "run", plan, "--out", tmp_path / "out", "--dry-run")
    assert r.returncode == 0, r.stderr
    assert "scenes: 2 (the operator sets up each scene" in r.stdout and "8 shots" in r.stdout
    assert not (tmp_path / "out").exists()


TINY = """
[rig]
carries = "rig"
[rig.turntable]
backend = "sim"
speed_deg_s = 90.0
[rig.camera]
backend = "sim"
[rig.sim]
scale = 0.25
env_height = 16
probe_env_height = 32
[plan]
scene_angles = [0.0, 90.0, 180.0, 270.0]
exposure = [0.004, 0.064]
[plan.probe]
circle = [28.75, 30.0, 22.5]
[[plan.samples]]
name = "matte"
circle = [80.0, 30.0, 22.5]
"""


def test_ctrl_c_stops_cleanly_and_resume_finishes(tmp_path):
    import json
    import signal
    import time

    # Two scenes and a 10 s move between them (90 degrees at 9 deg/s): after the first "moved" record the session
    # cannot finish before the Ctrl-C unless this process is starved for 10 s.
    plan = tmp_path / "tiny.toml"
    plan.write_text(TINY.replace("speed_deg_s = 90.0", "speed_deg_s = 9.0")
                    .replace("scene_angles = [0.0, 90.0, 180.0, 270.0]", "scene_angles = [0.0, 90.0]"))
    out = tmp_path / "s"
    # the installed console script, as a user runs it (`python -m capture` exits by SIGINT, -2, about half the
    # time after the same clean stop: a CPython/runpy quirk outside brdfrig)
    script = Path(sys.executable).parent / "brdfrig"
    # SIGINT at its default in the child, as in a terminal: a test run started as a background job of a
    # non-interactive shell inherits it ignored, and the Ctrl-C would then never arrive
    p = subprocess.Popen([str(script), "capture", "run", str(plan), "--out", str(out), "--no-fit", "--no-progress"],
                         cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 60
    journal = out / "journal.jsonl"
    # the whole journal: its tail alone loses the "moved" record once the shots after it are written
    while time.monotonic() < deadline and (not journal.exists() or b'"moved"' not in journal.read_bytes()):
        time.sleep(0.01)
    p.send_signal(signal.SIGINT)  # Ctrl-C lands mid-shot at 0 degrees or mid-move to 90
    _, err = p.communicate(timeout=60)
    assert p.returncode == 130, err
    assert err.strip().endswith("brdfrig: interrupted")
    records = [json.loads(line) for line in journal.read_text().splitlines()]
    assert records[-1]["event"] == "stop" and records[-1]["status"] == "interrupted"
    assert "turntable stopped" in records[-1]["reason"]
    r = brdfrig("capture", "resume", out, "--no-fit", "--no-progress")
    assert r.returncode == 0, r.stderr
    assert "session complete: " in r.stdout
    from brdfrig.session.store import SessionStore

    store = SessionStore.open(out)
    assert store.verify().passed and sum(e.get("kind") == "exposure" for e in store.files.values()) == 4


def _snapshot(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_a_session_in_use_is_refused_by_every_other_writer(tmp_path):
    """Two real processes: a run waiting at its operator prompt holds the lock; resume and refit are refused."""
    import os
    import select
    import time

    plan = tmp_path / "plan.toml"
    plan.write_text(PLAN.replace("ROT", "[0]"))
    out = tmp_path / "s"
    script = Path(sys.executable).parent / "brdfrig"
    holder = subprocess.Popen([str(script), "capture", "run", str(plan), "--out", str(out), "--no-fit",
                               "--no-progress"], cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE)
    try:
        seen, deadline = b"", time.monotonic() + 90
        while b"press Enter" not in seen:  # the run is at its first operator prompt, the lock held
            ready, _, _ = select.select([holder.stdout], [], [], max(0.0, deadline - time.monotonic()))
            assert ready and holder.poll() is None, (seen, holder.stderr.read() if holder.poll() is not None else "")
            seen += os.read(holder.stdout.fileno(), 4096)
        before = _snapshot(out)
        expected = f"session {out} in use by PID {holder.pid}: wait for it to finish (nothing was changed)"
        for command in (("capture", "resume", out, "--yes", "--no-fit", "--no-progress"),
                        ("refit", out, "--no-progress")):
            r = brdfrig(*command)
            assert r.returncode == 2, (command, r.stderr)
            assert r.stderr.strip().splitlines() == [f"brdfrig {command[0]}: error: {expected}"], command
            assert _snapshot(out) == before, command  # nothing written
        holder.stdin.write(b"q\n")
        holder.stdin.close()
        assert holder.wait(timeout=60) == 0
    finally:
        if holder.poll() is None:
            holder.kill()
            holder.wait()
    assert b"session paused" in seen + holder.stdout.read()
    r = brdfrig("capture", "resume", out, "--yes", "--no-fit", "--no-progress")  # the lock died with its holder
    assert r.returncode == 0 and "session complete" in r.stdout, r.stderr


HOLD_AT_FIT = """
import contextlib, sys

from brdfrig.cli.main import main
from brdfrig.session import refit, store

real_locked, paused = store.SessionStore.locked, []


def pause(where):
    if not paused:
        paused.append(where)
        print("PAUSED", where, flush=True)
        sys.stdin.readline()


@contextlib.contextmanager
def locked(self):
    # the first request for the writer lock once the shooting has ended is the fit stage's: pause before it
    if any(r.get("event") == "stop" and r.get("status") == "complete" for r in self.journal()):
        pause("lock request after shooting")
    with real_locked(self) as s:
        yield s


def fit(session_dir, *args, **kwargs):  # the fit proper: pause in it, then skip the 50 s fit
    pause("fit")
    return refit.SessionRefit(str(session_dir), "(fit skipped by the test)")


store.SessionStore.locked = locked
refit.refit_session = fit
sys.exit(main(sys.argv[1:]))
"""


def test_the_lock_is_held_from_shooting_through_the_fit(tmp_path):
    """A real `capture run` paused at the start of its fit stage: a concurrent resume and refit are refused."""
    import os
    import select
    import time

    plan = tmp_path / "tiny.toml"
    plan.write_text(TINY)
    out = tmp_path / "s"
    holder = subprocess.Popen([sys.executable, "-c", HOLD_AT_FIT, "capture", "run", str(plan), "--out", str(out),
                               "--yes", "--no-progress"], cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE)
    try:
        seen, deadline = b"", time.monotonic() + 90
        while b"PAUSED" not in seen:
            ready, _, _ = select.select([holder.stdout], [], [], max(0.0, deadline - time.monotonic()))
            assert ready and holder.poll() is None, (seen, holder.stderr.read() if holder.poll() is not None else "")
            seen += os.read(holder.stdout.fileno(), 4096)
        assert '"status": "complete"' in (out / "journal.jsonl").read_text().splitlines()[-1]  # shooting is over
        before = _snapshot(out)
        expected = f"session {out} in use by PID {holder.pid}: wait for it to finish (nothing was changed)"
        for command in (("capture", "resume", out, "--yes", "--no-fit", "--no-progress"),
                        ("refit", out, "--no-progress")):
            r = brdfrig(*command)
            assert (r.returncode, r.stderr.strip().splitlines()) == (2, [f"brdfrig {command[0]}: error: {expected}"]), \
                (command, seen, r.stdout)
            assert _snapshot(out) == before, command  # nothing written
        holder.stdin.write(b"\n")
        holder.stdin.close()
        assert holder.wait(timeout=60) == 0, holder.stderr.read()
    finally:
        if holder.poll() is None:
            holder.kill()
            holder.wait()
    assert b"results in (fit skipped by the test)" in holder.stdout.read()
