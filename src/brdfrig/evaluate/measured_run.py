"""The whole measured-materials benchmark: every material x model x scene count x noise level, with progress.

Per scene count and material: its ground truth is rendered (or read from the
cache), then every noise level is fitted (materials in a fixed random order, so
that the results so far, written to ``checkpoint``, and the progress bar's ETA are
a fair sample of the whole run): one ``auto`` fit
gives every candidate model (:func:`brdfrig.evaluate.measured.fit_all_and_relight`),
models it did not fit are fitted alone (fitter failures are recorded as failed cases).  One untimed warm-up fit of every model on a
small subset of the first material's pixels runs before the first timed fit (numba
kernels load, tables get built).  The optional peer (``--peer mitsuba``:
:mod:`brdfrig.evaluate.mitsuba_peer`) fits Mitsuba's ``principled`` BSDF to the
same (noisy) pixels of the first scene, in one-scene runs only, and is relit by
Mitsuba: one more "model" named ``peer:mitsuba``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from brdfrig.errors import InputError
from brdfrig.evaluate.measured import (CaseResult, CaseSetup, Material, Truth, failed_case, fit_all_and_relight,
                                       fit_and_relight, find_materials, list_materials, make_cache, model_names, render_truth)
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
    """``truth, noise, seed -> CaseResult`` of a peer (InputError when it is not installed)."""
    if name != "mitsuba":
        raise InputError(f"unknown peer {name!r} (known: mitsuba)")
    try:
        import mitsuba  # noqa: F401

        from brdfrig.evaluate import mitsuba_peer  # noqa: F401
    except ImportError as exc:
        raise InputError(f"--peer mitsuba needs brdfrig.evaluate.mitsuba_peer and Mitsuba 3 ({exc})") from exc
    return _mitsuba_case


def _mitsuba_case(truth: Truth, noise: float, seed: int) -> CaseResult:
    """Mitsuba's ``principled`` BSDF fitted to the first fit scene's image (:func:`~brdfrig.evaluate.mitsuba_peer.fit_principled`)
    and relit by Mitsuba under each relight probe; ``fit_seconds`` is the peer's own fit time."""
    from brdfrig.evaluate.measured import noisy_scenes
    from brdfrig.evaluate.mitsuba_peer import fit_principled, render_principled
    from brdfrig.fit.metrics import relative_rms

    size = truth.setup.size
    scene = noisy_scenes(truth.scenes[:1], noise, seed)[0]
    image = np.zeros((size, size, 3))
    image[truth.rows, truth.cols] = np.maximum(scene.radiance, 0.0)
    c0 = time.process_time()
    params, seconds = fit_principled(image, scene.env.latlong.image)
    cpu = time.process_time() - c0
    errors, relit = {}, {}
    for probe, (env, reference) in truth.relight.items():
        relit[probe] = render_principled(params, env.latlong.image, size)[truth.rows, truth.cols]
        errors[probe] = relative_rms(relit[probe], reference, truth.weights)
    m = truth.material
    return CaseResult(m.name, PEER_PREFIX + "mitsuba", "principled", truth.setup.scenes, float(noise), errors, seconds,
                      None, m.held_out, cpu_seconds=cpu, relit=relit)


def _warm_up(truth: Truth, models) -> None:
    """Untimed fits of ``models`` on every WARMUP_STRIDE-th pixel of ``truth`` (compiles kernels, builds tables)."""
    sub = slice(None, None, WARMUP_STRIDE)
    scenes = [Scene(s.env, s.normals[sub], s.radiance[sub], s.weights[sub]) for s in truth.scenes[:1]]
    small = replace(truth, scenes=scenes, normals=truth.normals[sub], weights=truth.weights[sub],
                    relight={k: (e, r[sub]) for k, (e, r) in truth.relight.items()})
    fit_all_and_relight(small, models)


def _robust(truth: Truth, model: str, noise: float, seed: int, fit=None) -> CaseResult:
    """:func:`fit_and_relight`, a fit that raises recorded as a failed case (the run goes on)."""
    try:
        return fit_and_relight(truth, model, noise=noise, seed=seed, fit=fit)
    except Exception as exc:  # noqa: BLE001 - any model's bug must not end a long run; it is reported
        return failed_case(truth, model, noise, exc)


