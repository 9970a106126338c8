"""Session runner and resume, on fake devices (the real simulators are exercised by the crash and demo tests)."""

from __future__ import annotations

import contextlib
import errno
import os

import pytest

from brdfrig.rig.camera import Camera
from brdfrig.session import store as store_mod
from brdfrig.session.config import session_config_from_dict
from brdfrig.session.runner import resume_session, run_session
from brdfrig.session.store import DiskFullError, SessionStore


class FakeTurntable:
    def __init__(self):
        self.moves, self.stops = [], 0

    def move_to(self, angle):
        self.moves.append(angle)
        return angle

    def stop(self):
        self.stops += 1


class FakeCamera(Camera):
    """Writes a small file whose content depends only on (table angle, exposure time)."""

    def __init__(self, table, fail_at=None, exc=None):
        self.table, self.time, self.shots = table, None, []
        self.fail_at, self.exc = fail_at, exc

    def set_exposure(self, time_s, iso, f_number):
        self.time = time_s

    def capture(self, dest_dir):
        if self.fail_at is not None and len(self.shots) == self.fail_at:
            raise self.exc
        angle = self.table.moves[-1] if self.table.moves else 0.0
        self.shots.append((angle, self.time))
        path = os.path.join(dest_dir, f"IMG_{len(self.shots):04d}.dng")
        with open(path, "wb") as f:
            f.write(f"angle={angle} time={self.time}".encode() * 50)
        return path

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        pass


def config(carries="rig", scenes=3, rotations=(0, 90), settle_s=None):
    doc = {
        "session": {"name": "fake"},
        "rig": {"carries": carries, "turntable": {"backend": "sim"}, "camera": {"backend": "sim"}},
        "plan": {"scenes": scenes, "exposure": [0.01, 0.04, 0.16],
                 "probe": {"circle": [10, 10, 5]}, "samples": [{"name": "a", "circle": [30, 10, 5]}]},
        "fit": {"model": "diffuse", "lmax": 2},
    }
    if carries == "samples":
        doc["plan"]["probe_rotations"] = list(rotations)
    if settle_s is not None:
        doc["plan"]["settle_s"] = settle_s
    return session_config_from_dict(doc, "test")


def rig(fail_at=None, exc=None, devices=None):
    @contextlib.contextmanager
    def factory(cfg, journal=None):
        tt = FakeTurntable()
        cam = FakeCamera(tt, fail_at, exc)
        if devices is not None:
            devices.append((tt, cam))
        yield tt, cam

    return factory


def shots_in(store: SessionStore) -> dict:
    return {e["key"]: e for e in store.files.values() if e.get("kind") == "exposure"}


def test_complete_run_stores_every_shot(tmp_path):
    dev = []
    status, store = run_session(config(), tmp_path / "s", prompt=None, progress=False, rig_factory=rig(devices=dev))
    assert status == "complete"
    assert len(shots_in(store)) == 3 * 3
    assert dev[0][0].moves == [0.0, 120.0, 240.0]
    assert store.verify().passed and len(store.verify().ok) == 9
    assert store.journal()[-1]["event"] == "stop" and store.journal()[-1]["status"] == "complete"


def test_ctrl_c_stops_table_and_resume_shoots_only_the_rest(tmp_path):
    dev = []
    with pytest.raises(KeyboardInterrupt):
        run_session(config(), tmp_path / "s", prompt=None, progress=False,
                    rig_factory=rig(fail_at=4, exc=KeyboardInterrupt(), devices=dev))
    assert dev[0][0].stops == 1
    store = SessionStore.open(tmp_path / "s")
    stop = store.journal()[-1]
    assert (stop["event"], stop["status"]) == ("stop", "interrupted")
    assert len(shots_in(store)) == 4
    status, store = resume_session(tmp_path / "s", prompt=None, progress=False, rig_factory=rig(devices=dev))
    assert status == "complete"
    assert len(dev[1][1].shots) == 5  # 9 planned - 4 stored
    assert len(shots_in(store)) == 9 and store.verify().passed


def test_corrupt_file_is_set_aside_and_shot_again(tmp_path):
    _, store = run_session(config(scenes=1), tmp_path / "s", prompt=None, progress=False, rig_factory=rig())
    victim = sorted(shots_in(store).values(), key=lambda e: e["key"])[1]
    rel = next(r for r, e in store.files.items() if e is victim)
    data = bytearray((tmp_path / "s" / rel).read_bytes())
    data[3] ^= 0xFF
    (tmp_path / "s" / rel).write_bytes(bytes(data))
    dev = []
    status, store = resume_session(tmp_path / "s", prompt=None, progress=False, rig_factory=rig(devices=dev))
    assert status == "complete" and len(dev[0][1].shots) == 1
    v = store.verify()
    assert v.passed and rel in v.untracked  # the damaged file is kept, not trusted
    assert (tmp_path / "s" / rel).read_bytes() == bytes(data)


