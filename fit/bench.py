"""Time-vs-error benchmark of every BRDF model and solver (the engine of ``brdfrig bench``).

The material is a GGX sphere (alpha = 0.3 over a coloured Lambertian base,
:data:`TRUTH`) rendered by the ground-truth quadrature (:mod:`fit.groundtruth`)
under a fit lighting, either once (one scene) or with the lighting turned
about the vertical (+y) axis in 30 degree steps (twelve scenes).  The linear
models ``diffuse``, ``lobe`` and ``full`` are fitted with each solver
(``paper``, ``joint``, ``tikhonov``) at each band limit ``l = p = 1..12``,
``full+prior`` (always Tikhonov toward the microfacet prior) at each band
limit, and ``microfacet`` (no band limit) once, all through
:func:`fit.fitter.fit_brdf`; the fitted BRDF relights
the sphere under a DIFFERENT lighting and is compared with the ground truth
there (relative RMS over the weighted pixels).  Times are wall-clock medians
of repeated fits, progress bars off.

Headline timings: a 512x512 three-channel fit of ``full`` at ``l = p = 8``
with twelve scenes and with one scene (``--quick``: 48x48 at ``l = p = 3``).  Their images are the ground-truth
renders of the table's sphere resampled (bilinear, in normal space) onto the
512x512 pixel grid: timing depends on the pixel count, not on the image
content, and brute-force rendering 12 x 512^2 pixels would dominate the
benchmark.

This module takes plain environments and a sphere-geometry callable;
``capture/cmd_bench.py`` loads the maps.
"""

from __future__ import annotations

import math
import os
import statistics
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from fit.analytic import GGX
from fit.groundtruth import render_groundtruth
from fit.scene import Environment, Scene

__all__ = [
    "MODELS",
    "SOLVERS",
    "TRUTH",
    "BenchConfig",
    "BenchRow",
    "BenchResult",
    "QUICK",
    "FULL",
    "rotate_environment",
    "run_benchmark",
    "format_table",
    "format_solver_comparison",
    "pareto_front",
    "plot_pareto",
    "rows_to_json",
]

MODELS = ("diffuse", "lobe", "full", "full+prior", "microfacet")
SOLVERS = ("paper", "joint", "tikhonov")
TRUTH = GGX(alpha=0.3, f0=0.04, diffuse=(0.6, 0.4, 0.2))
"""The benchmark's material: GGX alpha = 0.3, dielectric Fresnel f0 = 0.04, orange Lambertian base."""

TIME_BUDGET_S = 4.0
"""Repeated fits of one case stop once their total time exceeds this (slow cases get fewer runs)."""

SphereGeometry = Callable[[int], tuple[np.ndarray, np.ndarray]]
"""``size -> (normals (N, 3), weights (N,))`` of the pixels of a size x size sphere image (MATH.md)."""


@dataclass(frozen=True)
class BenchConfig:
    """What the benchmark runs.

    Attributes
    ----------
    sphere_size : int
        Image size (pixels) of the table's sphere.
    lmax_values : tuple of int
        Band limits ``l = p`` of the linear models.
    scene_counts : tuple of int
        Numbers of scenes (1 = the fit lighting; 12 = turned in 30 degree steps).
    runs : int
        Fits per timing (the median is reported).
    headline_size : int
        Image size of the headline timings (0 = skip them).
    headline_lmax : int
        Band limit ``l = p`` of the headline timings (8 in the full benchmark).
    """

    sphere_size: int
    lmax_values: tuple[int, ...]
    scene_counts: tuple[int, ...]
    runs: int
    headline_size: int
    headline_lmax: int = 8


QUICK = BenchConfig(sphere_size=32, lmax_values=(1, 2, 3), scene_counts=(1,), runs=1, headline_size=48, headline_lmax=3)
FULL = BenchConfig(sphere_size=64, lmax_values=tuple(range(1, 13)), scene_counts=(1, 12), runs=3, headline_size=512)


@dataclass
class BenchRow:
    """One benchmark measurement (``solver``/``lmax`` are ``"-"``/0 for the microfacet model)."""

    model: str
    solver: str
    lmax: int
    scenes: int
    seconds: float
    relight_error: float
    rank: int | None
    condition: float | None


@dataclass
class BenchResult:
    """All rows, the headline timings and the lighting used.

    ``headline`` maps a scene count to the median seconds of the ``full``
    ``l = p = headline_lmax`` joint fit of ``headline_size`` x ``headline_size``
    three-channel images.
    """

    rows: list[BenchRow]
    headline: dict[int, float] = field(default_factory=dict)
    headline_size: int = 0
    headline_lmax: int = 8
    lighting: str = ""


