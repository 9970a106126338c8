"""Benchmark: ``auto`` exposure plan vs a fixed 9-stop bracket (``python -m benchmarks.bench_plan``).

On the simulated bench (``brdfrig.sim.bench``, photographed by ``brdfrig.sim.camera``
with the sensor of ``config/sim-bench.toml``), two scenes of interest:

* low contrast: the matte sample sphere under the room light (metering mask = its disc);
* high contrast: the chrome probe, which reflects the sun and the windows (mask = its disc).

For each, the ``auto`` plan (metering shots, then :func:`brdfrig.session.plan.auto_bracket`)
and a fixed bracket of 9 exposures one stop apart centred on the metering time
are shot, merged exactly as the pipeline does (:func:`brdfrig.session.pipeline.merge_files`)
and compared with the simulator's true radiance over the disc: relative RMS
error, median absolute relative error, and the fraction of pixels with no
usable exposure.  Medians over ``--repeats`` noise draws.  Metering frames are
counted in the auto plan's shots.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

__all__ = ["main", "compare_plans"]


def _disc(shape, circle) -> np.ndarray:
    yy, xx = np.mgrid[0 : shape[0], 0 : shape[1]]
    cx, cy, r = circle
    return (xx + 0.5 - cx) ** 2 + (yy + 0.5 - cy) ** 2 <= (0.97 * r) ** 2


def compare_plans(scale: float = 0.5, repeats: int = 3, seed: int = 0) -> list[dict]:
    """Shoot, merge and score both plans on both scenes; one dict per (scene, plan) with medians over repeats."""
    from brdfrig.cli.demo import DEMO_CONFIG
    from brdfrig.session.config import load_session_config
    from brdfrig.session.pipeline import merge_files
    from brdfrig.session.plan import meter_bracket
    from brdfrig.hdr.raw import read_frame
    from brdfrig.sim.bench import SimBench
    from brdfrig.sim.camera import SimulatedCamera

    config = load_session_config(DEMO_CONFIG)
    cam_cfg, plan = config.rig.camera, config.plan
    bench = SimBench(carries="rig", scale=scale, env_height=32, probe_env_height=128)
    truth = bench.radiance(0.0).astype(np.float64)
    scenes = {
        "low contrast (matte sphere)": _disc(bench.frame_shape, bench.sample_circles["matte"]),
        "high contrast (chrome probe)": _disc(bench.frame_shape, bench.probe_circle),
    }
    fixed = tuple(plan.meter_time_s * 2.0**k for k in range(-4, 5))
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-plan-") as tmp:
        for scene, mask in scenes.items():
            stats: dict[str, list] = {"auto": [], "fixed 9-stop": []}
            for rep in range(repeats):
                camera = SimulatedCamera(bench, None, full_well_e=cam_cfg.full_well_e,
                                         read_noise_e=cam_cfg.read_noise_e, seed=seed + rep)
                shots: list[Path] = []

                def shoot(t: float) -> Path:
                    camera.set_exposure(t, cam_cfg.iso, cam_cfg.f_number)
                    path = camera.capture(tmp)
                    shots.append(path)
                    return path

                n0 = len(shots)
                times, _ = meter_bracket(lambda i, t: read_frame(shoot(t))[0], config, lambda shape: mask)
                n_meter = len(shots) - n0
                for name, bracket, extra in (("auto", times, n_meter), ("fixed 9-stop", fixed, 0)):
                    paths = [shoot(t) for t in bracket]
                    merged = merge_files(paths, cam_cfg.full_well_e, cam_cfg.read_noise_e)
                    m, t = merged.radiance[mask].astype(np.float64), truth[mask]
                    rel = np.abs(m - t) / np.maximum(t, 1e-12)
                    stats[name].append((
                        len(bracket) + extra,
                        float(np.sqrt(np.sum((m - t) ** 2) / np.sum(t**2))),
                        float(np.median(rel)),
                        float(np.mean(~merged.usable[mask].all(axis=-1))),
                        float(truth[mask].max() / np.percentile(truth[mask], 0.5)),
                    ))
                for p in shots:
                    p.unlink()
            for name, values in stats.items():
                v = np.median(np.array(values), axis=0)
                rows.append({"scene": scene, "plan": name, "shots": int(v[0]), "rms": v[1], "median": v[2],
                             "unusable": v[3], "range": v[4]})
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_plan", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=3, help="noise draws per case (medians reported)")
    parser.add_argument("--scale", type=float, default=0.5, help="simulated frame scale (1 = 640 x 240)")
    args = parser.parse_args(argv)
    rows = compare_plans(args.scale, args.repeats)
    print(f"auto exposure plan vs fixed 9-stop bracket (medians of {args.repeats} noise draws; "
          "auto counts its metering shots)")
    print(f"{'scene':<30} {'range':>9} {'plan':<13} {'shots':>5} {'rel RMS':>9} {'median':>9} {'unusable':>9}")
    for r in rows:
        print(f"{r['scene']:<30} {r['range']:>8.0f}x {r['plan']:<13} {r['shots']:>5d} {100 * r['rms']:>8.2f}% "
              f"{100 * r['median']:>8.2f}% {100 * r['unusable']:>8.2f}%")
    by = {(r["scene"], r["plan"]): r for r in rows}
    low, high = "low contrast (matte sphere)", "high contrast (chrome probe)"
    print(f"\nlow contrast: auto {by[low, 'auto']['shots']} shots vs fixed {by[low, 'fixed 9-stop']['shots']} "
          f"(ratio {by[low, 'auto']['shots'] / by[low, 'fixed 9-stop']['shots']:.2f}); "
          f"high contrast: auto/fixed rel RMS ratio "
          f"{by[high, 'auto']['rms'] / by[high, 'fixed 9-stop']['rms']:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
