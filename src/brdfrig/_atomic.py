"""The one atomic file writer: temp file in the same directory, fsync, rename, fsync of the directory.

A reader (or a crash at any moment) sees either the old file or the complete
new one, never a partial file under the final name.  On any failure the
temporary file is removed and the target is unchanged.  Files are created
with mode ``0o666`` minus the process umask (what ``open()`` would give),
not the ``0o600`` of :func:`tempfile.mkstemp`.

- :func:`write_bytes` / :func:`write_text` for data held in memory;
- :func:`temp_path` for libraries that write by file name (OpenEXR,
  OpenImageIO, matplotlib, tifffile): it yields a temporary path with the
  target's suffix, and moves the file into place when the block succeeds.

``overwrite=False`` finishes with ``os.link``, which raises
``FileExistsError`` instead of replacing an existing file (``--no-clobber``,
stored session files).  A full disk raises
:class:`brdfrig.errors.DiskFullError` naming the target, also when a library
reports it as something other than ``OSError(ENOSPC)`` (OpenEXR raises
``RuntimeError``, numpy's ``tofile`` under tifffile an ``OSError`` without
errno): the free space is checked when such a write fails.
"""

from __future__ import annotations

import errno
import os
import secrets
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

from brdfrig.errors import DiskFullError

__all__ = ["write_bytes", "write_text", "temp_path", "fsync_dir", "write_all"]

_FULL_BYTES = 64 * 1024  # a failed write with less free space than this is reported as a full disk


def fsync_dir(path: str | os.PathLike) -> None:
    """fsync a directory, so that a rename or link in it survives a crash."""
    fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_all(fd: int, data: bytes) -> None:
    """``os.write`` until every byte of ``data`` is written (a single call may write fewer)."""
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view):]


def _create_temp(path: Path, suffix: str) -> Path:
    """A new empty file next to ``path`` (hidden name, mode 0o666 & ~umask)."""
    while True:
        tmp = path.parent / f".{path.name}.{secrets.token_hex(4)}.tmp{suffix}"
        try:
            os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
            return tmp
        except FileExistsError:
            continue
        except OSError as exc:  # unwritable or read-only directory, no inodes: name the target, not the temp
            raise type(exc)(exc.errno, exc.strerror, str(path)) from None


def _disk_is_full(directory: Path) -> bool:
    try:
        st = os.statvfs(directory)
    except OSError:
        return False
    return st.f_bavail * st.f_frsize < _FULL_BYTES


def _finish(tmp: Path, path: Path, overwrite: bool) -> None:
    fd = os.open(tmp, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
    if overwrite:
        os.replace(tmp, path)
    else:
        try:
            os.link(tmp, path)
        except FileExistsError:
            raise FileExistsError(errno.EEXIST, f"{path} already exists; not overwritten") from None
        os.unlink(tmp)
    fsync_dir(path.parent)


def temp_path(path: str | os.PathLike, *, overwrite: bool = True):
    """Context manager: a temporary path next to ``path``; when the block succeeds the file written there replaces ``path``.

    The temporary file exists (empty) when the block starts, so the writer
    replaces it; its name ends in the target's suffix, so libraries choosing
    a format by extension choose the target's.
    """
    return _temp(Path(path), overwrite, Path(path).suffix)


@contextmanager
def _temp(path: Path, overwrite: bool, suffix: str) -> Iterator[Path]:
    tmp = _create_temp(path, suffix)
    try:
        yield tmp
        _finish(tmp, path, overwrite)
    except BaseException as exc:
        if isinstance(exc, OSError) and exc.errno is not None:
            full = exc.errno == errno.ENOSPC
        else:  # libraries report a short write without errno (numpy: "N requested and M written") or otherwise
            full = not isinstance(exc, KeyboardInterrupt) and _disk_is_full(path.parent)
        tmp.unlink(missing_ok=True)
        if full and not isinstance(exc, DiskFullError):
            raise DiskFullError(errno.ENOSPC, f"disk full while writing {path}; nothing already stored was changed"
                                ) from exc
        raise


def write_bytes(path: str | os.PathLike, data: bytes, *, overwrite: bool = True) -> Path:
    """Write ``data`` to ``path`` atomically; returns ``Path(path)``."""
    path = Path(path)
    with _temp(path, overwrite, "") as tmp:
        fd = os.open(tmp, os.O_WRONLY | os.O_TRUNC)
        try:
            write_all(fd, data)
        finally:
            os.close(fd)
    return path


def write_text(path: str | os.PathLike, text: str, *, overwrite: bool = True, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` atomically (encoded with ``encoding``); returns ``Path(path)``."""
    return write_bytes(path, text.encode(encoding), overwrite=overwrite)
