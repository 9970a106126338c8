"""``brdfrig rig check`` end to end on the simulators, and its bad-input messages."""

from __future__ import annotations

from pathlib import Path

import pytest

from brdfrig.cli.main import main

SIM_BENCH = Path(__file__).resolve().parents[1] / "src" / "brdfrig" / "config" / "sim-bench.toml"


def test_simulated_rig_check_passes(capsys, tmp_path):
    assert main(["rig", "check", "--simulate", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "move to 10 deg" in out and "confirmed at 10.0000 deg, table at 10.0000 deg" in out
    assert "file says 0.01 s, ISO 100, f/8" in out
    assert "all devices work" in out
    assert len(list(tmp_path.glob("*.dng"))) == 1


def test_rig_check_from_a_session_config(capsys, tmp_path):
    if not SIM_BENCH.exists():
        pytest.skip("config/sim-bench.toml not present")
    text = SIM_BENCH.read_text().replace("scale = 1.0", "scale = 0.25").replace("env_height = 64", "env_height = 8")
    cfg = tmp_path / "bench.toml"
    cfg.write_text(text)
    assert main(["rig", "check", "--config", str(cfg)]) == 0
    assert "all devices work" in capsys.readouterr().out


def test_wrong_port_is_reported_naming_the_setting(capsys):
    assert main(["rig", "check", "--port", "/dev/ttyBRDFRIG-NOPE"]) == 1
    out = capsys.readouterr().out
    assert "turntable" in out and "FAILED" in out and "'port'" in out


def test_impossible_values_name_the_setting(capsys):
    assert main(["rig", "check", "--port", "/dev/null", "--steps-per-degree", "-80"]) == 1
    assert "steps_per_degree must be a positive" in capsys.readouterr().out
    assert main(["rig", "check", "--simulate", "--exposure", "0"]) == 2
    assert "--exposure must be a positive" in capsys.readouterr().err
