"""Time-vs-error benchmark of every BRDF model and solver (the engine of ``brdfrig bench``).

The material is a GGX sphere (alpha = 0.3 over a coloured Lambertian base,
:data:`TRUTH`) rendered by the ground-truth quadrature (:mod:`brdfrig.fit.groundtruth`)
under a fit lighting, either once (one scene) or with the lighting turned
about the vertical (+y) axis in 30 degree steps (twelve scenes).  The linear
models ``diffuse``, ``lobe`` and ``full`` are fitted with each solver
(``paper``, ``joint``, ``tikhonov``) at each band limit ``l = p = 1..12``,
``full+prior`` (always Tikhonov toward the microfacet prior) at each band
limit, and ``microfacet`` (no band limit) once, all through
:func:`brdfrig.fit.fitter.fit_brdf`; the fitted BRDF relights
the sphere under a DIFFERENT lighting and is compared with the ground truth
there (relative RMS over the weighted pixels).

Plan (what makes the full run take minutes instead of ~15).  Measured phase by
phase (2-core machine, load average ~3.5 from other jobs, one full run of 434 s):
ground truth 12 s (3%), warm-up 1 s, table fits 405 s (94%), headline 14 s.
Inside the table's fits, 54% is the microfacet prior that every ``full+prior``
fit refits (the same fit at each of the 12 band limits; 200 s), then
identifiability 15%, design 9%, QR 9%, lighting projection 7%.

- The ground truth is rendered once per lighting (each rotated fit lighting,
  the test lighting) and shared by every case and by the headline images; the
  renderer is passed in, so ``capture`` can cache renders on disk keyed by
  their inputs.
- One untimed warm-up fit (``auto``, every model, on a tiny sphere) first:
  numba kernels load and tables are built before any timing.
- Timing rule (:func:`time_runs`): every case is fitted once; a case faster
  than :data:`FAST_S` gets ``runs`` (3) fits and reports their median;
  slower cases get further runs (up to ``runs``) only while the projected
  total of the table stays within ``BenchConfig.budget_s``.  Each row
  records its run times (``n`` column).
- Cases run in a fixed random order, so the progress bar's rate-based ETA is
  an unbiased estimate of the remaining time (the cost of a case varies
  ~1000-fold with model, band limit and scene count); the table is sorted.

Headline timings: a 512x512 three-channel fit of ``full`` at ``l = p = 8``
with twelve scenes and with one scene (``--quick``: 48x48 at ``l = p = 3``),
median of ``runs`` fits each.  Their images are the ground-truth
renders of the table's sphere resampled (bilinear, in normal space) onto the
512x512 pixel grid: timing depends on the pixel count, not on the image
content, and brute-force rendering 12 x 512^2 pixels would dominate the
benchmark.

This module takes plain environments, a sphere-geometry callable and a
ground-truth renderer; ``capture/cmd_bench.py`` loads the maps and caches the
renders.
"""

from __future__ import annotations

import math
import os
import statistics
import time
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field, fields
from functools import partial
from pathlib import Path
from typing import Callable, TypeVar

import numpy as np

from brdfrig._atomic import temp_path
from brdfrig.fit.analytic import GGX
from brdfrig.fit.registry import LINEAR_SH, PRIOR_OF, SOLVERS
from brdfrig.fit.groundtruth import render_groundtruth
from brdfrig.fit.metrics import relative_rms
from brdfrig.fit.rotation import axis_rotation
from brdfrig.fit.scene import Environment, Scene

__all__ = [
    "MODELS",
    "SOLVERS",
    "TRUTH",
    "FAST_S",
    "BenchConfig",
    "BenchRow",
    "BenchResult",
    "QUICK",
    "FULL",
    "plan_cases",
    "time_runs",
    "run_benchmark",
    "format_table",
    "format_solver_comparison",
    "format_phases",
    "pareto_front",
    "plot_pareto",
    "rows_to_json",
    "result_from_json",
]

MODELS = LINEAR_SH + ("full+prior", "microfacet")
"""The models of the table (from :mod:`brdfrig.fit.registry`)."""
TRUTH = GGX(alpha=0.3, f0=0.04, diffuse=(0.6, 0.4, 0.2))
"""The benchmark's material: GGX alpha = 0.3, dielectric Fresnel f0 = 0.04, orange Lambertian base."""

