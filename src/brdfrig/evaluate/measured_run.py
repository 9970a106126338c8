"""The whole measured-materials benchmark: every material x model x scene count x noise level, with progress.

Per scene count and material: its ground truth is rendered (or read from the
cache), then every noise level is fitted (materials in a fixed random order, so
that the results so far, written to ``checkpoint``, and the progress bar's ETA are
a fair sample of the whole run): one ``auto`` fit
gives every candidate model (:func:`brdfrig.evaluate.measured.fit_all_and_relight`),
models it did not fit are fitted alone (fitter failures are recorded as failed cases); each fit is written as a
BRDF file under the output directory (:func:`brdfrig.evaluate.measured.fit_path`).  One untimed warm-up fit of
every model on a small subset of the first material's pixels runs in each process before its first timed fit
(numba kernels load, tables get built).  With ``workers`` > 1 the materials are shared out to Dask worker
processes of a local cluster (:func:`run_measured_benchmark`).  A run interrupted after some materials is
continued with ``--resume`` from the cases its checkpoint holds
(:func:`~brdfrig.evaluate.measured_report.load_partial`); those among the worst that ``worst.png`` shows are
relit again from their BRDF files (:func:`image_resumed`).  The optional peer (``--peer mitsuba``:
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
                                       fit_and_relight, find_materials, list_materials, make_cache, model_names,
                                       relight_fits, render_truth)
from brdfrig.fit.scene import Scene

__all__ = ["MeasuredResult", "run_measured_benchmark", "image_resumed", "run_from_args", "PEER_PREFIX"]

PEER_PREFIX = "peer:"
CPU_KEY = "CPU, all threads"
WARMUP_STRIDE = 23
"""The warm-up fits use every WARMUP_STRIDE-th pixel of the first material's sphere."""


@dataclass
class MeasuredResult:
    """Every case of a run, the setups, the references of the headline cases, and where the time went.

    ``phases`` maps a phase to seconds: wall seconds of each phase summed over the materials (over the
    ``workers`` processes side by side when more than one), ``"CPU, all threads"`` the process CPU seconds of
    the material runs, ``"total"`` the run's wall seconds (of every session of a resumed run).  ``truths`` maps
    ``(scenes, material name)`` to its :class:`Truth` (kept for the sphere images; none for the resumed runs).
    ``resumed``: material runs (material x scene count) taken from an earlier session's checkpoint.
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
    workers: int = 1
    seed: int = 0
    resumed: int = 0


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


def _robust(truth: Truth, model: str, noise: float, seed: int, keep: Path | None) -> CaseResult:
    """:func:`fit_and_relight`, a fit that raises recorded as a failed case (the run goes on)."""
    try:
        return fit_and_relight(truth, model, noise=noise, seed=seed, keep=keep)
    except Exception as exc:  # noqa: BLE001 - any model's bug must not end a long run; it is reported
        return failed_case(truth, model, noise, exc)


def _robust_peer(truth: Truth, model: str, noise: float, seed: int, peer_case) -> CaseResult:
    try:
        return peer_case(truth, noise, seed)
    except Exception as exc:  # noqa: BLE001
        return failed_case(truth, model, noise, exc)


def _robust_all(truth: Truth, models, noise: float, seed: int, keep: Path | None) -> list[CaseResult]:
    """:func:`fit_all_and_relight`, falling back to one fit per model when it raises."""
    try:
        return fit_all_and_relight(truth, models, noise=noise, seed=seed, keep=keep)
    except Exception:  # noqa: BLE001
        return [_robust(truth, m, noise, seed, keep) for m in models]


@dataclass
class _MaterialRun:
    """What :func:`_run_material` returns: the truth, its cases, seconds per phase, ground-truth cache use."""

    truth: Truth
    cases: list[CaseResult]
    phases: dict[str, float]
    cache_hits: int
    cache_misses: int


_WARMED: set = set()
"""Model tuples this process has warmed up (:func:`_warm_up`): once per process, the first material's pixels."""


def _phase_keys(count: int) -> tuple[str, str]:
    label = f"{count} scene{'s' if count > 1 else ''}"
    return f"ground truth, {label}", f"fits, {label}"


