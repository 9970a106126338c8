"""Benchmark: the peer a user would pick instead of brdfrig, on measured materials.

Run as ``python -m benchmarks.bench_mitsuba_peer [--materials A B ...] [--size N] [--iterations K] [--spp S] [--loss log|l2]``.

For each measured material (``../shared/data/measured``, loaded with
:func:`brdfrig.fit.measured.load_measured`, tabulated to MERL's grid and rendered by
:func:`brdfrig.fit.groundtruth.render_tabulated`, the ground truth) a sphere of ``size`` px is rendered
under grace and under ennis (128x64, issue 10's standard case).  Mitsuba 3 fits its ``principled``
BSDF to the grace image (:func:`brdfrig.evaluate.mitsuba_peer.fit_principled`) and renders the fit
under ennis (:func:`brdfrig.evaluate.mitsuba_peer.render_principled`).  Printed per material: the
peer's fit seconds, its relighting error (relative RMS over the sphere pixels at least 2 px inside
the limb) and its parameters.  Needs ``brdfrig[bench]``.
"""

from __future__ import annotations

import argparse
import statistics

import numpy as np

from brdfrig.evaluate.mitsuba_peer import fit_principled, render_principled
from brdfrig.evaluate.probes import DEFAULT_PROBE_DIR, probe_environment
from brdfrig.fit.groundtruth import render_tabulated
from brdfrig.fit.measured import load_measured, tabulate
from brdfrig.fit.metrics import relative_rms
from brdfrig.hdr.sphere import sphere_pixels

MEASURED_DIR = DEFAULT_PROBE_DIR.parents[1] / "data" / "measured"
DEFAULT_MATERIALS = ("rgl/acrylic_felt_green", "rgl/paper_blue", "rgl/ilm_l3_37_metallic", "rgl/cc_amber_citrine")


def _image(values: np.ndarray, px, size: int) -> np.ndarray:
    out = np.zeros((size, size, values.shape[1]))
    out[px.rows, px.cols] = values
    return out


def run(material: str, size: int, iterations: int, spp: int, loss: str = "log") -> dict:
    """Fit and relight one material; returns its row of the table."""
    path = MEASURED_DIR / (material + ("" if material.startswith("nielsen/") else "_rgb") + ".h5")
    table = tabulate(load_measured(path))
    fit_env, relight_env = probe_environment("grace", rows=64), probe_environment("ennis", rows=64)
    px = sphere_pixels((size, size), (size / 2, size / 2, size / 2), margin_px=2.0)
    inside = px.weights > 0
    image = _image(render_tabulated(table, px.normals, fit_env), px, size)
    truth = render_tabulated(table, px.normals[inside], relight_env)
    params, seconds = fit_principled(image, fit_env.latlong.image, spp=spp, iterations=iterations, seed=0, loss=loss)
    relit = render_principled(params, relight_env.latlong.image, size, spp=1024)[px.rows[inside], px.cols[inside]]
    err = relative_rms(relit, truth)
    return {"material": material, "seconds": seconds, "relight_error": err, "params": params}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--materials", nargs="+", default=list(DEFAULT_MATERIALS))
    parser.add_argument("--size", type=int, default=96)
    parser.add_argument("--iterations", type=int, default=120)
    parser.add_argument("--spp", type=int, default=16)
    parser.add_argument("--loss", choices=("log", "l2"), default="log")
    args = parser.parse_args(argv)
    rows = []
    for material in args.materials:
        row = run(material, args.size, args.iterations, args.spp, args.loss)
        rows.append(row)
        p = row["params"]
        print(f"{material:32s} {row['seconds']:7.1f} s  relight {row['relight_error']:7.2%}  "
              f"base {np.round(p['base_color'], 3).tolist()} rough {p['roughness']:.3f} metal {p['metallic']:.3f} "
              f"spec {p['specular']:.3f} sheen {p['sheen']:.3f} coat {p['clearcoat']:.3f}", flush=True)
    errs = [r["relight_error"] for r in rows]
    print(f"median relight error {statistics.median(errs):.2%}, worst {max(errs):.2%}, "
          f"median fit time {statistics.median(r['seconds'] for r in rows):.1f} s "
          f"({args.size} px, {args.iterations} iterations x {args.spp} spp, {args.loss} loss)")


if __name__ == "__main__":
    main()
