"""``brdfrig envsh``: the SH reconstruction figure of an environment map."""

from __future__ import annotations

import re

import numpy as np
import pytest

from brdfrig.cli.main import main
from brdfrig.fit.shproject import reconstruct_latlong
from brdfrig.hdr.exr import write_exr


@pytest.fixture
def bandlimited_map(tmp_path):
    """A positive lat-long map band-limited to l = 4 (so any band limit >= 4 reproduces it exactly)."""
    coeffs = np.random.default_rng(0).normal(scale=0.2, size=(25, 3))
    coeffs[0] = 5.0
    path = tmp_path / "env.exr"
    write_exr(path, reconstruct_latlong(coeffs, 32, 64).astype(np.float32), latlong=True)
    return path


def test_writes_png_and_reports_errors(bandlimited_map, tmp_path, capsys):
    out = tmp_path / "fig.png"
    assert main(["envsh", str(bandlimited_map), "--bands", "6,1", "--window", "none", "-o", str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    errors = {int(l): float(e) for l, e in re.findall(r"l <=\s+(\d+): relative RMS error\s+([\d.]+)%", capsys.readouterr().out)}
    assert set(errors) == {1, 6}
    assert errors[6] <= 1e-4  # float32 file round trip only
    assert errors[1] > 1.0  # bands 2..4 are missing
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_real_probe(real_probes, tmp_path):
    out = tmp_path / "probe.png"
    assert main(["envsh", str(real_probes[0]), "--bands", "2,8", "--window", "hann", "-o", str(out)]) == 0
    assert out.stat().st_size > 1000


@pytest.mark.parametrize(
    "extra, message",
    [(["--bands", "3,x"], "--bands"), (["--bands", "-1"], "--bands"), (["--bands", "40"], "resolves band limits")],
)
def test_bad_arguments_exit_2_without_output(bandlimited_map, tmp_path, capsys, extra, message):
    out = tmp_path / "fig.png"
    assert main(["envsh", str(bandlimited_map), *extra, "-o", str(out)]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()


def test_missing_input_and_output_dir(tmp_path, capsys, bandlimited_map):
    assert main(["envsh", str(tmp_path / "nope.hdr"), "-o", str(tmp_path / "f.png")]) == 2
    assert "nope.hdr" in capsys.readouterr().err
    assert main(["envsh", str(bandlimited_map), "-o", str(tmp_path / "missing" / "f.png")]) == 2
    assert "--output" in capsys.readouterr().err
