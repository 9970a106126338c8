"""Measured-materials benchmark: fit a sphere of a real material under one probe, relight it under others.

The standard case (issue 10; everyone tuning a model calls :func:`relight_case`):

- a sphere of ``size`` px (radius ``size/2``, MATH.md image convention), its pixels
  from :func:`brdfrig.hdr.sphere.sphere_pixels` (limb pixels with weight 0 are left out);
- ground truth: the material rendered by its ground-truth renderer (measured
  materials: :mod:`brdfrig.fit.groundtruth` with the sharp-lobe quadrature; analytic
  ones: :func:`brdfrig.fit.groundtruth.render_groundtruth`) under the fit probe
  box-downsampled to ``2 env_rows x env_rows`` (:func:`brdfrig.evaluate.probes.probe_environment`),
  and under each relight probe; renders are cached on disk
  (:class:`brdfrig.evaluate.cache.CachedGroundTruth`, keyed by the material file's
  sha256, every input and the renderer's source);
- ``scenes`` > 1, ``arrangement`` "turns" (default): the fit lighting turned about +y by
  ``30 k`` degrees, k = 0 .. scenes-1 (a rig on a turntable); "tilts": the fit lighting
  itself, then tilted about +x by each of :data:`TILT_DEG` in turn (a rig tilted, or set up
  again elsewhere in the room: lighting from other elevations, which turns never give);
- noise: each fitted pixel value times ``1 + noise * N(0, 1)`` (per channel, seeded);
- the model is fitted by :func:`brdfrig.fit.fitter.fit_brdf` (wall clock timed) and
  relit (``brdf.predict``) under each relight probe; the error is the relative RMS
  over the sphere's pixels (:func:`brdfrig.fit.metrics.relative_rms`, pixel weights).

Materials: every ``*.h5`` neural fit (or MERL ``.binary``) under ``rgl/`` and
``nielsen/`` of :data:`MEASURED_DIR`, named ``group/stem`` (``_rgb`` dropped); the
``nielsen`` group is held out from tuning (:data:`HELD_OUT_GROUPS`).

Module CLI (also ``brdfrig bench --measured``)::

    python -m brdfrig.evaluate.measured --materials rgl/acrylic_felt_green,nielsen/cardboard \\
        --models auto,microfacet --scenes 1 --noise 0.01 --out measured-out

Without ``--scenes``/``--noise`` the run is the whole benchmark: one and twelve
scenes, noise-free and 1% noise.
"""

from __future__ import annotations

import argparse
import hashlib
import math
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from brdfrig.errors import InputError
from brdfrig.evaluate.cache import CachedGroundTruth, brdf_identity
from brdfrig.evaluate.probes import DEFAULT_PROBE_DIR, probe_environment, probe_turn
from brdfrig.fit.metrics import relative_rms
from brdfrig.fit.rotation import axis_rotation
from brdfrig.fit.scene import Environment, Scene

__all__ = [
    "MEASURED_DIR",
    "HELD_OUT_GROUPS",
    "DEFAULT_CACHE_DIR",
    "Material",
    "CaseSetup",
    "Truth",
    "CaseResult",
    "model_names",
    "list_materials",
    "find_materials",
    "scene_rotations",
    "scene_label",
    "render_truth",
    "fit_and_relight",
    "fit_all_and_relight",
    "relight_fits",
    "fit_path",
    "FITS_DIR",
    "failed_case",
    "relight_case",
    "main",
]

