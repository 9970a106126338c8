"""From a stored session to fitted BRDFs: verify, merge, unwrap the probe, sample the spheres, fit, report.

Stages (each a function, so tests and the demo can run them separately):

1. :func:`open_verified` - open the session and verify every raw file against
   the manifest; refuse (``ValueError`` naming the files) if any fails.
2. :func:`merge_frames` - merge each (scene, table angle) bracket with
   ``brdfrig.hdr.bracket.merge_files`` (the path of ``brdfrig merge``); results are cached in ``DIR/cache`` under the
   sha256 of the raw files' hashes, exposure times and merge settings, so a
   refit reuses every merge whose inputs did not change.
3. :func:`scene_lighting` - unwrap the probe of each frame with
   ``brdfrig.hdr.probe.unwrap_probe`` and combine the table rotations of a scene with
   ``brdfrig.hdr.probe.average_rotations`` (robust to blemishes) into an
   ``brdfrig.fit.scene.Environment``.
4. :func:`sample_scenes` - pixels, normals and limb weights of each sample
   sphere from ``brdfrig.hdr.sphere.sphere_pixels``; pixels saturated or dark in every
   exposure get weight 0.
5. :func:`run_pipeline` - fit each sample with ``brdfrig.fit.fitter.fit_brdf``, save the
   BRDF (``brdfrig.fit.brdffile.save_brdf``), a figure like the seed's figure 6
   (``brdfrig.report.figures``) and ``stats.json`` in a fresh ``results/fit-NNN``.
"""

from __future__ import annotations

import hashlib
import json
import sys
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from brdfrig.errors import ConfigError, StoreError
from brdfrig.session.config import FitPreset, SessionConfig, stored_session_config
from brdfrig._atomic import write_bytes as atomic_write_bytes
from brdfrig.session.store import SessionStore, check_shot_entry
from brdfrig.fit.brdffile import jsonable
from brdfrig.fit.metrics import relative_rms
from brdfrig.fit.report import FitReport, summary_line

__all__ = [
    "MergedFrame",
    "SampleResult",
    "PipelineResult",
    "open_verified",
    "merge_frames",
    "scene_lighting",
    "sample_scenes",
    "run_pipeline",
    "MERGE_CACHE_VERSION",
]

#: Bump when the merge's inputs or settings change meaning: old cache entries are then ignored.
MERGE_CACHE_VERSION = 2


@dataclass(frozen=True)
class MergedFrame:
    """A merged bracket: radiance (H, W, C) float32 (frame units per second) and usable-sample mask (H, W, C)."""

    radiance: np.ndarray
    usable: np.ndarray
    cached: bool = False


@dataclass
class SampleResult:
    """Fit of one sample: the BRDF, the fit report, the BRDF file and figure written, summary statistics."""

    name: str
    brdf: object
    report: FitReport
    brdf_path: Path
    figure_path: Path | None
    stats: dict


@dataclass
class PipelineResult:
    """Everything one pipeline run produced."""

    results_dir: Path
    samples: list[SampleResult] = field(default_factory=list)
    merged: int = 0
    merged_from_cache: int = 0
    scenes: list = field(default_factory=list)


def open_verified(session_dir: str | Path) -> tuple[SessionStore, SessionConfig]:
    """Open a session and verify its raw files against the manifest.

    Raises
    ------
    ValueError
        If any file listed in the manifest is missing or fails its sha256 (all named),
        or the session is not complete (shots missing: run ``brdfrig capture resume``).
    """
    store = SessionStore.open(session_dir)
    check = store.verify(prefix="raw/")
    if not check.passed:
        raise StoreError(
            f"session {store.root} fails verification, refusing to process it: {check.describe()} "
            "(restore the files from a backup, or `brdfrig capture resume` to shoot them again)"
        )
    config = stored_session_config(store.config, str(store.root / "session.json"))
    return store, config


def _exposure_files(store: SessionStore) -> dict[tuple[int, float], list[tuple[str, dict]]]:
    """Stored exposure files grouped by (scene, angle), as (relative path, manifest entry)."""
    groups: dict[tuple[int, float], list[tuple[str, dict]]] = {}
    for rel, e in sorted(store.files.items()):
        if e.get("kind") == "exposure":
            check_shot_entry(rel, e, store.root / "manifest.json", required=("key", "scene", "angle_deg"))
            groups.setdefault((e["scene"], e["angle_deg"]), []).append((rel, e))
    return groups


def check_complete(store: SessionStore, config: SessionConfig) -> None:
    """Raise ``ValueError`` if a (scene, angle) of the plan has no stored exposure."""
    groups = _exposure_files(store)
    missing = [
        f"scene {s + 1} angle {a:g}" for s in range(config.plan.scenes) for a in config.table_angles(s)
        if (s, a) not in groups
    ]
    if missing:
        raise StoreError(
            f"session {store.root} is incomplete ({', '.join(missing)} not shot): "
            f"finish it with `brdfrig capture resume {store.root}`"
        )


