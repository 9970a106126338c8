"""Run a capture plan on the rig into a crash-safe session directory, and resume it.

:func:`run_session` walks the plan scene by scene, table angle by table angle,
exposure by exposure, storing each camera file the moment it arrives
(``brdfrig.session.store``).  What counts as done is what the manifest lists and
verifies, so a session killed at any point (power cut, SIGKILL, Ctrl-C, full
disk) is finished by :func:`resume_session` without reshooting anything
complete: files that fail their checksum are set aside (kept on disk,
untracked) and shot again under a new name.

Scenes come from the table (``carries = "rig"``: each angle is a new lighting)
or from the operator (``carries = "samples"``: the run pauses before each scene
and prompts; answering ``q`` stops it, to be resumed later).  Ctrl-C stops the
table, records an ``interrupted`` stop in the journal and re-raises.

A run or resume holds the session's writer lock (``SessionStore.locked``) from
before its first write to its last, including the fit that follows the shooting
(``then``); after every table move it waits the plan's
``settle_s``; every retry, resynchronisation and re-approach of the turntable
driver is a journal record (``turntable_*`` events).
"""

from __future__ import annotations

import contextlib
import errno
import sys
import time
from pathlib import Path
from typing import Callable

import numpy as np

from brdfrig.session.config import ConfigError, SessionConfig, stored_session_config
from brdfrig.session.plan import Plan, build_plan, meter_bracket, shot_key
from brdfrig.session.store import DiskFullError, SessionStore

__all__ = ["run_session", "resume_session", "check_circles", "completed_shots", "frame_mask", "RAW_SUBDIR"]

RAW_SUBDIR = "raw"
def check_circles(config: SessionConfig, shape: tuple[int, int], hint: str) -> None:
    """ConfigError naming the key if a circle of the plan is not inside a frame of ``shape`` (H, W)."""
    from brdfrig.hdr.probe import check_circle_in_frame

    circles = [("[plan.probe]", config.plan.probe.circle)] + [
        (f"[[plan.samples]] {s.name!r}", s.circle) for s in config.plan.samples]
    for where, circle in circles:
        if circle is not None:
            try:
                check_circle_in_frame(shape, circle, f"key 'circle' in {where} of {config.source}")
            except ValueError as exc:
                raise ConfigError(f"{exc} {hint}") from None


def frame_mask(shape: tuple[int, int], config: SessionConfig) -> np.ndarray | None:
    """Union of the probe and sample discs given in the plan, as an (H, W) bool mask (None if none given).

    Called with the first metering frame's shape: a circle outside the frame the
    camera delivers is a :class:`ConfigError` there, before the bracket is shot.
    """
    check_circles(config, shape, "the camera delivers: fix the circle in the plan and start a new session")
    circles = [config.plan.probe.circle] + [s.circle for s in config.plan.samples]
    circles = [c for c in circles if c is not None]
    if not circles:
        return None
    yy, xx = np.mgrid[0 : shape[0], 0 : shape[1]]
    mask = np.zeros(shape, bool)
    for cx, cy, r in circles:
        mask |= (xx + 0.5 - cx) ** 2 + (yy + 0.5 - cy) ** 2 <= r * r
    return mask


def completed_shots(store: SessionStore) -> dict[str, str]:
    """Shot keys the manifest lists (exposures and metering frames) -> relative path of their file."""
    return {e["key"]: rel for rel, e in store.files.items() if e.get("kind") in ("exposure", "meter")}


