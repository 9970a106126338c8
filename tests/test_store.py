"""Session store: atomic writes, manifest verification, refusals, torn journal lines, a full disk."""

from __future__ import annotations

import errno
import hashlib
import json
import os

import pytest

from brdfrig.session import store as store_mod
from brdfrig.session.store import DiskFullError, SessionStore, StoreError, atomic_write_bytes


def make_raw(store: SessionStore, name: str, data: bytes) -> str:
    src = store.incoming / f"{name}.dng"
    src.write_bytes(data)
    return store.store_file(src, "raw", name, kind="exposure", key=name)


def test_store_file_hashes_and_verifies(tmp_path):
    s = SessionStore.create(tmp_path / "sess", {"x": 1})
    rel = make_raw(s, "shot", b"abc" * 1000)
    assert rel == "raw/shot.dng"
    entry = json.loads((tmp_path / "sess" / "manifest.json").read_text())["files"][rel]
    assert entry["sha256"] == hashlib.sha256(b"abc" * 1000).hexdigest()  # independent oracle
    assert entry["size"] == 3000
    assert not list(s.incoming.iterdir())
    assert SessionStore.open(tmp_path / "sess").verify().ok == [rel]


def test_flipped_byte_and_missing_file_are_named(tmp_path):
    s = SessionStore.create(tmp_path / "sess", {})
    a, b = make_raw(s, "a", b"1" * 100), make_raw(s, "b", b"2" * 100)
    data = bytearray((tmp_path / "sess" / a).read_bytes())
    data[17] ^= 0x01
    (tmp_path / "sess" / a).write_bytes(bytes(data))
    (tmp_path / "sess" / b).unlink()
    v = SessionStore.open(tmp_path / "sess").verify()
    assert v.corrupt == [a] and v.missing == [b] and not v.passed
    assert "checksum mismatch: raw/a.dng" in v.describe() and "missing: raw/b.dng" in v.describe()


def test_never_overwrites_a_stored_name(tmp_path):
    s = SessionStore.create(tmp_path / "sess", {})
    first = make_raw(s, "shot", b"first")
    second = make_raw(s, "shot", b"second")
    assert (first, second) == ("raw/shot.dng", "raw/shot.a1.dng")
    assert (tmp_path / "sess" / first).read_bytes() == b"first"
    with pytest.raises(FileExistsError):
        atomic_write_bytes(tmp_path / "sess" / first, b"x", overwrite=False)
    assert (tmp_path / "sess" / first).read_bytes() == b"first"
    assert not [p for p in (tmp_path / "sess" / "raw").iterdir() if p.name.endswith(".tmp")]


def test_refuses_non_session_and_existing_session(tmp_path):
    other = tmp_path / "photos"
    other.mkdir()
    (other / "holiday.jpg").write_bytes(b"keep me")
    with pytest.raises(StoreError, match=r"exists, is not empty and is not a brdfrig session"):
        SessionStore.create(other, {})
    assert [p.name for p in other.iterdir()] == ["holiday.jpg"]
    assert (other / "holiday.jpg").read_bytes() == b"keep me"
    SessionStore.create(tmp_path / "sess", {})
    with pytest.raises(StoreError, match=r"already holds a session; continue it with `brdfrig capture resume"):
        SessionStore.create(tmp_path / "sess", {})
    with pytest.raises(StoreError, match=r"is not a brdfrig session"):
        SessionStore.open(other)


def test_refuses_newer_format_version_without_touching_it(tmp_path):
    s = SessionStore.create(tmp_path / "sess", {})
    make_raw(s, "a", b"data")
    info_path = tmp_path / "sess" / "session.json"
    info = json.loads(info_path.read_text())
    info["version"] = store_mod.FORMAT_VERSION + 1
    info_path.write_text(json.dumps(info))
    before = {p: p.read_bytes() for p in (tmp_path / "sess").rglob("*") if p.is_file()}
    with pytest.raises(StoreError, match=rf"session format version {store_mod.FORMAT_VERSION + 1}; this brdfrig reads"):
        SessionStore.open(tmp_path / "sess")
    after = {p: p.read_bytes() for p in (tmp_path / "sess").rglob("*") if p.is_file()}
    assert before == after


