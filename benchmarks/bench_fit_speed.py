"""Speed of :func:`brdfrig.fit.fitter.fit_brdf` on the headline cases of ``brdfrig bench``, stage by stage.

Run ``python -m benchmarks.bench_fit_speed`` (``--runs N``, default 7; ``--quick`` for a 128x128 sphere at
l = p = 4).  The two headline cases (issue 4: a 512x512 three-channel fit of ``full`` at l = p = 8 with
the joint solver, twelve scenes <= 5 s, one scene <= 1 s) are built exactly as :func:`brdfrig.evaluate.bench.run_benchmark`
builds them, with its functions: the GGX sphere :data:`brdfrig.evaluate.bench.TRUTH` rendered by the ground truth at
:data:`brdfrig.evaluate.bench.FULL`'s ``sphere_size`` under the first real probe turned about the vertical axis in
30 degree steps (:func:`brdfrig.fit.rotation.axis_rotation` about +y), resampled onto the headline sphere's pixels
(``brdfrig.evaluate.bench._resample``).  Maps and sphere geometry are loaded as ``brdfrig bench`` loads them
(``brdfrig.cli.bench``, ``brdfrig.hdr.sphere``): imported inside :func:`main` only, this driver is not part of
``fit``'s library import graph.

Printed: per case, the median / min / max wall time of ``fit_brdf`` over the runs (one untimed warm-up
first: numba and cached tables), the median of each stage of ``FitReport.stage_seconds``
(:data:`brdfrig.fit.stream.STAGES`), and a peer measured in the same run: LAPACK's SVD-based least squares
(``numpy.linalg.lstsq``, ``gelsd``; the answer of the joint solver) of the dense, column-equilibrated
design of as many random usable pixels as the fit used (the design assembled by ``brdfrig.fit.system``
outside the timing: the peer's time is the dense solve alone, all channels, one BLAS thread as in
the fit); ``ratio`` = fit median / peer median.  The machine is shared: the load averages before
and after are printed.
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import sys
import time

import numpy as np
from threadpoolctl import threadpool_limits

from brdfrig.evaluate.bench import FULL, QUICK, TRUTH, _resample
from brdfrig.fit.rotation import axis_rotation
from brdfrig.fit.fitter import DEFAULT_MAX_THETA_DEG, fit_brdf
from brdfrig.fit.stream import STAGES
from brdfrig.fit.groundtruth import render_groundtruth
from brdfrig.fit.scene import Environment, Scene
from brdfrig.fit.shproject import project_environment
from brdfrig.fit.system import ModelSpec, design_block

TARGETS_S = {1: 1.0, 12: 5.0}
"""Issue 4's targets (seconds) for the 512x512, l = p = 8 headline, by number of scenes."""


def headline_scenes(fit_env: Environment, sphere, sphere_size: int, headline_size: int, counts=(1, 12)) -> dict[int, list[Scene]]:
    """The headline cases of :func:`brdfrig.evaluate.bench.run_benchmark`: scene count -> scenes.

    ``sphere``: ``size -> (normals, weights)``; the ground truth is rendered at ``sphere_size`` and
    resampled to ``headline_size``, as the benchmark does.
    """
    normals, weights = sphere(sphere_size)
    seen = weights > 0
    normals = normals[seen]
    envs = [fit_env.rotated(axis_rotation("y", 30 * k)) for k in range(max(counts))]
    big_normals, big_weights = sphere(headline_size)
    big = [_resample(render_groundtruth(TRUTH, normals, e), normals, sphere_size, big_normals) for e in envs]
    return {c: [Scene(envs[k], big_normals, big[k], big_weights) for k in range(c)] for c in counts}


def time_fits(scenes: list[Scene], lmax: int, runs: int) -> tuple[list[float], list[dict], dict]:
    """Wall times (s), stage seconds of each run, and the last report, of ``runs`` headline fits."""
    kwargs = dict(model="full", lmax=lmax, pmax=lmax, solver="joint", progress=False, estimate=False)
    fit_brdf(scenes, **kwargs)  # warm-up: numba compilation, cached rotation tables
    times, stages, report = [], [], None
    for _ in range(runs):
        t0 = time.perf_counter()
        report = fit_brdf(scenes, **kwargs).report
        times.append(time.perf_counter() - t0)
        stages.append(report.stage_seconds)
    return times, stages, report


def peer_lstsq_seconds(scenes: list[Scene], lmax: int, rows: int, runs: int, seed: int = 0) -> list[float]:
    """Seconds of ``numpy.linalg.lstsq`` (all channels) on the dense equilibrated design of ``rows`` random usable pixels."""
    rng = np.random.default_rng(seed)
    cos_max = math.cos(math.radians(DEFAULT_MAX_THETA_DEG))
    spec = ModelSpec("full", lmax, lmax)
    usable = [np.flatnonzero((s.weights > 0) & (s.normals[:, 2] >= cos_max)) for s in scenes]
    owner = np.concatenate([np.full(len(u), k) for k, u in enumerate(usable)])
    pick = np.sort(rng.choice(len(owner), min(rows, len(owner)), replace=False))
    offsets = np.concatenate([[0], np.cumsum([len(u) for u in usable])])
    parts_a, parts_b = [], []
    for k, s in enumerate(scenes):
        px = usable[k][pick[owner[pick] == k] - offsets[k]]
        if len(px):
            sw = np.sqrt(s.weights[px])
            parts_a.append(design_block(spec, project_environment(s.env, lmax), s.normals[px]) * sw[:, None, None])
            parts_b.append(s.radiance[px] * sw[:, None])
    a, b = np.concatenate(parts_a), np.concatenate(parts_b)
    channels = [np.ascontiguousarray(a[:, :, c]) for c in range(a.shape[2])]
    channels = [m / np.where(np.linalg.norm(m, axis=0) > 0, np.linalg.norm(m, axis=0), 1.0) for m in channels]
    times = []
    with threadpool_limits(limits=1, user_api="blas"):  # as in fit_brdf: one BLAS thread
        for _ in range(runs):
            t0 = time.perf_counter()
            for c, m in enumerate(channels):
                np.linalg.lstsq(m, b[:, c], rcond=1e-9)
            times.append(time.perf_counter() - t0)
    return times