MEASURED_DIR = Path(__file__).resolve().parents[4] / "shared" / "data" / "measured"
"""``../shared/data/measured`` beside the source tree (``rgl/``, ``nielsen/``)."""
HELD_OUT_GROUPS = ("nielsen",)
"""Material groups kept out of tuning (a user's materials): reported separately."""
DEFAULT_CACHE_DIR = Path(tempfile.gettempdir()) / "brdfrig-gt-cache"
"""Where :func:`relight_case` caches ground-truth renders unless told otherwise (shared by callers on this machine)."""
TURN_DEG = 30.0
"""Angle between turned scenes (degrees about +y)."""
TILT_DEG = (45.0, -45.0, 90.0)
"""Tilts (degrees about +x) of the second, third and fourth scenes of the "tilts" arrangement."""
ARRANGEMENTS = ("turns", "tilts")
"""How the scenes after the first light the sphere (see the module docstring)."""
FITS_DIR = "fits"
"""Subdirectory of a run's output where each case's fitted BRDF is kept (:func:`fit_path`)."""
MATERIAL_SUFFIXES = (".h5", ".binary")


def model_names() -> tuple[str, ...]:
    """Every model the fitter offers, ``auto`` first (the fitter's registry; never listed here)."""
    from brdfrig.fit.registry import MODELS

    return tuple(MODELS)


@dataclass
class Material:
    """A material of the benchmark: a measured file (loaded on first use) or an in-memory BRDF.

    Attributes
    ----------
    name : str
        ``group/stem`` for files (``rgl/acrylic_felt_green``), any label otherwise.
    path : Path or None
        The measured file (neural ``.h5`` with its ``.json``, or MERL ``.binary``).
    brdf : object or None
        The BRDF (loaded from ``path`` on first use when None).
    held_out : bool
        Kept out of tuning (``nielsen`` group).
    """

    name: str
    path: Path | None = None
    brdf: object = None
    held_out: bool = False
    _identity: bytes | None = field(default=None, repr=False)

    @classmethod
    def from_path(cls, path: str | Path) -> "Material":
        path = Path(path)
        if not path.is_file():
            raise InputError(f"measured material {path} does not exist")
        stem = path.stem[: -len("_rgb")] if path.stem.endswith("_rgb") else path.stem
        group = path.parent.name
        return cls(f"{group}/{stem}", path, None, group in HELD_OUT_GROUPS)

    def load(self):
        """The material's BRDF (read with :func:`brdfrig.fit.measured.load_measured` on first use)."""
        if self.brdf is None:
            from brdfrig.fit.measured import load_measured

            self.brdf = load_measured(self.path)
        return self.brdf

    @property
    def stacks_lightings(self) -> bool:
        """Whether the BRDF renders under stacked lightings (:class:`~brdfrig.evaluate.cache.CachedGroundTruth`)."""
        return bool(getattr(self.load(), "stacks_lightings", False))

    def identity(self) -> bytes:
        """Cache identity: sha256 of the file (and its ``.json`` beside it), else of the BRDF's values, and of
        the source of the modules that render it (:func:`_renderer_sources`)."""
        if self._identity is None:
            h = hashlib.sha256()
            for module in _renderer_sources(self.path is not None):
                h.update(Path(module.__file__).read_bytes())
            if self.path is None:
                h.update(brdf_identity(self.brdf))
            else:
                h.update(self.path.read_bytes())
                side = self.path.with_suffix(".json")
                if side.is_file():
                    h.update(side.read_bytes())
            self._identity = h.digest()
        return self._identity


def list_materials(root: str | Path = MEASURED_DIR) -> list[Material]:
    """Every measured material under ``root`` (``group/NAME.h5`` or ``.binary``), sorted by name."""
    root = Path(root)
    if not root.is_dir():
        raise InputError(f"measured-materials directory {root} does not exist")
    paths = sorted(p for p in root.glob("*/*") if p.suffix in MATERIAL_SUFFIXES)
    if not paths:
        raise InputError(f"no measured materials (*/*.h5, */*.binary) under {root}")
    return [Material.from_path(p) for p in paths]