def merge_policy(config: SessionConfig):
    """The ``brdfrig.hdr.bracket.MergePolicy`` of a session: the defaults of ``brdfrig merge`` with the camera's
    noise model (``[rig.camera] full_well_e``, ``read_noise_e``)."""
    from brdfrig.hdr.bracket import MergePolicy

    cam = config.rig.camera
    return MergePolicy(full_well=cam.full_well_e, read_noise=cam.read_noise_e, colour_space=cam.colour_space)


def merge_files(paths: list[Path], full_well_e: float, read_noise_e: float, colour_space: str = "camera"
                ) -> MergedFrame:
    """Merge one bracket of camera files with ``brdfrig.hdr.bracket.merge_files`` (the path of ``brdfrig merge``).

    Times come from the files' metadata; ``usable`` is False where every
    exposure was dark or saturated.
    """
    from brdfrig.hdr.bracket import MergePolicy
    from brdfrig.hdr.bracket import merge_files as merge_bracket_files
    from brdfrig.hdr.merge import FLAG_DARK, FLAG_SATURATED

    policy = MergePolicy(full_well=full_well_e, read_noise=read_noise_e, colour_space=colour_space)
    merged = merge_bracket_files(paths, policy).merge
    usable = (merged.flags != FLAG_DARK) & (merged.flags != FLAG_SATURATED)
    return MergedFrame(merged.radiance, usable)


def merge_frames(store: SessionStore, config: SessionConfig, *, progress: bool = True
                 ) -> dict[tuple[int, float], MergedFrame]:
    """Merge every (scene, angle) bracket, reusing ``DIR/cache`` entries keyed by content hash."""
    from tqdm import tqdm

    from brdfrig.hdr.exr import read_exr, write_exr

    policy = merge_policy(config)
    settings = {**asdict(policy), "version": MERGE_CACHE_VERSION}
    out = {}
    groups = _exposure_files(store)
    for (scene, angle), files in tqdm(groups.items(), desc="merge brackets", unit="frame", file=sys.stderr,
                                      disable=not progress, dynamic_ncols=True):
        key = hashlib.sha256(
            json.dumps({"files": [e["sha256"] for _, e in files], **settings}, sort_keys=True).encode()
        ).hexdigest()[:32]
        cache = store.root / "cache" / f"merge-{key}.exr"
        if cache.is_file():
            try:
                rgb, extra, _ = read_exr(cache)
                out[(scene, angle)] = MergedFrame(rgb, extra["usable"].reshape(rgb.shape) > 0.5, cached=True)
                continue
            except (ValueError, OSError, KeyError):
                pass  # unreadable cache entry: merge again and replace it
        merged = merge_files([store.root / rel for rel, _ in files], policy.full_well, policy.read_noise,
                             policy.colour_space)
        write_exr(cache, merged.radiance, extra_channels={"usable": merged.usable.astype(np.float32)},
                  attributes={"cache_key": key})
        out[(scene, angle)] = merged
    return out


def scene_lighting(config: SessionConfig, merged: dict[tuple[int, float], MergedFrame], scene: int):
    """The ``Environment`` of one scene from its probe frames (table rotations averaged robustly)."""
    from brdfrig.hdr.probe import combine_probe
    from brdfrig.lighting import environment_from_probe

    probe = config.plan.probe
    if probe.circle is None:
        raise ValueError(f"[plan.probe] of {config.source} has no 'circle' = [cx, cy, r]")
    frames = [merged[(scene, a)] for a in config.table_angles(scene)]
    unusable = ~np.all([f.usable.all(axis=-1) for f in frames], axis=0)
    capture = combine_probe([f.radiance for f in frames], [probe.circle], albedo=probe.albedo,
                            names=[f"scene {scene + 1} probe at {a:g} deg" for a in config.table_angles(scene)])
    return environment_from_probe(capture, mask=unusable, rim=probe.rim, name=f"scene {scene + 1} probe")


def sample_scenes(config: SessionConfig, merged: dict[tuple[int, float], MergedFrame], envs: list,
                  ) -> dict[str, tuple[list, object]]:
    """Per sample name: one ``brdfrig.fit.scene.Scene`` per scene (frames of a scene's table angles averaged),
    and the ``brdfrig.hdr.sphere.SpherePixels`` (rows, cols) of its pixels."""
    from brdfrig.fit.scene import Scene
    from brdfrig.hdr.sphere import sphere_pixels

    out: dict[str, tuple[list, object]] = {}
    for sample in config.plan.samples:
        if sample.circle is None:
            raise ConfigError(f"[[plan.samples]] {sample.name!r} of {config.source} has no 'circle' = [cx, cy, r]")
        shape = next(iter(merged.values())).radiance.shape[:2]
        px = sphere_pixels(shape, sample.circle)
        scenes = []
        for s, env in enumerate(envs):
            frames = [merged[(s, a)] for a in config.table_angles(s)]
            rad = np.mean([f.radiance[px.rows, px.cols] for f in frames], axis=0).astype(np.float64)
            usable = np.all([f.usable[px.rows, px.cols].all(axis=-1) for f in frames], axis=0)
            weights = np.where(usable & np.all(np.isfinite(rad), axis=1), px.weights, 0.0)
            scenes.append(Scene(env, np.asarray(px.normals, np.float64), np.nan_to_num(rad), weights))
        out[sample.name] = (scenes, px)
    return out


