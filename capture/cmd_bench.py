"""``brdfrig bench``: time-vs-error benchmark of the BRDF models and solvers (engine: :mod:`fit.bench`).

Lighting: the real lat-long probes of ``--probes`` (default ``../shared/data/probes``
beside the source tree) when at least two are present (fit under the first,
relight under the second), otherwise the simulated bench's procedural room
(``rig.sim_bench``) and its held-out lighting.  The output says which.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

DEFAULT_PROBES = Path(__file__).resolve().parents[2] / "shared" / "data" / "probes"
MAP_ROWS = {"quick": 16, "full": 64}
"""Lat-long rows the maps are box-downsampled to (width = 2 rows): the ground truth's cost is linear in it."""


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "bench",
        help="time-vs-error benchmark of models x solvers x band limits (table, Pareto PNG, headline timings)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--quick", action="store_true", help="small sphere, band limits 1-3, one scene, one run (< 1 min)")
    p.add_argument("--out", type=Path, default=Path("bench-out"), help="directory for bench.png and bench.json (default: %(default)s)")
    p.add_argument("--probes", type=Path, default=DEFAULT_PROBES, help="directory of lat-long .hdr/.exr probes (default: %(default)s)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=run)


def _box_downsample(image, rows: int):
    """Average blocks of a lat-long image down to ``rows x 2 rows`` (rows must divide the height)."""
    import numpy as np

    h, w = image.shape[:2]
    if h % rows or w != 2 * h:
        raise ValueError(f"lat-long map of {w}x{h} cannot be box-downsampled to {2 * rows}x{rows} (need width = 2 height, height divisible by {rows})")
    f = h // rows
    return image.reshape(rows, f, 2 * rows, f, -1).mean(axis=(1, 3))


def _environment(image):
    import numpy as np

    from fit.scene import Environment
    from hdr.envmap import latlong_directions

    dirs, omega = latlong_directions(*image.shape[:2])
    return Environment(dirs.reshape(-1, 3), np.asarray(image, np.float64).reshape(-1, image.shape[2]), omega.ravel())


def _procedural(rows: int):
    """(fit, test) environments from D's simulated bench: its procedural room and its held-out lighting."""
    from rig.sim_bench import SimBench

    sim = SimBench(env_height=rows)
    return sim.environment(0.0), sim.heldout_environment()


def run(args) -> int:
    import numpy as np

    from capture.store import atomic_write_bytes
    from fit.bench import FULL, QUICK, format_solver_comparison, format_table, plot_pareto, rows_to_json, run_benchmark
    from hdr.sphere import sphere_pixels

    config = QUICK if args.quick else FULL
    rows = MAP_ROWS["quick" if args.quick else "full"]
    probes = sorted([*args.probes.glob("*.hdr"), *args.probes.glob("*.exr")]) if args.probes.is_dir() else []
    if len(probes) >= 2:
        from hdr.exr import read_image

        maps = [_box_downsample(np.asarray(read_image(p), np.float64)[..., :3], rows) for p in probes[:2]]
        fit_env, test_env = (_environment(m) for m in maps)
        lighting = f"real probes: fit {probes[0].name}, relight {probes[1].name} ({2 * rows}x{rows})"
    else:
        fit_env, test_env = _procedural(rows)
        lighting = f"procedural maps of rig.sim_bench ({2 * rows}x{rows}; no real probes in {args.probes})"

    def sphere(size: int):
        px = sphere_pixels((size, size), (size / 2, size / 2, size / 2))
        return px.normals, px.weights

    print(f"brdfrig bench ({'quick' if args.quick else 'full'}): lighting = {lighting}", flush=True)
    result = run_benchmark(fit_env, test_env, sphere, config, lighting=lighting, progress=not args.no_progress)

    print()
    print(f"All fits: GGX alpha=0.3 sphere of {config.sphere_size}x{config.sphere_size} px; "
          "relight_err = relative RMS vs the ground truth under the other map; time = median wall clock")
    print(format_table(result.rows))
    print()
    print("Solver comparison (relighting error):")
    print(format_solver_comparison(result.rows))
    print()
    print("Headline timings:")
    targets = {1: 1.0, 12: 5.0} if (result.headline_size, result.headline_lmax) == (512, 8) else {}
    size, l = result.headline_size, result.headline_lmax
    for scenes, seconds in result.headline.items():
        verdict = f"  (target <= {targets[scenes]:g} s: {'met' if seconds <= targets[scenes] else 'NOT met'})" if scenes in targets else ""
        print(f"  {size}x{size} px x 3 channels, full l=p={l}, joint solver, {scenes:>2} scene(s): {seconds:.3f} s{verdict}")

    args.out.mkdir(parents=True, exist_ok=True)
    png = plot_pareto(result, args.out / "bench.png")
    out_json = args.out / "bench.json"
    atomic_write_bytes(out_json, json.dumps(rows_to_json(result), indent=1).encode())
    print(f"\nwrote {png} and {out_json}", file=sys.stdout)
    return 0