def find_materials(names, root: str | Path = MEASURED_DIR) -> list[Material]:
    """The materials named (``group/stem``, or a bare stem when unambiguous), in the order given."""
    every = list_materials(root)
    by_name = {m.name: m for m in every}
    out = []
    for name in names:
        hits = [by_name[name]] if name in by_name else [m for m in every if m.name.split("/", 1)[1] == name]
        if len(hits) != 1:
            what = "matches several" if hits else "matches no"
            raise InputError(f"material {name!r} {what} material under {root} (e.g. {every[0].name})")
        out.append(hits[0])
    return out


def _render_material(material: Material, normals: np.ndarray, env: Environment) -> np.ndarray:
    """Ground-truth render of a :class:`Material` seen from +z.

    Analytic families: :func:`brdfrig.fit.groundtruth.render_groundtruth` (cell-centre quadrature);
    measured ones: their ``predict``, the sharp-lobe quadrature render of the MERL table
    (:func:`brdfrig.fit.groundtruth.render_tabulated`; a network is tabulated first).
    """
    from brdfrig.fit.groundtruth import render_groundtruth

    brdf = material.load()
    if hasattr(brdf, "kernel_params"):
        return render_groundtruth(brdf, normals, env)
    return brdf.predict(env, normals)


def _renderer_sources(measured: bool):
    """Modules whose source decides a ground-truth render (measured: table render; else analytic kernels)."""
    from brdfrig.fit import analytic, groundtruth, rho

    if not measured:
        return (groundtruth, analytic, rho)
    from brdfrig.fit import measured as measured_module
    from brdfrig.fit import merl, quadrature

    return (groundtruth, quadrature, measured_module, merl)


def make_cache(directory: str | Path = DEFAULT_CACHE_DIR) -> CachedGroundTruth:
    """The disk cache of :class:`Material` renders in ``directory`` (keys: :meth:`Material.identity` and the inputs)."""
    return CachedGroundTruth(Path(directory), render=_render_material, sources=())


@dataclass(frozen=True)
class CaseSetup:
    """Geometry and lighting of a benchmark case (defaults: the issue's standard case).

    A relight probe that is the lighting of one of the fit scenes (the fit probe itself, or turned as a turned or
    tilted scene is: ``grace@y180`` with twelve turns) is refused: its error would be the fit's own residual.
    """

    size: int = 96
    fit_probe: str = "grace"
    relight_probes: tuple[str, ...] = ("ennis", "pisa")
    env_rows: int = 64
    scenes: int = 1
    probe_dir: Path = DEFAULT_PROBE_DIR
    arrangement: str = "turns"

    def __post_init__(self) -> None:
        if not (isinstance(self.size, (int, np.integer)) and self.size >= 4):
            raise InputError(f"sphere size must be an integer >= 4 pixels, got {self.size!r}")
        if self.arrangement not in ARRANGEMENTS:
            raise InputError(f"scene arrangement must be one of {', '.join(ARRANGEMENTS)}, got {self.arrangement!r}")
        most = int(360 / TURN_DEG) if self.arrangement == "turns" else 1 + len(TILT_DEG)
        if not (isinstance(self.scenes, (int, np.integer)) and 1 <= self.scenes <= most):
            raise InputError(f"scenes must be an integer in 1..{most} for {self.arrangement}, got {self.scenes!r}")
        if not self.relight_probes:
            raise InputError("at least one relight probe is needed")
        for probe in self.relight_probes:
            scene = _fit_scene_of(self, probe)
            if scene is not None:
                raise InputError(f"relight probe {probe!r} is the lighting of fit scene {scene + 1} of {self.scenes} "
                                 f"({self.fit_probe} {self.arrangement}): its error would be how the fit reproduces its "
                                 "own image, not relighting; name a lighting no fit scene shows")


@dataclass
class Truth:
    """Ground truth of one material under one :class:`CaseSetup`: sphere pixels, fit scenes, relit references.

    ``rows``/``cols`` place the pixels in the ``size x size`` image; ``scenes`` hold the
    noise-free fit renders; ``relight`` maps a probe name to ``(env, (N, 3) reference radiance)``.
    """

    material: Material
    setup: CaseSetup
    rows: np.ndarray
    cols: np.ndarray
    normals: np.ndarray
    weights: np.ndarray
    scenes: list[Scene]
    relight: dict[str, tuple[Environment, np.ndarray]]


