"""Session configuration in TOML: the rig, the capture plan and the fit preset.

A session file (``config/sim-bench.toml`` is the shipped example) holds up to
five top-level tables; ``brdfrig capture run PLAN.toml [--rig RIG.toml]
[--fit PRESET.toml]`` may take ``[rig]`` and ``[fit]`` from separate files
(a table in a separate file replaces the one in the plan file)::

    [session]            name, notes
    [rig]                carries = "samples" | "rig"
    [rig.turntable]      backend = "grbl" | "sim" | "none", port, baud, steps_per_degree,
                         backlash_deg, speed_deg_s, timeout_s
    [rig.camera]         backend = "gphoto2" | "watch" | "sim", iso, f_number, watch_dir,
                         timeout_s, overhead_s, full_well_e, read_noise_e,
                         colour_space = "camera" | "rec709" | "acescg"
    [rig.sim]            parameters of the simulated bench (seed, environment, frame scale)
    [plan]               scenes, scene_angles, probe_rotations, exposure = "auto" | [times],
                         target_snr, meter_time_s, stop_step, max_exposures, settle_s
    [plan.probe]         circle = [cx, cy, r] (pixels), albedo, rim
    [[plan.samples]]     name, circle = [cx, cy, r]
    [fit]                model, lmax, pmax, solver

Scenes (lighting conditions) come in two ways (MATH.md pitfall 1: the full
model needs several differing scenes).  With ``carries = "rig"`` the turntable
carries camera, probe and samples: scene ``s`` is the table at
``scene_angles[s]`` and there is one probe rotation per scene.  With
``carries = "samples"`` the table carries the probe and samples only: each
scene is set up by the operator (the run pauses and prompts) and the probe is
shot at every angle of ``probe_rotations`` so that its blemishes move and can
be removed (``brdfrig.hdr.probe.average_rotations``).

Every error names the file, the table, the key and what is allowed, e.g.
``unknown key 'exposre' in [plan] of plan.toml; did you mean 'exposure'?``.
"""

from __future__ import annotations

import difflib
import math
import tomllib
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable

from brdfrig.errors import ConfigError
from brdfrig.fit.registry import MODELS, SOLVERS
from brdfrig.ranges import (
    ALBEDO,
    BACKLASH_DEG,
    BANDS,
    BAUD,
    COLOUR_SPACES,
    EXPOSURE_S,
    FULL_WELL_E,
    PIXELS,
    READ_NOISE_E,
    STEPS_PER_DEGREE,
    Range,
)

__all__ = [
    "ConfigError",
    "TurntableConfig",
    "CameraConfig",
    "RigConfig",
    "SampleConfig",
    "ProbeConfig",
    "PlanConfig",
    "FitPreset",
    "SessionConfig",
    "load_session_config",
    "load_rig_config",
    "load_fit_preset",
    "session_config_from_dict",
    "FIT_MODELS",
    "FIT_SOLVERS",
    "fit_preset_from_dict",
    "stored_session_config",
]

FIT_MODELS = MODELS
FIT_SOLVERS = SOLVERS
CAMERA_BACKENDS = ("gphoto2", "watch", "sim")
TURNTABLE_BACKENDS = ("grbl", "sim", "none")
CARRIES = ("samples", "rig")
_ANGLE = Range(-360, 360)


# ----------------------------------------------------------------------------------------------
# Typed sections.  Defaults are the documented values of a key left out.


@dataclass(frozen=True)
class TurntableConfig:
    """Turntable settings (degrees, seconds).

    ``backend = "sim"`` runs ``brdfrig.sim.grbl.GrblSimulator`` on a pseudo-terminal
    and drives it with the real ``brdfrig.rig.turntable.GrblTurntable`` driver;
    ``"none"`` means there is no table (every angle must then be 0).
    """

    backend: str = "sim"
    port: str = ""
    baud: int = 115200
    steps_per_degree: float = 80.0
    backlash_deg: float = 0.5
    speed_deg_s: float = 90.0
    timeout_s: float = 30.0