def test_torn_journal_line_is_skipped_and_terminated(tmp_path):
    s = SessionStore.create(tmp_path / "sess", {})
    s.append("one", n=1)
    with open(tmp_path / "sess" / "journal.jsonl", "ab") as f:
        f.write(b'{"event": "torn", "ti')  # a crash mid-append
    s2 = SessionStore.open(tmp_path / "sess")
    s2.append("two", n=2)
    events = [r["event"] for r in s2.journal()]
    assert events == ["session_created", "one", "two"]


def test_disk_full_keeps_everything_stored(tmp_path, monkeypatch):
    s = SessionStore.create(tmp_path / "sess", {})
    a = make_raw(s, "a", b"A" * 500)
    manifest_before = (tmp_path / "sess" / "manifest.json").read_bytes()
    import brdfrig._atomic as atomic_mod

    real = atomic_mod.write_all

    def full(fd, data):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(atomic_mod, "write_all", full)
    src = s.incoming / "b.dng"
    src.write_bytes(b"B" * 500)
    with pytest.raises(DiskFullError, match=r"disk full while writing .*manifest.json; nothing already stored was changed"):
        s.store_file(src, "raw", "b", kind="exposure", key="b")
    monkeypatch.setattr(atomic_mod, "write_all", real)
    assert (tmp_path / "sess" / "manifest.json").read_bytes() == manifest_before
    reopened = SessionStore.open(tmp_path / "sess")
    v = reopened.verify()
    assert v.ok == [a] and v.passed
    assert src.exists() and not v.untracked  # the camera file was not lost, no half-stored copy
    assert not [p for p in (tmp_path / "sess").rglob("*.tmp*")]


def test_results_dirs_are_fresh_and_appear_only_when_committed(tmp_path):
    s = SessionStore.create(tmp_path / "sess", {})
    names = []
    for k in range(3):
        staging = s.staging_results_dir()
        (staging / "x.json").write_text(str(k))
        assert not list((tmp_path / "sess" / "results").glob("fit-*")) or names  # nothing visible before a commit
        names.append(s.commit_results(staging).name)
    assert names == ["fit-001", "fit-002", "fit-003"]
    assert (tmp_path / "sess" / "results" / "fit-002" / "x.json").read_text() == "1"


def test_a_dead_runs_staging_directory_is_removed_by_the_next_commit(tmp_path):
    s = SessionStore.create(tmp_path / "sess", {})
    dead = tmp_path / "sess" / "results" / ".staging-999999999-abc"  # no such PID
    dead.mkdir()
    (dead / "half.json").write_text("{")
    live = s.staging_results_dir()  # this process: kept until committed
    other = s.staging_results_dir()
    assert s.commit_results(live).name == "fit-001"
    assert not dead.exists() and other.exists()


def test_writer_lock_is_reentrant_in_one_thread_and_refused_to_another(tmp_path):
    import threading

    store = SessionStore.create(tmp_path / "s", {"k": 1})
    errors = []
    with store.locked():
        with SessionStore.open(tmp_path / "s").locked():  # a capture that fits what it shot locks twice
            pass
        t = threading.Thread(target=lambda: _try_lock(tmp_path / "s", errors))
        t.start()
        t.join()
    assert len(errors) == 1 and str(errors[0]) == (
        f"session {tmp_path / 's'} in use by PID {os.getpid()}: wait for it to finish (nothing was changed)")
    _try_lock(tmp_path / "s", errors)  # released on exit
    assert len(errors) == 1


def _try_lock(root, errors):
    try:
        with SessionStore.open(root).locked():
            pass
    except StoreError as exc:
        errors.append(exc)
