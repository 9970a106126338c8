"""The capture plan: which shots, in what order, how long it takes, and the ``auto`` exposure bracket.

A plan is a list of :class:`Shot` s grouped by scene and table angle.  With a
fixed bracket it is complete before the run; with ``exposure = "auto"`` the
times of each scene are decided by :func:`auto_bracket` from metering shots
taken at the start of the scene, and the plan counts the worst case
(``max_exposures`` per angle).

Auto exposure (after Hasinoff, Durand and Freeman, "Noise-optimal capture for
high dynamic range photography", CVPR 2010): from a metering frame, the scene's
irradiance range ``[E_lo, E_hi]`` (electrons per second, robust percentiles
over the probe and sample discs) is covered greedily from the top: the first
exposure is the longest that keeps ``E_hi`` below saturation; each next
exposure is the longest that does not saturate where the previous one stops
reaching ``target_snr``; it stops as soon as ``E_lo`` reaches the target SNR.
An exposure that would only re-cover a covered range is never taken, so a
low-contrast scene needs one or two exposures where a fixed bracket takes nine.
The noise model is shot noise plus read noise: a pixel collecting ``s``
electrons has ``SNR = s / sqrt(s + read_noise_e**2)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from brdfrig.errors import ConfigError
from brdfrig.session.config import SessionConfig

__all__ = [
    "Shot",
    "Plan",
    "build_plan",
    "describe_plan",
    "auto_bracket",
    "electrons_for_snr",
    "meter_range",
    "scenes_needed",
    "shot_key",
    "SATURATION_HEADROOM",
    "meter_bracket",
]

#: Fraction of the white level an exposure may put the brightest pixel at (headroom for noise and vignetting).
SATURATION_HEADROOM = 0.8
#: Metering steps down by this many stops while the metering frame has clipped pixels, at most this many frames.
METER_STEP_STOPS = 4
METER_MAX_SHOTS = 3
#: Largest step between consecutive exposures of an auto bracket, in stops (keeps a well-exposed overlap).
MAX_GAP_STOPS = 3.0
#: Shortest and longest exposure time the planner proposes, seconds.
MIN_TIME_S, MAX_TIME_S = 1.0 / 8000.0, 30.0


def shot_key(scene: int, angle_deg: float, kind: str, index: int) -> str:
    """Stable identifier of a shot, e.g. ``s03-a090.0-e02`` (kind ``e``) or ``s03-a090.0-m0`` (meter)."""
    return f"s{scene:02d}-a{angle_deg:05.1f}-{kind}{index:02d}"


@dataclass(frozen=True)
class Shot:
    """One exposure: scene index, table angle (degrees), index in the bracket, exposure time (s)."""

    scene: int
    angle_deg: float
    index: int
    time_s: float

    @property
    def key(self) -> str:
        return shot_key(self.scene, self.angle_deg, "e", self.index)


@dataclass(frozen=True)
class Plan:
    """What a session shoots.

    Attributes
    ----------
    config : SessionConfig
    angles : tuple of tuple of float
        Table angles (degrees) per scene.
    bracket : tuple of float or None
        Fixed exposure times (s), or None for ``auto`` (decided per scene at run time).
    scenes_needed : dict
        The identifiability analysis' answer for the configured model and band limit
        (``{"scenes": int or None, "text": str}``).
    """

    config: SessionConfig
    angles: tuple[tuple[float, ...], ...]
    bracket: tuple[float, ...] | None
    scenes_needed: dict

    @property
    def n_scenes(self) -> int:
        return len(self.angles)

    def max_shots_per_angle(self) -> int:
        """Exposures per table angle: the fixed bracket's length, or ``max_exposures`` for auto."""
        return len(self.bracket) if self.bracket is not None else self.config.plan.max_exposures

    def shots(self, scene: int, angle_deg: float, times: tuple[float, ...] | None = None) -> list[Shot]:
        """The shots at one table angle of one scene, longest exposure last (``times`` for auto)."""
        times = self.bracket if times is None else times
        return [Shot(scene, angle_deg, i, t) for i, t in enumerate(sorted(times))]

    def expected_time_s(self) -> float:
        """Upper estimate of the run time: exposures, per-shot overhead, metering and table moves."""
        cam, tt, plan = self.config.rig.camera, self.config.rig.turntable, self.config.plan
        total = 0.0
        prev = 0.0
        for angles in self.angles:
            for a in angles:
                total += abs(a - prev) / tt.speed_deg_s + plan.settle_s
                prev = a
            if self.bracket is None:  # metering: up to three frames per scene
                total += 3 * (plan.meter_time_s + cam.overhead_s)
                per_angle = plan.max_exposures * (cam.overhead_s + 4 * plan.meter_time_s)
            else:
                per_angle = sum(self.bracket) + len(self.bracket) * cam.overhead_s
            total += per_angle * len(angles)
        return total