def _robust_peer(truth: Truth, model: str, noise: float, seed: int, peer_case) -> CaseResult:
    try:
        return peer_case(truth, noise, seed)
    except Exception as exc:  # noqa: BLE001
        return failed_case(truth, model, noise, exc)


def _robust_all(truth: Truth, models, noise: float, seed: int) -> list[CaseResult]:
    """:func:`fit_all_and_relight`, falling back to one fit per model when it raises."""
    try:
        return fit_all_and_relight(truth, models, noise=noise, seed=seed)
    except Exception:  # noqa: BLE001
        return [_robust(truth, m, noise, seed) for m in models]


def run_measured_benchmark(materials: list[Material], models, setup: CaseSetup = CaseSetup(), *,
                           scene_counts=(1,), noises=(0.0,), seed: int = 0, cache_dir: Path | None = None,
                           peer: str | None = None, progress: bool = True, warm_up: bool = True,
                           checkpoint=None) -> MeasuredResult:
    """Run every case (see module docstring).  ``setup.scenes`` is replaced by each of ``scene_counts``;
    ``warm_up=False`` skips the untimed warm-up fits; ``checkpoint(result)`` (if given) is called after
    each material's fits with the cases so far."""
    from tqdm import tqdm

    models = tuple(models)
    known = model_names()
    bad = [m for m in models if m not in known]
    if bad:
        raise InputError(f"unknown model(s) {bad}; the fitter offers {list(known)}")
    peers = {PEER_PREFIX + peer: _peer_fit(peer)} if peer else {}
    cache = make_cache() if cache_dir is None else make_cache(cache_dir)
    result = MeasuredResult([], setup, tuple(scene_counts), tuple(noises), models + tuple(peers), list(materials))
    phases = result.phases
    for count in scene_counts:
        s = replace(setup, scenes=int(count))
        label = f"{count} scene{'s' if count > 1 else ''}"
        gt_key, fit_key = f"ground truth, {label}", f"fits, {label}"
        phases[gt_key] = phases[fit_key] = 0.0
        # A fixed random order: results so far (and the ETA) are a fair sample of all materials.
        order = [materials[k] for k in np.random.default_rng(0).permutation(len(materials))]
        for i, m in enumerate(tqdm(order, desc=label, unit="material", disable=not progress)):
            t0 = time.perf_counter()
            truth = result.truths[(count, m.name)] = render_truth(m, s, cache)
            phases[gt_key] += time.perf_counter() - t0
            if warm_up and i == 0 and count == scene_counts[0]:
                t0 = time.perf_counter()
                try:
                    _warm_up(truth, models)
                except Exception:  # noqa: BLE001 - a failing model is reported by its timed fits
                    pass
                phases["warm-up"] = time.perf_counter() - t0
            t0 = time.perf_counter()
            for noise in noises:
                result.cases += _robust_all(truth, models, noise, seed)
                for model, peer_case in peers.items():
                    if count == 1:  # the peer fits one image
                        result.cases.append(_robust_peer(truth, model, noise, seed, peer_case))
            phases[fit_key] += time.perf_counter() - t0
            if checkpoint is not None:
                checkpoint(result)
    result.cache_hits, result.cache_misses = cache.hits, cache.misses
    return result


def run_from_args(args) -> int:
    """Run the benchmark from parsed options (:func:`brdfrig.evaluate.measured.add_arguments` + ``--out``,
    ``--probes``, ``--no-progress``), print the table and summary, write PNGs and JSON into ``--out``."""
    from brdfrig.evaluate.measured_report import format_report, write_outputs, write_partial

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
    t0, c0 = time.perf_counter(), time.process_time()
    result = run_measured_benchmark(materials, models, setup, scene_counts=tuple(args.scenes), noises=tuple(args.noise),
                                    seed=args.seed, cache_dir=args.cache or Path(args.out) / "gt-cache", peer=args.peer,
                                    progress=not args.no_progress, warm_up=not args.no_warm_up,
                                    checkpoint=lambda r: write_partial(r, Path(args.out)))
    result.phases["total"] = time.perf_counter() - t0
    result.phases["total CPU (all threads)"] = time.process_time() - c0
    print(format_report(result), flush=True)
    for path in write_outputs(result, Path(args.out)):
        print(f"wrote {path.resolve()}")
    return 0
