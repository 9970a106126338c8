"""Crash-safe session directory: raw files, an append-only journal and a manifest of content hashes.

Layout of a session directory ``DIR``::

    DIR/session.json     format name + version, creation time, the validated session config
    DIR/journal.jsonl    one JSON record per event, appended and fsynced (never rewritten)
    DIR/manifest.json    sha256 and size of every stored file, with its metadata (rewritten atomically)
    DIR/raw/             camera files, each under a name never used before
    DIR/.incoming/       where the camera writes; a file is moved into raw/ only once complete
    DIR/cache/           derived data keyed by content hash (merged brackets); safe to delete
    DIR/results/fit-NNN/ one directory per pipeline run (BRDF files, figures, statistics)

Guarantees:

- Every write is atomic: temporary name in the same directory, ``fsync``, then
  ``os.link``/``os.replace`` and an ``fsync`` of the directory.  A crash leaves
  either the old state or the new one, never a partial file under a final name.
- No stored file is ever overwritten: raw files are linked into place with
  ``os.link``, which fails if the name exists.
- The manifest is the only source of truth: a file counts as stored when the
  manifest lists it and its sha256 verifies.  A file that reached ``raw/`` but
  not the manifest (crash in between) is "untracked": kept, never trusted.
- A full disk (``ENOSPC``) raises :class:`DiskFullError` naming what was being
  written; the manifest and every file already listed in it are untouched.
- The journal is append-only: a torn last line (crash mid-append) is ignored
  on reading and terminated before the next append.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import errno
import fcntl
import hashlib
import json
import math
import os
import re
import shutil
import tempfile
import threading
from dataclasses import dataclass, field
from pathlib import Path

from brdfrig._atomic import fsync_dir as _fsync_dir
from brdfrig._atomic import write_all as _write_fully
from brdfrig._atomic import write_bytes as atomic_write_bytes
from brdfrig.errors import DiskFullError, StoreError

__all__ = [
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "SessionStore",
    "StoreError",
    "DiskFullError",
    "Verification",
    "sha256_file",
    "find_sessions",
    "atomic_write_bytes",
]

FORMAT_NAME = "brdfrig-session"
FORMAT_VERSION = 1

SESSION_FILE = "session.json"
JOURNAL_FILE = "journal.jsonl"
MANIFEST_FILE = "manifest.json"
RAW_DIR = "raw"
INCOMING_DIR = ".incoming"
CACHE_DIR = "cache"
RESULTS_DIR = "results"
LOCK_FILE = ".lock"
_HELD_LOCKS: dict[tuple[str, int], int] = {}  # (session dir, thread) -> depth of locked() held


def find_sessions(root: str | os.PathLike) -> list[Path]:
    """Session directories (holding ``session.json``) at or below ``root``, sorted; results are not searched.

    Raises
    ------
    InputError
        If ``root`` is not a directory.
    """
    from brdfrig.errors import InputError

    root = Path(root)
    if not root.is_dir():
        raise InputError(f"{root} is not a directory")
    return sorted(p.parent for p in root.rglob(SESSION_FILE) if RESULTS_DIR not in p.relative_to(root).parts)


def _pid_alive(staging: Path) -> bool:
    """Whether the process named in a staging directory's name (``.staging-PID-*``) still runs."""
    try:
        os.kill(int(staging.name.split("-")[1]), 0)
    except (OSError, ValueError, IndexError):
        return False
    return True


def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="milliseconds")


def _disk_full(exc: OSError, what: Path) -> OSError:
    """Turn ``ENOSPC`` into :class:`DiskFullError` naming the file; other errors pass through."""
    if exc.errno == errno.ENOSPC:
        return DiskFullError(errno.ENOSPC, f"disk full while writing {what}; nothing already stored was changed")
    return exc