@dataclass(frozen=True)
class CameraConfig:
    """Camera settings: ISO, aperture and the sensor noise model used by ``auto`` exposure.

    ``full_well_e`` is the signal at the white level in electrons and
    ``read_noise_e`` the read noise in electrons: the SNR of a pixel collecting
    ``s`` electrons is ``s / sqrt(s + read_noise_e**2)``.  ``colour_space`` is
    the space the pipeline merges into (``brdfrig.hdr.colour``; ``"camera"``:
    camera RGB, unconverted) and the fitted BRDFs record.
    """

    backend: str = "sim"
    iso: int = 100
    f_number: float = 8.0
    watch_dir: str = ""
    timeout_s: float = 60.0
    overhead_s: float = 0.5
    full_well_e: float = 4000.0
    read_noise_e: float = 4.0
    colour_space: str = "camera"


@dataclass(frozen=True)
class RigConfig:
    """The rig: what the turntable carries, the table and the camera, and simulator settings."""

    carries: str = "rig"
    turntable: TurntableConfig = field(default_factory=TurntableConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    sim: dict = field(default_factory=dict)


@dataclass(frozen=True)
class ProbeConfig:
    """The chrome probe in the frame: circle ``(cx, cy, r)`` in pixels (image y down), albedo and rim mask."""

    circle: tuple[float, float, float] | None = None
    albedo: float | None = None
    rim: float = 0.97


@dataclass(frozen=True)
class SampleConfig:
    """A sample sphere in the frame: a name (used for file names) and its circle ``(cx, cy, r)`` in pixels."""

    name: str
    circle: tuple[float, float, float] | None = None


@dataclass(frozen=True)
class PlanConfig:
    """What to shoot.

    ``exposure`` is ``"auto"`` or a tuple of exposure times in seconds.  With
    ``"auto"`` a metering shot at ``meter_time_s`` decides, per scene, the
    bracket (steps of ``stop_step`` stops, at most ``max_exposures``) that
    reaches ``target_snr`` over the scene's dynamic range (``brdfrig.session.plan``).
    """

    scenes: int = 1
    scene_angles: tuple[float, ...] | None = None
    probe_rotations: tuple[float, ...] = (0.0,)
    exposure: str | tuple[float, ...] = "auto"
    target_snr: float = 20.0
    meter_time_s: float = 1.0 / 60.0
    stop_step: float = 1.0
    max_exposures: int = 9
    settle_s: float = 0.0
    probe: ProbeConfig = field(default_factory=ProbeConfig)
    samples: tuple[SampleConfig, ...] = ()


@dataclass(frozen=True)
class FitPreset:
    """Fit settings passed to ``brdfrig.fit.fitter.fit_brdf``."""

    model: str = "auto"
    lmax: int = 8
    pmax: int = 8
    solver: str = "joint"


@dataclass(frozen=True)
class SessionConfig:
    """A whole session: name, rig, plan and fit preset, after validation.

    ``source`` names the file(s) it came from (for messages only).
    """

    name: str = "session"
    notes: str = ""
    rig: RigConfig = field(default_factory=RigConfig)
    plan: PlanConfig = field(default_factory=PlanConfig)
    fit: FitPreset = field(default_factory=FitPreset)
    source: str = ""

    def table_angles(self, scene: int) -> tuple[float, ...]:
        """Table angles (degrees) shot in ``scene``: its scene angle (carries = rig) or the probe rotations."""
        if self.rig.carries == "rig":
            return (self.plan.scene_angles[scene],)
        return self.plan.probe_rotations

    def to_dict(self) -> dict:
        """Plain JSON-able dict (the session directory stores it); inverse of :func:`session_config_from_dict`."""
        d = asdict(self)
        d.pop("source")
        return d


# ----------------------------------------------------------------------------------------------
# Validation helpers.  Each checker takes (value, where) and returns the converted value.

Checker = Callable[[Any, str], Any]


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _number(lo: float | None = None, hi: float | None = None, *, open_lo: bool = False) -> Checker:
    rng = Range(lo, hi, open_lo=open_lo)
    return lambda v, where: rng.check(v, where, ConfigError)


def _integer(lo: int | None = None, hi: int | None = None) -> Checker:
    rng = Range(lo, hi, integer=True)
    return lambda v, where: rng.check(v, where, ConfigError)


def _in(rng: Range) -> Checker:
    return lambda v, where: rng.check(v, where, ConfigError)


def _choice(options: tuple[str, ...]) -> Checker:
    def check(v: Any, where: str) -> str:
        if v not in options:
            allowed = " | ".join(repr(o) for o in options)
            hint = difflib.get_close_matches(str(v), options, n=1)
            extra = f"; did you mean {hint[0]!r}?" if hint else ""
            raise ConfigError(f"{where} must be one of {allowed}, got {v!r}{extra}")
        return v

    return check


def _string(v: Any, where: str) -> str:
    if not isinstance(v, str):
        raise ConfigError(f"{where} must be a string, got {v!r}")
    return v


def _name(v: Any, where: str) -> str:
    v = _string(v, where)
    if not v or not all(c.isalnum() or c in "-_" for c in v):
        raise ConfigError(f"{where} must be a non-empty name of letters, digits, '-' and '_', got {v!r}")
    return v


def _angles(*, nonempty: bool) -> Checker:
    def check(v: Any, where: str) -> tuple[float, ...]:
        if not isinstance(v, list) or not all(_is_number(a) and _ANGLE.contains(a) for a in v):
            raise ConfigError(f"{where} must be a list of table angles in degrees{_ANGLE.text()}, "
                              f"e.g. [0, 90, 180, 270], got {v!r}")
        if nonempty and not v:
            raise ConfigError(
                f"{where} is empty: zero rotations would shoot nothing; give at least one table angle "
                "in degrees, e.g. [0] or [0, 90, 180, 270]"
            )
        if len(set(float(a) % 360.0 for a in v)) != len(v):
            raise ConfigError(f"{where} repeats an angle (modulo 360 degrees): {v!r}")
        return tuple(float(a) for a in v)

    return check


def _exposure(v: Any, where: str) -> str | tuple[float, ...]:
    if v == "auto":
        return "auto"
    if isinstance(v, list) and v and all(_is_number(t) and EXPOSURE_S.contains(t) for t in v):
        if len(set(v)) != len(v):
            raise ConfigError(f"{where} repeats an exposure time: {v!r}")
        return tuple(sorted(float(t) for t in v))
    raise ConfigError(
        f"{where} must be \"auto\" or a non-empty list of exposure times in seconds{EXPOSURE_S.text()} "
        f"(e.g. [0.001, 0.004, 0.016]), got {v!r}"
    )


def _circle(v: Any, where: str) -> tuple[float, float, float]:
    if not (isinstance(v, list) and len(v) == 3 and all(_is_number(c) and PIXELS.contains(c) for c in v)) or v[2] <= 0:
        raise ConfigError(f"{where} must be [cx, cy, r] in pixels with r > 0 (each{PIXELS.text()}), got {v!r}")
    return (float(v[0]), float(v[1]), float(v[2]))


def _table(v: Any, where: str) -> dict:
    if not isinstance(v, dict):
        raise ConfigError(f"{where} must be a table, got {v!r}")
    return v


def _check_keys(table: dict, schema: dict[str, Checker], section: str, source: str) -> dict:
    """Validate ``table`` against ``schema``; return the converted values of the keys present."""
    out = {}
    for key, value in table.items():
        if key not in schema:
            hint = difflib.get_close_matches(key, list(schema), n=1)
            extra = f"; did you mean {hint[0]!r}?" if hint else f"; allowed keys: {', '.join(schema)}"
            raise ConfigError(f"unknown key {key!r} in [{section}] of {source}{extra}")
        out[key] = schema[key](value, f"key {key!r} in [{section}] of {source}")
    return out


_TURNTABLE_SCHEMA: dict[str, Checker] = {
    "backend": _choice(TURNTABLE_BACKENDS),
    "port": _string,
    "baud": _in(BAUD),
    "steps_per_degree": _in(STEPS_PER_DEGREE),
    "backlash_deg": _in(BACKLASH_DEG),
    "speed_deg_s": _number(0.1, 3600),
    "timeout_s": _number(0, 3600, open_lo=True),
}
_CAMERA_SCHEMA: dict[str, Checker] = {
    "backend": _choice(CAMERA_BACKENDS),
    "iso": _integer(1, 10_000_000),
    "f_number": _number(0.5, 256),
    "watch_dir": _string,
    "timeout_s": _number(0, 3600, open_lo=True),
    "overhead_s": _number(0, 600),
    "full_well_e": _in(FULL_WELL_E),
    "read_noise_e": _in(READ_NOISE_E),
    "colour_space": _choice(COLOUR_SPACES),
}
_RIG_SCHEMA: dict[str, Checker] = {
    "carries": _choice(CARRIES),
    "turntable": _table,
    "camera": _table,
    "sim": _table,
}
_PROBE_SCHEMA: dict[str, Checker] = {
    "circle": _circle,
    "albedo": _in(ALBEDO),
    "rim": _number(0.5, 1, open_lo=True),
}
_SAMPLE_SCHEMA: dict[str, Checker] = {"name": _name, "circle": _circle}
_PLAN_SCHEMA: dict[str, Checker] = {
    "scenes": _integer(1, 360),
    "scene_angles": _angles(nonempty=True),
    "probe_rotations": _angles(nonempty=True),
    "exposure": _exposure,
    "target_snr": _number(1, 1000),
    "meter_time_s": _in(EXPOSURE_S),
    "stop_step": _number(0.33, 4),
    "max_exposures": _integer(1, 20),
    "settle_s": _number(0, 600),
    "probe": _table,
    "samples": lambda v, where: v,  # checked item by item below
}
_FIT_SCHEMA: dict[str, Checker] = {
    "model": _choice(FIT_MODELS),
    "lmax": _in(BANDS),
    "pmax": _in(BANDS),
    "solver": _choice(FIT_SOLVERS),
}
_SESSION_SCHEMA: dict[str, Checker] = {"name": _name, "notes": _string}
_TOP_SCHEMA: dict[str, Checker] = {
    "session": _table,
    "rig": _table,
    "plan": _table,
    "fit": _table,
}


def _parse_rig(raw: dict, source: str) -> RigConfig:
    rig = _check_keys(raw, _RIG_SCHEMA, "rig", source)
    tt = TurntableConfig(**_check_keys(rig.pop("turntable", {}), _TURNTABLE_SCHEMA, "rig.turntable", source))
    cam = CameraConfig(**_check_keys(rig.pop("camera", {}), _CAMERA_SCHEMA, "rig.camera", source))
    for key, value in rig.get("sim", {}).items():
        if not (_is_number(value) or isinstance(value, (str, bool))):
            raise ConfigError(f"key {key!r} in [rig.sim] of {source} must be a number, string or boolean")
    cfg = RigConfig(turntable=tt, camera=cam, **rig)
    if tt.backend == "grbl" and not tt.port:
        raise ConfigError(f"[rig.turntable] of {source} has backend = \"grbl\" but no 'port' (e.g. \"/dev/ttyUSB0\")")
    if cam.backend == "watch" and not cam.watch_dir:
        raise ConfigError(f"[rig.camera] of {source} has backend = \"watch\" but no 'watch_dir'")
    if cam.backend == "sim" or tt.backend == "sim":
        if not (cam.backend == "sim" and tt.backend in ("sim", "none")):
            raise ConfigError(
                f"[rig] of {source}: the simulated camera needs the simulated turntable and vice versa "
                f"(camera backend {cam.backend!r}, turntable backend {tt.backend!r})"
            )
    return cfg


def _parse_plan(raw: dict, source: str, carries: str, turntable_backend: str) -> PlanConfig:
    plan = _check_keys(raw, _PLAN_SCHEMA, "plan", source)
    probe = ProbeConfig(**_check_keys(plan.pop("probe", {}), _PROBE_SCHEMA, "plan.probe", source))
    samples_raw = plan.pop("samples", [])
    if not isinstance(samples_raw, list):
        raise ConfigError(f"key 'samples' in [plan] of {source} must be an array of tables [[plan.samples]]")
    samples = []
    for i, s in enumerate(samples_raw):
        s = _check_keys(_table(s, f"[[plan.samples]] #{i + 1} of {source}"), _SAMPLE_SCHEMA, "plan.samples", source)
        if "name" not in s:
            raise ConfigError(f"[[plan.samples]] #{i + 1} of {source} has no 'name'")
        samples.append(SampleConfig(**s))
    names = [s.name for s in samples]
    if len(set(names)) != len(names):
        raise ConfigError(f"[[plan.samples]] of {source} repeat a name: {names}")
    if not samples:
        raise ConfigError(f"[plan] of {source} has no [[plan.samples]]: name at least one sample sphere")
    cfg = PlanConfig(probe=probe, samples=tuple(samples), **plan)
    if carries == "rig":
        angles = cfg.scene_angles
        if angles is None:
            angles = tuple(360.0 * s / cfg.scenes for s in range(cfg.scenes))
        elif "scenes" in plan and plan["scenes"] != len(angles):
            raise ConfigError(
                f"[plan] of {source}: 'scenes' = {plan['scenes']} but 'scene_angles' lists {len(angles)} angles"
            )
        if "probe_rotations" in plan and len(cfg.probe_rotations) > 1:
            raise ConfigError(
                f"key 'probe_rotations' in [plan] of {source}: with carries = \"rig\" the probe turns with the "
                "camera, so its rotations cannot move its blemishes; use scene_angles (one angle per scene)"
            )
        cfg = PlanConfig(**{**_fields(cfg), "scenes": len(angles), "scene_angles": angles})
    elif cfg.scene_angles is not None:
        raise ConfigError(
            f"key 'scene_angles' in [plan] of {source} needs carries = \"rig\" in [rig]; with carries = \"samples\" "
            "the operator sets up each scene and the table turns through 'probe_rotations'"
        )
    if turntable_backend == "none":
        used = cfg.scene_angles if carries == "rig" else cfg.probe_rotations
        if any(a != 0 for a in used):
            raise ConfigError(f"[plan] of {source} asks for table angles {list(used)} but [rig.turntable] backend = \"none\"")
    return cfg


def _fields(obj) -> dict:
    """Field values of a dataclass instance, not recursing into nested dataclasses."""
    return {f: getattr(obj, f) for f in obj.__dataclass_fields__}


def _parse_fit(raw: dict, source: str) -> FitPreset:
    return FitPreset(**_check_keys(raw, _FIT_SCHEMA, "fit", source))


def _read_toml(path: str | Path) -> dict:
    path = Path(path)
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except FileNotFoundError:
        raise ConfigError(f"configuration file {path} does not exist") from None
    except IsADirectoryError:
        raise ConfigError(f"configuration file {path} is a directory") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path} is not valid TOML: {exc}") from None