FAST_S = 1.0
"""A case whose first fit takes less than this (seconds) is always fitted ``runs`` times (median reported)."""

SphereGeometry = Callable[[int], tuple[np.ndarray, np.ndarray]]
"""``size -> (normals (N, 3), weights (N,))`` of the pixels of a size x size sphere image (MATH.md)."""

GroundTruth = Callable[[object, np.ndarray, Environment], np.ndarray]
"""``(brdf, normals (N, 3), env) -> (N, C)`` radiance, as :func:`brdfrig.fit.groundtruth.render_groundtruth`."""

T = TypeVar("T")


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
        Fits per timing (the median is reported); cases slower than :data:`FAST_S` may get fewer.
    headline_size : int
        Image size of the headline timings (0 = skip them).
    headline_lmax : int
        Band limit ``l = p`` of the headline timings (8 in the full benchmark).
    budget_s : float
        Soft budget (seconds) of the table's fits: repeats of slow cases stop when the projected total
        would exceed it (every case is still fitted once, fast cases ``runs`` times).
    """

    sphere_size: int
    lmax_values: tuple[int, ...]
    scene_counts: tuple[int, ...]
    runs: int
    headline_size: int
    headline_lmax: int = 8
    budget_s: float = math.inf


QUICK = BenchConfig(sphere_size=32, lmax_values=(1, 2, 3), scene_counts=(1,), runs=3, headline_size=48, headline_lmax=3,
                    budget_s=20.0)
FULL = BenchConfig(sphere_size=64, lmax_values=tuple(range(1, 13)), scene_counts=(1, 12), runs=3, headline_size=512,
                   budget_s=210.0)


@dataclass
class BenchRow:
    """One benchmark measurement (``solver``/``lmax`` are ``"-"``/0 for the microfacet model).

    ``seconds`` is the median of ``times`` (wall clock of each :func:`brdfrig.fit.fitter.fit_brdf` call).
    """

    model: str
    solver: str
    lmax: int
    scenes: int
    seconds: float
    relight_error: float
    rank: int | None
    condition: float | None
    times: tuple[float, ...] = ()

    @property
    def runs(self) -> int:
        return len(self.times)


@dataclass
class BenchResult:
    """All rows, the headline timings, the lighting used and where the benchmark's time went.

    ``headline`` maps a scene count to the median seconds of the ``full``
    ``l = p = headline_lmax`` joint fit of ``headline_size`` x ``headline_size``
    three-channel images; ``headline_times`` to all its run times.  ``phases``
    maps a phase name to wall seconds (:func:`format_phases`), ``fit_stages``
    a stage of :func:`brdfrig.fit.fitter.fit_brdf` to its seconds summed over every
    timed fit of the table.
    """

    rows: list[BenchRow]
    headline: dict[int, float] = field(default_factory=dict)
    headline_size: int = 0
    headline_lmax: int = 8
    lighting: str = ""
    headline_times: dict[int, tuple[float, ...]] = field(default_factory=dict)
    phases: dict[str, float] = field(default_factory=dict)
    fit_stages: dict[str, float] = field(default_factory=dict)


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


def _stats(report, model: str) -> tuple[int | None, float | None]:
    """(smallest rank, largest condition number) over channels of ``model`` in a fit report (None for microfacet)."""
    system = report.candidates[model].system
    if system is None:
        return None, None
    return int(np.min(system.rank)), float(np.max(system.condition_number))


def _fit(scenes: list[Scene], model: str, solver: str, lmax: int):
    from brdfrig.fit.fitter import fit_brdf

    if model == "microfacet":
        return fit_brdf(scenes, model=model, progress=False, estimate=False)
    return fit_brdf(scenes, model=model, lmax=lmax, pmax=lmax, solver=solver, progress=False, estimate=False)


def time_runs(
    fit: Callable[[], T], runs: int, extra_ok: Callable[[float], bool], fast_s: float = FAST_S,
    clock: Callable[[], float] = time.perf_counter,
) -> tuple[list[float], T]:
    """Wall times of repeated calls of ``fit`` and its last result: the benchmark's timing rule.

    ``fit`` runs once; if that took less than ``fast_s`` seconds it runs ``runs`` times in all.
    Otherwise each further run (up to ``runs``) happens only if ``extra_ok(median so far)`` says the
    time budget allows it.  Only ``fit`` is timed (inputs are built beforehand), by ``clock`` (seconds).

    Returns
    -------
    (times in seconds, result of the last call)
    """
    times: list[float] = []
    result = None
    while len(times) < runs:
        if times and times[0] >= fast_s and not extra_ok(statistics.median(times)):
            break
        t0 = clock()
        result = fit()
        times.append(clock() - t0)
    return times, result


def plan_cases(config: BenchConfig) -> list[tuple[str, str, int, int]]:
    """``(model, solver, l = p, scenes)`` of every table row, in table order.

    ``full+prior`` is always solved by Tikhonov toward the prior (:mod:`brdfrig.fit.fitter`): one row per band
    limit; ``microfacet`` has no band limit (``"-"``, 0).
    """
    cases = [(m, s, l, n) for n in config.scene_counts for m in LINEAR_SH
             for s in SOLVERS for l in config.lmax_values]
    cases += [("full+prior", "tikhonov", l, n) for n in config.scene_counts for l in config.lmax_values]
    cases += [("microfacet", "-", 0, n) for n in config.scene_counts]
    return cases


def _warm_up(sphere: SphereGeometry, env: Environment, groundtruth: GroundTruth) -> None:
    """Untimed fits of a tiny sphere by every model of the table but ``full+prior`` (whose parts they are): numba
    kernels load, tables get built."""
    from brdfrig.fit.fitter import fit_brdf

    normals, weights = sphere(12)
    seen = weights > 0
    scenes = [Scene(env, normals[seen], groundtruth(TRUTH, normals[seen], env), weights[seen])]
    for model in MODELS:
        if model not in PRIOR_OF:
            fit_brdf(scenes, model=model, lmax=2, pmax=2, progress=False, estimate=False)


def _add_stages(total: dict[str, float], report) -> None:
    """Add a fit report's ``stage_seconds`` to ``total``."""
    for stage, seconds in report.stage_seconds.items():
        total[stage] = total.get(stage, 0.0) + float(seconds)