def sha256_file(path: str | os.PathLike) -> str:
    """Hex sha256 of a file's content."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


@dataclass
class Verification:
    """Result of :meth:`SessionStore.verify`: relative paths by problem.

    ``ok`` lists the files whose sha256 and size match the manifest.
    """

    ok: list[str] = field(default_factory=list)
    missing: list[str] = field(default_factory=list)
    corrupt: list[str] = field(default_factory=list)
    untracked: list[str] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        return not self.missing and not self.corrupt

    def describe(self) -> str:
        """One line per problem, naming the files."""
        lines = []
        if self.corrupt:
            lines.append("checksum mismatch: " + ", ".join(self.corrupt))
        if self.missing:
            lines.append("missing: " + ", ".join(self.missing))
        return "; ".join(lines) if lines else f"{len(self.ok)} files verified"


class SessionStore:
    """A session directory (see the module docstring); create with :meth:`create`, reopen with :meth:`open`."""

    def __init__(self, root: Path, info: dict, manifest: dict):
        self.root = Path(root)
        self.info = info
        self._manifest = manifest

    # ------------------------------------------------------------------------------------ opening
    @classmethod
    def create(cls, root: str | os.PathLike, config: dict) -> "SessionStore":
        """Create a new session in ``root`` (which must not exist, or be an empty directory).

        Raises
        ------
        StoreError
            If ``root`` is a file, a non-empty directory that is not a session, or already a session.
        """
        root = Path(root)
        if root.exists():
            if not root.is_dir():
                raise StoreError(f"output {root} exists and is not a directory")
            if (root / SESSION_FILE).exists():
                raise StoreError(
                    f"output directory {root} already holds a session; continue it with "
                    f"`brdfrig capture resume {root}` or choose a new --out"
                )
            if any(root.iterdir()):
                raise StoreError(
                    f"output directory {root} exists, is not empty and is not a brdfrig session "
                    f"(no {SESSION_FILE}); refusing to write into it: choose a new --out"
                )
        # Build the directory under a temporary name, then rename it into place: a crash during creation
        # leaves either no session or a complete one (never a half-made directory that blocks a rerun).
        root.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{root.name}.creating-", dir=root.parent))
        try:
            for sub in (RAW_DIR, INCOMING_DIR, CACHE_DIR, RESULTS_DIR):
                (tmp / sub).mkdir()
            info = {"format": FORMAT_NAME, "version": FORMAT_VERSION, "created": _now(), "config": config}
            manifest = {"format": FORMAT_NAME, "version": FORMAT_VERSION, "files": {}}
            atomic_write_bytes(tmp / MANIFEST_FILE, _dumps(manifest))
            atomic_write_bytes(tmp / SESSION_FILE, _dumps(info))
            os.chmod(tmp, 0o755)
            os.rename(tmp, root)  # replaces an empty directory, fails on a non-empty one
            _fsync_dir(root.parent)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        store = cls(root, info, manifest)
        store.append("session_created", format_version=FORMAT_VERSION)
        return store

    @classmethod
    def open(cls, root: str | os.PathLike) -> "SessionStore":
        """Open an existing session directory.

        Raises
        ------
        StoreError
            If ``root`` is not a session, or was written by a newer format version.
        """
        root = Path(root)
        if not root.is_dir():
            raise StoreError(f"session directory {root} does not exist")
        info = _load_json(root / SESSION_FILE, f"{root} is not a brdfrig session (no readable {SESSION_FILE})")
        if info.get("format") != FORMAT_NAME:
            raise StoreError(f"{root / SESSION_FILE} is not a brdfrig session file (format {info.get('format')!r})")
        version = info.get("version")
        if not isinstance(version, int) or version > FORMAT_VERSION:
            raise StoreError(
                f"session {root} was written with session format version {version}; this brdfrig reads "
                f"versions <= {FORMAT_VERSION}: upgrade brdfrig to open it (nothing was changed)"
            )
        _check_session_info(info, root / SESSION_FILE)
        manifest = _load_json(root / MANIFEST_FILE, f"session {root} has no readable {MANIFEST_FILE}")
        _check_manifest(manifest, root / MANIFEST_FILE)
        for sub in (RAW_DIR, INCOMING_DIR, CACHE_DIR, RESULTS_DIR):
            (root / sub).mkdir(exist_ok=True)
        return cls(root, info, manifest)

    # ------------------------------------------------------------------------------------ writers
    @contextlib.contextmanager
    def locked(self):
        """Hold the session's writer lock (``DIR/.lock``, an exclusive ``flock``) for the ``with`` block.

        Every writer (capture run, resume, refit) holds it; the kernel releases it when the
        process dies, so a killed writer never leaves the session locked.  The lock is
        non-blocking and re-entrant within one thread (a capture that fits what it shot
        holds it once for both); another process, or another thread, is refused.

        Raises
        ------
        StoreError
            If another process holds it: "session DIR in use by PID N".
        """
        key = (os.path.realpath(self.root), threading.get_ident())
        if key in _HELD_LOCKS:
            _HELD_LOCKS[key] += 1
            try:
                yield self
            finally:
                _HELD_LOCKS[key] -= 1
            return
        fd = os.open(self.root / LOCK_FILE, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown"
                raise StoreError(f"session {self.root} in use by PID {holder}: wait for it to finish "
                                 "(nothing was changed)") from None
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
            _HELD_LOCKS[key] = 1
            try:
                yield self
            finally:
                del _HELD_LOCKS[key]
        finally:
            os.close(fd)  # releases the lock

    # ------------------------------------------------------------------------------------ journal
    def append(self, event: str, **fields) -> dict:
        """Append one record ``{"time", "event", **fields}`` to the journal and fsync it."""
        record = {"time": _now(), "event": event, **fields}
        line = (json.dumps(record, sort_keys=True) + "\n").encode()
        path = self.root / JOURNAL_FILE
        fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        try:
            size = os.fstat(fd).st_size
            if size:
                with open(path, "rb") as f:
                    f.seek(size - 1)
                    if f.read(1) != b"\n":  # torn record from a crash: terminate it, never rewrite it
                        line = b"\n" + line
            _write_fully(fd, line)
            os.fsync(fd)
        except OSError as exc:
            raise _disk_full(exc, path) from exc
        finally:
            os.close(fd)
        return record

    def journal(self) -> list[dict]:
        """All complete journal records, oldest first (torn lines from crashes are skipped)."""
        path = self.root / JOURNAL_FILE
        if not path.exists():
            return []
        out = []
        for line in path.read_bytes().split(b"\n"):
            try:
                rec = json.loads(line)
            except ValueError:
                continue
            if isinstance(rec, dict):
                out.append(rec)
        return out

    # ------------------------------------------------------------------------------------ files
    @property
    def files(self) -> dict[str, dict]:
        """Manifest entries by relative path: ``{"sha256", "size", **metadata}``."""
        return self._manifest["files"]

    @property
    def incoming(self) -> Path:
        """Directory where cameras write files before they are stored."""
        return self.root / INCOMING_DIR

    def unused_name(self, subdir: str, stem: str, suffix: str) -> str:
        """A relative path ``subdir/stem[.aN]suffix`` that no file (stored or not) uses yet."""
        n = 0
        while True:
            rel = f"{subdir}/{stem}{'' if n == 0 else f'.a{n}'}{suffix}"
            if not (self.root / rel).exists() and rel not in self.files:
                return rel
            n += 1

    def store_file(self, src: str | os.PathLike, subdir: str, stem: str, **meta) -> str:
        """Move a complete file (e.g. from :attr:`incoming`) into the session; return its relative path.

        The file is fsynced, linked under a fresh name (never replacing anything),
        hashed into the manifest (atomic rewrite) and journalled.  On error the
        source file is left where it was and the manifest is unchanged.
        """
        src = Path(src)
        rel = self.unused_name(subdir, stem, src.suffix.lower())
        dest = self.root / rel
        dest.parent.mkdir(parents=True, exist_ok=True)
        try:
            fd = os.open(src, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
            digest, size = sha256_file(src), src.stat().st_size
            os.link(src, dest)
            _fsync_dir(dest.parent)
        except OSError as exc:
            raise _disk_full(exc, dest) from exc
        try:
            self._add_to_manifest(rel, {"sha256": digest, "size": size, **meta})
        except OSError:
            os.unlink(dest)  # not listed, so not stored: the source file is still in place
            raise
        os.unlink(src)
        self.append("file", path=rel, sha256=digest, **meta)
        return rel

    def write_file(self, rel: str, data: bytes, **meta) -> str:
        """Store new bytes under the relative path ``rel`` (must not exist) and list them in the manifest."""
        dest = self.root / rel
        dest.parent.mkdir(parents=True, exist_ok=True)
        if rel in self.files:
            raise FileExistsError(f"{dest} is already stored in the session; refusing to overwrite it")
        atomic_write_bytes(dest, data, overwrite=False)
        digest = hashlib.sha256(data).hexdigest()
        self._add_to_manifest(rel, {"sha256": digest, "size": len(data), **meta})
        self.append("file", path=rel, sha256=digest, **meta)
        return rel

    def _add_to_manifest(self, rel: str, entry: dict) -> None:
        new = {**self._manifest, "files": {**self.files, rel: entry}}
        atomic_write_bytes(self.root / MANIFEST_FILE, _dumps(new))
        self._manifest = new

    def reject(self, rels: list[str], reason: str) -> None:
        """Drop entries from the manifest (the files stay on disk, untracked) and journal why."""
        if not rels:
            return
        files = {k: v for k, v in self.files.items() if k not in rels}
        rejected = list(self._manifest.get("rejected", [])) + [
            {"path": r, "reason": reason, "entry": self.files[r]} for r in rels if r in self.files
        ]
        new = {**self._manifest, "files": files, "rejected": rejected}
        atomic_write_bytes(self.root / MANIFEST_FILE, _dumps(new))
        self._manifest = new
        self.append("rejected", paths=list(rels), reason=reason)

    def verify(self, prefix: str = "") -> Verification:
        """Check the sha256 and size of every manifest entry (under ``prefix``); list untracked raw files."""
        result = Verification()
        for rel, entry in sorted(self.files.items()):
            if not rel.startswith(prefix):
                continue
            path = self.root / rel
            if not path.is_file():
                result.missing.append(rel)
            elif path.stat().st_size != entry["size"] or sha256_file(path) != entry["sha256"]:
                result.corrupt.append(rel)
            else:
                result.ok.append(rel)
        raw = self.root / RAW_DIR
        if raw.is_dir():
            for p in sorted(raw.rglob("*")):
                rel = p.relative_to(self.root).as_posix()
                if p.is_file() and rel not in self.files:
                    result.untracked.append(rel)
        return result

    def staging_results_dir(self) -> Path:
        """A new private directory ``results/.staging-PID-*`` to build one pipeline run's outputs in.

        Nothing in it counts until :meth:`commit_results` renames it to ``fit-NNN``; a run
        that dies leaves only its staging directory, which a later commit removes.
        """
        base = self.root / RESULTS_DIR
        base.mkdir(exist_ok=True)
        return Path(tempfile.mkdtemp(prefix=f".staging-{os.getpid()}-", dir=base))

    def commit_results(self, staging: Path) -> Path:
        """Rename a finished staging directory to the next free ``results/fit-NNN`` (atomic; earlier
        results are never overwritten) and remove staging directories of runs that died."""
        base = self.root / RESULTS_DIR
        _fsync_dir(staging)
        n = 1 + max((int(m.group(1)) for p in base.iterdir() if (m := re.fullmatch(r"fit-(\d+)", p.name))), default=0)
        while True:
            path = base / f"fit-{n:03d}"
            if not path.exists():
                try:
                    os.rename(staging, path)  # fails if another run filled that name meanwhile
                    break
                except OSError as exc:
                    if exc.errno not in (errno.ENOTEMPTY, errno.EEXIST):
                        raise
            n += 1
        _fsync_dir(base)
        for p in base.glob(".staging-*"):
            if p.is_dir() and not _pid_alive(p):
                shutil.rmtree(p, ignore_errors=True)
        return path

    def clean_incoming(self) -> list[str]:
        """Remove leftovers in :attr:`incoming` (files a crashed run never stored); return their names."""
        names = []
        for p in sorted(self.incoming.iterdir()):
            if p.is_file():
                p.unlink()
                names.append(p.name)
        return names

    @property
    def config(self) -> dict:
        """The session config dict stored at creation."""
        return self.info["config"]


def _dumps(obj) -> bytes:
    return (json.dumps(obj, indent=1, sort_keys=True) + "\n").encode()


def _load_json(path: Path, message: str) -> dict:
    try:
        with open(path, "rb") as f:
            data = json.load(f)
    except (OSError, ValueError):
        raise StoreError(message) from None
    if not isinstance(data, dict):
        raise StoreError(message)
    return data


def _damaged(path: Path, what: str) -> StoreError:
    return StoreError(f"{path} is damaged: {what}; restore it from a backup (nothing was changed)")


def _check_session_info(info: dict, path: Path) -> None:
    """StoreError naming ``path`` and the key unless ``info`` has the fields of a session file."""
    for key, kind in (("created", str), ("config", dict)):
        if not isinstance(info.get(key), kind):
            raise _damaged(path, f"key {key!r} is missing or not a {kind.__name__} (got {info.get(key)!r:.60})")


_SHOT_FIELDS = {"key": str, "scene": int, "angle_deg": (int, float), "time_s": (int, float)}  # "key" required


def check_shot_entry(rel: str, entry: dict, path: Path, required: tuple[str, ...] = ("key",)) -> None:
    """StoreError naming ``path`` and ``rel`` unless a shot's manifest entry has well-formed shot fields.

    Fields in ``required`` must be present; the others of ``key, scene,
    angle_deg, time_s`` must be well-formed when present.
    """
    for key, kind in _SHOT_FIELDS.items():
        if key not in entry and key not in required:
            continue
        value = entry.get(key)
        if isinstance(value, bool) or not isinstance(value, kind) or (
                isinstance(value, float) and not math.isfinite(value)):
            raise _damaged(path, f"entry {rel!r}: key {key!r} is missing or malformed (got {value!r:.60})")
    if entry.get("scene", 0) < 0 or not entry.get("time_s", 1) > 0:
        raise _damaged(path, f"entry {rel!r}: scene {entry.get('scene')} / time_s {entry.get('time_s')} out of range")


def _check_manifest(manifest: dict, path: Path) -> None:
    """StoreError naming ``path`` and the entry/key unless every manifest entry has the fields its readers use."""
    files = manifest.get("files")
    if not isinstance(files, dict):
        raise _damaged(path, f"key 'files' is missing or not a table (got {files!r:.60})")
    if not isinstance(manifest.get("rejected", []), list):
        raise _damaged(path, "key 'rejected' is not a list")
    for rel, entry in files.items():
        where = f"entry {rel!r}"
        if Path(rel).is_absolute() or ".." in Path(rel).parts:
            raise _damaged(path, f"{where} is not a path inside the session")
        if not isinstance(entry, dict):
            raise _damaged(path, f"{where} is not a table")
        sha = entry.get("sha256")
        if not (isinstance(sha, str) and re.fullmatch(r"[0-9a-f]{64}", sha)):
            raise _damaged(path, f"{where}: key 'sha256' is missing or not a sha256 hex digest")
        size = entry.get("size")
        if isinstance(size, bool) or not isinstance(size, int) or size < 0:
            raise _damaged(path, f"{where}: key 'size' is missing or not a byte count")
        if entry.get("kind") in ("exposure", "meter"):
            check_shot_entry(rel, entry, path)