def _sphere(size: int):
    from brdfrig.hdr.sphere import sphere_pixels

    px = sphere_pixels((size, size), (size / 2, size / 2, size / 2))
    seen = px.weights > 0
    return px.rows[seen], px.cols[seen], np.ascontiguousarray(px.normals[seen]), px.weights[seen]


def scene_rotations(setup: CaseSetup) -> list[np.ndarray | None]:
    """The rotation of the fit lighting in each scene of ``setup`` (None: the probe as captured)."""
    if setup.arrangement == "turns":
        return [None] + [axis_rotation("y", TURN_DEG * k) for k in range(1, setup.scenes)]
    return [None] + [axis_rotation("x", deg) for deg in TILT_DEG[: setup.scenes - 1]]


def _fit_scene_of(setup: CaseSetup, probe: str) -> int | None:
    """Index of the fit scene of ``setup`` lit as the relight ``probe`` (the fit probe turned as that scene, to
    1e-9), or None."""
    name, rotation = probe_turn(probe)
    if name != str(setup.fit_probe):
        return None
    for k, r in enumerate(scene_rotations(setup)):
        if np.allclose(rotation, np.eye(3) if r is None else r, rtol=0.0, atol=1e-9):
            return k
    return None


def scene_label(scenes: int, arrangement: str = "turns") -> str:
    """``"1 scene"``, ``"12 turned scenes"``, ``"4 tilted scenes"``: how reports name a scene count."""
    if scenes == 1:
        return "1 scene"
    return f"{scenes} {'turned' if arrangement == 'turns' else 'tilted'} scenes"


def render_truth(material: Material, setup: CaseSetup = CaseSetup(), cache: CachedGroundTruth | None = None) -> Truth:
    """Render (or read from ``cache``) the fit scenes and relight references of ``material``."""
    cache = make_cache() if cache is None else cache
    rows, cols, normals, weights = _sphere(setup.size)
    fit_env = probe_environment(setup.fit_probe, setup.env_rows, setup.probe_dir)
    fit_envs = [fit_env if rotation is None else fit_env.rotated(rotation) for rotation in scene_rotations(setup)]
    relight_envs = [probe_environment(name, setup.env_rows, setup.probe_dir) for name in setup.relight_probes]
    images = cache.renders(material, normals, fit_envs + relight_envs, identity=material.identity())
    scenes = [Scene(env, normals, image, weights) for env, image in zip(fit_envs, images)]
    relight = {name: (env, image) for name, env, image in zip(setup.relight_probes, relight_envs, images[len(fit_envs):])}
    return Truth(material, setup, rows, cols, normals, weights, scenes, relight)