def run_pipeline(session_dir: str | Path, fit: FitPreset | None = None, *, progress: bool = True,
                 echo: Callable[[str], None] = print, figures: bool = True,
                 batch_id: str | None = None) -> PipelineResult:
    """Verify, merge (cached), build the scenes, fit every sample, and write BRDF files, figures and stats.

    ``figures=False`` skips the PNG figures (``SampleResult.figure_path`` is then None);
    ``batch_id`` is stored in ``stats.json`` (see :mod:`brdfrig.session.refit`).
    The caller holds the session's writer lock.
    """
    from tqdm import tqdm

    from brdfrig.report.figures import fit_figure
    from brdfrig.fit.brdffile import save_brdf
    from brdfrig.fit.fitter import fit_brdf

    store, config = open_verified(session_dir)
    check_complete(store, config)
    fit = fit or config.fit
    merged = merge_frames(store, config, progress=progress)
    n_cached = sum(m.cached for m in merged.values())
    echo(f"merged {len(merged)} brackets ({n_cached} reused from the cache)")
    envs = [scene_lighting(config, merged, s)
            for s in tqdm(range(config.plan.scenes), desc="unwrap probe", unit="scene", file=sys.stderr,
                          disable=not progress, dynamic_ncols=True)]
    per_sample = sample_scenes(config, merged, envs)
    results_dir = store.staging_results_dir()  # renamed to results/fit-NNN only once complete
    result = PipelineResult(results_dir, merged=len(merged), merged_from_cache=n_cached, scenes=envs)
    stats_all = {"session": str(store.root), "fit": asdict(fit), "batch": batch_id,
                 "colour_space": config.rig.camera.colour_space, "merged": len(merged), "merged_from_cache": n_cached,
                 "samples": {}}
    for name, (scenes, pixels) in per_sample.items():
        echo(f"fitting {name}: {len(scenes)} scene(s), model {fit.model}, lmax {fit.lmax}, pmax {fit.pmax}, "
             f"solver {fit.solver}")
        res = fit_brdf(scenes, model=fit.model, lmax=fit.lmax, pmax=fit.pmax, solver=fit.solver, progress=progress,
                       estimate=True)
        brdf_path = results_dir / f"{name}.brdf.json"
        report = res.report
        save_brdf(brdf_path, res.brdf, report,
                  provenance={"session": str(store.root), "sample": name},
                  colour_space=config.rig.camera.colour_space)
        own = []
        for s in scenes:
            w = s.weights > 0
            pred = res.brdf.predict(s.env, s.normals[w])
            own.append(relative_rms(pred, s.radiance[w]))
        stats = {"model": res.brdf.model, "scenes": len(scenes), "self_relative_rms": own,
                 "self_relative_rms_mean": float(np.mean(own))}
        figure_path = results_dir / f"{name}.png" if figures else None
        if figures:
            fit_figure(figure_path, scenes, pixels, res.brdf,
                       title=f"{name}: {res.brdf.model} fit, lmax {fit.lmax}, {len(scenes)} scene(s)")
        result.samples.append(SampleResult(name, res.brdf, report, brdf_path, figure_path, stats))
        stats_all["samples"][name] = {**stats, "brdf": brdf_path.name, "figure": figure_path and figure_path.name,
                                      "report": jsonable(report)}
        if not result.samples[:-1]:
            echo(report.identifiability_summary)  # depends on the lighting only: the same for every sample
        echo(f"  {name}: {summary_line(report)}; image error {100 * stats['self_relative_rms_mean']:.2f}% "
             f"(relative RMS over {len(scenes)} scene(s)) -> {brdf_path}")
        for warning in report.warnings:
            echo(f"  {name}: warning: {warning}")
    if figures:
        from brdfrig.report.html import SampleReport, write_report

        write_report(results_dir / "report.html", f"brdfrig session {config.name}: {results_dir.name}",
                     [SampleReport(s.name, s.brdf, stats_all["samples"][s.name]["report"], s.figure_path.read_bytes())
                      for s in result.samples], notes=str(store.root))
        stats_all["report"] = "report.html"
    atomic_write_bytes(results_dir / "stats.json", json.dumps(jsonable(stats_all), indent=1).encode())
    result.results_dir = results_dir = store.commit_results(results_dir)
    for sample in result.samples:
        sample.brdf_path = results_dir / sample.brdf_path.name
        sample.figure_path = sample.figure_path and results_dir / sample.figure_path.name
    store.append("fit", results=str(results_dir.relative_to(store.root)), fit=stats_all["fit"],
                 samples={k: v["model"] for k, v in stats_all["samples"].items()})
    return result