def rotate_environment(env: Environment, angle_rad: float) -> Environment:
    """The environment turned by ``angle_rad`` about the vertical (+y) axis (right-handed)."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    rot = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    return Environment(np.asarray(env.dirs) @ rot.T, env.radiance, env.solid_angle)


def _relative_rms(pred: np.ndarray, truth: np.ndarray, weights: np.ndarray) -> float:
    w = weights[:, None]
    return float(math.sqrt(np.sum(w * (pred - truth) ** 2) / max(np.sum(w * truth**2), 1e-300)))


def _resample(image_values: np.ndarray, normals: np.ndarray, size: int, new_normals: np.ndarray) -> np.ndarray:
    """Bilinear resampling of per-pixel values of a ``size`` sphere image at other normals (normal space)."""
    from scipy.ndimage import map_coordinates

    grid = np.zeros((size, size, image_values.shape[1]))
    cols = np.clip(np.floor((normals[:, 0] + 1) * size / 2).astype(int), 0, size - 1)
    rows = np.clip(np.floor((1 - normals[:, 1]) * size / 2).astype(int), 0, size - 1)
    grid[rows, cols] = image_values
    x = (new_normals[:, 0] + 1) * size / 2 - 0.5
    y = (1 - new_normals[:, 1]) * size / 2 - 0.5
    return np.stack([map_coordinates(grid[..., c], [y, x], order=1, mode="nearest") for c in range(grid.shape[2])], 1)


def _stats(report: dict, model: str) -> tuple[int | None, float | None]:
    """(smallest rank, largest condition number) over channels of ``model`` in a fit report (None for microfacet)."""
    info = report.get("candidates", {}).get(model, {})
    rank, cond = info.get("rank"), info.get("condition_number")
    rank = None if rank is None else int(np.min(rank))
    cond = None if cond is None else float(np.max(cond))
    return rank, cond


def _fit(scenes: list[Scene], model: str, solver: str, lmax: int):
    from fit.fitter import fit_brdf

    if model == "microfacet":
        return fit_brdf(scenes, model=model, progress=False)
    return fit_brdf(scenes, model=model, lmax=lmax, pmax=lmax, solver=solver, progress=False)


def _timed(scenes: list[Scene], model: str, solver: str, lmax: int, runs: int, budget_s: float = TIME_BUDGET_S):
    """(median seconds, last FitResult) over up to ``runs`` fits; stops repeating after ``budget_s`` seconds.

    Only :func:`fit.fitter.fit_brdf` is timed (scenes are built beforehand): the work a user's fit does.
    """
    times, result = [], None
    while len(times) < runs and sum(times) < budget_s:
        t0 = time.perf_counter()
        result = _fit(scenes, model, solver, lmax)
        times.append(time.perf_counter() - t0)
    return statistics.median(times), result


def run_benchmark(
    fit_env: Environment,
    test_env: Environment,
    sphere: SphereGeometry,
    config: BenchConfig,
    *,
    lighting: str = "",
    progress: bool = True,
) -> BenchResult:
    """Run the benchmark (see module docstring).

    Parameters
    ----------
    fit_env, test_env : Environment
        The lighting of the fits and the different lighting of the relighting check (3 channels).
    sphere : callable
        ``size -> (normals, weights)`` of a sphere image (``hdr.sphere`` via ``capture``).
    config : BenchConfig
    lighting : str
        Description of the maps, carried into the result.
    progress : bool
        tqdm progress bars on stderr.
    """
    from tqdm import tqdm

    normals, weights = sphere(config.sphere_size)
    seen = weights > 0
    normals, weights = normals[seen], weights[seen]
    max_scenes = max(config.scene_counts)
    envs = [rotate_environment(fit_env, math.radians(30 * k)) for k in range(max_scenes)]
    images = [render_groundtruth(TRUTH, normals, e) for e in tqdm(envs, desc="ground truth", disable=not progress)]
    truth_test = render_groundtruth(TRUTH, normals, test_env)

    # full+prior is always solved by Tikhonov toward the prior (fit.fitter): one solver row per band limit.
    cases = [(m, s, l, n) for n in config.scene_counts for m in ("diffuse", "lobe", "full")
             for s in SOLVERS for l in config.lmax_values]
    cases += [("full+prior", "tikhonov", l, n) for n in config.scene_counts for l in config.lmax_values]
    cases += [("microfacet", "-", 0, n) for n in config.scene_counts]
    rows = []
    for model, solver, lmax, count in tqdm(cases, desc="fits", disable=not progress):
        scenes = [Scene(envs[k], normals, images[k], weights) for k in range(count)]
        seconds, result = _timed(scenes, model, solver, lmax, config.runs)
        err = _relative_rms(result.brdf.predict(test_env, normals), truth_test, weights)
        rank, cond = _stats(result.report, model)
        rows.append(BenchRow(model, solver, lmax, count, seconds, err, rank, cond))

    headline = {}
    if config.headline_size:
        big_normals, big_weights = sphere(config.headline_size)
        big = [_resample(img, normals, config.sphere_size, big_normals) for img in images]
        for count in sorted({1, max_scenes}):
            scenes = [Scene(envs[k], big_normals, big[k], big_weights) for k in range(count)]
            # Every run counts here (no time budget): the headline is a median, not one possibly cold run.
            headline[count] = _timed(scenes, "full", "joint", config.headline_lmax, config.runs, budget_s=math.inf)[0]
    return BenchResult(rows, headline, config.headline_size, config.headline_lmax, lighting)


def format_table(rows: list[BenchRow]) -> str:
    """Fixed-width table of all rows."""
    head = f"{'model':<11} {'solver':<9} {'l=p':>3} {'scenes':>6} {'time_s':>8} {'relight_err':>11} {'rank':>5} {'cond':>9}"
    lines = [head, "-" * len(head)]
    for r in rows:
        rank = "-" if r.rank is None else str(r.rank)
        cond = "-" if r.condition is None else f"{r.condition:.2e}"
        lmax = "-" if r.model == "microfacet" else str(r.lmax)
        lines.append(f"{r.model:<11} {r.solver:<9} {lmax:>3} {r.scenes:>6} {r.seconds:>8.3f} {r.relight_error:>11.3e} {rank:>5} {cond:>9}")
    return "\n".join(lines)


def format_solver_comparison(rows: list[BenchRow]) -> str:
    """Relighting error of paper vs joint vs tikhonov per (model, scenes, band limit), flagging where paper wins."""
    table: dict[tuple[str, int, int], dict[str, float]] = {}
    for r in rows:
        if r.solver in SOLVERS:
            table.setdefault((r.model, r.scenes, r.lmax), {})[r.solver] = r.relight_error
    head = f"{'model':<11} {'scenes':>6} {'l=p':>3} {'paper':>9} {'joint':>9} {'tikhonov':>9}  note"
    lines = [head, "-" * len(head)]
    for (model, scenes, lmax), errs in table.items():
        cells = " ".join(f"{errs[s]:>9.3e}" if s in errs else f"{'-':>9}" for s in SOLVERS)
        best_new = min(errs.get("joint", math.inf), errs.get("tikhonov", math.inf))
        note = "paper better" if errs.get("paper", math.inf) < best_new * (1 - 1e-6) else ""
        lines.append(f"{model:<11} {scenes:>6} {lmax:>3} {cells}  {note}")
    return "\n".join(lines)


def pareto_front(rows: list[BenchRow]) -> list[BenchRow]:
    """Rows not dominated in (time, error): sorted by time, each strictly more accurate than all faster ones."""
    front, best = [], math.inf
    for r in sorted(rows, key=lambda r: (r.seconds, r.relight_error)):
        if r.relight_error < best:
            front.append(r)
            best = r.relight_error
    return front


def plot_pareto(result: BenchResult, path: str | os.PathLike) -> Path:
    """Write a PNG of relighting error against fit time, one colour per model, with the Pareto front.

    Written to a temporary name in the same directory and renamed, so no partial file is left.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    fig, ax = plt.subplots(figsize=(8, 5.5), dpi=110)
    for model in MODELS:
        for scenes, marker in zip(sorted({r.scenes for r in result.rows}), "os^D"):
            sel = [r for r in result.rows if r.model == model and r.scenes == scenes]
            if sel:
                ax.scatter([r.seconds for r in sel], [r.relight_error for r in sel], marker=marker, s=22, alpha=0.75,
                           label=f"{model}, {scenes} scene{'s' if scenes > 1 else ''}")
    front = pareto_front(result.rows)
    ax.step([r.seconds for r in front], [r.relight_error for r in front], where="post", color="k", lw=1.2,
            label="Pareto front")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("fit time (s, median)")
    ax.set_ylabel("relighting error (relative RMS, different map)")
    ax.set_title(f"brdfrig bench: GGX alpha=0.3 sphere, {result.lighting}", fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.tmp{os.getpid()}.png")
    try:
        fig.savefig(tmp)
        os.replace(tmp, path)
    finally:
        plt.close(fig)
        tmp.unlink(missing_ok=True)
    return path


def rows_to_json(result: BenchResult) -> dict:
    """JSON-able form of a result."""
    return {
        "lighting": result.lighting,
        "headline": {"size": result.headline_size, "model": "full", "lmax": result.headline_lmax, "pmax": result.headline_lmax, "solver": "joint",
                     "seconds_by_scenes": {str(k): v for k, v in result.headline.items()}},
        "rows": [asdict(r) for r in result.rows],
    }