@dataclass
class CaseResult:
    """One fit of one material by one model, relit.

    Attributes
    ----------
    material, model : str
        Material name and the model asked for.
    chosen_model : str
        The model the fitter returned (``auto``'s choice).
    scenes : int
    noise : float
        Relative Gaussian noise of the fitted pixels.
    errors : dict
        Relight probe -> relative RMS error over the sphere's pixels.
    fit_seconds : float
        Wall clock of the fit.
    estimate : float or None
        The fitter's own estimate of its relighting error (None if it reports none).
    held_out : bool
    estimate_method : str
        How the fitter obtained ``estimate``.
    lighting_estimates : dict
        Relight probe -> the fitter's estimate for that lighting (:func:`brdfrig.fit.relight.lighting_estimate`
        of the fit's report); empty for a model relit from ``auto``'s candidates.
    lighting_estimate_details : dict
        Relight probe -> how that estimate was obtained (its method and detail, with the numbers it combined).
    cpu_seconds : float or None
        Process CPU time of the fit (all threads; less sensitive to other jobs than the wall clock).
    failure : str or None
        Why the fit raised (then the errors are NaN).
    fit_file : str or None
        The fitted BRDF's file (:mod:`brdfrig.fit.brdffile`, with its report), relative to the run's output
        directory (:func:`fit_path`); None where the run kept no files.
    relit : dict
        Relight probe -> (N, 3) relit radiance (not written to JSON).
    """

    material: str
    model: str
    chosen_model: str
    scenes: int
    noise: float
    errors: dict[str, float]
    fit_seconds: float
    estimate: float | None
    held_out: bool
    estimate_method: str = ""
    lighting_estimates: dict[str, float | None] = field(default_factory=dict)
    lighting_estimate_details: dict[str, str] = field(default_factory=dict)
    cpu_seconds: float | None = None
    failure: str | None = None
    fit_file: str | None = None
    relit: dict[str, np.ndarray] = field(default_factory=dict, repr=False)

    @property
    def error(self) -> float:
        """Error under the first relight probe (the headline number)."""
        return next(iter(self.errors.values()))

    def estimate_for(self, probe: str | None = None) -> float | None:
        """The estimate for relight probe ``probe`` (None: the headline one): its lighting estimate where there is
        one, else ``estimate``."""
        value = self.lighting_estimates.get(next(iter(self.errors)) if probe is None else probe)
        return self.estimate if value is None else value


def reported_estimate(report: dict) -> tuple[float | None, str]:
    """The fitter's estimate of its relighting error under other lighting and how it was obtained.

    ``report`` is the dict of a :class:`brdfrig.fit.report.FitReport`; ``(None, "")`` if it has none.
    """
    est = report.get("relight")
    if isinstance(est, dict) and est.get("value") is not None and np.isfinite(est["value"]):
        return float(est["value"]), str(est.get("method", ""))
    return None, ""


def noisy_scenes(scenes: list[Scene], noise: float, seed: int = 0) -> list[Scene]:
    """The scenes with each pixel value times ``1 + noise * N(0, 1)`` (one seeded generator over all scenes)."""
    if not (math.isfinite(noise) and noise >= 0):
        raise InputError(f"noise must be a finite number >= 0, got {noise!r}")
    if noise == 0:
        return list(scenes)
    rng = np.random.default_rng(seed)
    return [Scene(s.env, s.normals, s.radiance * (1 + noise * rng.standard_normal(s.radiance.shape)), s.weights)
            for s in scenes]


def relight_fits(truth: Truth, brdfs: dict) -> dict[str, tuple[dict[str, float], dict[str, np.ndarray]]]:
    """name -> (errors, relit radiance) of each BRDF in ``brdfs`` under every relight probe of ``truth``
    (:func:`brdfrig.fit.relight.predict_under`: the tables share their design, the analytic ones render under
    all the probes at once)."""
    from brdfrig.fit.relight import predict_under

    probes = list(truth.relight)
    preds = predict_under(brdfs, [truth.relight[p][0] for p in probes], truth.normals)
    out = {m: ({}, {}) for m in brdfs}
    for m, pred in preds.items():
        for k, probe in enumerate(probes):
            out[m][1][probe] = pred[k]
            out[m][0][probe] = relative_rms(pred[k], truth.relight[probe][1], truth.weights)
    return out


def _lighting_estimates(truth: Truth, report: dict) -> dict[str, dict]:
    """The :class:`CaseResult` fields ``lighting_estimates`` and ``lighting_estimate_details``: relight probe ->
    :func:`brdfrig.fit.relight.lighting_estimate` of the fit under it, and how it was obtained."""
    from brdfrig.fit.relight import lighting_estimate

    est = {probe: lighting_estimate(report, env, truth.normals, truth.weights) for probe, (env, _) in truth.relight.items()}
    return {"lighting_estimates": {p: e.value for p, e in est.items()},
            "lighting_estimate_details": {p: e.how for p, e in est.items()}}