def session_config_from_dict(doc: dict, source: str = "<dict>", *, rig_doc: dict | None = None,
                             fit_doc: dict | None = None, rig_source: str = "", fit_source: str = "") -> SessionConfig:
    """Validate a parsed session document (the TOML tables) into a :class:`SessionConfig`.

    ``rig_doc``/``fit_doc`` (documents with a ``[rig]``/``[fit]`` table) replace the
    plan document's own tables.  Raises :class:`ConfigError` naming file, table and key.
    """
    _check_keys(doc, _TOP_SCHEMA, "top level", source)
    rig_raw, rig_src = doc.get("rig", {}), source
    if rig_doc is not None:
        _check_keys(rig_doc, {"rig": _table}, "top level", rig_source)
        rig_raw, rig_src = rig_doc.get("rig", {}), rig_source
    fit_raw, fit_src = doc.get("fit", {}), source
    if fit_doc is not None:
        _check_keys(fit_doc, {"fit": _table}, "top level", fit_source)
        fit_raw, fit_src = fit_doc.get("fit", {}), fit_source
    session = _check_keys(doc.get("session", {}), _SESSION_SCHEMA, "session", source)
    rig = _parse_rig(rig_raw, rig_src)
    if "plan" not in doc:
        raise ConfigError(f"{source} has no [plan] table: a session file needs one")
    plan = _parse_plan(doc["plan"], source, rig.carries, rig.turntable.backend)
    fit = _parse_fit(fit_raw, fit_src)
    sources = " + ".join(dict.fromkeys(s for s in (source, rig_src, fit_src) if s))
    return SessionConfig(rig=rig, plan=plan, fit=fit, source=sources, **session)


