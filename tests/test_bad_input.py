"""Bad input through the ``brdfrig`` command: one clear line, exit 2, nothing stored or given changed.

Each row of :data:`ROWS` is one bad input (a command line run in a fresh copy
of a small workspace, after an optional setup that damages something).  The
test asserts the exit code, that the last line of stderr is the error line and
matches the row's pattern, that no traceback is printed, and that no file of
the workspace changed, appeared or disappeared.  docs/BAD_INPUT.md is the
table of these rows with the line brdfrig printed; the test fails when it
differs from what brdfrig says now.  Regenerate it with::

    .venv/bin/python tests/test_bad_input.py
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import os
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import pytest

import brdfrig
from brdfrig.cli.main import main

DOC = Path(__file__).resolve().parents[1] / "docs" / "BAD_INPUT.md"
SIM_BENCH = Path(brdfrig.__file__).parent / "config" / "sim-bench.toml"
IGNORED = {".lock"}  # the session writer lock file: not stored data


@dataclass(frozen=True)
class Row:
    """One bad input: ``argv`` (relative to the workspace) after ``setup(ws)``; the expected line and exit code."""

    id: str
    what: str
    argv: tuple[str, ...]
    expect: str  # regex the error line must match
    code: int = 2
    setup: Callable[[Path], None] | None = field(default=None, compare=False)
    needs_root: bool = False


# ------------------------------------------------------------------------------------------ workspace
def _latlong(h: int = 32, w: int = 64) -> np.ndarray:
    from brdfrig.hdr.envmap import latlong_directions

    d, _ = latlong_directions(h, w)
    sun = np.clip(d @ np.array([0.3, 0.8, 0.5]), 0, None) ** 4
    return (0.2 + 0.5 * (d[..., 1:2] + 1) + 3 * sun[..., None]) * np.array([1.0, 0.85, 0.7], np.float32)


def _diffuse_brdf(albedo=(0.8, 0.6, 0.4), scale: float = 1.0):
    from brdfrig.fit.models import DiffuseBRDF
    from brdfrig.fit.system import ModelSpec

    # Lambertian: a_l = albedo * (1, 2/3, 1/4) for bands 0, 1, 2 (cosine-lobe SH)
    x = scale * np.outer([1.0, 2.0 / 3.0, 0.25], albedo)
    return DiffuseBRDF(ModelSpec("diffuse", 2, 0), x)


def _dng(path: Path, radiance: np.ndarray, t: float) -> None:
    from brdfrig.hdr.dng import write_dng

    black, white = 256, 16383
    raw = black + np.clip(radiance * t, 0, 1.1) * (white - black)
    write_dng(path, np.clip(np.round(raw), 0, white).astype(np.uint16), black_level=black,
              white_level=white, exposure_time_s=t, f_number=8.0, iso=100)


def _plan(ws: Path, name: str, old: str, new: str) -> None:
    text = SIM_BENCH.read_text()
    assert old in text, old
    (ws / name).write_text(text.replace(old, new, 1))


def _damaged_report(path: Path) -> None:
    """A diffuse BRDF file whose report holds a one-image estimate and a negative resampled table."""
    from brdfrig.fit.brdffile import save_brdf

    tables = np.ones((2, 3, 2, 4, 3))
    tables[1, 0, 0, 2, 1] = -0.5
    save_brdf(path, _diffuse_brdf(), report={"relight": {"value": 0.05, "method": "rotated-lighting spread", "detail": ""},
                                             "candidates": {"bivariate+measured": {"fit_report": {"resampled_tables": tables}}}})


def build_workspace(ws: Path) -> None:
    """The good inputs the rows misuse (written once, copied for every row)."""
    from brdfrig.fit.brdffile import save_brdf
    from brdfrig.hdr.exr import write_exr

    ws.mkdir(parents=True, exist_ok=True)
    write_exr(ws / "env.exr", _latlong(), latlong=True)
    save_brdf(ws / "brdf.json", _diffuse_brdf())
    save_brdf(ws / "huge.json", _diffuse_brdf(scale=1e308))
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["render", str(ws / "brdf.json"), "--lighting", str(ws / "env.exr"), "--size", "64",
                     "-o", str(ws / "sphere.exr")]) == 0
    shutil.copy(ws / "sphere.exr", ws / "p.exr")
    write_exr(ws / "flat.exr", np.full((64, 64, 3), 0.5, np.float32))
    x = np.linspace(0, 1, 96)[None, :]
    rng = np.random.default_rng(0)  # noise: the merged EXR does not compress below the tiny disk's size
    radiance = 2.0 * 10 ** (2 * x) * (1 + 0.05 * rng.standard_normal((64, 96)))
    _dng(ws / "a.dng", radiance, 1 / 400)
    _dng(ws / "b.dng", radiance, 1 / 100)
    shutil.copy(ws / "a.dng", ws / "a-copy.dng")
    shutil.copy(ws / "sphere.exr", ws / "exists.exr")
    _plan(ws, "plan-exposure.toml", 'exposure = "auto"', "exposure = [1e9]")
    _plan(ws, "plan-overhead.toml", "overhead_s = 0.5", "overhead_s = 1e300")
    _plan(ws, "plan-speed.toml", "speed_deg_s = 180.0", "speed_deg_s = 1e-6")
    _plan(ws, "plan-simkey.toml", "seed = 0", "seed = 0\nsacle = 2.0")
    _plan(ws, "plan-simscale.toml", "scale = 1.0", "scale = 100.0")
    _plan(ws, "plan-circle.toml", "circle = [115.0, 120.0, 90.0]", "circle = [615.0, 120.0, 90.0]")


def _session(ws: Path) -> Path:
    """A small valid session ``ws/sess`` (the shipped plan, one stored exposure)."""
    from brdfrig.session.config import load_session_config
    from brdfrig.session.store import SessionStore

    store = SessionStore.create(ws / "sess", load_session_config(SIM_BENCH).to_dict())
    src = store.incoming / "shot.dng"
    shutil.copy(ws / "a.dng", src)
    store.store_file(src, "raw", "s0-a0-e0", kind="exposure", key="s0-a0-e0", scene=0, angle_deg=0.0, time_s=0.0025)
    return ws / "sess"


def _damage(file: str, change: Callable[[dict], None] | None = None, text: str | None = None):
    def setup(ws: Path) -> None:
        path = _session(ws) / file
        if text is not None:
            path.write_text(text)
            return
        doc = json.loads(path.read_text())
        change(doc)
        path.write_text(json.dumps(doc))

    return setup


def _entry(doc: dict) -> dict:
    return next(iter(doc["files"].values()))


def _hard_link(ws: Path) -> None:
    os.link(ws / "p.exr", ws / "link.exr")


def _tiny_disk(ws: Path) -> None:
    (ws / "full").mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=8k", "tmpfs", str(ws / "full")], capture_output=True)
    if r.returncode:
        pytest.skip(f"cannot mount a tmpfs: {r.stderr.decode().strip()}")


def _read_only_dir(ws: Path) -> None:
    (ws / "ro").mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=8k", "tmpfs", str(ws / "ro")], capture_output=True)
    if r.returncode:
        pytest.skip(f"cannot mount a tmpfs: {r.stderr.decode().strip()}")


IS = r"is the input {}: brdfrig never overwrites its inputs; choose another output name"
M = ("merge", "a.dng", "b.dng")
ROWS: list[Row] = [
    # -- commands destroying their own inputs (issue 11 item 2)
    Row("probe-self", "probe output = its input", ("probe", "p.exr", "-o", "p.exr"), IS.format("p.exr")),
    Row("probe-self-path", "the same file by another path", ("probe", "p.exr", "-o", "./sub/../p.exr"),
        IS.format("p.exr"), setup=lambda ws: (ws / "sub").mkdir()),
    Row("probe-self-link", "the same file through a hard link", ("probe", "p.exr", "-o", "link.exr"),
        IS.format("p.exr"), setup=_hard_link),
    Row("fit-self", "fit output = its sphere image",
        ("fit", "--scene", "env.exr", "sphere.exr", "-o", "sphere.exr"), IS.format("sphere.exr")),
    Row("render-self", "render output = its lighting",
        ("render", "brdf.json", "--lighting", "env.exr", "--size", "16", "-o", "env.exr"), IS.format("env.exr")),
    Row("merge-self", "merge output = a frame", ("merge", "a.dng", "b.dng", "-o", "a.dng"), IS.format("a.dng")),
    Row("render-png", "render to a .png name (it writes EXR)",
        ("render", "brdf.json", "--lighting", "env.exr", "--size", "16", "-o", "preview.png"),
        r"writes a linear OpenEXR image; name the output \*\.exr"),
    Row("no-clobber", "--no-clobber and the output exists", (*M, "-o", "exists.exr", "--no-clobber"),
        r"exists and --no-clobber is given: nothing written"),
    Row("fit-figure-json", "fit --figure not a PNG",
        ("fit", "--scene", "env.exr", "sphere.exr", "--figure", "f.jpg", "-o", "o.json"), r"writes a PNG figure"),
    Row("fit-references-garbage", "fit --references a damaged file",
        ("fit", "--scene", "env.exr", "sphere.exr", "--references", "refs.npz", "-o", "o.json"),
        r"refs\.npz: unreadable reference tables", setup=lambda ws: (ws / "refs.npz").write_bytes(b"PK\x03\x04 cut short")),
    # -- garbage that used to be written with exit 0 (item 4)
    Row("read-noise-nan", "merge --read-noise nan", (*M, "--read-noise", "nan", "-o", "o.exr"),
        r"argument --read-noise: must be a number in \[0, 10000\], got 'nan'"),
    Row("full-well-negative", "merge --full-well -5", (*M, "--full-well", "-5", "-o", "o.exr"),
        r"argument --full-well: must be a number in \[1, 1e\+07\], got '-5'"),
    Row("full-well-zero", "merge --full-well 0", (*M, "--full-well", "0", "-o", "o.exr"),
        r"argument --full-well: must be a number in \[1, 1e\+07\], got '0'"),
    Row("times-inf", "merge --times with inf", (*M, "--times", "0.01,inf", "-o", "o.exr"),
        r"argument --times: each exposure time \(s\) must be a number in \(0, 3600\], got 'inf'"),
    Row("same-frame-twice", "the same frame twice", ("merge", "a.dng", "a.dng", "-o", "o.exr"),
        r"a\.dng is given twice \(also as a\.dng\): a bracket needs distinct frames"),
    Row("same-pixels-twice", "two copies of one frame", ("merge", "a.dng", "a-copy.dng", "-o", "o.exr"),
        r"a-copy\.dng and a\.dng hold identical pixels: the same frame given twice"),
    Row("render-damaged-report", "render a BRDF file whose resampled tables are negative",
        ("render", "damaged.json", "--lighting", "env.exr", "--size", "16", "-o", "o.exr"),
        r"damaged\.json: damaged fit report, no relighting estimate: resampled_tables of bivariate\+measured must be "
        r"finite non-negative", setup=lambda ws: _damaged_report(ws / "damaged.json")),
    Row("brdf-1e308", "BRDF file with coefficients 1e308",
        ("render", "huge.json", "--lighting", "env.exr", "--size", "16", "-o", "o.exr"),
        r"huge\.json: rendering gives \d+ non-finite value\(s\)"),
    Row("camera-mask-400", "probe --camera-mask 400", ("probe", "p.exr", "--camera-mask", "400", "-o", "e.exr"),
        r"argument --camera-mask: must be a number in \[0, 90\], got '400'"),
    Row("camera-mask-nan", "probe --camera-mask nan", ("probe", "p.exr", "--camera-mask", "nan", "-o", "e.exr"),
        r"argument --camera-mask: must be a number in \[0, 90\], got 'nan'"),
    Row("albedo-2", "probe --albedo 2", ("probe", "p.exr", "--albedo", "2", "-o", "e.exr"),
        r"argument --albedo: each albedo must be a number in \(0, 1\], got '2'"),
    Row("lmax-99", "fit --lmax 99", ("fit", "--scene", "env.exr", "sphere.exr", "--lmax", "99", "-o", "o.json"),
        r"argument --lmax: must be an integer in \[0, 30\], got '99'"),
    Row("config-exposure", "config exposure = [1e9]", ("capture", "run", "plan-exposure.toml", "--out", "s", "--dry-run"),
        r"key 'exposure' in \[plan\] of plan-exposure\.toml must be .*in \(0, 3600\]"),
    Row("config-overhead", "config overhead_s = 1e300",
        ("capture", "run", "plan-overhead.toml", "--out", "s", "--dry-run"),
        r"key 'overhead_s' in \[rig\.camera\] of plan-overhead\.toml must be a number in \[0, 600\], got 1e\+300"),
    Row("config-speed", "config speed_deg_s = 1e-6", ("capture", "run", "plan-speed.toml", "--out", "s", "--dry-run"),
        r"key 'speed_deg_s' in \[rig\.turntable\] of plan-speed\.toml must be a number in \[0\.1, 3600\], got 1e-06"),
    Row("config-sim-key", "[rig.sim] misspelt key, --dry-run",
        ("capture", "run", "plan-simkey.toml", "--out", "s", "--dry-run"),
        r"unknown key 'sacle' in \[rig\.sim\] of plan-simkey\.toml; did you mean 'scale'\?"),
    Row("config-sim-value", "[rig.sim] scale = 100, --dry-run",
        ("capture", "run", "plan-simscale.toml", "--out", "s", "--dry-run"),
        r"\[rig\.sim\] of plan-simscale\.toml: scale must be a number in \[0\.1, 8\], got 100\.0"),
    Row("config-circle-outside", "probe circle outside the frame, before shooting",
        ("capture", "run", "plan-circle.toml", "--out", "s"),
        r"key 'circle' in \[plan\.probe\] of plan-circle\.toml \(615\.00, 120\.00, 90\.00\) extends outside "
        r"the 640x240 image of the simulated camera"),
    # -- damaged session files: named, with the key (item 5)
    Row("session-json-truncated", "session.json truncated", ("refit", "sess"),
        r"sess is not a brdfrig session \(no readable session\.json\)", setup=_damage("session.json", text='{"form')),
    Row("session-json-no-config", "session.json without 'config'", ("refit", "sess"),
        r"session\.json is damaged: key 'config' is missing", setup=_damage("session.json", lambda d: d.pop("config"))),
    Row("session-json-no-plan", "stored config without [plan]", ("refit", "sess"),
        r"session\.json is damaged: in its stored config, key 'plan' is missing",
        setup=_damage("session.json", lambda d: d["config"].pop("plan"))),
    Row("session-json-bad-value", "stored config with scenes = 'many'", ("refit", "sess"),
        r"key 'scenes' in \[plan\] of sess/session\.json must be an integer in \[1, 360\], got 'many'",
        setup=_damage("session.json", lambda d: d["config"]["plan"].update(scenes="many"))),
    Row("manifest-truncated", "manifest.json truncated", ("refit", "sess"),
        r"session sess has no readable manifest\.json", setup=_damage("manifest.json", text='{"files": {')),
    Row("manifest-files-list", "manifest 'files' is a list", ("refit", "sess"),
        r"manifest\.json is damaged: key 'files' is missing or not a table",
        setup=_damage("manifest.json", lambda d: d.update(files=[]))),
    Row("manifest-no-sha", "manifest entry without sha256", ("refit", "sess"),
        r"manifest\.json is damaged: entry 'raw/s0-a0-e0\.dng': key 'sha256' is missing",
        setup=_damage("manifest.json", lambda d: _entry(d).pop("sha256"))),
    Row("manifest-no-scene", "manifest exposure without 'scene'", ("refit", "sess"),
        r"manifest\.json is damaged: entry 'raw/s0-a0-e0\.dng': key 'scene' is missing or malformed",
        setup=_damage("manifest.json", lambda d: _entry(d).pop("scene"))),
    Row("manifest-resume", "resume with a damaged manifest", ("capture", "resume", "sess", "--yes", "--no-fit"),
        r"manifest\.json is damaged: entry 'raw/s0-a0-e0\.dng': key 'size' is missing or not a byte count",
        setup=_damage("manifest.json", lambda d: _entry(d).update(size="big"))),
    # -- a benchmark's unfinished run: never overwritten, never resumed from nothing
    Row("bench-unfinished", "bench --measured into the directory of an unfinished run",
        ("bench", "--measured", "--out", "run"),
        r"run/measured\.partial\.json holds an unfinished run: continue it with --resume, or give another --out",
        setup=lambda ws: (ws / "run").mkdir() or (ws / "run" / "measured.partial.json").write_text("{}")),
    Row("bench-resume-nothing", "bench --measured --resume with nothing to resume", ("bench", "--measured", "--resume", "--out", "run"),
        r"--resume: run holds no unfinished run \(measured\.partial\.json is absent\)"),
    # -- sizes that would exhaust memory, files without what they need
    Row("probe-width-huge", "probe --width 200000", ("probe", "p.exr", "--width", "200000", "-o", "e.exr"),
        r"argument --width: must be an integer in \[8, 16384\], got '200000'"),
    Row("render-size-huge", "render --size 60000",
        ("render", "brdf.json", "--lighting", "env.exr", "--size", "60000", "-o", "o.exr"),
        r"argument --size: must be an integer in \[1, 4096\], got '60000'"),
    Row("no-sphere", "fit on an image without a sphere",
        ("fit", "--scene", "env.exr", "flat.exr", "--lmax", "2", "-o", "o.json"),
        r"flat\.exr: no sphere found in the image \(.*\); give the sphere's circle with --circle cx,cy,r"),
    Row("missing-file", "an input that does not exist", ("probe", "nope.exr", "-o", "e.exr"),
        r"nope\.exr: no such image file"),
    Row("read-only-dir", "output in a read-only directory", (*M, "-o", "ro/o.exr"),
        r"ro/o\.exr: Read-only file system", setup=_read_only_dir, needs_root=True),
    Row("disk-full", "a full disk (8 KiB tmpfs)", (*M, "-o", "full/o.exr"),
        r"disk full while writing full/o\.exr; nothing already stored was changed", setup=_tiny_disk, needs_root=True),
]


# ------------------------------------------------------------------------------------------ running
def _snapshot(ws: Path) -> dict[str, str]:
    return {str(p.relative_to(ws)): hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else "dir"
            for p in sorted(ws.rglob("*")) if p.name not in IGNORED}


def run_row(row: Row, base: Path, ws: Path) -> tuple[int, str, str, dict, dict]:
    """Run ``row`` in a fresh copy ``ws`` of ``base``; returns (code, error line, stderr, before, after)."""
    shutil.copytree(base, ws)
    mounted = False
    try:
        if row.setup is not None:
            row.setup(ws)
        mounted = [d for d in (ws / "full", ws / "ro") if os.path.ismount(d)]
        before = _snapshot(ws)
        err = io.StringIO()
        cwd = os.getcwd()
        os.chdir(ws)
        try:
            with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
                code = main(list(row.argv))
        finally:
            os.chdir(cwd)
        after = _snapshot(ws)
    finally:
        for d in mounted:
            subprocess.run(["umount", str(d)], check=True)
    text = err.getvalue().replace(f"{ws}/", "").replace(f"{ws.resolve()}/", "")  # paths as typed: relative
    lines = text.strip().splitlines()
    return code, lines[-1] if lines else "", text, before, after


def doc_table(results: list[tuple[Row, int, str]]) -> str:
    def cell(s: str) -> str:
        return s.replace("|", "\\|")

    out = [
        "# Bad input: what brdfrig says",
        "",
        "Generated by `tests/test_bad_input.py` (run it as a script to regenerate); the test fails when brdfrig",
        "says something else. Every command runs in a directory holding the named files; exit 2 means a user",
        "error (one line on stderr, nothing written, no input changed); a bug would print a traceback and exit 1.",
        "",
        "| case | input | what brdfrig says | exit |",
        "|---|---|---|---|",
    ]
    for row, code, line in results:
        out.append(f"| {row.id} | {cell(row.what)}: `brdfrig {cell(' '.join(row.argv))}` | {cell(line)} | {code} |")
    return "\n".join(out) + "\n"


def _documented() -> dict[str, tuple[str, int]]:
    rows = {}
    for line in DOC.read_text().splitlines() if DOC.is_file() else []:
        m = re.fullmatch(r"\| ([\w-]+) \| .* \| (.*) \| (\d+) \|", line)
        if m and m.group(1) != "case":
            rows[m.group(1)] = (m.group(2).replace("\\|", "|"), int(m.group(3)))
    return rows


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("bad-input") / "base"
    build_workspace(path)
    return path


@pytest.fixture(autouse=True)
def _library(tmp_path, monkeypatch):
    monkeypatch.setenv("BRDFRIG_LIBRARY", str(tmp_path / "library.sqlite"))


@pytest.mark.parametrize("row", ROWS, ids=[r.id for r in ROWS])
def test_bad_input_is_one_line_exit_2_and_changes_nothing(row, base, tmp_path):
    if row.needs_root and os.geteuid() != 0:
        pytest.skip("needs root (mounts a tiny tmpfs)")
    code, line, text, before, after = run_row(row, base, tmp_path / "ws")
    assert "Traceback" not in text, text
    assert code == row.code, text
    assert line.startswith(f"brdfrig {row.argv[0]}: error: "), text
    assert re.search(row.expect, line), (row.expect, line)
    assert after == before, "files changed, appeared or disappeared"
    documented = _documented()
    assert documented.get(row.id) == (line, code), (
        f"docs/BAD_INPUT.md row {row.id!r} says {documented.get(row.id)}, brdfrig says {(line, code)}: "
        "regenerate it with `.venv/bin/python tests/test_bad_input.py`")


def test_the_document_lists_exactly_these_rows():
    assert sorted(_documented()) == sorted(r.id for r in ROWS)


# ------------------------------------------------------------------------------------------ bugs
@pytest.mark.parametrize("exc", [TypeError("unsupported operand"), KeyError("radiance")])
def test_a_bug_shows_its_traceback_and_asks_for_a_report(exc, monkeypatch, capsys):
    import brdfrig.cli.probe as probe

    def buggy(args):
        raise exc

    monkeypatch.setattr(probe, "run", buggy)
    code = main(["probe", "x.exr", "-o", "y.exr"])
    err = capsys.readouterr().err
    assert code == 1
    assert "Traceback (most recent call last)" in err and type(exc).__name__ in err
    assert err.strip().splitlines()[-1] == (
        f"brdfrig probe: internal error: this is a bug in brdfrig {brdfrig.__version__}, not in your input; "
        "please report it to the brdfrig issue tracker with the command line and the traceback above")


def test_a_user_error_is_one_line(monkeypatch, capsys):
    import brdfrig.cli.probe as probe
    from brdfrig.errors import InputError

    def user_error(args):
        raise InputError("x.exr: not a readable EXR file")

    monkeypatch.setattr(probe, "run", user_error)
    assert main(["probe", "x.exr", "-o", "y.exr"]) == 2
    assert capsys.readouterr().err == "brdfrig probe: error: x.exr: not a readable EXR file\n"


def test_a_plain_value_error_is_a_bug_not_bad_input(monkeypatch, capsys):
    import brdfrig.cli.probe as probe

    def internal(args):
        raise ValueError("operands could not be broadcast together")

    monkeypatch.setattr(probe, "run", internal)
    assert main(["probe", "x.exr", "-o", "y.exr"]) == 1
    assert "Traceback" in capsys.readouterr().err


def test_render_clamps_negative_radiance_and_says_so(base, tmp_path, capsys):
    """SH ringing can predict negative radiance: never written, counted in a warning."""
    from brdfrig.fit.brdffile import save_brdf
    from brdfrig.hdr.exr import read_exr

    ringing = _diffuse_brdf()
    ringing.x[2] = -3 * ringing.x[0]  # a band-2 term far beyond any real material: negative near the limb
    save_brdf(tmp_path / "ringing.json", ringing)
    out = tmp_path / "r.exr"
    assert main(["render", str(tmp_path / "ringing.json"), "--lighting", str(base / "env.exr"), "--size", "32",
                 "-o", str(out)]) == 0
    assert re.search(r"warning: \d+ pixel-channel\(s\) .* rendered negative .*: clamped to 0", capsys.readouterr().err)
    rgb, _, _ = read_exr(out)
    assert rgb.min() == 0.0 and np.isfinite(rgb).all() and rgb.max() > 0


def test_a_full_disk_during_refit_says_how_to_go_on(base, tmp_path, monkeypatch, capsys):
    """ENOSPC inside the pipeline (simulated: the refit raises it) -> one line: free space, then refit again."""
    import errno

    import brdfrig.session.refit as refit_mod

    shutil.copytree(base, tmp_path / "ws")
    session = _session(tmp_path / "ws")

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(session / "cache" / "merge.exr"))

    monkeypatch.setattr(refit_mod, "refit_session", full)
    assert main(["refit", str(session)]) == 2
    assert capsys.readouterr().err == (f"brdfrig refit: error: disk full while writing {session}/cache/merge.exr: "
                                       f"free some space, then run `brdfrig refit {session}` again\n")


def test_a_full_disk_during_capture_says_resume(tmp_path, capsys):
    """A capture filling a 96 KiB tmpfs: one line naming the stored files and `brdfrig capture resume DIR`."""
    if os.geteuid() != 0:
        pytest.skip("needs root (mounts a tiny tmpfs)")
    text = SIM_BENCH.read_text().replace("scenes = 12", "scenes = 1").replace("scale = 1.0", "scale = 0.25")
    for old, new in (("115.0, 120.0, 90.0", "28.75, 30.0, 22.5"), ("320.0, 120.0, 90.0", "80.0, 30.0, 22.5"),
                     ("525.0, 120.0, 90.0", "131.25, 30.0, 22.5")):  # the circles at scale 0.25
        text = text.replace(old, new)
    (tmp_path / "small.toml").write_text(text)
    disk = tmp_path / "disk"
    disk.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=96k", "tmpfs", str(disk)], capture_output=True).returncode:
        pytest.skip("cannot mount a tmpfs")
    try:
        code = main(["capture", "run", str(tmp_path / "small.toml"), "--out", str(disk / "s"), "--no-progress",
                     "--no-fit", "--yes"])
    finally:
        subprocess.run(["umount", str(disk)], check=True)
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert code == 2 and "Traceback" not in line
    assert re.fullmatch(rf"brdfrig capture: error: disk full while writing {disk}/s/\S+; nothing already stored was "
                        rf"changed; the \d+ files stored so far in {disk}/s are intact; free some space and run "
                        rf"`brdfrig capture resume {disk}/s`", line), line


def test_a_real_cameras_frame_is_checked_at_the_first_metering_shot(base):
    """No simulator to ask before shooting: the first frame's shape is checked against the plan's circles."""
    from brdfrig.errors import ConfigError
    from brdfrig.session.config import load_session_config
    from brdfrig.session.runner import frame_mask

    config = load_session_config(base / "plan-circle.toml")
    with pytest.raises(ConfigError, match=r"key 'circle' in \[plan\.probe\] of .*plan-circle\.toml \(615\.00, 120\.00, "
                                          r"90\.00\) extends outside the 640x240 image the camera delivers"):
        frame_mask((240, 640), config)
    assert frame_mask((240, 640), load_session_config(SIM_BENCH)).sum() > 0


if __name__ == "__main__":  # regenerate docs/BAD_INPUT.md
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        os.environ["BRDFRIG_LIBRARY"] = str(Path(tmp) / "library.sqlite")
        build_workspace(Path(tmp) / "base")
        results = []
        for i, row in enumerate(ROWS):
            if row.needs_root and os.geteuid() != 0:
                sys.exit(f"row {row.id} needs root: run as root to regenerate the whole table")
            code, line, _, _, _ = run_row(row, Path(tmp) / "base", Path(tmp) / f"ws{i}")
            results.append((row, code, line))
    DOC.parent.mkdir(exist_ok=True)
    DOC.write_text(doc_table(results))
    print(f"wrote {DOC} ({len(results)} rows)")
