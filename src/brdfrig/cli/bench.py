"""brdfrig bench: time against error for the BRDF models and solvers, on analytic or measured materials.

Without --measured: every model, solver and band limit on analytic BRDFs, fitted
under one lighting and relit under another: the real lat-long probes of --probes
(default ../shared/data/probes beside the source tree) when at least two are
present, otherwise the simulated bench's procedural room and its held-out
lighting (the output says which). Fast cases report medians of 3 runs; slow ones
repeat only within the time budget (the n column). A Pareto PNG, JSON of every
number and report.html (the PNG and the tables) go into --out.

With --measured: every material of ../shared/data/measured rendered by brute-force
quadrature under one real probe, fitted by every model and auto, relit under two
others; one and twelve turned scenes, noise-free and 1% noise (choose with
--scenes and --noise); per-material table, summary (median, 90th percentile,
worst), fit times, PNGs of the errors and of the worst five, JSON, report.html.
Every fit is kept as a BRDF file with its report (brdfrig render takes it), in
OUT/fits/GROUP/NAME/MODEL-<k>scene|turns|tilts-noise<sigma>.brdf.json; the JSON
names each case's file. After each material the cases so far go to
OUT/measured.partial.json; --resume continues an interrupted run from it (the
same options).

Ground-truth renders are cached in OUT/gt-cache, keyed by every input and the
renderer's source, so a second run skips them and a changed input or renderer
never reuses a stale one. Map resolution: 128 x 64 for the full run.
"""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path

from brdfrig.cli._command import add_command, add_progress_argument
from brdfrig.errors import InputError
from brdfrig.ranges import Range
from brdfrig.evaluate.cache import CachedGroundTruth
from brdfrig.evaluate.probes import box_downsample as _box_downsample
from brdfrig.evaluate.measured import add_arguments as add_measured_arguments

DEFAULT_PROBES = Path(__file__).resolve().parents[4] / "shared" / "data" / "probes"
MAP_ROWS = {"quick": 16, "full": 64}
"""Lat-long rows the maps are box-downsampled to (width = 2 rows): the ground truth's cost is linear in it."""


def register(subparsers) -> None:
    p = add_command(subparsers, "bench",
                    "time-vs-error benchmark of models x solvers x band limits (table, Pareto PNG, headline timings)",
                    __doc__)
    p.add_argument("--quick", action="store_true", help="small sphere, band limits 1-3, one scene (< 30 s)")
    p.add_argument("--out", type=Path, default=Path("bench-out"),
                   help="directory for bench.png, bench.json, report.html and the ground-truth cache gt-cache/ "
                        "(default: %(default)s)")
    p.add_argument("--budget", type=Range(0, 86400, open_lo=True).arg(), default=None, metavar="SECONDS",
                   help="soft time budget of the table's fits: slow cases (>= 1 s) are repeated only while it "
                        "allows; every case runs at least once, faster ones 3 times (default: 210 full, 20 quick)")
    p.add_argument("--probes", type=Path, default=DEFAULT_PROBES, help="directory of lat-long .hdr/.exr probes (default: %(default)s)")
    add_progress_argument(p)
    p.add_argument("--measured", action="store_true",
                   help="the measured-materials benchmark instead (fit under one probe, "
                        "relight under others, every model; table, summary, errors.png, worst.png, estimates.png, "
                        "report.html, measured.json)")
    add_measured_arguments(p)
    p.set_defaults(func=run)


def _procedural(rows: int):
    """(fit, test) environments from D's simulated bench: its procedural room and its held-out lighting."""
    from brdfrig.sim.bench import SimBench

    sim = SimBench(env_height=rows)
    return sim.environment(0.0), sim.heldout_environment()