def _default_fit(scenes, model, material: str):
    """:func:`brdfrig.fit.fitter.fit_brdf` without progress bars, the material left out of the reference tables."""
    from brdfrig.fit.fitter import fit_brdf
    from brdfrig.fit.references import shipped

    return fit_brdf(scenes, model=model, progress=False, reference_tables=shipped().without([material]))


def _timed_fit(truth: Truth, model: str, noise: float, seed: int, fit):
    scenes = noisy_scenes(truth.scenes, noise, seed)
    t0, c0 = time.perf_counter(), time.process_time()
    result = fit(scenes, model) if fit is not None else _default_fit(scenes, model, truth.material.name)
    seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
    report = result.report.to_dict() if hasattr(result.report, "to_dict") else result.report
    return result, report, seconds, cpu


def fit_path(material: str, model: str, scenes: int, arrangement: str, noise: float) -> Path:
    """Where a run keeps one case's fitted BRDF, relative to its output directory:
    ``fits/GROUP/NAME/MODEL-<k>scene|<k>turns|<k>tilts-noise<sigma>.brdf.json``."""
    kind = "scene" if scenes == 1 else arrangement
    return Path(FITS_DIR, *material.split("/"), f"{model}-{scenes}{kind}-noise{noise:g}.brdf.json")


def _keep(keep: Path | None, truth: Truth, model: str, noise: float, seed: int, brdf, report: dict) -> str | None:
    """Write one case's fitted ``brdf`` and its ``report`` as a BRDF file under the output directory ``keep``
    (:func:`fit_path`); the path relative to ``keep`` (None, and nothing written, without ``keep``)."""
    if keep is None:
        return None
    from brdfrig.fit.brdffile import save_brdf

    s = truth.setup
    rel = fit_path(truth.material.name, model, s.scenes, s.arrangement, noise)
    path = Path(keep) / rel
    path.parent.mkdir(parents=True, exist_ok=True)
    save_brdf(path, brdf, report, provenance={
        "command": "brdfrig bench --measured", "model": model, "material": truth.material.name,
        "material_file": str(truth.material.path), "fit_probe": s.fit_probe, "scenes": s.scenes,
        "arrangement": s.arrangement, "size": s.size, "env_rows": s.env_rows, "noise": noise, "seed": seed})
    return rel.as_posix()


def fit_and_relight(truth: Truth, model: str, *, noise: float = 0.0, seed: int = 0, fit=None,
                    keep: Path | None = None) -> CaseResult:
    """Fit ``model`` to the truth's scenes (with ``noise``) and relight it under every relight probe.

    ``fit`` : callable ``(scenes, model) -> FitResult`` (default :func:`brdfrig.fit.fitter.fit_brdf`
    without progress bars, the material itself left out of the reference tables of ``bivariate+measured``);
    only it is timed.  ``keep``: the run's output directory, where the fit is written (:func:`fit_path`).
    """
    result, report, seconds, cpu = _timed_fit(truth, model, noise, seed, fit)
    errors, relit = relight_fits(truth, {model: result.brdf})[model]
    estimate, method = reported_estimate(report)
    return CaseResult(truth.material.name, model, str(report.get("chosen_model", model)), truth.setup.scenes,
                      float(noise), errors, seconds, estimate, truth.material.held_out,
                      estimate_method=method, **_lighting_estimates(truth, report), cpu_seconds=cpu,
                      fit_file=_keep(keep, truth, model, noise, seed, result.brdf, report), relit=relit)