def scenes_needed(model: str, lmax: int, pmax: int) -> dict:
    """Ask the fitter's identifiability analysis how many differing scenes ``model`` at ``lmax`` needs.

    Returns ``{"scenes": int, "text": str}``.  Only the full model needs several
    scenes (``brdfrig.fit.identifiability.scenes_needed``); ``auto`` asks for what the
    full model needs, since it picks the richest model the data determine.
    """
    from brdfrig.fit.identifiability import scenes_needed as full_scenes

    full = full_scenes(lmax)
    if model in ("full", "auto"):
        text = f"the full model at lmax={lmax} needs >= {full} differing scenes (lighting conditions)"
        if model == "auto":
            text += "; with fewer, auto picks a model one scene determines (diffuse, lobe, microfacet)"
        return {"scenes": full, "text": text}
    if model == "full+prior":
        return {"scenes": 1, "text": f"full+prior takes what {full} differing scenes would determine from the data "
                                     "and the rest from a one-scene prior fit"}
    return {"scenes": 1, "text": f"model {model!r} is determined by one scene (the full model would need {full})"}


def build_plan(config: SessionConfig) -> Plan:
    """The plan of a validated session config (no device is touched)."""
    angles = tuple(config.table_angles(s) for s in range(config.plan.scenes))
    bracket = None if config.plan.exposure == "auto" else tuple(sorted(config.plan.exposure))
    fit = config.fit
    return Plan(config, angles, bracket, scenes_needed(fit.model, fit.lmax, fit.pmax))


def describe_plan(plan: Plan) -> str:
    """The plan as printed before a run: scenes, angles, exposures, shots, expected time, scenes needed."""
    cfg = plan.config
    n_angles = sum(len(a) for a in plan.angles)
    n_shots = n_angles * plan.max_shots_per_angle()
    how = (
        "the turntable carries the whole rig: each table angle is a new lighting"
        if cfg.rig.carries == "rig"
        else "the operator sets up each scene (the run pauses and prompts); the table turns the probe"
    )
    if plan.bracket is None:
        exp = (
            f"auto (metering shot per scene, target SNR {cfg.plan.target_snr:g}, "
            f"<= {cfg.plan.max_exposures} exposures {cfg.plan.stop_step:g} stop apart)"
        )
        shots = f"<= {n_shots} shots (+ metering)"
    else:
        exp = ", ".join(_fmt_time(t) for t in plan.bracket)
        shots = f"{n_shots} shots"
    lines = [
        f"session {cfg.name!r} ({cfg.source})",
        f"  scenes: {plan.n_scenes} ({how})",
        f"  table angles: " + "; ".join(", ".join(f"{a:g}" for a in angs) for angs in plan.angles),
        f"  samples: {', '.join(s.name for s in cfg.plan.samples)}",
        f"  exposures per angle: {exp}",
        f"  {shots}, expected time about {plan.expected_time_s():.0f} s",
        f"  fit: model {cfg.fit.model}, lmax {cfg.fit.lmax}, pmax {cfg.fit.pmax}, solver {cfg.fit.solver}",
    ]
    need = plan.scenes_needed
    lines.append(f"  identifiability: {need['text']}")
    if cfg.rig.carries == "rig" and plan.n_scenes > 1 and (cfg.fit.model == "auto" or cfg.fit.model.startswith("bivariate")):
        lines.append(
            "  note: turns of the whole rig light the sphere from the same elevations in every scene; the tables "
            "(bivariate models) learn more from scenes tilted or set up elsewhere in the room (carries = \"samples\": "
            "the run prompts for each scene; README, real materials)"
        )
    if need["scenes"] is not None and plan.n_scenes < need["scenes"]:
        lines.append(
            f"  WARNING: {plan.n_scenes} scene(s) planned, fewer than the {need['scenes']} needed: the fit will "
            "fall back to a model the data determine (see the fit report)"
        )
    return "\n".join(lines)


def _fmt_time(t: float) -> str:
    return f"1/{1 / t:.0f} s" if t < 0.5 else f"{t:g} s"


def electrons_for_snr(target_snr: float, read_noise_e: float) -> float:
    """Signal (electrons) at which ``s / sqrt(s + r^2)`` equals ``target_snr``: ``(k^2 + sqrt(k^4 + 4 k^2 r^2)) / 2``."""
    k2 = target_snr**2
    return 0.5 * (k2 + math.sqrt(k2 * k2 + 4.0 * k2 * read_noise_e**2))


def meter_range(frame: np.ndarray, time_s: float, full_well_e: float, mask: np.ndarray | None = None,
                *, low_pct: float = 0.5, high_pct: float = 100.0) -> tuple[float, float, float]:
    """Scene irradiance range from a metering frame, in electrons per second.

    Parameters
    ----------
    frame : (H, W, C) float
        Decoded linear frame, 1.0 = saturation (``brdfrig.hdr.raw.decode_raw``).
    time_s : float
        Its exposure time.
    full_well_e : float
        Electrons at saturation.
    mask : (H, W) bool, optional
        Pixels that matter (probe and sample discs); all pixels if None.
    low_pct, high_pct : float
        Percentiles taken as the darkest and brightest levels to cover.

    Returns
    -------
    e_lo, e_hi : float
        Electrons per second at the low and high percentiles (e_lo >= one electron per exposure).
    clipped : float
        Fraction of the masked samples at or above 0.98 of saturation (the range is then a lower bound).
    """
    values = frame[mask] if mask is not None else frame.reshape(-1, frame.shape[-1])
    values = values.ravel()
    e = np.clip(values, 0.0, None) * full_well_e / time_s
    e_lo = max(float(np.percentile(e, low_pct)), 1.0 / time_s)
    e_hi = max(float(np.percentile(e, high_pct)), e_lo)
    clipped = float(np.mean(values >= 0.98))
    return e_lo, e_hi, clipped