class _Runner:
    """One pass over the plan (fresh or resumed): see :func:`run_session`."""

    def __init__(self, store: SessionStore, plan: Plan, turntable, camera, *, prompt: Callable[[str], str] | None,
                 progress: bool, sleep: Callable[[float], None] = time.sleep):
        self.store, self.plan, self.cfg = store, plan, plan.config
        self.turntable, self.camera = turntable, camera
        self.prompt, self.progress, self.sleep = prompt, progress, sleep
        self.done = completed_shots(store)
        self.angle: float | None = None

    # -------------------------------------------------------------------------------- devices
    def _move(self, angle: float) -> None:
        if self.turntable is None or self.angle == angle:
            return
        self.turntable.move_to(angle)
        self.angle = angle
        settle = self.cfg.plan.settle_s
        if settle > 0:
            self.sleep(settle)  # vibration of the bench dies down before the shutter opens
        self.store.append("moved", angle_deg=angle, settle_s=settle)

    def _shoot(self, key: str, time_s: float, kind: str, scene: int, angle: float) -> str:
        cam = self.cfg.rig.camera
        self.camera.set_exposure(time_s, cam.iso, cam.f_number)
        self.camera.begin_shot(key)  # the simulator's noise follows the shot, not the capture count
        path = self.camera.capture(self.store.incoming)
        rel = self.store.store_file(path, RAW_SUBDIR, key, kind=kind, key=key, scene=scene, angle_deg=angle,
                                    time_s=time_s)
        self.done[key] = rel
        return rel

    # -------------------------------------------------------------------------------- auto exposure
    def _bracket(self, scene: int, angle: float) -> tuple[float, ...]:
        """The scene's exposure times: fixed, or from the journal, or metered now (journalled)."""
        if self.plan.bracket is not None:
            return self.plan.bracket
        for rec in reversed(self.store.journal()):
            if rec.get("event") == "bracket" and rec.get("scene") == scene and all(
                k in self.done for k in rec["meter_keys"]
            ):
                return tuple(rec["times"])
        from brdfrig.hdr.raw import read_frame

        self._move(angle)
        keys = []

        def shoot(i: int, t: float) -> np.ndarray:
            key = shot_key(scene, angle, "m", i)
            rel = self.done.get(key) or self._shoot(key, t, "meter", scene, angle)
            keys.append(key)
            return read_frame(self.store.root / rel)[0]

        times, info = meter_bracket(shoot, self.cfg, lambda shape: frame_mask(shape, self.cfg))
        self.store.append("bracket", scene=scene, meter_keys=keys, times=list(times), **info)
        return times

    # -------------------------------------------------------------------------------- the run
    def _scene_ready(self, scene: int, resumed: bool) -> bool:
        """Operator prompt before a scene (carries = samples); False if the operator stops."""
        if self.cfg.rig.carries == "rig" or self.prompt is None:
            return True
        what = "check the bench is as it was for" if resumed else "set up (move the bench or change the lights) for"
        try:
            answer = self.prompt(
                f"\n{what} scene {scene + 1}/{self.plan.n_scenes}, then press Enter (q + Enter to stop; "
                f"`brdfrig capture resume {self.store.root}` continues later): "
            )
        except EOFError:  # no operator (stdin closed): pause rather than assume the scene is set up
            answer = "q"
        if answer.strip().lower() in ("q", "quit", "stop"):
            return False
        self.store.append("scene_ready", scene=scene)
        return True

    def run(self) -> str:
        from tqdm import tqdm

        plan = self.plan
        total = sum(len(a) for a in plan.angles) * plan.max_shots_per_angle()
        bar = tqdm(total=total, unit="shot", disable=not self.progress, file=sys.stderr, dynamic_ncols=True)
        try:
            for scene, angles in enumerate(plan.angles):
                started = any(e.get("scene") == scene for e in self.store.files.values())
                scene_shots = self._scene_remaining(scene, angles)
                if scene_shots == 0:
                    bar.update(len(angles) * plan.max_shots_per_angle())
                    continue
                if not self._scene_ready(scene, started):
                    return "paused"
                self.store.append("scene_start", scene=scene, angles=list(angles))
                for angle in angles:
                    times = self._bracket(scene, angle)
                    shots = plan.shots(scene, angle, times)
                    bar.update(plan.max_shots_per_angle() - len(shots))
                    for shot in shots:
                        bar.set_description(
                            f"scene {scene + 1}/{plan.n_scenes} angle {angle:g} exp {shot.index + 1}/{len(shots)}"
                        )
                        if shot.key not in self.done:
                            self._move(angle)
                            self._shoot(shot.key, shot.time_s, "exposure", scene, angle)
                        bar.update(1)
                self.store.append("scene_done", scene=scene)
            return "complete"
        finally:
            bar.close()

    def _scene_remaining(self, scene: int, angles: tuple[float, ...]) -> int:
        """Shots still missing in ``scene`` (unknown auto brackets count as missing)."""
        missing = 0
        for angle in angles:
            if self.plan.bracket is None and not any(
                r.get("event") == "bracket" and r.get("scene") == scene for r in self.store.journal()
            ):
                return 1
            times = self.plan.bracket
            if times is None:
                times = next(tuple(r["times"]) for r in reversed(self.store.journal())
                             if r.get("event") == "bracket" and r.get("scene") == scene)
            missing += sum(s.key not in self.done for s in self.plan.shots(scene, angle, times))
        return missing