def fit_all_and_relight(truth: Truth, models, *, noise: float = 0.0, seed: int = 0,
                        keep: Path | None = None) -> list[CaseResult]:
    """One result per model in ``models``, from ONE ``auto`` fit where possible.

    ``auto`` fits every candidate on the same pixels (:attr:`brdfrig.fit.fitter.FitResult.brdfs`): a
    model among them is relit from that fit, its ``fit_seconds`` being the candidate's own fit time
    (the report's ``seconds``; auto's shared stages left out; ``cpu_seconds`` None) and its estimate
    the candidate's own.  A model auto did not fit (e.g. skipped as undetermined) is fitted alone.
    ``keep``: the run's output directory, where each fit is written (:func:`fit_path`; a candidate's file
    holds its entry of auto's report).
    """
    models = tuple(models)
    out: dict[str, CaseResult] = {}
    if "auto" in models:
        result, report, seconds, cpu = _timed_fit(truth, "auto", noise, seed, None)
        estimate, method = reported_estimate(report)
        chosen = report["chosen_model"]
        brdfs = {m: b for m, b in result.brdfs.items() if m in models and m != "auto"}
        relights = relight_fits(truth, {**brdfs, chosen: result.brdf})  # the chosen fit is relit once
        errors, relit = relights[chosen]
        mat = truth.material
        out["auto"] = CaseResult(mat.name, "auto", report["chosen_model"], truth.setup.scenes, float(noise), errors,
                                 seconds, estimate, mat.held_out, estimate_method=method,
                                 **_lighting_estimates(truth, report), cpu_seconds=cpu,
                                 fit_file=_keep(keep, truth, "auto", noise, seed, result.brdf, report), relit=relit)
        for name, brdf in brdfs.items():
            cand = report["candidates"].get(name, {})
            estimate, method = reported_estimate(cand)
            errors, relit = relights[name]
            out[name] = CaseResult(mat.name, name, name, truth.setup.scenes, float(noise), errors,
                                   float(cand.get("seconds", math.nan)), estimate, mat.held_out, estimate_method=method,
                                   fit_file=_keep(keep, truth, name, noise, seed, brdf, cand), relit=relit)
    for name in models:
        if name not in out:
            out[name] = fit_and_relight(truth, name, noise=noise, seed=seed, keep=keep)
    return [out[m] for m in models]


def failed_case(truth: Truth, model: str, noise: float, exc: BaseException) -> CaseResult:
    """The result of a fit that raised: NaN errors, ``failure`` naming the exception."""
    return CaseResult(truth.material.name, model, "-", truth.setup.scenes, float(noise),
                      {p: math.nan for p in truth.relight}, math.nan, None, truth.material.held_out,
                      failure=f"{type(exc).__name__}: {exc}")


def _as_material(material) -> Material:
    if isinstance(material, Material):
        return material
    if isinstance(material, (str, Path)):
        path = Path(material)
        return Material.from_path(path) if path.suffix else find_materials([str(material)])[0]
    return Material(type(material).__name__, None, material)


def relight_case(material, model: str, *, size: int = 96, fit_probe: str = "grace",
                 relight_probes: tuple[str, ...] = ("ennis", "pisa"), env_rows: int = 64, scenes: int = 1,
                 arrangement: str = "turns", noise: float = 0.0, seed: int = 0, cache_dir: str | Path = DEFAULT_CACHE_DIR,
                 probe_dir: str | Path = DEFAULT_PROBE_DIR) -> CaseResult:
    """The standard case for one material and one model (see module docstring).

    Parameters
    ----------
    material : Material, path, name or BRDF
        A measured file (``.h5``/``.binary``), a material name (``rgl/NAME`` or ``NAME``), or any BRDF
        object the ground-truth renderer takes (e.g. :class:`brdfrig.fit.analytic.GGX`).
    model : str
        A model name of the fitter (:func:`model_names`).
    size, fit_probe, relight_probes, env_rows, scenes, arrangement : see :class:`CaseSetup`.
    noise, seed : relative pixel noise of the fit images and its seed.
    cache_dir : where ground-truth renders are cached.
    """
    setup = CaseSetup(int(size), fit_probe, tuple(relight_probes), int(env_rows), int(scenes), Path(probe_dir),
                      arrangement)
    truth = render_truth(_as_material(material), setup, make_cache(cache_dir))
    return fit_and_relight(truth, model, noise=noise, seed=seed)