def run_benchmark(
    fit_env: Environment,
    test_env: Environment,
    sphere: SphereGeometry,
    config: BenchConfig,
    *,
    lighting: str = "",
    progress: bool = True,
    groundtruth: GroundTruth = render_groundtruth,
) -> BenchResult:
    """Run the benchmark (see module docstring).

    Parameters
    ----------
    fit_env, test_env : Environment
        The lighting of the fits and the different lighting of the relighting check (3 channels).
    sphere : callable
        ``size -> (normals, weights)`` of a sphere image (``brdfrig.hdr.sphere`` via ``capture``).
    config : BenchConfig
    lighting : str
        Description of the maps, carried into the result.
    progress : bool
        tqdm progress bars on stderr (the table's bar shows cases done / total and an ETA).
    groundtruth : callable
        ``(brdf, normals, env) -> radiance`` (default :func:`brdfrig.fit.groundtruth.render_groundtruth`;
        ``capture`` passes a disk-cached one).  Called once per lighting.
    """
    phases: dict[str, float] = {}
    with _phase(phases, "ground truth"):
        truth = _render_truth(fit_env, test_env, sphere, config, groundtruth, progress)
    with _phase(phases, "warm-up"):
        _warm_up(sphere, fit_env, groundtruth)
    with _phase(phases, "table fits"):
        rows, stages = _fit_table(truth, test_env, config, progress)
    headline, headline_times = {}, {}
    if config.headline_size:
        with _phase(phases, "headline"):
            headline, headline_times = _headline_timings(sphere, truth, config, progress)
    return BenchResult(rows, headline, config.headline_size, config.headline_lmax, lighting, headline_times, phases,
                       stages)


@contextmanager
def _phase(phases: dict[str, float], name: str):
    """Record the wall seconds of the ``with`` block as ``phases[name]``."""
    t0 = time.perf_counter()
    yield
    phases[name] = time.perf_counter() - t0


