"""Benchmark of the SH core against peer libraries doing the same work in the same run.

Run ``python -m benchmarks.bench_sh`` (``--quick`` for a smaller, faster run).  Prints one
row per (task, implementation): median wall time over repeats after one warm-up
call (numba compilation and cached tables excluded for everyone), and the ratio
of brdfrig's time to that peer's.  Peers that only work one item per call are
timed on a subset and scaled linearly to the full task; the table says so.

Tasks (issue 2):

1. real SH up to l = 20 at 1e6 directions (float64);
2. rotation of one l <= 10 coefficient vector by 1e5 rotations;
3. ``local_lighting`` as the fitter calls it (l <= 12, 3 channels, 1e5 normals);
4. projection of a 1024x512 lat-long map (3 channels) to l = 30.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

#: brdfrig should be no slower than this factor times the fastest peer on each task.
TARGET_RATIO = 1.5


@dataclass
class Timing:
    task: str
    name: str
    seconds: float
    note: str = ""
    ours: bool = False


def median_time(fn: Callable[[], object], repeats: int, scale: float = 1.0) -> float:
    """Median wall time of ``fn()`` over ``repeats`` calls after one warm-up call, times ``scale``."""
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times) * scale


def _random_dirs(n: int, rng: np.random.Generator) -> np.ndarray:
    d = rng.normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def bench_eval(n: int, lmax: int, repeats: int, rng) -> list[Timing]:
    import pyshtools
    import sphericart
    from scipy.special import sph_harm_y_all

    from brdfrig.fit.sh import sh_eval

    task = f"SH eval l<={lmax}, {n:.0e} dirs"
    dirs = _random_dirs(n, rng)
    calc = sphericart.SphericalHarmonics(lmax)
    sub = dirs[: max(1, n // 10)]
    tiny = dirs[:300]

    def scipy_all():
        theta = np.arccos(np.clip(sub[:, 2], -1, 1))
        return sph_harm_y_all(lmax, lmax, theta, np.arctan2(sub[:, 1], sub[:, 0]))

    def pysh_loop():
        theta = np.arccos(np.clip(tiny[:, 2], -1, 1))
        phi = np.arctan2(tiny[:, 1], tiny[:, 0])
        for t, p in zip(theta, phi):
            pyshtools.expand.spharm(lmax, t, p, kind="real", degrees=False, normalization="ortho", csphase=1)

    return [
        Timing(task, "brdfrig.fit.sh.sh_eval", median_time(lambda: sh_eval(dirs, lmax), repeats), ours=True),
        Timing(task, "sphericart (direct)", median_time(lambda: calc.compute(dirs), repeats)),
        Timing(task, "scipy sph_harm_y_all", median_time(scipy_all, max(1, repeats // 2), n / sub.shape[0]),
               f"complex; timed on {sub.shape[0]:.0e} dirs, scaled"),
        Timing(task, "pyshtools spharm", median_time(pysh_loop, 1, n / tiny.shape[0]),
               f"one dir per call; timed on {tiny.shape[0]}, scaled"),
    ]


def _pysh_rotation_peer(task: str, lmax: int, channels: int, k: int, rng) -> Timing:
    """pyshtools: one ``SHRotateRealCoef`` call per rotation and channel."""
    import pyshtools

    dj = pyshtools.rotate.djpi2(lmax)
    cilm = rng.normal(size=(2, lmax + 1, lmax + 1))
    angles = rng.uniform(0, np.pi, size=(2000, 3))

    def run():
        for x in angles:
            for _ in range(channels):
                pyshtools.rotate.SHRotateRealCoef(cilm, x, dj)

    return Timing(task, "pyshtools SHRotateRealCoef", median_time(run, 1, k / angles.shape[0]),
                  f"one rotation x channel per call; timed on {angles.shape[0]}, scaled")


def _spherical_rotation_peer(task: str, lmax: int, channels: int, k: int, rng) -> Timing:
    """spherical: batched complex Wigner D, then a per-band complex product with the coefficients."""
    import quaternionic
    import spherical

    wigner = spherical.Wigner(lmax)
    sub = min(k, 10000)
    quats = quaternionic.array(rng.normal(size=(sub, 4))).normalized
    coeffs = rng.normal(size=((lmax + 1) ** 2, channels)) + 0j

    def run():
        d = wigner.D(quats)
        for l in range(lmax + 1):
            n = 2 * l + 1
            i0 = wigner.Dindex(l, -l, -l)
            np.einsum("kij,jc->kic", d[:, i0 : i0 + n * n].reshape(sub, n, n), coeffs[l * l : (l + 1) ** 2])

    return Timing(task, "spherical Wigner.D (batched)", median_time(run, 1, k / sub),
                  f"complex basis; timed on {sub:.0e}, scaled")


def bench_rotation(k: int, lmax: int, repeats: int, rng) -> list[Timing]:
    from scipy.spatial.transform import Rotation

    from brdfrig.fit.rotation import rotate_coeffs

    task = f"rotate l<={lmax} coeffs, {k:.0e} rotations"
    rotations = Rotation.random(k, random_state=1).as_matrix()
    coeffs = rng.normal(size=((lmax + 1) ** 2, 1))
    return [
        Timing(task, "brdfrig.fit.rotation.rotate_coeffs", median_time(lambda: rotate_coeffs(coeffs, rotations), repeats),
               "1 channel", ours=True),
        _pysh_rotation_peer(task, lmax, 1, k, rng),
        _spherical_rotation_peer(task, lmax, 1, k, rng),
    ]


def bench_local(k: int, lmax: int, channels: int, repeats: int, rng) -> list[Timing]:
    from brdfrig.fit.rotation import local_lighting

    task = f"local_lighting l<={lmax}, {channels} ch, {k:.0e} normals"
    normals = _random_dirs(k, rng)
    coeffs = rng.normal(size=((lmax + 1) ** 2, channels))
    return [
        Timing(task, "brdfrig.fit.rotation.local_lighting", median_time(lambda: local_lighting(coeffs, normals), repeats),
               ours=True),
        _pysh_rotation_peer(task, lmax, channels, k, rng),
        _spherical_rotation_peer(task, lmax, channels, k, rng),
    ]


def bench_projection(height: int, lmax: int, repeats: int, rng) -> list[Timing]:
    import pyshtools

    from brdfrig.fit.sh import sh_eval
    from brdfrig.fit.shproject import project_latlong

    width = 2 * height
    task = f"project {width}x{height} map (3 ch) to l<={lmax}"
    image = rng.uniform(size=(height, width, 3))
    grid = np.ascontiguousarray(image.transpose(2, 0, 1))

    # the same samples through the dense general path: SH matrix of every pixel times the weighted radiance
    lam = -2 * np.pi * ((np.arange(width) + 0.5) / width - 0.5)
    phi = -np.pi * ((np.arange(height) + 0.5) / height - 0.5)
    cp = np.cos(phi)[:, None]
    dirs = np.stack(np.broadcast_arrays(np.sin(lam) * cp, np.sin(phi)[:, None], np.cos(lam) * cp), -1).reshape(-1, 3)
    weighted = image.reshape(-1, 3) * (cp * (2 * np.pi / width) * (np.pi / height)).repeat(width, 1).reshape(-1, 1)

    def dense():
        out = np.zeros(((lmax + 1) ** 2, 3))
        for s in range(0, dirs.shape[0], 65536):
            out += sh_eval(dirs[s : s + 65536], lmax).T @ weighted[s : s + 65536]
        return out

    def dh():
        return [pyshtools.expand.SHExpandDH(g, norm=4, sampling=2, lmax_calc=lmax) for g in grid]

    return [
        Timing(task, "brdfrig.fit.shproject.project_latlong", median_time(lambda: project_latlong(image, lmax), repeats),
               "separable: FFT + Fejer rule", ours=True),
        Timing(task, "pyshtools SHExpandDH", median_time(dh, repeats), "3 calls; Driscoll-Healy grid of the same size"),
        Timing(task, "sphericart dense quadrature", median_time(dense, max(1, repeats // 2)),
               "Y of every pixel @ weighted radiance"),
    ]


def format_table(rows: list[Timing]) -> str:
    """Table of timings with ratios ours/peer and a verdict per task against ``TARGET_RATIO``."""
    lines = [f"{'task':44s} {'implementation':38s} {'median s':>9s} {'ours/peer':>9s}  note", "-" * 130]
    tasks = list(dict.fromkeys(r.task for r in rows))
    verdicts = []
    for task in tasks:
        group = [r for r in rows if r.task == task]
        ours = next(r for r in group if r.ours)
        for r in group:
            ratio = "" if r.ours else f"{ours.seconds / r.seconds:9.2f}"
            lines.append(f"{task:44s} {r.name:38s} {r.seconds:9.4f} {ratio:>9s}  {r.note}")
        fastest = min((r for r in group if not r.ours), key=lambda r: r.seconds)
        ratio = ours.seconds / fastest.seconds
        verdicts.append(
            f"{task}: brdfrig / fastest peer ({fastest.name}) = {ratio:.2f} "
            f"-> {'OK' if ratio <= TARGET_RATIO else 'SLOWER than target'} (target <= {TARGET_RATIO})"
        )
    return "\n".join(lines + ["-" * 130] + verdicts)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_sh", description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="10x fewer directions and rotations (smoke run)")
    parser.add_argument("--repeats", type=int, default=5, help="timed calls per measurement (median)")
    args = parser.parse_args(argv)
    if args.repeats < 1:
        raise SystemExit("--repeats must be >= 1")
    from tqdm import tqdm

    scale = 10 if args.quick else 1
    rng = np.random.default_rng(0)
    jobs = [
        lambda: bench_eval(1_000_000 // scale, 20, args.repeats, rng),
        lambda: bench_rotation(100_000 // scale, 10, args.repeats, rng),
        lambda: bench_local(100_000 // scale, 12, 3, args.repeats, rng),
        lambda: bench_projection(512, 30, args.repeats, rng),
    ]
    rows: list[Timing] = []
    for job in tqdm(jobs, desc="bench_sh", file=sys.stderr):
        rows += job()
    print(format_table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
