"""`brdfrig rig check`: find and exercise the configured devices and report what works.

The turntable check connects (GRBL 1.1 greeting, `$$` settings), homes,
rotates to +10 degrees and back with read-back verification, and stops; it
prints the firmware version and every `$$` setting the board reports.  The
camera check sets an exposure, takes one picture into `--out` (default: a
temporary folder), reads the exposure and the camera model back from the
file's metadata and prints the spheres it finds in the picture
(the most mirror-like one is the probe, as `brdfrig locate` decides), with their circles in pixels.
Devices come from the `[rig]` table of a rig file or a session file
(`--config`), or from flags; `--simulate` runs the GRBL simulator on a
pseudo-terminal and the simulated camera, through the same drivers.  With no
device configured, or an `--out` that is not a writable folder, it stops
before touching anything (exit 2).
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from brdfrig.errors import InputError
from brdfrig.ranges import BACKLASH_DEG, BAUD, EXPOSURE_S, STEPS_PER_DEGREE

CHECK_ANGLE_DEG = 10.0


@dataclass(frozen=True)
class _TableSettings:
    backend: str  # "grbl" | "sim" | "none"
    port: str
    baud: int
    steps_per_degree: float
    backlash_deg: float
    timeout_s: float


@dataclass(frozen=True)
class _CameraSettings:
    backend: str  # "gphoto2" | "watch" | "sim" | "none"
    iso: float
    f_number: float
    time_s: float
    watch_dir: str
    timeout_s: float


def register(subparsers) -> None:
    p = subparsers.add_parser("rig", help="check the turntable and camera",
                              description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="rig_command", required=True, metavar="ACTION")
    c = sub.add_parser("check", help="find and exercise the configured devices; report what works")
    c.add_argument("--config", help="rig or session TOML file whose [rig] table describes the devices")
    c.add_argument("--simulate", action="store_true", help="use the GRBL simulator and the simulated camera")
    c.add_argument("--port", help="turntable serial port (e.g. /dev/ttyUSB0); omit for no turntable")
    c.add_argument("--baud", type=BAUD.arg(), default=115200, help="turntable baud rate (default 115200)")
    c.add_argument("--steps-per-degree", type=STEPS_PER_DEGREE.arg(), default=80.0, help="motor steps per table degree")
    c.add_argument("--backlash", type=BACKLASH_DEG.arg(), default=0.5, help="gear play in degrees")
    c.add_argument("--camera", choices=("gphoto2", "watch", "sim", "none"), default="none",
                   help="camera backend (default none)")
    c.add_argument("--watch-dir", default="", help="folder the tethering software writes into (--camera watch)")
    c.add_argument("--exposure", type=EXPOSURE_S.arg(), default=0.01,
                   help="test exposure time in seconds (default 0.01)")
    c.add_argument("--out", help="folder for the test picture (default: a temporary folder)")
    p.set_defaults(func=run)


def _settings(args) -> tuple[_TableSettings, _CameraSettings, dict, str]:
    """Device settings from --config, or from the flags."""
    if args.config:
        from brdfrig.session.config import load_rig_config

        rig = load_rig_config(args.config)
        tt, cam = rig.turntable, rig.camera
        table = _TableSettings(tt.backend, tt.port, tt.baud, tt.steps_per_degree, tt.backlash_deg, tt.timeout_s)
        camera = _CameraSettings(cam.backend, cam.iso, cam.f_number, args.exposure, cam.watch_dir, cam.timeout_s)
        return table, camera, dict(rig.sim), rig.carries
    if args.simulate:
        table = _TableSettings("sim", "", args.baud, args.steps_per_degree, args.backlash, 30.0)
        return table, _CameraSettings("sim", 100, 8.0, args.exposure, "", 10.0), {"scale": 0.25, "env_height": 16}, "rig"
    table = _TableSettings("grbl" if args.port else "none", args.port or "", args.baud, args.steps_per_degree,
                           args.backlash, 30.0)
    camera = _CameraSettings(args.camera, 100, 8.0, args.exposure, args.watch_dir, 60.0)
    return table, camera, {}, "rig"


def _check_turntable(s: _TableSettings, stack: contextlib.ExitStack, report) -> object | None:
    """Connect, home, move to +10 deg and back; return the simulator (or None) for the simulated camera."""
    from brdfrig.rig.errors import DeviceNotFound, RigError
    from brdfrig.rig.turntable import GrblTurntable

    if s.backend == "none":
        report("turntable", "skipped", "no turntable configured")
        return None
    sim = None
    port = s.port
    if s.backend == "sim":
        from brdfrig.sim.grbl import GrblSimulator

        sim = stack.enter_context(GrblSimulator(steps_per_degree=s.steps_per_degree, backlash_deg=s.backlash_deg,
                                                max_rate_deg_s=360.0, baud=s.baud, homing_time_s=0.2))
        port = sim.port
    try:
        table = GrblTurntable(port, s.baud, s.steps_per_degree, s.backlash_deg, homing_timeout_s=s.timeout_s)
    except ValueError as exc:
        report("turntable", "FAILED", str(exc))
        return sim
    try:
        with table:
            report("turntable", "ok", f"{table.firmware} on {s.port or 'simulator'} at {s.baud} baud, "
                                      f"$100={s.steps_per_degree:g} steps/deg, max rate {table.rate_deg_s:g} deg/s")
            report("  settings", "ok", " ".join(f"${k}={v:g}" for k, v in sorted(table.settings.items())))
            t0 = time.monotonic()
            table.home()
            report("  home", "ok", f"homed in {time.monotonic() - t0:.1f} s, position 0 confirmed")
            for target in (CHECK_ANGLE_DEG, 0.0):
                got = table.move_to(target)
                where = f", table at {sim.table_angle_deg:.4f} deg" if sim is not None else ""
                report(f"  move to {target:g} deg", "ok", f"confirmed at {got:.4f} deg{where}")
            table.stop()
            report("  stop", "ok", "feed hold + reset acknowledged, table stopped")
    except RigError as exc:
        stopped = "" if isinstance(exc, DeviceNotFound) else " (the table was stopped)"
        report("turntable", "FAILED", f"{type(exc).__name__}: {exc}{stopped}")
    return sim


def _check_camera(s: _CameraSettings, sim, sim_opts: dict, carries: str, out: Path, report) -> None:
    from brdfrig.rig.errors import RigError

    if s.backend == "none":
        report("camera", "skipped", "no camera configured")
        return
    try:
        if s.backend == "sim":
            from brdfrig.devices import make_sim_bench
            from brdfrig.sim.camera import SimulatedCamera

            camera = SimulatedCamera(make_sim_bench(sim_opts, carries, "the rig check's simulated bench"), sim)
        elif s.backend == "gphoto2":
            from brdfrig.rig.gphoto import GphotoCamera

            camera = GphotoCamera()
        else:
            from brdfrig.rig.watch_folder import WatchFolderCamera

            camera = WatchFolderCamera(s.watch_dir, timeout_s=s.timeout_s,
                                       trigger=lambda msg: print(f"rig check: {msg}", file=sys.stderr))
        with camera:
            camera.set_exposure(s.time_s, s.iso, s.f_number)
            report("camera", "ok", f"{s.backend}: exposure {s.time_s:g} s, ISO {s.iso:g}, f/{s.f_number:g} set")
            path = camera.capture(out)
        report("  capture", "ok", f"{path} ({path.stat().st_size} bytes)")
    except (RigError, ValueError, OSError) as exc:
        report("camera", "FAILED", f"{type(exc).__name__}: {exc}")
        return
    try:
        from brdfrig.hdr.raw import read_camera_model, read_exposure

        exp = read_exposure(path)
        model = read_camera_model(path) or "camera model not recorded"
        report("  metadata", "ok", f"{model}; file says {exp.time_s:g} s, ISO {exp.iso:g}, f/{exp.f_number:g}")
    except (ValueError, OSError) as exc:
        report("  metadata", "FAILED", str(exc))
        return
    _report_spheres(path, report)


def _report_spheres(path: Path, report) -> None:
    """The spheres found in the test picture (probe first), or a note that none was found (not a failure)."""
    from brdfrig.cli.locate import locate
    from brdfrig.hdr.detect import SphereNotFoundError

    try:
        found = locate(path, 8)
    except SphereNotFoundError as exc:
        report("  spheres", "none", f"{exc} (aim the camera at the bench and light it to see them here)")
        return
    except (ValueError, OSError) as exc:
        report("  spheres", "FAILED", f"cannot read the picture: {exc}")
        return

    def circle(c) -> str:
        return "(" + ", ".join(f"{v:.1f}" for v in c) + ")"

    samples = ", ".join(circle(c) for c in found["samples"]) or "none"
    report("  spheres", "ok", f"{1 + len(found['samples'])} found: probe {circle(found['probe'])} px, "
                              f"samples {samples} px (circles cx, cy, r; plan lines: brdfrig locate)")


def run(args) -> int:
    table_s, camera_s, sim_opts, carries = _settings(args)
    if table_s.backend == "none" and camera_s.backend == "none":
        raise InputError("nothing was checked: no turntable and no camera configured (give --config FILE, "
                         "--port and/or --camera, or --simulate)")
    if args.out and not (Path(args.out).is_dir() and os.access(args.out, os.W_OK | os.X_OK)):
        raise InputError(f"--out {args.out!r} is not a writable folder: create it or choose another "
                         "(nothing was moved)")
    failures, skipped = [], []

    def report(device: str, status: str, detail: str) -> None:
        if status == "FAILED":
            failures.append(device)
        elif status == "skipped":
            skipped.append(device)
        print(f"{device:<22} {status:<8} {detail}", flush=True)

    with contextlib.ExitStack() as stack:
        sim = _check_turntable(table_s, stack, report)
        out = Path(args.out) if args.out else Path(stack.enter_context(tempfile.TemporaryDirectory()))
        _check_camera(camera_s, sim, sim_opts, carries, out, report)
    if failures:
        print(f"{len(failures)} check(s) failed: {', '.join(failures)}")
    else:
        print("all devices work" + (f" (not checked: {', '.join(skipped)})" if skipped else ""))
    return 1 if failures else 0