def run(args) -> int:
    if args.measured:
        from brdfrig.evaluate.measured_run import run_from_args

        return run_from_args(args)
    import numpy as np

    from brdfrig._atomic import write_bytes as atomic_write_bytes
    from brdfrig.evaluate.bench import (FAST_S, FULL, QUICK, format_phases, format_solver_comparison, format_table, plot_pareto,
                           rows_to_json, run_benchmark)
    from brdfrig.hdr.sphere import sphere_pixels
    from brdfrig.lighting import environment_from_latlong
    from brdfrig.report.html import write_page

    config = QUICK if args.quick else FULL
    if args.budget is not None:
        if not args.budget > 0:
            raise InputError(f"--budget must be a positive number of seconds, got {args.budget}")
        config = dataclasses.replace(config, budget_s=args.budget)
    rows = MAP_ROWS["quick" if args.quick else "full"]
    probes = sorted([*args.probes.glob("*.hdr"), *args.probes.glob("*.exr")]) if args.probes.is_dir() else []
    if len(probes) >= 2:
        from brdfrig.hdr.exr import read_image

        maps = [_box_downsample(np.asarray(read_image(p), np.float64)[..., :3], rows) for p in probes[:2]]
        fit_env, test_env = (environment_from_latlong(m) for m in maps)
        lighting = f"real probes: fit {probes[0].name}, relight {probes[1].name} ({2 * rows}x{rows})"
    else:
        fit_env, test_env = _procedural(rows)
        lighting = f"procedural maps of brdfrig.sim.bench ({2 * rows}x{rows}; no real probes in {args.probes})"

    def sphere(size: int):
        px = sphere_pixels((size, size), (size / 2, size / 2, size / 2))
        return px.normals, px.weights

    args.out.mkdir(parents=True, exist_ok=True)
    cache = CachedGroundTruth(args.out / "gt-cache")
    print(f"brdfrig bench ({'quick' if args.quick else 'full'}): lighting = {lighting}", flush=True)
    result = run_benchmark(fit_env, test_env, sphere, config, lighting=lighting, progress=not args.no_progress,
                           groundtruth=cache)

    tables = (f"All fits: GGX alpha=0.3 sphere of {config.sphere_size}x{config.sphere_size} px; "
              "relight_err = relative RMS vs the ground truth under the other map; "
              f"time_s = median wall clock of n fits (n = {config.runs} below {FAST_S:g} s; slower cases as the budget allows)\n"
              + format_table(result.rows))
    solvers = "Solver comparison (relighting error):\n" + format_solver_comparison(result.rows)
    targets = {1: 1.0, 12: 5.0} if (result.headline_size, result.headline_lmax) == (512, 8) else {}
    size, l = result.headline_size, result.headline_lmax
    headline = ["Headline timings:"]
    for scenes, seconds in result.headline.items():
        verdict = f"  (target <= {targets[scenes]:g} s: {'met' if seconds <= targets[scenes] else 'NOT met'})" if scenes in targets else ""
        runs = " ".join(f"{t:.2f}" for t in result.headline_times[scenes])
        headline.append(f"  {size}x{size} px x 3 channels, full l=p={l}, joint solver, {scenes:>2} scene(s): {seconds:.3f} s "
                        f"(median of {runs}){verdict}")
    phases = (f"Where the time went (ground truth: {cache.misses} rendered, {cache.hits} from {cache.directory}):\n"
              + format_phases(result))
    sections = [("Time against error", tables), ("Solvers", solvers), ("Headline timings", "\n".join(headline)),
                ("Where the time went", phases)]
    print("\n" + "\n\n".join(text for _, text in sections))

    png = plot_pareto(result, args.out / "bench.png")
    out_json = args.out / "bench.json"
    atomic_write_bytes(out_json, json.dumps(rows_to_json(result), indent=1).encode())
    page = write_page(args.out / "report.html", f"brdfrig bench ({'quick' if args.quick else 'full'}): {lighting}",
                      [("Relighting error against fit time (Pareto front)", png)] + sections)
    print(f"\nwrote {png.resolve()}, {out_json.resolve()} and {page.resolve()}", file=sys.stdout)
    return 0