def _split(text: str) -> list[str]:
    return [t.strip() for t in text.split(",") if t.strip()]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The measured benchmark's options (shared by this module's CLI and ``brdfrig bench --measured``)."""
    g = parser.add_argument_group("measured-materials benchmark")
    g.add_argument("--materials", type=_split, default=None, metavar="NAME,...",
                   help="materials (group/name or name; default: every one under --measured-dir)")
    g.add_argument("--models", type=_split, default=None, metavar="MODEL,...",
                   help="models (default: every model of the fitter, auto first)")
    g.add_argument("--scenes", type=int, nargs="+", default=[1, 12], metavar="N",
                   help="scene counts (1 = the fit probe; 12 = turned in 30 degree steps; default: 1 12; "
                        "split a long run with --scenes 1 and --scenes 12; at most 4 with --arrangement tilts)")
    g.add_argument("--arrangement", choices=ARRANGEMENTS, default="turns",
                   help="scenes after the first: the fit probe turned about the vertical in 30 degree steps (turns), "
                        "or tilted about the horizontal by 45, -45 and 90 degrees (tilts) (default: %(default)s)")
    g.add_argument("--noise", type=float, nargs="+", default=[0.0, 0.01], metavar="SIGMA",
                   help="relative pixel noise levels, seeded (default: 0 0.01)")
    g.add_argument("--size", type=int, default=96, help="sphere image size in pixels (default: %(default)s)")
    g.add_argument("--fit-probe", default="grace", help="probe of the fit (default: %(default)s)")
    g.add_argument("--relight-probes", type=_split, default=["ennis", "pisa"], metavar="NAME,...",
                   help="probes of the relighting (default: ennis,pisa; the first is the headline); NAME@AXISDEGREES "
                        "turns one (grace@y180: the fit room turned half round); a fit scene's own lighting is refused")
    g.add_argument("--env-rows", type=int, default=64, help="lat-long rows of the probes (default: %(default)s)")
    g.add_argument("--measured-dir", type=Path, default=MEASURED_DIR, help="measured materials (default: %(default)s)")
    g.add_argument("--seed", type=int, default=0, help="noise seed (default: %(default)s)")
    g.add_argument("--cache", type=Path, default=None, metavar="DIR",
                   help=f"ground-truth render cache (default: OUT/gt-cache; {DEFAULT_CACHE_DIR} is relight_case's)")
    g.add_argument("--peer", choices=["mitsuba"], default=None, help="also fit the Mitsuba principled peer")
    g.add_argument("--workers", type=int, default=1, metavar="N",
                   help="Dask worker processes that fit materials side by side, each with cores / N numba threads "
                        "(default: %(default)s, in this process)")
    g.add_argument("--resume", action="store_true",
                   help="continue the unfinished run in --out (same options): its finished materials are kept, "
                        "the others run")
    g.add_argument("--no-warm-up", action="store_true",
                   help="skip the untimed warm-up fits (the first material's fit times then include compilation)")


def main(argv: list[str] | None = None) -> int:
    """``python -m brdfrig.evaluate.measured``: run the benchmark and print its table (exit 2 on bad input)."""
    from brdfrig.evaluate.measured_run import run_from_args

    parser = argparse.ArgumentParser(prog="python -m brdfrig.evaluate.measured", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(parser)
    parser.add_argument("--out", type=Path, default=Path("measured-out"), help="output directory (default: %(default)s)")
    parser.add_argument("--probes", type=Path, default=DEFAULT_PROBE_DIR, help="probe directory (default: %(default)s)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")
    args = parser.parse_args(argv)
    try:
        return run_from_args(args)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