def load_session_config(plan_path: str | Path, rig_path: str | Path | None = None,
                        fit_path: str | Path | None = None) -> SessionConfig:
    """Read and validate a session plan TOML file, optionally with separate rig and fit files."""
    return session_config_from_dict(
        _read_toml(plan_path), str(plan_path),
        rig_doc=None if rig_path is None else _read_toml(rig_path),
        fit_doc=None if fit_path is None else _read_toml(fit_path),
        rig_source=str(rig_path or ""), fit_source=str(fit_path or ""),
    )


def load_rig_config(path: str | Path) -> RigConfig:
    """The ``[rig]`` of a rig file (e.g. ``config/rig-bench.toml``) or of a whole session file (validated in full)."""
    doc = _read_toml(path)
    if "plan" in doc:
        return session_config_from_dict(doc, str(path)).rig
    _check_keys(doc, {"rig": _table, "session": _table, "fit": _table}, "top level", str(path))
    if "rig" not in doc:
        raise ConfigError(f"{path} has no [rig] table: describe the turntable and camera there "
                          "(see config/rig-bench.toml)")
    return _parse_rig(doc["rig"], str(path))


def load_fit_preset(path: str | Path) -> FitPreset:
    """Read a fit preset file (a ``[fit]`` table)."""
    doc = _read_toml(path)
    _check_keys(doc, {"fit": _table}, "top level", str(path))
    return _parse_fit(doc.get("fit", {}), str(path))


