"""``brdfrig refit`` verifies the session before anything else: flipped bytes and missing files are named."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from brdfrig.session.config import session_config_from_dict
from brdfrig.session.store import FORMAT_VERSION, SessionStore

ROOT = Path(__file__).resolve().parents[1]


def brdfrig(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "brdfrig", *map(str, args)], cwd=ROOT, capture_output=True,
                          text=True, timeout=120)


def make_session(path: Path, n: int = 3) -> SessionStore:
    cfg = session_config_from_dict({
        "rig": {"carries": "rig", "turntable": {"backend": "sim"}, "camera": {"backend": "sim"}},
        "plan": {"scenes": 1, "exposure": [0.01 * 2**i for i in range(n)], "probe": {"circle": [5, 5, 4]},
                 "samples": [{"name": "a", "circle": [15, 5, 4]}]},
    }, "t")
    store = SessionStore.create(path, cfg.to_dict())
    for i in range(n):
        src = store.incoming / f"IMG_{i}.dng"
        src.write_bytes(bytes(range(256)) * 8)
        store.store_file(src, "raw", f"s00-a000.0-e{i:02d}", kind="exposure", key=f"s00-a000.0-e{i:02d}", scene=0,
                         angle_deg=0.0, time_s=0.01 * 2**i)
    return store


def test_flipped_byte_is_named_and_nothing_is_processed(tmp_path):
    store = make_session(tmp_path / "s")
    victim = tmp_path / "s" / "raw" / "s00-a000.0-e01.dng"
    data = bytearray(victim.read_bytes())
    data[1000] ^= 0x10
    victim.write_bytes(bytes(data))
    r = brdfrig("refit", tmp_path / "s", "--model", "diffuse")
    assert r.returncode == 2, r.stderr
    line = r.stderr.strip().splitlines()[-1]
    assert line.startswith("brdfrig refit: error: session ") and "fails verification" in line
    assert "checksum mismatch: raw/s00-a000.0-e01.dng" in line
    assert "e00" not in line and "e02" not in line
    assert not list((tmp_path / "s" / "results").iterdir())  # refused before writing anything
    assert victim.read_bytes() == bytes(data)  # and the evidence is left as it was


def test_missing_file_is_named(tmp_path):
    make_session(tmp_path / "s")
    (tmp_path / "s" / "raw" / "s00-a000.0-e02.dng").unlink()
    r = brdfrig("refit", tmp_path / "s")
    assert r.returncode == 2 and "missing: raw/s00-a000.0-e02.dng" in r.stderr


def test_newer_format_and_non_session_are_refused(tmp_path):
    make_session(tmp_path / "s")
    info = json.loads((tmp_path / "s" / "session.json").read_text())
    info["version"] = FORMAT_VERSION + 1
    (tmp_path / "s" / "session.json").write_text(json.dumps(info))
    r = brdfrig("refit", tmp_path / "s")
    assert r.returncode == 2 and f"session format version {FORMAT_VERSION + 1}" in r.stderr
    r = brdfrig("capture", "resume", tmp_path / "s")
    assert r.returncode == 2 and "upgrade brdfrig" in r.stderr
    (tmp_path / "plain").mkdir()
    r = brdfrig("refit", tmp_path / "plain")
    assert r.returncode == 2 and "is not a brdfrig session" in r.stderr


def test_bad_fit_option_is_named(tmp_path):
    make_session(tmp_path / "s")
    r = brdfrig("refit", tmp_path / "s", "--lmax", "99")
    assert r.returncode == 2 and "argument --lmax: must be an integer in [0, 30], got '99'" in r.stderr
