"""Session configuration: the shipped files load, and every kind of mistake names file, table and key."""

from __future__ import annotations

from pathlib import Path

import pytest

from brdfrig.session.config import ConfigError, load_fit_preset, load_session_config, stored_session_config

CONFIG_DIR = Path(__file__).resolve().parents[1] / "src" / "brdfrig" / "config"

BASE = """
[session]
name = "t"
[rig]
carries = "rig"
[rig.turntable]
backend = "sim"
[rig.camera]
backend = "sim"
[plan]
scenes = 4
exposure = [0.01, 0.04]
[plan.probe]
circle = [100, 100, 50]
[[plan.samples]]
name = "a"
circle = [300, 100, 50]
"""


def write(tmp_path: Path, text: str, name: str = "plan.toml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def test_shipped_configs_load():
    files = sorted(CONFIG_DIR.glob("*.toml"))
    assert any(f.name == "sim-bench.toml" for f in files)
    for f in files:
        if f.name.startswith("fit-"):
            load_fit_preset(f)
        elif f.name.startswith("rig-"):
            cfg = load_session_config(CONFIG_DIR / "sim-bench.toml", rig_path=f)
            assert cfg.rig.camera.backend != "sim" and f.name in cfg.source
        elif f.name.startswith("plan-"):  # a plan for a real bench: used with the real-bench rig file
            assert load_session_config(f, rig_path=CONFIG_DIR / "rig-bench.toml").rig.carries == "samples"
        else:
            load_session_config(f)
    assert {"fit-quick.toml", "fit-full.toml", "rig-bench.toml"} <= {f.name for f in files}


def test_sim_bench_has_enough_scenes_for_the_full_model():
    from brdfrig.fit.identifiability import scenes_needed

    cfg = load_session_config(CONFIG_DIR / "sim-bench.toml")
    assert cfg.rig.carries == "rig"
    assert cfg.plan.scenes >= scenes_needed(cfg.fit.lmax)


def test_rig_carries_spreads_scene_angles(tmp_path):
    cfg = load_session_config(write(tmp_path, BASE))
    assert cfg.plan.scene_angles == (0.0, 90.0, 180.0, 270.0)
    assert [cfg.table_angles(s) for s in range(4)] == [(0.0,), (90.0,), (180.0,), (270.0,)]
    assert cfg.plan.exposure == (0.01, 0.04)


def test_round_trip_through_session_dict(tmp_path):
    cfg = load_session_config(write(tmp_path, BASE))
    again = stored_session_config(cfg.to_dict(), "stored")
    assert again.to_dict() == cfg.to_dict()


def test_typo_suggests_the_key(tmp_path):
    p = write(tmp_path, BASE.replace("exposure =", "exposre ="))
    with pytest.raises(ConfigError) as e:
        load_session_config(p)
    assert str(e.value) == f"unknown key 'exposre' in [plan] of {p}; did you mean 'exposure'?"


@pytest.mark.parametrize(
    "old, new, expected",
    [
        ('carries = "rig"', 'carries = "rigg"', "key 'carries' in [rig] of {p} must be one of 'samples' | 'rig', got 'rigg'; did you mean 'rig'?"),
        ("scenes = 4", "scenes = 0", "key 'scenes' in [plan] of {p} must be an integer in [1, 360], got 0"),
        ("exposure = [0.01, 0.04]", "exposure = [0.01, -1]", "key 'exposure' in [plan] of {p} must be \"auto\""),
        ("circle = [100, 100, 50]", "circle = [100, 100]", "key 'circle' in [plan.probe] of {p} must be [cx, cy, r]"),
        ('backend = "sim"\n[rig.camera]', 'backend = "grbl"\n[rig.camera]', "has backend = \"grbl\" but no 'port'"),
        ("[session]", "[sesion]", "unknown key 'sesion' in [top level] of {p}; did you mean 'session'?"),
        ('name = "a"', 'name = "a b"', "key 'name' in [plan.samples] of {p} must be a non-empty name"),
        ('[rig.camera]\nbackend = "sim"', '[rig.camera]\nbackend = "sim"\ncolour_space = "srgb"',
         "key 'colour_space' in [rig.camera] of {p} must be one of 'camera' | 'rec709' | 'acescg', got 'srgb'"),
    ],
)
def test_bad_values_are_named(tmp_path, old, new, expected):
    assert old in BASE
    p = write(tmp_path, BASE.replace(old, new, 1))
    with pytest.raises(ConfigError) as e:
        load_session_config(p)
    assert expected.format(p=p) in str(e.value)


def test_zero_rotations_is_refused(tmp_path):
    text = BASE.replace('carries = "rig"', 'carries = "samples"').replace("scenes = 4", "scenes = 2\nprobe_rotations = []")
    p = write(tmp_path, text)
    with pytest.raises(ConfigError, match=r"key 'probe_rotations' in \[plan\] of .*plan.toml is empty: zero rotations"):
        load_session_config(p)


def test_zero_scene_angles_is_refused(tmp_path):
    p = write(tmp_path, BASE.replace("scenes = 4", "scene_angles = []"))
    with pytest.raises(ConfigError, match=r"key 'scene_angles' in \[plan\].* is empty"):
        load_session_config(p)


def test_missing_file_and_bad_toml(tmp_path):
    with pytest.raises(ConfigError, match="does not exist"):
        load_session_config(tmp_path / "nope.toml")
    with pytest.raises(ConfigError, match="is not valid TOML"):
        load_session_config(write(tmp_path, "[plan\n"))


def test_separate_rig_and_fit_files_replace_the_plan_tables(tmp_path):
    plan = write(tmp_path, BASE)
    fit = write(tmp_path, '[fit]\nmodel = "diffuse"\nlmax = 3\n', "fit.toml")
    rig = write(tmp_path, '[rig]\ncarries = "rig"\n[rig.turntable]\nbackend = "sim"\nsteps_per_degree = 40\n', "rig.toml")
    cfg = load_session_config(plan, rig, fit)
    assert (cfg.fit.model, cfg.fit.lmax, cfg.rig.turntable.steps_per_degree) == ("diffuse", 3, 40.0)
    bad = write(tmp_path, '[fit]\nsolver = "qr"\n', "bad.toml")
    with pytest.raises(ConfigError, match=r"key 'solver' in \[fit\] of .*bad.toml must be one of 'paper' \| 'joint' \| 'tikhonov'"):
        load_session_config(plan, None, bad)


def test_fit_choices_match_the_fitter():
    from brdfrig.session.config import FIT_MODELS, FIT_SOLVERS
    from brdfrig.fit import fitter

    assert set(FIT_MODELS) == set(fitter.MODELS)
    assert set(FIT_SOLVERS) == set(getattr(fitter, "SOLVERS", FIT_SOLVERS))


def test_camera_colour_space_reaches_the_pipelines_merge(tmp_path):
    from brdfrig.session.pipeline import merge_policy

    assert merge_policy(load_session_config(write(tmp_path, BASE))).colour_space == "camera"  # the default
    cfg = load_session_config(write(tmp_path, BASE.replace('[rig.camera]\nbackend = "sim"',
                                                           '[rig.camera]\nbackend = "sim"\ncolour_space = "acescg"')))
    assert cfg.rig.camera.colour_space == "acescg" and merge_policy(cfg).colour_space == "acescg"
    assert stored_session_config(cfg.to_dict(), "session.json").rig.camera.colour_space == "acescg"
