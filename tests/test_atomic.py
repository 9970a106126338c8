"""brdfrig._atomic: the one atomic writer (umask mode, nothing left behind, no-clobber, full disk)."""

from __future__ import annotations

import errno
import os
import shutil
import stat
import subprocess
from pathlib import Path

import numpy as np
import pytest

import brdfrig._atomic as atomic
from brdfrig.errors import DiskFullError


@pytest.fixture
def umask_027():
    old = os.umask(0o027)
    yield 0o027
    os.umask(old)


def _mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def test_files_get_the_users_umask_not_0600(tmp_path, umask_027):
    from brdfrig.hdr.exr import write_exr

    paths = [atomic.write_bytes(tmp_path / "a.bin", b"x"), atomic.write_text(tmp_path / "b.txt", "y"),
             write_exr(tmp_path / "c.exr", np.ones((4, 4, 3), np.float32))]
    with atomic.temp_path(tmp_path / "d.txt") as tmp:
        tmp.write_text("z")
    paths.append(tmp_path / "d.txt")
    assert [_mode(p) for p in paths] == [0o640] * 4  # 0o666 & ~0o027, as open() would give
    assert (tmp_path / "b.txt").read_text() == "y" and (tmp_path / "d.txt").read_text() == "z"


def test_failure_leaves_no_temp_and_the_old_file(tmp_path, monkeypatch):
    target = tmp_path / "keep.json"
    atomic.write_bytes(target, b"old")

    def broken(fd, data):
        raise OSError(errno.EIO, "I/O error")

    monkeypatch.setattr(atomic, "write_all", broken)
    with pytest.raises(OSError, match="I/O error"):
        atomic.write_bytes(target, b"new")
    monkeypatch.undo()
    with pytest.raises(KeyError):
        with atomic.temp_path(target) as tmp:
            tmp.write_bytes(b"half")
            raise KeyError("writer crashed")
    assert target.read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.json"]


def test_no_clobber_refuses_an_existing_file(tmp_path):
    target = tmp_path / "out.bin"
    atomic.write_bytes(target, b"first")
    with pytest.raises(FileExistsError, match="already exists; not overwritten"):
        atomic.write_bytes(target, b"second", overwrite=False)
    assert target.read_bytes() == b"first"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.bin"]


def test_enospc_becomes_disk_full_naming_the_file(tmp_path, monkeypatch):
    def full(fd, data):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(atomic, "write_all", full)
    with pytest.raises(DiskFullError, match=r"disk full while writing .*x\.bin") as e:
        atomic.write_bytes(tmp_path / "x.bin", b"data")
    assert e.value.errno == errno.ENOSPC and isinstance(e.value, OSError)
    assert not list(tmp_path.iterdir())


@pytest.fixture
def tiny_disk(tmp_path):
    """A 64 KiB tmpfs (needs root and mount permission; skipped otherwise)."""
    mnt = tmp_path / "tiny"
    mnt.mkdir()
    if os.geteuid() != 0 or not shutil.which("mount") or subprocess.run(
            ["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mnt)], capture_output=True).returncode:
        pytest.skip("mounting a tmpfs needs root")
    yield mnt
    subprocess.run(["umount", str(mnt)], check=True)


def test_openexr_on_a_full_disk_is_disk_full_not_runtime_error(tiny_disk):
    """OpenEXR reports ENOSPC as a RuntimeError: the writer recognises the full disk and says so."""
    from brdfrig.hdr.exr import write_exr

    noise = np.random.default_rng(0).random((256, 256, 3), dtype=np.float32)  # ~0.75 MB, incompressible
    with pytest.raises(DiskFullError, match=r"disk full while writing .*big\.exr"):
        write_exr(tiny_disk / "big.exr", noise)
    assert not list(tiny_disk.iterdir())


def test_tifffile_short_write_on_a_full_disk_is_disk_full(tiny_disk):
    """tifffile (numpy tofile) reports "N requested and M written" without errno: still a full disk."""
    from brdfrig.hdr.dng import write_dng

    cfa = np.random.default_rng(1).integers(0, 16383, (256, 256), dtype=np.uint16)  # 128 KiB, uncompressed
    with pytest.raises(DiskFullError, match=r"disk full while writing .*f\.dng"):
        write_dng(tiny_disk / "f.dng", cfa, black_level=0, white_level=16383, exposure_time_s=0.01, f_number=8.0,
                  iso=100)
    assert not list(tiny_disk.iterdir())
