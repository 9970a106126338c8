"""The material library (SQLite catalogue): schema, migrations, filters, crash and concurrency safety."""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import signal
import sqlite3
import subprocess
import sys
import time

import pytest

from brdfrig.errors import StoreError
from brdfrig.session.library import MIGRATIONS, SCHEMA_VERSION, Library


def _fit(lib, i, **kw):
    args = {"model": "diffuse", "brdf_path": f"/x/{i}.json", "results_dir": f"/x/fit-{i:03d}", "version": "t"}
    return lib.record_fit("/x/session", "matte", **{**args, **kw})


def test_fits_are_recorded_once_and_filtered(tmp_path):
    with Library(tmp_path / "lib.sqlite") as lib:
        assert lib.schema_version == SCHEMA_VERSION and lib.integrity_check() == "ok"
        assert _fit(lib, 1, image_error=0.02) and not _fit(lib, 1, image_error=0.02)  # same results dir: once
        _fit(lib, 2, model="microfacet", relighting_estimate=0.08, image_error=0.01)
        _fit(lib, 3, model="lobe", image_error=0.2)
        assert len(lib.fits()) == 3
        assert [f.model for f in lib.fits(model="microfacet")] == ["microfacet"]
        # the relighting estimate is the error when known, else the image error
        assert sorted(f.model for f in lib.fits(max_error=0.05)) == ["diffuse"]
        assert lib.fits(since="2999-01-01") == [] and len(lib.fits(sample="matte")) == 3
        assert lib.sessions()[0]["fits"] == 3


def test_a_version_1_catalogue_is_migrated_with_its_rows(tmp_path):
    path = tmp_path / "old.sqlite"
    db = sqlite3.connect(path)
    db.executescript(MIGRATIONS[1] + "PRAGMA user_version = 1;")  # a catalogue written by the first release
    db.execute("INSERT INTO sessions (root, name, samples, added) VALUES ('/s', 's', '[]', 'then')")
    db.execute("INSERT INTO fits (session_id, sample, model, brdf_path, results_dir, version, recorded) "
               "VALUES (1, 'a', 'lobe', '/s/a.json', '/s/fit-001', '0.1', 'then')")
    db.commit()
    db.close()
    with Library(path) as lib:
        assert lib.schema_version == SCHEMA_VERSION
        (fit,) = lib.fits()
        assert (fit.model, fit.relighting_estimate, fit.session) == ("lobe", None, "s")


def test_a_newer_catalogue_is_refused_unchanged(tmp_path):
    path = tmp_path / "new.sqlite"
    db = sqlite3.connect(path)
    db.execute(f"PRAGMA user_version = {SCHEMA_VERSION + 1}")
    db.close()
    before = path.read_bytes()
    with pytest.raises(StoreError, match=f"schema version {SCHEMA_VERSION + 1}.*upgrade brdfrig"):
        Library(path)
    assert path.read_bytes() == before


def test_a_file_that_is_not_a_catalogue_is_named(tmp_path):
    path = tmp_path / "junk.sqlite"
    path.write_bytes(b"not a database at all" * 100)
    with pytest.raises(StoreError, match="junk.sqlite is not a readable brdfrig library"):
        Library(path)


def _writer(path, start, count):
    with Library(path) as lib:
        for i in range(start, start + count):
            _fit(lib, i)


def test_two_processes_writing_at_once_are_serialised(tmp_path):
    path = tmp_path / "lib.sqlite"
    Library(path).close()
    ctx = mp.get_context("spawn")
    procs = [ctx.Process(target=_writer, args=(path, k * 1000, 150)) for k in range(2)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(120)
        assert p.exitcode == 0
    with Library(path) as lib:
        assert len(lib.fits()) == 300 and lib.integrity_check() == "ok"


def test_a_process_killed_mid_batch_leaves_a_consistent_catalogue(tmp_path):
    path = tmp_path / "lib.sqlite"
    code = ("import sys, time; from brdfrig.session.library import Library\n"
            "lib = Library(sys.argv[1])\n"
            "for i in range(100000):\n"
            "    lib.record_fit('/x/s', 'a', model='m', brdf_path=f'/x/{i}', results_dir=f'/x/fit-{i}', version='t')\n"
            "    print(i, flush=True)\n")
    p = subprocess.Popen([sys.executable, "-c", code, str(path)], stdout=subprocess.PIPE, text=True)
    done = -1
    for line in p.stdout:  # wait until at least 200 fits were committed, then kill mid-write
        done = int(line)
        if done >= 200:
            break
    os.kill(p.pid, signal.SIGKILL)
    p.wait()
    with Library(path) as lib:
        assert lib.integrity_check() == "ok"
        recorded = {f.results_dir for f in lib.fits()}
    # every fit the writer reported committed is there (it prints after the commit)
    assert {f"/x/fit-{i}" for i in range(done + 1)} <= recorded
    assert len(recorded) <= done + 2


def test_exports_are_recorded(tmp_path):
    with Library(tmp_path / "lib.sqlite") as lib:
        lib.record_export(tmp_path / "a.brdf.json", "merl", tmp_path / "a.binary", 0.004, "t")
        (row,) = lib.exports(tmp_path / "a.brdf.json")
        assert (row["format"], row["relative_rms"]) == ("merl", 0.004) and lib.exports(tmp_path / "b.json") == []


def test_add_root_registers_each_verified_session_once(tmp_path):
    from brdfrig.session.store import SessionStore

    root = tmp_path / "results" / "bench"  # a root whose own path holds "results" is still searched
    for name in ("a/s1", "s2"):
        SessionStore.create(root / name, {"session": {"name": name.split("/")[-1]}})
    with Library(tmp_path / "lib.sqlite") as lib:
        assert lib.add_root(root) == [("s1", True), ("s2", True)]
        assert lib.add_root(root) == [("s1", False), ("s2", False)]
