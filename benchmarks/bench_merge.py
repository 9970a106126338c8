"""Benchmark of :func:`brdfrig.hdr.merge.merge_bracket` against OpenCV's ``MergeDebevec`` on the same synthetic data.

Run as ``python -m benchmarks.bench_merge [--quick] [--out DIR]``.

1. Accuracy: a radiance image over 1e5:1 (log-uniform), shot by a simulated
   sensor (Poisson shot noise, Gaussian read noise, clipping, 16-bit
   quantisation) at 7 exposures 1 stop apart; relative error of each merge
   against the known radiance, overall and per decade, printed as a table
   and plotted to ``DIR/bench_merge.png``.
2. Throughput: a 12-megapixel (4000 x 3000) RGB 7-exposure uint16 bracket
   merged by both in the same run; medians of ``repeats`` timed runs after
   one warm-up, and the ratio; brdfrig also with ``clip_radius=1`` (the
   default, for demosaiced frames), to show the cost of weighting out the
   neighbourhoods of clipped pixels.

3. Memory (``--memory``): a 7 x 24 MP (6000 x 4000) 16-bit TIFF bracket
   (``--format dng``: uncompressed RGGB DNGs of the same frames) written to a
   temporary directory (deleted afterwards), merged by ``brdfrig merge`` with
   its defaults (``--align``: and alignment) in a child process; peak resident
   set size (``getrusage`` of the child) and wall time of ``repeats`` runs.

The synthetic frames are not demosaiced (every pixel is measured
independently), so brdfrig merges them with ``clip_radius=0``.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

FULL_WELL, READ_NOISE = 20000.0, 5.0
TIMES = 2.0 ** np.arange(-6, 1)  # 7 exposures, 1 stop apart


def synthetic_bracket(h: int, w: int, seed: int = 0) -> tuple[np.ndarray, list[np.ndarray]]:
    """Known radiance (log-uniform 6e-4 .. 60 full scale per second, 1e5:1) and its 7 uint16 frames."""
    rng = np.random.default_rng(seed)
    radiance = np.exp(rng.uniform(np.log(6e-4), np.log(60.0), (h, w, 3)))
    frames = []
    for t in TIMES:
        electrons = rng.poisson(np.minimum(radiance * t, 4.0) * FULL_WELL) + rng.normal(0, READ_NOISE, radiance.shape)
        frames.append(np.round(np.clip(electrons / FULL_WELL, 0, 1) * 65535).astype(np.uint16))
    return radiance, frames


def _methods():
    import cv2

    from brdfrig.hdr.merge import merge_bracket

    def ours(frames, weighting, clip_radius=0):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return merge_bracket(frames, TIMES, weighting=weighting, clip_radius=clip_radius, full_well=FULL_WELL,
                                 read_noise=READ_NOISE).radiance

    merge_cv = cv2.createMergeDebevec()
    return {
        "brdfrig optimal": lambda f: ours(f, "optimal"),
        "brdfrig Debevec hat": lambda f: ours(f, "debevec"),
        "OpenCV MergeDebevec": lambda f: merge_cv.process(f, TIMES.astype(np.float32)) / 65535.0,
    }


def accuracy(h: int, w: int, out_dir: Path) -> dict:
    """Relative errors of each method on one synthetic bracket; prints a table, writes a PNG."""
    radiance, frames = synthetic_bracket(h, w)
    decades = [(6 * 10.0**k, 6 * 10.0 ** (k + 1)) for k in range(-4, 1)]
    rows = {}
    for name, merge in _methods().items():
        rel = np.abs(merge(frames) / radiance - 1)
        per_decade = [float(np.sqrt(np.mean(rel[(radiance >= lo) & (radiance < hi)] ** 2))) for lo, hi in decades]
        rows[name] = {"median": float(np.median(rel)), "mean": float(np.mean(rel)),
                      "p95": float(np.percentile(rel, 95)), "rms_per_decade": per_decade}
    print(f"\nAccuracy: {w}x{h} RGB, 7 exposures 1 stop apart (1/64..1 s), radiance 1e5:1, "
          f"full well {FULL_WELL:.0f} e-, read noise {READ_NOISE:.0f} e-; relative error |X/X_true - 1|")
    head = "".join(f"  {lo:.0e}-{hi:.0e}" for lo, hi in decades)
    print(f"{'method':22s} {'median':>8s} {'mean':>8s} {'p95':>8s}   RMS per radiance decade:{head}")
    for name, r in rows.items():
        dec = "".join(f"  {v:13.4f}" for v in r["rms_per_decade"])
        print(f"{name:22s} {r['median']:8.4f} {r['mean']:8.4f} {r['p95']:8.4f}   {'':24s}{dec}")
    ref = rows["OpenCV MergeDebevec"]
    print(f"median error, OpenCV / brdfrig optimal: {ref['median'] / rows['brdfrig optimal']['median']:.1f}x")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    centres = [np.sqrt(lo * hi) for lo, hi in decades]
    fig, ax = plt.subplots(figsize=(6, 4))
    for name, r in rows.items():
        ax.loglog(centres, r["rms_per_decade"], "o-", label=name)
    ax.set_xlabel("true radiance (full scale per second)")
    ax.set_ylabel("RMS relative error")
    ax.set_title("HDR merge accuracy, 7 exposures 1 stop apart")
    ax.legend()
    fig.tight_layout()
    out_dir.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_dir / "bench_merge.png", dpi=120)
    plt.close(fig)
    return rows


def throughput(h: int, w: int, repeats: int) -> dict:
    """Median wall time of brdfrig's merge and OpenCV's MergeDebevec on an (h, w) 7-frame uint16 bracket."""
    from tqdm import tqdm

    from brdfrig.hdr.merge import merge_bracket

    tile_h, tile_w = h // 4, w // 4
    _, tile = synthetic_bracket(tile_h, tile_w, seed=1)
    frames = [np.ascontiguousarray(np.tile(f, (4, 4, 1))) for f in tile]
    methods = _methods()
    methods.pop("brdfrig Debevec hat")
    methods["brdfrig clip_radius=1"] = lambda f: merge_bracket(f, TIMES, clip_radius=1, full_well=FULL_WELL,
                                                               read_noise=READ_NOISE)
    times = {}
    for name, merge in methods.items():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # clip_radius=1 on independent pixels: many saturated in every frame
            merge(frames)  # warm-up (numba compilation / cache load, OpenCV's thread pool)
            runs = []
            for _ in tqdm(range(repeats), desc=name, file=sys.stderr, leave=False):
                t0 = time.perf_counter()
                merge(frames)
                runs.append(time.perf_counter() - t0)
        times[name] = float(np.median(runs))
    mp = h * w / 1e6
    print(f"\nThroughput: {w}x{h} ({mp:.0f} MP) RGB uint16, 7 exposures; median of {repeats} runs")
    print(f"{'method':22s} {'seconds':>8s} {'MP/s':>8s}")
    for name, t in times.items():
        print(f"{name:22s} {t:8.3f} {mp / t:8.1f}")
    ratio = times["OpenCV MergeDebevec"] / times["brdfrig optimal"]
    print(f"speed ratio brdfrig optimal / OpenCV: {ratio:.2f}x (> 1 = brdfrig faster)")
    print(f"cost of clip_radius=1: {times['brdfrig clip_radius=1'] / times['brdfrig optimal']:.2f}x the time")
    return {"seconds": times, "ratio": ratio}


def _write_frame(path: Path, frame: np.ndarray, fmt: str, time_s: float) -> Path:
    """One uint16 (H, W, 3) frame as a 16-bit TIFF, or as the RGGB mosaic of an uncompressed DNG."""
    if fmt == "tiff":
        import tifffile

        tifffile.imwrite(path, frame)
        return path
    from brdfrig.hdr.dng import write_dng

    cfa = np.empty(frame.shape[:2], np.uint16)
    for (y, x), c in zip(((0, 0), (0, 1), (1, 0), (1, 1)), (0, 1, 1, 2)):
        cfa[y::2, x::2] = frame[y::2, x::2, c]
    return write_dng(path, cfa, exposure_time_s=float(time_s), f_number=8.0, iso=100)


def memory(h: int, w: int, repeats: int, fmt: str = "tiff", align: bool = False) -> dict:
    """Peak RSS (GB) and wall time (s) of ``brdfrig merge`` (defaults) on an (h, w) 7-frame 16-bit bracket."""
    import resource
    import subprocess
    import tempfile

    with tempfile.TemporaryDirectory(prefix="bench-merge-") as tmp:
        tile = synthetic_bracket(h // 8, w // 8, seed=2)[1]
        paths = []
        for k, (f, t) in enumerate(zip(tile, TIMES)):
            frame = np.ascontiguousarray(np.tile(f, (8, 8, 1)))
            paths.append(_write_frame(Path(tmp) / f"f{k}.{'dng' if fmt == 'dng' else 'tif'}", frame, fmt, t))
        del tile, frame
        cmd = [sys.executable, "-m", "brdfrig.cli.main", "merge", *map(str, paths), "--times",
               ",".join(map(str, TIMES)), "--full-well", str(FULL_WELL), "--read-noise", str(READ_NOISE),
               "-o", str(Path(tmp) / "out.exr")] + (["--align"] if align else [])
        walls, peaks = [], []
        for _ in range(repeats):
            t0 = time.perf_counter()
            subprocess.run(cmd, check=True, capture_output=True)
            walls.append(time.perf_counter() - t0)
            peaks.append(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1e6)  # kB -> GB, max so far
    print(f"\nMemory: brdfrig merge{' --align' if align else ''} of 7 x {w}x{h} 16-bit {fmt.upper()}s: "
          f"peak RSS {max(peaks):.2f} GB, "
          f"median wall time {np.median(walls):.1f} s over {repeats} runs")
    return {"peak_gb": max(peaks), "seconds": float(np.median(walls))}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_merge", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="small images, 1 timed run (smoke test)")
    parser.add_argument("--out", type=Path, default=Path("bench-out"), help="directory for bench_merge.png")
    parser.add_argument("--repeats", type=int, default=3, help="timed runs per method (default: 3)")
    parser.add_argument("--memory", action="store_true",
                        help="only the memory benchmark: 7 x 24 MP 16-bit TIFFs through brdfrig merge")
    parser.add_argument("--format", choices=("tiff", "dng"), default="tiff", help="frame files of --memory")
    parser.add_argument("--align", action="store_true", help="--memory: merge with --align")
    args = parser.parse_args(argv)
    if args.memory:
        memory(4000, 6000, args.repeats, args.format, args.align)
        return 0
    if args.quick:
        accuracy(120, 160, args.out)
        throughput(300, 400, 1)
    else:
        accuracy(600, 800, args.out)
        throughput(3000, 4000, args.repeats)
    print(f"\nfigure: {args.out / 'bench_merge.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
