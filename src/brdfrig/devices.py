"""The configured devices: open the rig a session config describes (real drivers or the simulators).

The one place where backend names in a config become devices: ``grbl`` and ``none``
turntables, ``gphoto2``, ``watch`` and ``sim`` cameras, and the ``sim`` turntable (the
GRBL firmware simulator on a pseudo-terminal, driven by the real driver).  The session
runner receives :func:`open_rig` as its ``rig_factory`` and knows no backend itself.
"""

from __future__ import annotations

import contextlib
import difflib
from typing import Callable, Iterator

from brdfrig.session.config import ConfigError, SessionConfig
from brdfrig.session.runner import check_circles

__all__ = ["open_rig", "preflight", "sim_bench", "make_sim_bench"]


@contextlib.contextmanager
def open_rig(config: SessionConfig, journal: Callable[..., object] | None = None) -> Iterator[tuple[object, object]]:
    """Connect the configured turntable and camera; yield ``(turntable, camera)``, disconnect on exit.

    ``sim`` backends run the GRBL firmware simulator on a pseudo-terminal, driven
    by the real :class:`brdfrig.rig.turntable.GrblTurntable`, and the simulated camera
    reading the simulator's physical table angle.  ``journal(event, **fields)``
    receives the driver's retries (e.g. ``SessionStore.append``).  The turntable
    is stopped on the way out, whatever happened.
    """
    from brdfrig.rig.turntable import GrblTurntable

    tt_cfg, cam_cfg = config.rig.turntable, config.rig.camera
    with contextlib.ExitStack() as stack:
        table_state = None
        if tt_cfg.backend == "sim":
            from brdfrig.sim.grbl import GrblSimulator

            sim = stack.enter_context(GrblSimulator(**_sim_table_options(config)))
            port, table_state, settled = sim.port, sim, sim.settled
        else:
            port, settled = tt_cfg.port, None
        turntable = None
        if tt_cfg.backend != "none":
            turntable = stack.enter_context(
                GrblTurntable(port, tt_cfg.baud, tt_cfg.steps_per_degree, tt_cfg.backlash_deg,
                              homing_timeout_s=tt_cfg.timeout_s, journal=journal, settled=settled)
            )
            turntable.home()
        if cam_cfg.backend == "sim":
            from brdfrig.sim.camera import SimulatedCamera

            bench = sim_bench(config)
            camera = SimulatedCamera(bench, table_state, **_sim_camera_options(config))
        elif cam_cfg.backend == "gphoto2":
            from brdfrig.rig.gphoto import GphotoCamera

            camera = GphotoCamera()
        else:
            from brdfrig.rig.watch_folder import WatchFolderCamera

            camera = WatchFolderCamera(cam_cfg.watch_dir, timeout_s=cam_cfg.timeout_s)
        stack.enter_context(camera)
        yield turntable, camera


_SIM_TABLE_KEYS = ("table_start_deg",)


def sim_bench(config: SessionConfig):
    """The ``brdfrig.sim.bench.SimBench`` described by ``[rig.sim]`` of a session config."""
    return make_sim_bench(config.rig.sim, config.rig.carries, config.source)


def make_sim_bench(options: dict, carries: str, source: str):
    """A ``brdfrig.sim.bench.SimBench`` from ``[rig.sim]``-style options (unknown keys named, with ``source``)."""
    import inspect

    from brdfrig.sim.bench import SimBench

    opts = {k: v for k, v in options.items() if k not in _SIM_TABLE_KEYS}
    allowed = [p for p in inspect.signature(SimBench).parameters if p != "carries"]
    for key in opts:
        if key not in allowed:
            hint = difflib.get_close_matches(key, allowed, n=1)
            raise ConfigError(f"unknown key {key!r} in [rig.sim] of {source}"
                              + (f"; did you mean {hint[0]!r}?" if hint else f"; allowed keys: {', '.join(allowed)}"))
    try:
        return SimBench(carries=carries, **opts)
    except (ValueError, TypeError) as exc:
        raise ConfigError(f"[rig.sim] of {source}: {exc}") from None


def preflight(config: SessionConfig) -> None:
    """Checks that need no device, made before anything is shot (and by ``--dry-run``).

    With the simulated camera: the ``[rig.sim]`` options build a bench, and every
    circle of the plan lies inside its frame.  Raises :class:`ConfigError`.
    """
    if config.rig.camera.backend == "sim":
        check_circles(config, sim_bench(config).frame_shape, "of the simulated camera: fix the circle before shooting")


def _sim_table_options(config: SessionConfig) -> dict:
    """The simulated table's true mechanics: the configured ones (a correctly set-up board)."""
    tt = config.rig.turntable
    return {
        "steps_per_degree": tt.steps_per_degree,
        "backlash_deg": tt.backlash_deg,
        "max_rate_deg_s": tt.speed_deg_s,
        "baud": tt.baud,
        "start_angle_deg": float(config.rig.sim.get("table_start_deg", 37.0)),
    }


def _sim_camera_options(config: SessionConfig) -> dict:
    """The simulated sensor: the noise model the config declares (so auto exposure and merge match it)."""
    cam = config.rig.camera
    return {"full_well_e": cam.full_well_e, "read_noise_e": cam.read_noise_e,
            "seed": int(config.rig.sim.get("seed", 0))}