@dataclass
class _Truth:
    """The table's sphere pixels (seen ones only), the rotated fit lightings, their renders and the test render."""

    normals: np.ndarray
    weights: np.ndarray
    envs: list[Environment]
    images: list[np.ndarray]
    test: np.ndarray


def _render_truth(fit_env: Environment, test_env: Environment, sphere: SphereGeometry, config: BenchConfig,
                  groundtruth: GroundTruth, progress: bool) -> _Truth:
    """Ground-truth renders of :data:`TRUTH` under each fit lighting (turned in 30 degree steps) and the test one."""
    from tqdm import tqdm

    normals, weights = sphere(config.sphere_size)
    seen = weights > 0
    normals, weights = normals[seen], weights[seen]
    envs = [fit_env.rotated(axis_rotation("y", 30 * k)) for k in range(max(config.scene_counts))]
    images = [groundtruth(TRUTH, normals, e) for e in tqdm(envs, desc="ground truth", disable=not progress)]
    return _Truth(normals, weights, envs, images, groundtruth(TRUTH, normals, test_env))


class _StagedFit:
    """One table case's fit as :func:`time_runs` calls it; every run's ``stage_seconds`` are added to ``stages``."""

    def __init__(self, scenes: list[Scene], case: tuple[str, str, int, int], stages: dict[str, float]) -> None:
        self.scenes, self.case, self.stages = scenes, case, stages

    def __call__(self):
        model, solver, lmax, _ = self.case
        res = _fit(self.scenes, model, solver, lmax)
        _add_stages(self.stages, res.report)
        return res


def _another_run_fits(t_table: float, started: float, done: int, left: int, budget_s: float, run_s: float) -> bool:
    """Another run of ``run_s`` seconds fits the table's budget, the ``left`` cases costing the mean of the ``done``
    ones (``started`` seconds after ``t_table``; this one's cost if none is done)."""
    mean = started / done if done else run_s
    return time.perf_counter() - t_table + run_s + left * mean <= budget_s


def _fit_table(truth: _Truth, test_env: Environment, config: BenchConfig,
               progress: bool) -> tuple[list[BenchRow], dict[str, float]]:
    """Every case of :func:`plan_cases`, timed and relit: the rows in table order and the fits' summed stages."""
    from tqdm import tqdm

    # The rotated environments and their renders are shared by every case (scenes are views of them).
    scenes_of = {n: [Scene(truth.envs[k], truth.normals, truth.images[k], truth.weights) for k in range(n)]
                 for n in config.scene_counts}
    cases = plan_cases(config)
    # A fixed random order makes tqdm's rate-based ETA unbiased (case costs span three decades).
    order = np.random.default_rng(0).permutation(len(cases))
    rows: list[BenchRow | None] = [None] * len(cases)
    stages: dict[str, float] = {}
    t_table = time.perf_counter()
    bar = tqdm(order, desc="fits", unit="case", disable=not progress)
    for done, i in enumerate(bar):
        model, solver, lmax, count = cases[i]
        bar.set_postfix_str(f"{model} {solver} l={lmax} scenes={count}", refresh=True)
        budget = partial(_another_run_fits, t_table, time.perf_counter() - t_table, done, len(cases) - done - 1,
                         config.budget_s)
        times, result = time_runs(_StagedFit(scenes_of[count], cases[i], stages), config.runs, budget)
        rows[i] = _row(cases[i], times, result, test_env, truth)
    bar.close()
    return rows, stages


def _row(case: tuple[str, str, int, int], times: list[float], result, test_env: Environment, truth: _Truth) -> BenchRow:
    """A table row: a case's run times and how well its last fit relights the sphere under ``test_env``."""
    model, solver, lmax, count = case
    err = relative_rms(result.brdf.predict(test_env, truth.normals), truth.test, truth.weights)
    rank, cond = _stats(result.report, model)
    return BenchRow(model, solver, lmax, count, statistics.median(times), err, rank, cond, tuple(times))