def test_disk_full_mid_session_loses_nothing_and_resumes(tmp_path, monkeypatch):
    real = store_mod._write_fully
    calls = {"n": 0}

    def filling(fd, data):
        calls["n"] += 1
        if calls["n"] > 12:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        real(fd, data)

    monkeypatch.setattr(store_mod, "_write_fully", filling)
    with pytest.raises(DiskFullError) as e:
        run_session(config(), tmp_path / "s", prompt=None, progress=False, rig_factory=rig())
    msg = str(e.value)
    assert "disk full while writing" in msg and "stored so far" in msg and "brdfrig capture resume" in msg
    monkeypatch.setattr(store_mod, "_write_fully", real)
    store = SessionStore.open(tmp_path / "s")
    stored = dict(store.files)
    assert stored and store.verify().passed and not store.verify().untracked
    status, store = resume_session(tmp_path / "s", prompt=None, progress=False, rig_factory=rig())
    assert status == "complete" and len(shots_in(store)) == 9
    for rel, entry in stored.items():  # nothing stored before the full disk changed
        assert store.files[rel]["sha256"] == entry["sha256"]


def test_operator_scenes_pause_and_resume(tmp_path):
    answers = iter(["", "q"])
    cfg = config(carries="samples", scenes=2, rotations=(0, 90, 180))
    status, store = run_session(cfg, tmp_path / "s", prompt=lambda text: next(answers), progress=False,
                                rig_factory=rig())
    assert status == "paused" and len(shots_in(store)) == 3 * 3
    prompts = []
    status, store = resume_session(tmp_path / "s", prompt=lambda t: prompts.append(t) or "", progress=False,
                                   rig_factory=rig())
    assert status == "complete" and len(shots_in(store)) == 2 * 3 * 3
    assert len(prompts) == 1 and "scene 2/2" in prompts[0]


def test_runner_waits_settle_s_after_every_move(tmp_path):
    """settle_s is counted in the estimate; the runner must also wait it, once per table move."""
    dev, waits = [], []
    status, store = run_session(config(settle_s=2.5), tmp_path / "s", prompt=None, progress=False,
                                rig_factory=rig(devices=dev), sleep=waits.append)
    assert status == "complete"
    assert dev[0][0].moves == [0.0, 120.0, 240.0]
    assert waits == [2.5, 2.5, 2.5]  # one settle per move, none per shot
    assert [r["settle_s"] for r in store.journal() if r["event"] == "moved"] == [2.5, 2.5, 2.5]
    waits.clear()
    run_session(config(), tmp_path / "t", prompt=None, progress=False, rig_factory=rig(), sleep=waits.append)
    assert waits == []  # settle_s = 0 (the default) asks for no wait


def test_turntable_retries_are_journalled_in_the_session(tmp_path):
    """A resent final approach (line noise, lost ``ok``) shows in the session journal, and the shot is right."""
    from brdfrig.rig.turntable import GrblTurntable
    from brdfrig.sim.grbl import GrblSimulator
    from brdfrig.sim.soak import SOAK_DRIVER_TIMING

    seen = {}

    @contextlib.contextmanager
    def factory(cfg, journal=None):
        with GrblSimulator(steps_per_degree=80.0, backlash_deg=0.5, max_rate_deg_s=1e5, homing_time_s=0.002,
                           tick_s=0.001) as sim:
            with GrblTurntable(sim.port, 115200, 80.0, 0.5, journal=journal, settled=sim.settled,
                               **SOAK_DRIVER_TIMING) as table:
                table.home()
                table.move_to(300.0)  # the first scene angle, 0, is then approached from below
                sim.rewrite_command("G90 G0 X0.000000", "G90 G0 X900.000000", drop_ok=True)
                tt = FakeTurntable()
                tt.move_to = lambda a: (tt.moves.append(a), table.move_to(a), seen.setdefault(a, sim.table_angle_deg))[1]
                yield tt, FakeCamera(tt)

    status, store = run_session(config(scenes=2), tmp_path / "s", prompt=None, progress=False, rig_factory=factory)
    assert status == "complete"
    assert seen == {0.0: 0.0, 180.0: 180.0}  # the physical table angle when each scene was shot
    events = [r["event"] for r in store.journal()]
    resync = [r for r in store.journal() if r["event"] == "turntable_resync"]
    assert resync and resync[0]["command"] == "G90 G0 X0.000000" and resync[0]["reason"] == "no reply"
    assert "turntable_reapproach" in events[events.index("turntable_resync"):]
