"""What one image cannot tell apart: per measured material, a table that reproduces the fit image at least as well
as the true BRDF's own table, and how far the two relight apart.

Per material (96 px sphere, fit under grace, relit under ennis, 128 x 64, noise-free; the measured benchmark's
cached ground truth): the true BRDF projected on the bivariate grid (``project_to_nodes``, ``P cos^2 phi_d +
Q sin^2 phi_d``) and its weighted relative RMS residual on the fit pixels (the limb margin and 2000-pixel subsample
of ``fit_bivariate``); then the smoothest non-negative table of the same grid (the largest ``lam_rel`` of
:data:`LAMBDAS`) whose residual on those pixels is no larger. The data prefer that table to the truth's, so an
estimator that trusts the image cannot tell them apart; its worst-case relighting error over the two is at least
half their distance (``apart``). Prints one row per material, the summary, and writes ``ambiguity.json``::

    python -m benchmarks.bench_ambiguity [--materials rgl/paper_blue,...] [--grid 32,12] [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np

LAMBDAS = (1e-3, 1e-2, 1e-1, 1.0)
"""``lam_rel`` tried, weakest first (the plain fit's own floor is 0.3)."""


def ambiguity(material, grid: tuple[int, int], cache) -> dict:
    """The row of one material (module docstring); ``apart`` None when no table reproduces the image as well."""
    from tqdm import tqdm

    from brdfrig.evaluate.measured import CaseSetup, render_truth
    from brdfrig.fit import bivariate as bv
    from brdfrig.fit.metrics import relative_rms
    from brdfrig.fit.microfacet import _subsample
    from brdfrig.fit.scene import Scene

    nh, nd = grid
    truth = render_truth(material, CaseSetup(relight_probes=("ennis",)), cache)
    s = truth.scenes[0]
    inside = s.normals[:, 2] >= math.cos(math.radians(80.0))
    scenes = [Scene(s.env, s.normals, s.radiance, np.where(inside, s.weights, 0.0))]
    fit_picks, check_picks = _subsample(scenes, bv.DEFAULT_MAX_PIXELS, np.random.default_rng(0))
    quad = {"cone_deg": bv.FIT_CONE_DEG, "subdiv": bv.FIT_SUBDIV}
    qr, yy = bv._stream(scenes, fit_picks, nh, nd, 3, quad, tqdm(disable=True))
    check_rows, check_y = bv._check_system(scenes, check_picks, nh, nd, quad)
    _, problems = bv._problems(qr, yy, check_rows, check_y, nh, nd)

    def residual(x):
        return math.sqrt(sum(ch.residual(xc) for ch, xc in zip(problems, x)) / yy.sum())

    def relit(tables):
        return bv.BivariateBRDF(tables[:, 0], tables[:, 1]).predict(env, truth.normals)

    nodes = np.moveaxis(bv.project_to_nodes(material.load(), nh, nd), 0, 1)  # (C, 2, nh, nd)
    env, reference = truth.relight["ennis"]
    truth_relit = relit(nodes)
    row = {"truth_residual": residual(nodes.reshape(3, -1)), "truth_relit": relative_rms(truth_relit, reference, truth.weights),
           "lam_rel": None, "residual": None, "apart": None}
    for lam in LAMBDAS:
        x = np.maximum(np.stack([ch.constrained(lam, None) for ch in problems]), 0.0)
        if residual(x) <= row["truth_residual"]:
            row.update(lam_rel=lam, residual=residual(x),
                       apart=relative_rms(relit(x.reshape(3, 2, nh, nd)), truth_relit, truth.weights))
    return row


def main(argv: list[str] | None = None) -> int:
    from brdfrig.evaluate.measured import DEFAULT_CACHE_DIR, find_materials, list_materials, make_cache

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--materials", default=None, help="comma-separated names (default: all)")
    parser.add_argument("--grid", default="32,12", help="nh,nd of the tables (default: %(default)s)")
    parser.add_argument("--cache", type=Path, default=DEFAULT_CACHE_DIR, help="ground-truth cache (default: %(default)s)")
    parser.add_argument("--out", type=Path, default=Path("bench-out"), help="where ambiguity.json goes")
    args = parser.parse_args(argv)
    grid = tuple(int(v) for v in args.grid.split(","))
    mats = list_materials() if args.materials is None else find_materials(args.materials.split(","))
    cache, rows = make_cache(args.cache), {}
    print(f"{'material':34s} {'truth: image':>12s} {'relit':>7s} | {'table: lam':>10s} {'image':>7s} {'apart':>7s}")
    for m in mats:
        t0 = time.perf_counter()
        r = rows[m.name] = ambiguity(m, grid, cache)
        tail = "no table reproduces the image as well" if r["apart"] is None else \
            f"{r['lam_rel']:10g} {100 * r['residual']:6.2f}% {100 * r['apart']:6.2f}%"
        print(f"{m.name:34s} {100 * r['truth_residual']:11.2f}% {100 * r['truth_relit']:6.2f}% | {tail}  "
              f"({time.perf_counter() - t0:.0f} s)", flush=True)
    apart = np.array([r["apart"] for r in rows.values() if r["apart"] is not None]) * 100
    if len(apart):
        print(f"apart (relit distance between the truth's table and a table the image prefers), {len(apart)} of {len(rows)}: "
              f"median {np.median(apart):.2f}%, 90th percentile {np.percentile(apart, 90):.2f}%, worst {apart.max():.2f}%")
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "ambiguity.json").write_text(json.dumps({"grid": grid, "materials": rows}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
