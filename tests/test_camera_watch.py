"""Watched-folder backend: a writer thread plays the vendor tethering software."""

from __future__ import annotations

import threading
import time

import pytest

from brdfrig.rig.errors import DeviceTimeout
from brdfrig.rig.watch_folder import WatchFolderCamera


def slow_writer(path, chunks, pause_s):
    def run():
        with open(path, "wb") as f:
            for chunk in chunks:
                f.write(chunk)
                f.flush()
                time.sleep(pause_s)

    t = threading.Thread(target=run)
    t.start()
    return t


def test_waits_for_a_new_complete_file(tmp_path):
    watch, dest = tmp_path / "tether", tmp_path / "dest"
    watch.mkdir(), dest.mkdir()
    (watch / "OLD_0001.CR2").write_bytes(b"old")  # already there: not a new capture
    (watch / "notes.txt").write_bytes(b"x")  # not a camera file
    # stable_s far above the writer's 0.05 s pauses: a busy machine may stall this process (writer and watcher
    # alike) for a moment, and a file unchanged for stable_s counts as complete
    with WatchFolderCamera(watch, timeout_s=30.0, stable_s=2.0, poll_s=0.02) as cam:
        cam.set_exposure(0.25, 100, 8)
        chunks = [bytes([k]) * 1000 for k in range(8)]
        writer = slow_writer(watch / "IMG_0002.CR2", chunks, 0.05)  # growing for ~0.4 s
        t0 = time.monotonic()
        path = cam.capture(dest)
        waited = time.monotonic() - t0
        writer.join()
    assert path == dest / "IMG_0002.CR2"
    assert path.read_bytes() == b"".join(chunks)  # complete, not a snapshot of a growing file
    assert waited >= 0.4
    assert (watch / "IMG_0002.CR2").exists()  # the vendor's copy stays
    assert sorted(p.name for p in dest.iterdir()) == ["IMG_0002.CR2"]


def test_successive_captures_take_successive_files(tmp_path):
    watch, dest = tmp_path / "w", tmp_path / "d"
    watch.mkdir(), dest.mkdir()
    shots = iter(["A_1.NEF", "A_2.NEF"])
    cam = WatchFolderCamera(watch, timeout_s=3.0, stable_s=0.05, poll_s=0.01,
                            trigger=lambda msg: (watch / next(shots)).write_bytes(msg.encode()))
    with cam:
        cam.set_exposure(0.5, 200, 5.6)
        first, second = cam.capture(dest), cam.capture(dest)
    assert (first.name, second.name) == ("A_1.NEF", "A_2.NEF")
    assert b"0.5 s, ISO 200, f/5.6" in first.read_bytes()


def test_timeout_names_the_folder(tmp_path):
    with WatchFolderCamera(tmp_path, timeout_s=0.2, stable_s=0.05, poll_s=0.02) as cam:
        with pytest.raises(DeviceTimeout, match="watch_dir"):
            cam.capture(tmp_path)


def test_missing_folder_and_bad_settings_are_named(tmp_path):
    with pytest.raises(OSError, match="watch_dir"):
        WatchFolderCamera(tmp_path / "nope").open()
    with pytest.raises(ValueError, match="timeout_s"):
        WatchFolderCamera(tmp_path, timeout_s=0)
    with pytest.raises(ValueError, match="exposure time"):
        WatchFolderCamera(tmp_path).set_exposure(0, 100, 8)