def _headline_timings(sphere: SphereGeometry, truth: _Truth, config: BenchConfig,
                      progress: bool) -> tuple[dict[int, float], dict[int, tuple[float, ...]]]:
    """Median and all run times of the ``full`` joint fit of ``headline_size`` images, by scene count (1 and all)."""
    from tqdm import tqdm

    big_normals, big_weights = sphere(config.headline_size)
    big = [_resample(img, truth.normals, config.sphere_size, big_normals) for img in truth.images]
    headline, headline_times = {}, {}
    for count in tqdm(sorted({1, len(truth.envs)}), desc="headline", disable=not progress):
        scenes = [Scene(truth.envs[k], big_normals, big[k], big_weights) for k in range(count)]
        # Every run counts here (no budget): the headline is a median, not one possibly unlucky run.
        fit = partial(_fit, scenes, "full", "joint", config.headline_lmax)
        times, _ = time_runs(fit, config.runs, lambda s: True)
        headline[count], headline_times[count] = statistics.median(times), tuple(times)
    return headline, headline_times

def format_table(rows: list[BenchRow]) -> str:
    """Fixed-width table of all rows (``n`` = fits timed; ``time_s`` = their median)."""
    head = (f"{'model':<11} {'solver':<9} {'l=p':>3} {'scenes':>6} {'time_s':>8} {'n':>2} {'relight_err':>11} "
            f"{'rank':>5} {'cond':>9}")
    lines = [head, "-" * len(head)]
    for r in rows:
        rank = "-" if r.rank is None else str(r.rank)
        cond = "-" if r.condition is None else f"{r.condition:.2e}"
        lmax = "-" if r.model == "microfacet" else str(r.lmax)
        lines.append(f"{r.model:<11} {r.solver:<9} {lmax:>3} {r.scenes:>6} {r.seconds:>8.3f} {r.runs:>2} "
                     f"{r.relight_error:>11.3e} {rank:>5} {cond:>9}")
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


def format_phases(result: BenchResult) -> str:
    """Where the benchmark's wall time went: its phases, then the fitter's stages summed over the table's fits."""
    total = sum(result.phases.values())
    lines = [f"  {name:<14} {s:>8.1f} s  {s / total:>4.0%}" for name, s in result.phases.items()]
    lines.append(f"  {'total':<14} {total:>8.1f} s")
    if result.fit_stages:
        fit_total = sum(result.fit_stages.values())
        parts = ", ".join(f"{k} {v:.1f} s ({v / fit_total:.0%})" for k, v in
                          sorted(result.fit_stages.items(), key=lambda kv: -kv[1]) if v > 0)
        lines.append(f"  inside the table's fits (fit_brdf stages, all runs): {parts}")
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
    try:
        with temp_path(path) as tmp:
            fig.savefig(tmp)
    finally:
        plt.close(fig)
    return path


def rows_to_json(result: BenchResult) -> dict:
    """JSON-able form of a result (inverse: :func:`result_from_json`)."""
    return {
        "lighting": result.lighting,
        "headline": {"size": result.headline_size, "model": "full", "lmax": result.headline_lmax, "pmax": result.headline_lmax, "solver": "joint",
                     "seconds_by_scenes": {str(k): v for k, v in result.headline.items()},
                     "times_by_scenes": {str(k): list(v) for k, v in result.headline_times.items()}},
        "phases_seconds": result.phases,
        "fit_stages_seconds": result.fit_stages,
        "rows": [{**asdict(r), "times": list(r.times)} for r in result.rows],
    }


def result_from_json(data: dict) -> BenchResult:
    """The :class:`BenchResult` of a :func:`rows_to_json` dict (e.g. a ``bench.json`` read back)."""
    head = data["headline"]
    names = {f.name for f in fields(BenchRow)}
    rows = [BenchRow(**{**{k: v for k, v in r.items() if k in names}, "times": tuple(r["times"])}) for r in data["rows"]]
    return BenchResult(
        rows,
        {int(k): v for k, v in head["seconds_by_scenes"].items()},
        head["size"],
        head["lmax"],
        data["lighting"],
        {int(k): tuple(v) for k, v in head.get("times_by_scenes", {}).items()},
        dict(data.get("phases_seconds", {})),
        dict(data.get("fit_stages_seconds", {})),
    )