def fit_preset_from_dict(d: dict, source: str) -> FitPreset:
    """Validate a ``[fit]`` table given as a dict."""
    return _parse_fit(d, source)


def _to_lists(obj):
    if isinstance(obj, tuple):
        return [_to_lists(v) for v in obj]
    if isinstance(obj, dict):
        return {k: _to_lists(v) for k, v in obj.items()}
    return obj


def stored_session_config(d: dict, source: str) -> SessionConfig:
    """Rebuild the :class:`SessionConfig` stored in a session directory by :meth:`SessionConfig.to_dict`.

    A damaged stored config (a table or key missing or of the wrong type) raises
    :class:`ConfigError` naming ``source`` and the key, like any config file.
    """
    try:
        doc = _stored_document(_to_lists(d))
    except (KeyError, TypeError, AttributeError) as exc:
        what = f"key {exc.args[0]!r} is missing" if isinstance(exc, KeyError) else f"a table is malformed ({exc})"
        raise ConfigError(f"{source} is damaged: in its stored config, {what}; "
                          "restore it from a backup (nothing was changed)") from None
    return session_config_from_dict(doc, source)


def _stored_document(d: dict) -> dict:
    """The TOML-like document of a stored config (the inverse of :meth:`SessionConfig.to_dict`)."""
    plan = dict(d["plan"])
    plan["samples"] = [{k: v for k, v in s.items() if v is not None} for s in plan["samples"]]
    plan["probe"] = {k: v for k, v in plan["probe"].items() if v is not None}
    if d["rig"]["carries"] != "rig":
        plan.pop("scene_angles", None)
    else:
        plan.pop("probe_rotations", None)
    plan = {k: v for k, v in plan.items() if v is not None}
    return {
        "session": {"name": d["name"], "notes": d["notes"]},
        "rig": d["rig"],
        "plan": plan,
        "fit": d["fit"],
    }
