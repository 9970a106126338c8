"""The material library: one SQLite file cataloguing sessions and every fit made of them.

Where the file is: ``--library FILE``, else ``$BRDFRIG_LIBRARY``, else
``$XDG_DATA_HOME/brdfrig/library.sqlite`` (``~/.local/share/brdfrig/library.sqlite``).

Schema (``PRAGMA user_version`` holds its version, :data:`SCHEMA_VERSION`):

- ``sessions``: one row per registered session directory (``root`` is its absolute
  path), its name, sample names and when it was created and registered;
- ``fits``: one row per results directory (``results_dir`` is unique, so a fit is
  never recorded twice): session, sample, model, band limits, solver, the fit's
  image error and relighting-error estimate, the BRDF file, brdfrig's version, when;
- ``exports``: one row per export of a BRDF file: format, file, the error it introduces, when.

Every write is one transaction; the file runs in WAL mode with a busy timeout, so
two processes writing at once are serialised by SQLite, and a killed process
leaves the last committed state.  A file written by a newer brdfrig (higher
``user_version``) is refused, never altered.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import sqlite3
from contextlib import closing
from dataclasses import dataclass
from pathlib import Path

from brdfrig.errors import StoreError

__all__ = ["SCHEMA_VERSION", "Library", "FitRecord", "default_library_path"]

SCHEMA_VERSION = 3

MIGRATIONS: dict[int, str] = {
    # version 1: sessions and fits
    1: """
        CREATE TABLE sessions (
            id INTEGER PRIMARY KEY,
            root TEXT NOT NULL UNIQUE,
            name TEXT NOT NULL,
            samples TEXT NOT NULL,
            created TEXT,
            added TEXT NOT NULL
        );
        CREATE TABLE fits (
            id INTEGER PRIMARY KEY,
            session_id INTEGER NOT NULL REFERENCES sessions(id),
            sample TEXT NOT NULL,
            model TEXT NOT NULL,
            lmax INTEGER, pmax INTEGER, solver TEXT,
            image_error REAL,
            brdf_path TEXT NOT NULL,
            results_dir TEXT NOT NULL,
            version TEXT NOT NULL,
            recorded TEXT NOT NULL,
            UNIQUE (results_dir, sample)
        );
    """,
    # version 2: the relighting-error estimate, the requested model, seconds, and an index for listings
    2: """
        ALTER TABLE fits ADD COLUMN requested_model TEXT;
        ALTER TABLE fits ADD COLUMN relighting_estimate REAL;
        ALTER TABLE fits ADD COLUMN seconds REAL;
        CREATE INDEX fits_by_session ON fits(session_id, recorded);
    """,
    # version 3: exports of fitted BRDFs, with the error each introduces
    3: """
        CREATE TABLE exports (
            id INTEGER PRIMARY KEY,
            brdf_path TEXT NOT NULL,
            format TEXT NOT NULL,
            path TEXT NOT NULL,
            relative_rms REAL,
            version TEXT NOT NULL,
            recorded TEXT NOT NULL,
            UNIQUE (path, recorded)
        );
    """,
}


def default_library_path() -> Path:
    """``$BRDFRIG_LIBRARY``, else ``$XDG_DATA_HOME/brdfrig/library.sqlite`` (XDG default ``~/.local/share``)."""
    env = os.environ.get("BRDFRIG_LIBRARY")
    if env:
        return Path(env)
    data = os.environ.get("XDG_DATA_HOME") or str(Path.home() / ".local" / "share")
    return Path(data) / "brdfrig" / "library.sqlite"


def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


@dataclass(frozen=True)
class FitRecord:
    """One catalogued fit (a row of ``fits`` joined with its session)."""

    session: str
    session_root: str
    sample: str
    model: str
    requested_model: str | None
    lmax: int | None
    pmax: int | None
    solver: str | None
    image_error: float | None
    relighting_estimate: float | None
    seconds: float | None
    brdf_path: str
    results_dir: str
    version: str
    recorded: str


_FIT_COLUMNS = ("s.name", "s.root", "f.sample", "f.model", "f.requested_model", "f.lmax", "f.pmax", "f.solver",
                "f.image_error", "f.relighting_estimate", "f.seconds", "f.brdf_path", "f.results_dir", "f.version",
                "f.recorded")


class Library:
    """An open catalogue file (see the module docstring).  Use as a context manager or call :meth:`close`.

    Parameters
    ----------
    path : path-like
        The SQLite file; created (with its directory) when missing.

    Raises
    ------
    StoreError
        If the file is not a brdfrig library, is damaged, or was written by a newer brdfrig.
    """

    def __init__(self, path) -> None:
        self.path = Path(path)
        if self.path.exists() and not self.path.is_file():
            raise StoreError(f"library {self.path} is not a file")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        try:
            self._db = sqlite3.connect(self.path, timeout=30.0, isolation_level=None)
            self._db.execute("PRAGMA busy_timeout = 30000")
            self._check_version()  # before anything that writes (WAL mode rewrites the header)
            self._db.execute("PRAGMA journal_mode = WAL")
            self._db.execute("PRAGMA foreign_keys = ON")
            self._migrate()
        except sqlite3.DatabaseError as exc:
            raise StoreError(f"library {self.path} is not a readable brdfrig library ({exc})") from None

    # ------------------------------------------------------------------------------------ schema
    def _check_version(self) -> None:
        version = self._db.execute("PRAGMA user_version").fetchone()[0]
        if version > SCHEMA_VERSION:
            self._db.close()
            raise StoreError(f"library {self.path} has schema version {version}; this brdfrig reads versions "
                             f"<= {SCHEMA_VERSION}: upgrade brdfrig to use it (nothing was changed)")

    def _migrate(self) -> None:
        version = self._db.execute("PRAGMA user_version").fetchone()[0]
        for v in range(version + 1, SCHEMA_VERSION + 1):
            try:  # one transaction per step: the schema and its version change together or not at all
                self._db.executescript(f"BEGIN IMMEDIATE; {MIGRATIONS[v]}; PRAGMA user_version = {v}; COMMIT;")
            except BaseException:
                if self._db.in_transaction:
                    self._db.execute("ROLLBACK")
                raise

    def _transaction(self):
        """``with`` block: one IMMEDIATE transaction (writers serialised), committed or rolled back."""
        db = self._db

        class _Tx:
            def __enter__(self_inner):
                db.execute("BEGIN IMMEDIATE")
                return db

            def __exit__(self_inner, kind, exc, tb):
                db.execute("ROLLBACK" if kind else "COMMIT")
                return False

        return _Tx()

    @property
    def schema_version(self) -> int:
        return self._db.execute("PRAGMA user_version").fetchone()[0]

    def integrity_check(self) -> str:
        """SQLite's ``PRAGMA integrity_check`` result (``"ok"`` for a sound file)."""
        return self._db.execute("PRAGMA integrity_check").fetchone()[0]

    def close(self) -> None:
        self._db.close()

    def __enter__(self) -> "Library":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------------------------ sessions
    def add_session(self, root) -> tuple[str, bool]:
        """Register the session at ``root`` after verifying it against its manifest.

        Returns
        -------
        (name, added) : the session's name and False if it was registered already.

        Raises
        ------
        StoreError
            If ``root`` is not a session or a stored file fails its checksum.
        """
        from brdfrig.session.store import SessionStore

        store = SessionStore.open(root)
        check = store.verify()
        if not check.passed:
            raise StoreError(f"session {store.root} does not verify: {check.describe()}")
        config = store.config
        name = str(config.get("session", {}).get("name") or store.root.name)
        samples = [s.get("name") for s in config.get("plan", {}).get("samples", []) if isinstance(s, dict)]
        with self._transaction() as db:
            cur = db.execute("INSERT OR IGNORE INTO sessions (root, name, samples, created, added) VALUES (?,?,?,?,?)",
                             (str(store.root.resolve()), name, json.dumps(samples), store.info.get("created"), _now()))
        return name, cur.rowcount == 1

    def add_root(self, root) -> list[tuple[str, bool]]:
        """Register every session found below ``root`` (directories holding a ``session.json``)."""
        from brdfrig.session.store import find_sessions

        return [self.add_session(p) for p in find_sessions(root)]

    def session_roots(self) -> list[str]:
        return [r[0] for r in self._db.execute("SELECT root FROM sessions ORDER BY name, root")]

    # ------------------------------------------------------------------------------------ fits
    def record_fit(self, session_root, sample: str, *, model: str, brdf_path, results_dir, version: str,
                   requested_model: str | None = None, lmax: int | None = None, pmax: int | None = None,
                   solver: str | None = None, image_error: float | None = None,
                   relighting_estimate: float | None = None, seconds: float | None = None) -> bool:
        """Record one fit; the session is registered first if needed.  False if this results directory
        and sample were recorded already (a retried task records nothing twice)."""
        root = str(Path(session_root).resolve())
        with self._transaction() as db:
            row = db.execute("SELECT id FROM sessions WHERE root = ?", (root,)).fetchone()
            if row is None:
                db.execute("INSERT INTO sessions (root, name, samples, created, added) VALUES (?,?,?,?,?)",
                           (root, Path(root).name, "[]", None, _now()))
                row = db.execute("SELECT id FROM sessions WHERE root = ?", (root,)).fetchone()
            cur = db.execute(
                "INSERT OR IGNORE INTO fits (session_id, sample, model, requested_model, lmax, pmax, solver, "
                "image_error, relighting_estimate, seconds, brdf_path, results_dir, version, recorded) "
                "VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?,?)",
                (row[0], sample, model, requested_model, lmax, pmax, solver, image_error, relighting_estimate,
                 seconds, str(Path(brdf_path).resolve()), str(Path(results_dir).resolve()), version, _now()))
        return cur.rowcount == 1

    def fits(self, *, model: str | None = None, max_error: float | None = None, sample: str | None = None,
             since: str | None = None, session: str | None = None) -> list[FitRecord]:
        """Catalogued fits, newest first, filtered by model, error (relighting estimate, else image error),
        sample name, ISO date/time ``since``, and session name or root."""
        where, args = [], []
        for clause, value in (("f.model = ?", model), ("f.sample = ?", sample), ("f.recorded >= ?", since)):
            if value is not None:
                where.append(clause)
                args.append(value)
        if max_error is not None:
            where.append("COALESCE(f.relighting_estimate, f.image_error) <= ?")
            args.append(max_error)
        if session is not None:
            where.append("(s.name = ? OR s.root = ?)")
            args += [session, str(Path(session).resolve())]
        sql = (f"SELECT {', '.join(_FIT_COLUMNS)} FROM fits f JOIN sessions s ON s.id = f.session_id"
               + (" WHERE " + " AND ".join(where) if where else "") + " ORDER BY f.recorded DESC, f.id DESC")
        with closing(self._db.execute(sql, args)) as cur:
            return [FitRecord(*row) for row in cur.fetchall()]

    def sessions(self) -> list[dict]:
        """Registered sessions with their number of catalogued fits."""
        sql = ("SELECT s.name, s.root, s.samples, s.created, s.added, COUNT(f.id) FROM sessions s "
               "LEFT JOIN fits f ON f.session_id = s.id GROUP BY s.id ORDER BY s.name, s.root")
        return [{"name": n, "root": r, "samples": json.loads(sm), "created": c, "added": a, "fits": k}
                for n, r, sm, c, a, k in self._db.execute(sql)]

    def record_export(self, brdf_path, fmt: str, path, relative_rms: float | None, version: str) -> None:
        """Record one export of a BRDF file (format, file written, its approximation error)."""
        with self._transaction() as db:
            db.execute("INSERT INTO exports (brdf_path, format, path, relative_rms, version, recorded) "
                       "VALUES (?,?,?,?,?,?)", (str(Path(brdf_path).resolve()), fmt, str(Path(path).resolve()),
                                                relative_rms, version, _now()))

    def exports(self, brdf_path=None) -> list[dict]:
        """Recorded exports (of one BRDF file, or all), newest first."""
        sql = "SELECT brdf_path, format, path, relative_rms, version, recorded FROM exports"
        args = []
        if brdf_path is not None:
            sql += " WHERE brdf_path = ?"
            args.append(str(Path(brdf_path).resolve()))
        keys = ("brdf_path", "format", "path", "relative_rms", "version", "recorded")
        return [dict(zip(keys, row)) for row in self._db.execute(sql + " ORDER BY recorded DESC, id DESC", args)]

