"""The whole measured-materials benchmark: every material x model x scene count x noise level, with progress.

Per scene count, every material's ground truth is rendered (or read from the
cache) first, then every case is fitted in a fixed order: material, noise
level, model (``auto`` first).  One untimed warm-up fit of every model on a
small subset of the first material's pixels runs before any timing (numba
kernels load, tables get built).  The optional peer (``--peer mitsuba``:
:mod:`brdfrig.evaluate.mitsuba_peer`) is fitted to the same pixels as one more
"model" named ``peer:mitsuba``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from brdfrig.errors import InputError
from brdfrig.evaluate.measured import (CaseResult, CaseSetup, Material, Truth, fit_and_relight, find_materials,
                                       list_materials, make_cache, model_names, render_truth)
from brdfrig.fit.scene import Scene

__all__ = ["MeasuredResult", "run_measured_benchmark", "run_from_args", "PEER_PREFIX"]

PEER_PREFIX = "peer:"
WARMUP_STRIDE = 23
"""The warm-up fits use every WARMUP_STRIDE-th pixel of the first material's sphere."""


@dataclass
class MeasuredResult:
    """Every case of a run, the setups, the references of the headline cases, and where the time went.

    ``truths`` maps ``(scenes, material name)`` to its :class:`Truth` (kept for the sphere images).
    """

    cases: list[CaseResult]
    setup: CaseSetup
    scene_counts: tuple[int, ...]
    noises: tuple[float, ...]
    models: tuple[str, ...]
    materials: list[Material]
    truths: dict[tuple[int, str], Truth] = field(default_factory=dict, repr=False)
    phases: dict[str, float] = field(default_factory=dict)
    cache_hits: int = 0
    cache_misses: int = 0


def _peer_fit(name: str):
    """``(scenes, model) -> FitResult`` of a peer (ImportError names what is missing)."""
    if name != "mitsuba":
        raise InputError(f"unknown peer {name!r} (known: mitsuba)")
    try:
        from brdfrig.evaluate.mitsuba_peer import fit_principled
    except ImportError as exc:
        raise InputError(f"--peer mitsuba needs brdfrig.evaluate.mitsuba_peer and Mitsuba 3 ({exc})") from exc

    def fit(scenes, model):
        return fit_principled(scenes)

    return fit


def _warm_up(truth: Truth, models) -> None:
    sub = slice(None, None, WARMUP_STRIDE)
    scenes = [Scene(s.env, s.normals[sub], s.radiance[sub], s.weights[sub]) for s in truth.scenes[:1]]
    small = replace(truth, scenes=scenes, normals=truth.normals[sub], weights=truth.weights[sub],
                    relight={k: (e, r[sub]) for k, (e, r) in truth.relight.items()})
    for model in models:
        if not model.startswith(PEER_PREFIX):
            fit_and_relight(small, model)


def run_measured_benchmark(materials: list[Material], models, setup: CaseSetup = CaseSetup(), *,
                           scene_counts=(1,), noises=(0.0,), seed: int = 0, cache_dir: Path | None = None,
                           peer: str | None = None, progress: bool = True) -> MeasuredResult:
    """Run every case (see module docstring).  ``setup.scenes`` is replaced by each of ``scene_counts``."""
    from tqdm import tqdm

    models = tuple(models)
    known = model_names()
    bad = [m for m in models if m not in known]
    if bad:
        raise InputError(f"unknown model(s) {bad}; the fitter offers {list(known)}")
    fits = {m: None for m in models}
    if peer:
        fits[PEER_PREFIX + peer] = _peer_fit(peer)
    cache = make_cache() if cache_dir is None else make_cache(cache_dir)
    result = MeasuredResult([], setup, tuple(scene_counts), tuple(noises), tuple(fits), list(materials))
    t_fit = 0.0
    for count in scene_counts:
        s = replace(setup, scenes=int(count))
        t0 = time.perf_counter()
        for m in tqdm(materials, desc=f"ground truth ({count} scene{'s' if count > 1 else ''})", unit="material",
                      disable=not progress):
            result.truths[(count, m.name)] = render_truth(m, s, cache)
        result.phases[f"ground truth, {count} scene(s)"] = time.perf_counter() - t0
        if count == scene_counts[0]:
            t0 = time.perf_counter()
            _warm_up(result.truths[(count, materials[0].name)], models)
            result.phases["warm-up"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        total = len(materials) * len(noises) * len(fits)
        with tqdm(total=total, desc=f"fits ({count} scene{'s' if count > 1 else ''})", unit="fit",
                  disable=not progress) as bar:
            for m in materials:
                for noise in noises:
                    for model, fit in fits.items():
                        bar.set_postfix_str(f"{m.name} {model} noise={noise:g}", refresh=False)
                        case = fit_and_relight(result.truths[(count, m.name)], model, noise=noise, seed=seed, fit=fit)
                        result.cases.append(case)
                        bar.update()
        t_fit += time.perf_counter() - t0
        result.phases[f"fits, {count} scene(s)"] = time.perf_counter() - t0
    result.cache_hits, result.cache_misses = cache.hits, cache.misses
    return result


def run_from_args(args) -> int:
    """Run the benchmark from parsed options (:func:`brdfrig.evaluate.measured.add_arguments` + ``--out``,
    ``--probes``, ``--no-progress``), print the table and summary, write PNGs and JSON into ``--out``."""
    from brdfrig.evaluate.measured_report import format_report, write_outputs

    for name, value in (("--size", args.size), ("--env-rows", args.env_rows)):
        if value < 1:
            raise InputError(f"{name} must be a positive integer, got {value}")
    for noise in args.noise:
        if not (np.isfinite(noise) and 0 <= noise < 1):
            raise InputError(f"--noise must be in [0, 1), got {noise}")
    materials = (find_materials(args.materials, args.measured_dir) if args.materials
                 else list_materials(args.measured_dir))
    models = tuple(args.models) if args.models else model_names()
    setup = CaseSetup(args.size, args.fit_probe, tuple(args.relight_probes), args.env_rows, 1, args.probes)
    t0 = time.perf_counter()
    result = run_measured_benchmark(materials, models, setup, scene_counts=tuple(args.scenes), noises=tuple(args.noise),
                                    seed=args.seed, cache_dir=Path(args.out) / "gt-cache", peer=args.peer,
                                    progress=not args.no_progress)
    result.phases["total"] = time.perf_counter() - t0
    print(format_report(result), flush=True)
    for path in write_outputs(result, Path(args.out)):
        print(f"wrote {path.resolve()}")
    return 0