def _run_material(material: Material, setup: CaseSetup, models: tuple, noises: tuple, seed: int, cache_dir: Path | None,
                  peer: str | None, warm_up: bool, keep: Path | None, threads: int | None = None) -> _MaterialRun:
    """One material's ground truth (rendered or from the cache) and its fits at every noise level (and the peer's,
    one scene only).  ``keep``: the output directory the fits are written to (None: not kept);
    ``threads``: numba threads of this process (a Dask worker's share of the cores)."""
    if threads is not None:
        import numba

        numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    c0 = time.process_time()
    gt_key, fit_key = _phase_keys(setup.scenes)
    cache = make_cache() if cache_dir is None else make_cache(cache_dir)
    phases = {}
    t0 = time.perf_counter()
    truth = render_truth(material, setup, cache)
    phases[gt_key] = time.perf_counter() - t0
    if warm_up and models not in _WARMED:
        t0 = time.perf_counter()
        try:
            _warm_up(truth, models)
        except Exception:  # noqa: BLE001 - a failing model is reported by its timed fits
            pass
        _WARMED.add(models)
        phases["warm-up"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    cases = []
    for noise in noises:
        cases += _robust_all(truth, models, noise, seed, keep)
        if peer and setup.scenes == 1:  # the peer fits one image
            cases.append(_robust_peer(truth, PEER_PREFIX + peer, noise, seed, _peer_fit(peer)))
    phases[fit_key] = time.perf_counter() - t0
    phases[CPU_KEY] = time.process_time() - c0
    return _MaterialRun(truth, cases, phases, cache.hits, cache.misses)


def run_measured_benchmark(materials: list[Material], models, setup: CaseSetup = CaseSetup(), *,
                           scene_counts=(1,), noises=(0.0,), seed: int = 0, cache_dir: Path | None = None,
                           peer: str | None = None, progress: bool = True, warm_up: bool = True,
                           checkpoint=None, workers: int = 1, resume: MeasuredResult | None = None,
                           keep: Path | None = None) -> MeasuredResult:
    """Run every case (see module docstring).  ``setup.scenes`` is replaced by each of ``scene_counts``;
    ``warm_up=False`` skips the untimed warm-up fits; ``checkpoint(result)`` (if given) is called after
    each material's fits with the cases so far.  ``workers`` > 1: the materials are run by that many Dask worker
    processes on this machine (a local cluster), each with its share of the cores as numba threads.
    ``resume``: an earlier session's result of the same run (:func:`~brdfrig.evaluate.measured_report.load_partial`):
    its cases, times and cache counts are kept and its material runs are not run again.  ``keep``: an output
    directory where each case's fitted BRDF is written (:func:`~brdfrig.evaluate.measured.fit_path`; None: not kept)."""
    import os
    import sys

    from tqdm import tqdm

    t_start = time.perf_counter()
    models = tuple(models)
    known = model_names()
    bad = [m for m in models if m not in known]
    if bad:
        raise InputError(f"unknown model(s) {bad}; the fitter offers {list(known)}")
    if workers < 1:
        raise ValueError(f"workers must be at least 1, got {workers}")
    if peer:
        _peer_fit(peer)  # InputError now, not in every task
    result = MeasuredResult([], setup, tuple(scene_counts), tuple(noises), models + ((PEER_PREFIX + peer,) if peer else ()),
                            list(materials), workers=workers, seed=seed)
    for count in scene_counts:
        for key in _phase_keys(int(count)):
            result.phases[key] = 0.0
    finished = set()
    if resume is not None:
        result.cases += resume.cases
        for key, seconds in resume.phases.items():
            result.phases[key] = result.phases.get(key, 0.0) + seconds
        result.cache_hits, result.cache_misses = resume.cache_hits, resume.cache_misses
        finished = {(c.scenes, c.material) for c in resume.cases}
        result.resumed = len(finished)
    earlier = result.phases.get("total", 0.0)
    # A fixed random order: results so far (and the ETA) are a fair sample of all materials.
    order = [materials[k] for k in np.random.default_rng(0).permutation(len(materials))]
    jobs = [(replace(setup, scenes=int(count)), m) for count in scene_counts for m in order
            if (int(count), m.name) not in finished]
    desc = "materials" if len(scene_counts) == 1 else "materials x scene counts"
    bar = tqdm(total=len(jobs) + result.resumed, initial=result.resumed, desc=desc, unit="run", file=sys.stderr,
               disable=not progress, dynamic_ncols=True)

    def done(run: _MaterialRun) -> None:
        result.truths[(run.truth.setup.scenes, run.truth.material.name)] = run.truth
        result.cases += run.cases
        for key, seconds in run.phases.items():
            result.phases[key] = result.phases.get(key, 0.0) + seconds
        result.cache_hits += run.cache_hits
        result.cache_misses += run.cache_misses
        result.phases["total"] = earlier + time.perf_counter() - t_start
        bar.update()
        if checkpoint is not None:
            checkpoint(result)

    args = (models, tuple(noises), seed, cache_dir, peer, warm_up, keep)
    if workers == 1:
        for s, m in jobs:
            done(_run_material(m, s, *args))
    else:
        from dask.distributed import Client, LocalCluster, as_completed

        threads = max(1, (os.cpu_count() or 1) // workers)
        with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
                Client(cluster) as client:
            futures = [client.submit(_run_material, m, s, *args, threads, pure=False) for s, m in jobs]
            for fut in as_completed(futures):
                done(fut.result())
    bar.close()
    result.phases["total"] = earlier + time.perf_counter() - t_start
    return result


def image_resumed(result: MeasuredResult, out: Path, cache_dir: Path) -> int:
    """Relight again, under the headline probe, the resumed cases among the worst ``worst.png`` shows
    (:func:`~brdfrig.evaluate.measured_report.headline_cases` of
    :func:`~brdfrig.evaluate.measured_report.worst_model`), from their BRDF files under ``out`` and their ground
    truth (from the cache in ``cache_dir``, else rendered), so that the figure shows the worst of the whole run.

    A case is given its image (and ``result.truths`` its truth) only if its file reads and relights to the error
    the run recorded under that probe (relative difference below 1e-6); otherwise (missing, unreadable or changed)
    it stays without.  Returns how many were given."""
    from brdfrig.evaluate.measured_report import WORST_COUNT, headline_cases, worst_model
    from brdfrig.fit.brdffile import load_brdf

    model, probe = worst_model(result), result.setup.relight_probes[0]
    materials = {m.name: m for m in result.materials}
    cache = make_cache(cache_dir)
    given = 0
    for case in headline_cases(result, model)[:WORST_COUNT]:
        key = (case.scenes, case.material)
        if case.relit or not case.fit_file:
            continue
        try:
            brdf = load_brdf(Path(out) / case.fit_file)[0]
        except (InputError, OSError):
            continue
        truth = result.truths.get(key) or render_truth(materials[case.material], replace(result.setup, scenes=case.scenes),
                                                       cache)
        headline = replace(truth, relight={probe: truth.relight[probe]})
        errors, relit = relight_fits(headline, {model: brdf})[model]
        if abs(errors[probe] - case.errors[probe]) <= 1e-6 * case.errors[probe]:
            case.relit = relit
            result.truths[key] = truth
            given += 1
    return given


def run_from_args(args) -> int:
    """Run the benchmark from parsed options (:func:`brdfrig.evaluate.measured.add_arguments` + ``--out``,
    ``--probes``, ``--no-progress``), print the table and summary, write PNGs and JSON into ``--out``.

    An unfinished run in ``--out`` (its checkpoint, :data:`~brdfrig.evaluate.measured_report.PARTIAL_JSON`) is
    continued with ``--resume`` (the same options), and is never overwritten without it."""
    from brdfrig.evaluate.measured_report import PARTIAL_JSON, format_report, load_partial, setup_to_json, write_outputs, write_partial

    for name, value in (("--size", args.size), ("--env-rows", args.env_rows), ("--workers", args.workers)):
        if value < 1:
            raise InputError(f"{name} must be a positive integer, got {value}")
    for noise in args.noise:
        if not (np.isfinite(noise) and 0 <= noise < 1):
            raise InputError(f"--noise must be in [0, 1), got {noise}")
    out = Path(args.out)
    unfinished = (out / PARTIAL_JSON).exists()
    if unfinished and not args.resume:
        raise InputError(f"{out / PARTIAL_JSON} holds an unfinished run: continue it with --resume, or give another --out")
    if args.resume and not unfinished:
        raise InputError(f"--resume: {out} holds no unfinished run ({PARTIAL_JSON} is absent)")
    materials = (find_materials(args.materials, args.measured_dir) if args.materials
                 else list_materials(args.measured_dir))
    models = tuple(args.models) if args.models else model_names()
    setup = CaseSetup(args.size, args.fit_probe, tuple(args.relight_probes), args.env_rows, 1, args.probes,
                      args.arrangement)
    resume = None
    if unfinished:
        every = models + ((PEER_PREFIX + args.peer,) if args.peer else ())
        resume = load_partial(out, setup_to_json(setup, args.scenes, args.noise, every, args.seed),
                              [m.name for m in materials])
    cache_dir = args.cache or out / "gt-cache"
    result = run_measured_benchmark(materials, models, setup, scene_counts=tuple(args.scenes), noises=tuple(args.noise),
                                    seed=args.seed, cache_dir=cache_dir, peer=args.peer,
                                    progress=not args.no_progress, warm_up=not args.no_warm_up,
                                    checkpoint=lambda r: write_partial(r, out), workers=args.workers, resume=resume, keep=out)
    if resume is not None:
        print("worst.png: relighting the resumed cases among the worst from their BRDF files ...", flush=True)
        print(f"worst.png: {image_resumed(result, out, cache_dir)} resumed case(s) relit", flush=True)
    print(format_report(result), flush=True)
    for path in write_outputs(result, out):
        print(f"wrote {path.resolve()}")
    return 0
