"""``brdfrig rig check`` end to end on the simulators, and its bad-input messages."""

from __future__ import annotations

import re
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
    assert main(["rig", "check", "--port", "/dev/null", "--steps-per-degree", "-80"]) == 2  # refused up front
    assert "argument --steps-per-degree: must be a number in (0, 100000], got '-80'" in capsys.readouterr().err
    assert main(["rig", "check", "--simulate", "--exposure", "0"]) == 2
    assert "argument --exposure: must be a number in (0, 3600], got '0'" in capsys.readouterr().err


RIG_BENCH = Path(__file__).resolve().parents[1] / "src" / "brdfrig" / "config" / "rig-bench.toml"

RIG_ONLY_SIM = """
[rig]
carries = "rig"
[rig.turntable]
backend = "sim"
[rig.camera]
backend = "sim"
[rig.sim]
scale = 0.25
env_height = 8
"""


def test_rig_check_accepts_the_projects_rig_only_file(capsys):
    """config/rig-bench.toml tells the user to run `rig check` on it: it has a [rig] and no [plan]."""
    assert "[plan]" not in RIG_BENCH.read_text() and "rig check" in RIG_BENCH.read_text()
    rc = main(["rig", "check", "--config", str(RIG_BENCH)])
    out, err = capsys.readouterr()
    assert "[plan]" not in out + err
    # this machine has no GRBL board on the file's /dev/serial/by-id port: the check runs and names the setting
    assert rc == 1 and "turntable" in out and "FAILED" in out and "'port'" in out


def test_rig_check_of_a_rig_only_sim_file_passes(capsys, tmp_path):
    cfg = tmp_path / "rig.toml"
    cfg.write_text(RIG_ONLY_SIM)
    assert main(["rig", "check", "--config", str(cfg), "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "confirmed at 10.0000 deg, table at 10.0000 deg" in out and "all devices work" in out
    assert len(list(tmp_path.glob("*.dng"))) == 1


def test_rig_check_with_nothing_configured_says_so_and_fails(capsys):
    assert main(["rig", "check"]) == 2
    out, err = capsys.readouterr()
    assert "all devices work" not in out + err
    assert err.strip().splitlines() == [
        "brdfrig rig: error: nothing was checked: no turntable and no camera configured "
        "(give --config FILE, --port and/or --camera, or --simulate)"
    ]


def test_rig_check_refuses_a_missing_out_folder_before_moving_anything(capsys, tmp_path):
    missing = tmp_path / "newdir"
    assert main(["rig", "check", "--simulate", "--out", str(missing)]) == 2
    out, err = capsys.readouterr()
    assert out == ""  # no device line: nothing was connected, homed or moved
    assert err.strip() == (f"brdfrig rig: error: --out {str(missing)!r} is not a writable folder: create it or "
                           "choose another (nothing was moved)")
    assert not missing.exists()


def test_simulated_rig_check_prints_what_it_detected(capsys):
    """Firmware and $$ settings of the (simulated) GRBL board, the camera model, the spheres of a test frame."""
    import numpy as np

    from brdfrig.devices import make_sim_bench

    assert main(["rig", "check", "--simulate", "--exposure", "0.5"]) == 0
    out = capsys.readouterr().out
    assert "Grbl 1.1h" in out and re.search(r"settings\s+ok\s+.*\$100=80 \$110=21600", out)
    assert "metadata             ok       brdfrig SimulatedCamera; file says 0.5 s" in out
    line = next(ln for ln in out.splitlines() if ln.lstrip().startswith("spheres"))
    circles = [tuple(map(float, c.split(","))) for c in re.findall(r"\(([-\d., ]+)\)", line)]
    bench = make_sim_bench({"scale": 0.25, "env_height": 16}, "rig", "the rig check's simulated bench")  # --simulate's
    assert "3 found" in line and len(circles) == 3
    # Detected on the demosaiced DNG: centres within 0.3 px, radii within 0.75 px (3%) of the bench's true circles.
    truth = [bench.probe_circle, *sorted(bench.sample_circles.values())]
    err = np.abs(np.array(circles) - np.array(truth))
    assert err[:, :2].max() < 0.3 and err[:, 2].max() < 0.75, (circles, truth)


def test_rig_check_says_when_the_test_frame_shows_no_sphere(capsys):
    assert main(["rig", "check", "--simulate"]) == 0  # 0.01 s: too dark a frame to see the spheres; not a failure
    out = capsys.readouterr().out
    assert re.search(r"spheres\s+none\s+.*no sphere found", out) and "all devices work" in out