def format_tables(results: dict[int, dict], size: int, lmax: int) -> str:
    """The timing table and the per-stage table of :func:`run`'s results."""
    head = f"{'scenes':>6} {'runs':>4} {'median_s':>9} {'min_s':>7} {'max_s':>7} {'target_s':>8} {'rows':>7} {'peer_s':>7} {'ratio':>6}"
    lines = [f"fit_brdf(full, l=p={lmax}, joint), {size}x{size} px x 3 channels; peer = numpy.linalg.lstsq (gelsd) "
             "of the same number of dense design rows (solve only)", head, "-" * len(head)]
    for count, r in results.items():
        t = r["times"]
        target = f"{TARGETS_S[count]:.1f}" if (size, lmax) == (512, 8) and count in TARGETS_S else "-"
        peer = statistics.median(r["peer"]) if r["peer"] else math.nan
        lines.append(f"{count:>6} {len(t):>4} {statistics.median(t):>9.3f} {min(t):>7.3f} {max(t):>7.3f} {target:>8} "
                     f"{r['rows']:>7} {peer:>7.3f} {statistics.median(t) / peer:>6.2f}")
    lines += ["", "median seconds per stage (brdfrig.fit.stream.STAGES):"]
    head = f"{'scenes':>6} " + " ".join(f"{s:>15}" for s in STAGES)
    lines += [head, "-" * len(head)]
    for count, r in results.items():
        med = [statistics.median(st.get(s, math.nan) for st in r["stages"]) for s in STAGES]
        lines.append(f"{count:>6} " + " ".join(f"{m:>15.3f}" for m in med))
    return "\n".join(lines)


def run(fit_env: Environment, sphere, *, quick: bool = False, runs: int = 7, peer_runs: int = 3) -> dict[int, dict]:
    """Build the cases and time them; scene count -> {times, stages, rows, peer, report}."""
    config = QUICK if quick else FULL
    size = 128 if quick else config.headline_size
    lmax = 4 if quick else config.headline_lmax
    cases = headline_scenes(fit_env, sphere, config.sphere_size, size)
    out = {}
    for count, scenes in cases.items():
        times, stages, report = time_fits(scenes, lmax, runs)
        rows = report.candidates["full"].system.rows_used
        peer = peer_lstsq_seconds(scenes, lmax, rows, peer_runs) if peer_runs else []
        out[count] = dict(times=times, stages=stages, rows=rows, peer=peer, report=report)
        print(f"  {count} scene(s): median {statistics.median(times):.3f} s", file=sys.stderr, flush=True)
    return out


def _load() -> str:
    """1, 5 and 15 minute load averages (the machine is shared: timings depend on them)."""
    try:
        return " ".join(f"{v:.2f}" for v in os.getloadavg())
    except OSError:
        return "unknown"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--runs", type=int, default=7, help="timed fits per case (default: %(default)s)")
    p.add_argument("--peer-runs", type=int, default=3, help="timed peer solves per case, 0 = none (default: %(default)s)")
    p.add_argument("--quick", action="store_true", help="128x128 sphere at l = p = 4 (a smoke run)")
    args = p.parse_args(argv)
    if args.runs < 1 or args.peer_runs < 0:
        raise SystemExit("--runs must be >= 1 and --peer-runs >= 0")

    from brdfrig.cli.bench import DEFAULT_PROBES, MAP_ROWS, _box_downsample
    from brdfrig.lighting import environment_from_latlong
    from brdfrig.hdr.exr import read_image
    from brdfrig.hdr.sphere import sphere_pixels

    probes = sorted([*DEFAULT_PROBES.glob("*.hdr"), *DEFAULT_PROBES.glob("*.exr")]) if DEFAULT_PROBES.is_dir() else []
    if not probes:
        raise SystemExit(f"no lat-long probe in {DEFAULT_PROBES}")
    rows = MAP_ROWS["quick" if args.quick else "full"]
    fit_env = environment_from_latlong(_box_downsample(np.asarray(read_image(probes[0]), np.float64)[..., :3], rows))

    def sphere(size: int):
        px = sphere_pixels((size, size), (size / 2, size / 2, size / 2))
        return px.normals, px.weights

    print(f"lighting {probes[0].name} ({2 * rows}x{rows}); load average before: {_load()}", flush=True)
    results = run(fit_env, sphere, quick=args.quick, runs=args.runs, peer_runs=args.peer_runs)
    config = QUICK if args.quick else FULL
    print(format_tables(results, 128 if args.quick else config.headline_size, 4 if args.quick else config.headline_lmax))
    print(f"load average after: {_load()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