def auto_bracket(e_lo: float, e_hi: float, *, full_well_e: float, read_noise_e: float, target_snr: float,
                 base_time_s: float, stop_step: float = 1.0, max_exposures: int = 9,
                 max_gap_stops: float = MAX_GAP_STOPS) -> tuple[float, ...]:
    """Exposure times covering irradiances ``[e_lo, e_hi]`` (electrons/s) at ``target_snr``, greedily.

    Times lie on the grid ``base_time_s * 2**(stop_step * k)`` (integer k) within
    [1/8000 s, 30 s].  The first time keeps ``e_hi`` at or below
    ``SATURATION_HEADROOM`` of full well; each next one is the longest whose
    saturation level reaches down to where the previous one stops reaching
    ``target_snr``; the bracket stops once ``e_lo`` reaches ``target_snr`` (or at
    ``max_exposures``).  Consecutive times are at most ``max_gap_stops`` apart, so
    that neighbouring frames share well-exposed pixels (the merge checks the
    exposure ratios on them: ``brdfrig.hdr.merge.estimate_times``).  Returns the times,
    shortest first.
    """
    if not (e_hi >= e_lo > 0):
        raise ValueError(f"need 0 < e_lo <= e_hi, got e_lo={e_lo}, e_hi={e_hi}")
    s_min = electrons_for_snr(target_snr, read_noise_e)
    s_max = SATURATION_HEADROOM * full_well_e
    if s_min >= s_max:
        raise ConfigError(
            f"target SNR {target_snr:g} needs {s_min:.0f} electrons, more than the sensor's usable "
            f"{s_max:.0f} (full_well_e={full_well_e:g}): lower target_snr"
        )
    step = math.log(2.0) * stop_step
    k_min = math.ceil(math.log(MIN_TIME_S / base_time_s) / step - 1e-9)
    k_max = math.floor(math.log(MAX_TIME_S / base_time_s) / step + 1e-9)

    def longest_below(t_limit: float) -> int:
        """Largest grid index whose time is <= t_limit, clamped to the grid."""
        k = math.floor(math.log(t_limit / base_time_s) / step + 1e-9)
        return min(max(k, k_min), k_max)

    k = longest_below(s_max / e_hi)
    times = []
    while True:
        t = base_time_s * math.exp(step * k)
        times.append(t)
        reach = s_min / t  # lowest irradiance this exposure records at target SNR
        if reach <= e_lo or k >= k_max or len(times) >= max_exposures:
            break
        k_next = min(longest_below(s_max / reach), k + max(1, math.floor(max_gap_stops / stop_step + 1e-9)))
        k = max(k_next, k + 1)
    return tuple(sorted(times))


def meter_bracket(shoot: Callable[[int, float], np.ndarray], config: SessionConfig,
                  mask_for: Callable[[tuple[int, int]], np.ndarray | None] = lambda shape: None,
                  ) -> tuple[tuple[float, ...], dict]:
    """Meter a scene and decide its auto bracket.

    ``shoot(i, time_s)`` takes metering frame ``i`` and returns it decoded (1.0 =
    saturation).  The first frame is at ``meter_time_s``; while any sample in the
    mask is clipped, the next is ``METER_STEP_STOPS`` shorter (at most
    ``METER_MAX_SHOTS``).  The dark end is read from the first (longest) frame,
    the bright end from the last.  Returns ``(times, info)`` with ``info`` =
    ``{"e_lo", "e_hi", "clipped"}`` (electrons per second, clipped fraction left).
    """
    plan, cam = config.plan, config.rig.camera
    t, e_lo, e_hi, clipped = plan.meter_time_s, None, None, 0.0
    for i in range(METER_MAX_SHOTS):
        frame = shoot(i, t)
        lo, e_hi, clipped = meter_range(frame, t, cam.full_well_e, mask_for(frame.shape[:2]))
        e_lo = lo if e_lo is None else e_lo
        if clipped == 0.0 or t <= MIN_TIME_S:
            break
        t = max(t / 2.0**METER_STEP_STOPS, MIN_TIME_S)
    times = auto_bracket(e_lo, e_hi, full_well_e=cam.full_well_e, read_noise_e=cam.read_noise_e,
                         target_snr=plan.target_snr, base_time_s=plan.meter_time_s, stop_step=plan.stop_step,
                         max_exposures=plan.max_exposures)
    return times, {"e_lo": e_lo, "e_hi": e_hi, "clipped": clipped}
