"""Benchmark: the simulated bench's node-grid sample rendering against per-pixel quadrature.

Run as ``python -m benchmarks.bench_render [--scale S] [--env-height H] [--repeats N]``.

Both render the same sample spheres under the same lat-long environment with
:func:`brdfrig.fit.groundtruth.render_groundtruth`; the peer evaluates it at every
pixel of the sphere, :meth:`brdfrig.sim.bench.SimBench.render_sample` at a
``render_nodes`` x ``render_nodes`` grid and interpolates (cubic).  Printed:
median wall time of ``repeats`` runs after a warm-up, the ratio, and the
relative RMS difference of the two images (pixels within 5% of the radius
from the limb excluded, which the fitter weights out anyway).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

import numpy as np

from brdfrig.fit.groundtruth import render_groundtruth
from brdfrig.sim.bench import SimBench


def _median_time(fn, repeats: int) -> float:
    fn()  # warm-up (numba compilation, caches)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_render", description=__doc__.split("\n\n")[0])
    parser.add_argument("--scale", type=float, default=1.0, help="bench frame scale (1 = 640 x 240, radius 90)")
    parser.add_argument("--env-height", type=int, default=64, help="environment rows (columns = 2x)")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    bench = SimBench(scale=args.scale, env_height=args.env_height)
    env = bench.environment(0.0)
    print(f"frame {bench.frame_shape[1]} x {bench.frame_shape[0]}, env {2 * args.env_height} x {args.env_height}, "
          f"nodes {bench.render_nodes}^2, median of {args.repeats}", file=sys.stderr)
    print(f"{'sample':<8} {'pixels':>7} {'per-pixel s':>12} {'node grid s':>12} {'speed-up':>9} {'rel rms':>9}")
    for name in bench.sample_circles:
        px = bench._sample_pixels[name]
        normals = np.asarray(px.normals)
        brdf = bench.true_brdf(name)
        t_peer = _median_time(lambda: render_groundtruth(brdf, normals, env), args.repeats)
        t_ours = _median_time(lambda: bench.render_sample(name, env), args.repeats)
        exact = render_groundtruth(brdf, normals, env)
        ours = bench.render_sample(name, env)[2]
        keep = np.hypot(normals[:, 0], normals[:, 1]) < 0.95
        rel = np.sqrt(np.mean((ours[keep] - exact[keep]) ** 2) / np.mean(exact[keep] ** 2))
        print(f"{name:<8} {len(normals):>7} {t_peer:>12.3f} {t_ours:>12.3f} {t_peer / t_ours:>8.1f}x {rel:>9.5f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
