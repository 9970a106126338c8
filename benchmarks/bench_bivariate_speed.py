"""Speed of a one-scene ``bivariate`` fit of a 256 px sphere of a measured material (issue 10: <= 2 s).

Run ``python -m benchmarks.bench_bivariate_speed`` (``--runs N``, default 7; ``--material``, default
``rgl/paper_blue``; ``--size``, default 256).  The sphere is the measured benchmark's case
(:func:`brdfrig.evaluate.measured.render_truth`: the material's ground truth under the grace probe at 128 x 64,
cached in ``--cache``; the first run of a material renders it, about two minutes at 256 px).  Needs
``../shared/data``.

Printed: the median / min / max wall time of ``fit_brdf(model="bivariate")`` over the runs (one untimed
warm-up first: numba kernels load), the fit's pixel count, and a peer measured in the same run: the same
table fitted by hand, the dense weighted design of as many pixels as the fit used (the fit's own quadrature,
:func:`brdfrig.fit.bivariate._design`; ``design_s``) then SciPy's ``nnls`` once per channel (``solve_s``): the
non-negative least squares a user would write, without smoothness, lambda choice or the monotone variant;
``ratio`` = fit median / peer median (design + solve).  The machine is shared: the load averages before and after are printed.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from scipy.optimize import nnls

from benchmarks.bench_fit_speed import _load
from brdfrig.evaluate.measured import DEFAULT_CACHE_DIR, CaseSetup, find_materials, make_cache, render_truth
from brdfrig.fit import bivariate
from brdfrig.fit.fitter import fit_brdf
from brdfrig.fit.quadrature import lobe_quadrature

TARGET_S = 2.0
"""Issue 10's target for a one-scene bivariate fit of a 256 px sphere."""


def time_fits(scenes, runs: int) -> tuple[list[float], dict]:
    """Wall times (s) of ``runs`` bivariate fits after one warm-up, and the last fit's report."""
    fit_brdf(scenes, model="bivariate", progress=False)
    times, report = [], None
    for _ in range(runs):
        t0 = time.perf_counter()
        report = fit_brdf(scenes, model="bivariate", progress=False).report
        times.append(time.perf_counter() - t0)
    return times, report


def peer_seconds(scene, rows: int, runs: int, seed: int = 0) -> tuple[list[float], list[float]]:
    """Seconds of the dense weighted design of ``rows`` random usable pixels, and of ``scipy.optimize.nnls`` on it (every channel)."""
    usable = np.flatnonzero(scene.weights > 0)
    pick = np.sort(np.random.default_rng(seed).choice(usable, min(rows, len(usable)), replace=False))
    sw = np.sqrt(scene.weights[pick])
    design_s, solve_s = [], []
    for _ in range(runs):
        t0 = time.perf_counter()
        quad = lobe_quadrature(scene.env, cone_deg=bivariate.FIT_CONE_DEG, subdiv=bivariate.FIT_SUBDIV)
        design = bivariate._design(quad, scene.normals[pick], bivariate.DEFAULT_NH, bivariate.DEFAULT_ND) * sw[:, None, None]
        target = scene.radiance[pick] * sw[:, None]
        t1 = time.perf_counter()
        for c in range(design.shape[2]):
            a = np.ascontiguousarray(design[:, :, c])
            nnls(a, target[:, c], maxiter=50 * a.shape[1])
        design_s.append(t1 - t0)
        solve_s.append(time.perf_counter() - t1)
    return design_s, solve_s


def format_table(name: str, size: int, times: list[float], rows: int, design_s: list[float], solve_s: list[float]) -> str:
    head = (f"{'material':>16} {'size':>5} {'runs':>4} {'median_s':>9} {'min_s':>7} {'max_s':>7} {'target_s':>8} {'rows':>6} "
            f"{'design_s':>8} {'solve_s':>7} {'ratio':>6}")
    med, d, s = statistics.median(times), statistics.median(design_s), statistics.median(solve_s)
    return "\n".join([
        "fit_brdf(model='bivariate'), one scene, 3 channels; peer = the dense design of as many pixels + scipy.optimize.nnls "
        "(medians; ratio = fit / (design + solve))",
        head, "-" * len(head),
        f"{name:>16} {size:>5} {len(times):>4} {med:>9.3f} {min(times):>7.3f} {max(times):>7.3f} {TARGET_S:>8.1f} {rows:>6} "
        f"{d:>8.3f} {s:>7.3f} {med / (d + s):>6.2f}",
    ])


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--runs", type=int, default=7, help="timed fits (default: %(default)s)")
    p.add_argument("--peer-runs", type=int, default=3, help="timed peer solves (default: %(default)s)")
    p.add_argument("--material", default="rgl/paper_blue", help="measured material (default: %(default)s)")
    p.add_argument("--size", type=int, default=256, help="sphere image size in pixels (default: %(default)s)")
    p.add_argument("--cache", type=Path, default=DEFAULT_CACHE_DIR, help="ground-truth cache (default: %(default)s)")
    args = p.parse_args(argv)
    if args.runs < 1 or args.peer_runs < 1 or args.size < 8:
        raise SystemExit("--runs and --peer-runs must be >= 1, --size >= 8")
    material = find_materials([args.material])[0]
    print(f"{material.name}, {args.size} px; load average before: {_load()}", flush=True)
    truth = render_truth(material, CaseSetup(size=args.size, relight_probes=("ennis",), scenes=1), make_cache(args.cache))
    times, report = time_fits(truth.scenes, args.runs)
    rows = int(report.candidates["bivariate"].fit_report["pixels_used"])
    design_s, solve_s = peer_seconds(truth.scenes[0], rows, args.peer_runs)
    print(format_table(material.name.split("/")[-1], args.size, times, rows, design_s, solve_s))
    print(f"load average after: {_load()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