def _execute(store: SessionStore, plan: Plan, *, prompt, progress, rig_factory, sleep) -> str:
    """Run the plan with the rig open; always journal a final ``stop`` record with the exit status.

    ``rig_factory(config, journal=store.append)`` opens the rig (:func:`brdfrig.devices.open_rig`).
    """
    status, reason = "error", ""
    try:
        with rig_factory(plan.config, journal=store.append) as (turntable, camera):
            runner = _Runner(store, plan, turntable, camera, prompt=prompt, progress=progress, sleep=sleep)
            try:
                status = runner.run()
            except BaseException:
                if turntable is not None:
                    with contextlib.suppress(Exception):
                        turntable.stop()
                raise
        return status
    except KeyboardInterrupt:
        status, reason = "interrupted", "Ctrl-C: turntable stopped"
        raise
    except OSError as exc:
        if exc.errno == errno.ENOSPC:
            reason = str(exc)
            stored = len(store.files)
            raise DiskFullError(
                errno.ENOSPC,
                f"{exc.strerror}; the {stored} files stored so far in {store.root} are intact; free some space "
                f"and run `brdfrig capture resume {store.root}`",
            ) from exc
        reason = str(exc)
        raise
    except BaseException as exc:
        reason = f"{type(exc).__name__}: {exc}"
        raise
    finally:
        with contextlib.suppress(OSError):  # the disk may still be full: the journal then ends without it
            store.append("stop", status=status, reason=reason, files=len(store.files))


def run_session(config: SessionConfig, out_dir: str | Path, *, rig_factory, prompt: Callable[[str], str] | None = input,
                progress: bool = True, echo: Callable[[str], None] | None = None,
                sleep: Callable[[float], None] = time.sleep,
                then: Callable[[str, SessionStore], object] | None = None) -> tuple[str, SessionStore]:
    """Create the session directory ``out_dir`` and run the whole plan under the session's writer lock.

    Returns ``(status, store)`` with status ``"complete"`` or ``"paused"`` (operator
    stopped at a scene prompt).  Raises ``StoreError`` if ``out_dir`` exists and is
    not an empty directory or is in use, ``DiskFullError`` on a full disk, and
    re-raises ``KeyboardInterrupt`` after stopping the table.  ``sleep`` waits the
    plan's ``settle_s`` after each move.  ``rig_factory(config, journal=...)`` is a context
    manager yielding ``(turntable, camera)`` (:func:`brdfrig.devices.open_rig` for the
    configured devices; its :func:`brdfrig.devices.preflight` checks what it can first).
    ``then(status, store)``, if given, runs once the shooting ends, still under the
    same lock (the capture command fits there, so no other writer gets in between).
    """
    plan = build_plan(config)
    if echo:
        echo(_describe(plan))
    store = SessionStore.create(out_dir, config.to_dict())
    with store.locked():
        store.append("run_start", resumed=False)
        status = _execute(store, plan, prompt=prompt, progress=progress, rig_factory=rig_factory, sleep=sleep)
        if then is not None:
            then(status, store)
        return status, store


def resume_session(session_dir: str | Path, *, rig_factory, prompt: Callable[[str], str] | None = input,
                   progress: bool = True, echo: Callable[[str], None] | None = None,
                   sleep: Callable[[float], None] = time.sleep,
                   then: Callable[[str, SessionStore], object] | None = None) -> tuple[str, SessionStore]:
    """Finish a stopped or killed session: verify what is stored, set aside what fails, shoot the rest.

    Holds the session's writer lock from before its first write (a session in
    use by another process raises ``StoreError`` and nothing is changed) until
    ``then`` returns.  Returns ``(status, store)`` and calls ``then`` as :func:`run_session`.
    """
    store = SessionStore.open(session_dir)
    with store.locked():
        status, _ = _resume(store, prompt=prompt, progress=progress, rig_factory=rig_factory, echo=echo, sleep=sleep)
        if then is not None:
            then(status, store)
        return status, store


def _resume(store: SessionStore, *, prompt, progress, rig_factory, echo, sleep) -> tuple[str, SessionStore]:
    """:func:`resume_session` once the lock is held."""
    session_dir = store.root
    config = stored_session_config(store.config, f"{Path(session_dir) / 'session.json'}")
    check = store.verify(prefix=RAW_SUBDIR + "/")
    leftovers = store.clean_incoming()
    if check.corrupt or check.missing:
        store.reject(check.corrupt + check.missing, "failed verification on resume; shot again")
    plan = build_plan(config)
    if echo:
        echo(_describe(plan))
        echo(
            f"resuming {store.root}: {len(check.ok)} stored files verified"
            + (f", {len(check.corrupt) + len(check.missing)} failed and will be shot again "
               f"({', '.join(check.corrupt + check.missing)})" if check.corrupt or check.missing else "")
            + (f", {len(check.untracked)} untracked file(s) from an interrupted write kept aside" if check.untracked else "")
        )
    store.append("run_start", resumed=True, verified=len(check.ok), rejected=check.corrupt + check.missing,
                 untracked=check.untracked, incoming_removed=leftovers)
    return _execute(store, plan, prompt=prompt, progress=progress, rig_factory=rig_factory, sleep=sleep), store


def _describe(plan: Plan) -> str:
    from brdfrig.session.plan import describe_plan

    return describe_plan(plan)
