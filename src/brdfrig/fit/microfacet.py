"""The ``microfacet`` model: a GGX lobe per colour channel over a diffuse term, fitted by variable projection.

Model, per colour channel ``c``::

    rho_c = d_c / pi (A(s_c) + B(s_c) retro) + sum_{l=1..L} a_lc (2l+1)/(4 pi) P_l(cos_i) / cos_i
            + (f0_c + (f90_c - f0_c) (1 - h.wi)^5) D_alpha_c(n.h) G2_alpha_c / (4 cos_i cos_o)

- the diffuse term: an Oren-Nayar base (albedo ``d_c``, facet slope deviation
  ``s_c``; ``retro = max(0, cos dphi) sin(a) tan(b)``, :class:`brdfrig.fit.analytic.OrenNayar`;
  ``s = 0`` is Lambertian) plus, only when asked for (``series=True``: it
  extrapolates badly from one image, see :func:`fit_microfacet`), an SH series radially symmetric about the
  normal in bands ``1..L`` (the ``diffuse`` model of :mod:`brdfrig.fit.models`
  without its band 0): ``B = sum_l a_l sum_m L_lm Y_lm(n)``.  The base carries
  every band (no truncation error for a Lambertian, which an SH series alone
  needs ``L >= 8`` to approach: measured 0.8% relighting error at ``L = 8``,
  7% at ``L = 2``, the missing bands leaking into a broad lobe); the series
  absorbs what the base does not fit in the bands the lighting measures;
- the lobe: :class:`brdfrig.fit.analytic.GGX`'s lobe with its own roughness
  ``alpha_c``, normal-incidence reflectance ``f0_c`` and grazing reflectance
  ``f90_c`` with ``0 <= f0_c <= f90_c <= 1``: ``f90_c`` scales Schlick's
  curve (``f90 = 1`` is Schlick's), which keeps the lobe linear in its
  amplitudes and its Fresnel never above 1.  Left free, ``f90`` absorbed what
  the lobe and base could not fit (1.32 on Mitsuba's roughplastic).

For a fixed ``alpha_c`` the rendered sphere is LINEAR in the base written as
``(d A, d B)`` (a Lambertian and a retro-reflection column), the series
``a_lc`` and ``(f0_c, f90_c)``, so each channel is a one-dimensional nonlinear
least-squares problem in ``log(alpha_c)`` with the rest solved in closed form
at every step (variable projection, Golub & Pereyra 1973): the series columns
are projected out once per channel (their SVD; minimum norm where the lighting
leaves a band unexcited), then a four-column least-squares solve under the
constraints ``dA, dB, f0 >= 0``, ``f0 <= f90 <= 1`` (exact, :func:`brdfrig.fit.lsq.polytope_lsq`)
gives the amplitudes; ``s_c`` follows from ``B/A`` (clamped to
:data:`SIGMA_MAX`, reported).  This is identifiable from one image: ``L + 4``
linear unknowns and one roughness per channel against thousands of pixels.

Speed: the base's and the lobe's renders are brute-force quadrature
(:mod:`brdfrig.fit.groundtruth`; the lobe's: :func:`brdfrig.fit.columns.render_ggx_basis`) on a pixel
subsample under a coarsened copy of each environment:

- pixels: at most ``max_pixels`` (default 3000) drawn uniformly from the
  weighted pixels of all scenes.  With about a dozen unknowns per channel the
  subsample's statistical error is about ``sigma / sqrt(max_pixels)`` relative
  to the full image's, far below the model and quadrature errors;
- environment: samples binned into lat-long cells of ``180 / env_rows``
  degrees (default 48 rows, 3.75 degrees), summing solid angle and
  radiance x solid angle (energy-preserving) at the solid-angle-weighted mean
  direction.  A GGX lobe of roughness alpha spans roughly ``2 atan(alpha)``
  radians around the mirror direction (31 degrees at alpha = 0.3, 11 at
  alpha = 0.1), several cells wide down to alpha ~ 0.05 (the lower search bound);
- roughness search: one grid of log-spaced roughnesses renders all channels
  per pass; each channel is then refined by a bounded Brent search on its own
  bracket.  Every pass renders all channels (the lobe's evaluation, shared by
  the channels, is its cost) and is kept in :data:`brdfrig.fit.memo.RENDERS`
  by pixels, lighting and roughness, so the grid is rendered once for all the
  fits on one pixel set and lighting.

Relighting (``predict``) bins the environment into cells about half the smallest roughness wide
(measured < 2e-4 relative error against the full map).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq, minimize_scalar

from brdfrig.errors import InputError
from brdfrig.fit.analytic import GGX, Lambertian, OrenNayar, oren_nayar_ab
from brdfrig.fit.brdf import register_model
from brdfrig.fit.columns import render_ggx_basis
from brdfrig.fit.groundtruth import render_groundtruth, render_sharp
from brdfrig.fit.lsq import polytope_lsq
from brdfrig.fit.models import DiffuseBRDF
from brdfrig.fit.memo import RENDERS
from brdfrig.fit.quadrature import merge_cone
from brdfrig.fit.scene import Environment, Scene, content_digest
from brdfrig.fit.shproject import project_environment
from brdfrig.fit.system import ModelSpec, design_block

__all__ = ["MicrofacetBRDF", "fit_microfacet", "coarsen_environment"]

DEFAULT_LMAX = 8
DEFAULT_MAX_PIXELS = 3000
DEFAULT_ENV_ROWS = 48
DEFAULT_ALPHA_RANGE = (0.03, 1.0)
PREDICT_MIN_ROWS = 64
"""Fewest lat-long rows the environment is binned to when relighting (see :meth:`MicrofacetBRDF.predict`)."""
BASE_ENV_ROWS = 128
"""Environments with more samples than a 128-row lat-long map are coarsened to it for the base's renders."""
GRID_POINTS = 9
"""Log-spaced roughnesses of the shared first pass (the objective can have a shallow second minimum near the bounds)."""
ALPHA_XTOL = 1e-2
"""Brent tolerance in ``log(alpha)``: 1% in alpha, below what 1% pixel noise determines (measured 2-4%)."""
SERIES_MIN_GAIN = 0.01
"""The SH series is kept only when it lowers the check pixels' relative RMS error by more than this fraction."""
SERIES_RTOL = 1e-10
"""Singular values of a channel's weighted series columns below this fraction of the largest are dropped (minimum norm)."""
AMPLITUDE_G = np.array([[-1.0, 0, 0, 0], [0, -1.0, 0, 0], [0, 0, -1.0, 0], [0, 0, 1.0, -1.0], [0, 0, 0, 1.0]])
AMPLITUDE_H = np.array([0.0, 0.0, 0.0, 0.0, 1.0])
"""Constraints ``G (dA, dB, f0, f90) <= H`` of a channel's amplitudes: all >= 0 and ``f0 <= f90 <= 1``
(the lobe's Fresnel is ``f90`` times a Schlick curve from ``f0 / f90`` to 1: never above 1 at grazing)."""
SIGMA_MAX = math.pi / 2
"""Largest Oren-Nayar slope deviation (radians): ``B/A`` = 0.78 there; a fitted ratio above it is clamped (reported)."""
LOBE_MIN_FRACTION = 1e-3
"""A channel whose fitted lobe carries less than this fraction of its fitted radiance has no measurable lobe:
its roughness is then not determined (and does not matter)."""


@register_model("microfacet")
class MicrofacetBRDF:
    """A GGX lobe over an Oren-Nayar base (:class:`brdfrig.fit.analytic.GGX`) plus an SH series (module docstring).

    Implements :class:`brdfrig.fit.brdf.FittedBRDF`.

    Parameters
    ----------
    analytic : brdfrig.fit.analytic.GGX
        Per-channel ``alpha``, ``f0``, ``f90``, base albedo ``diffuse`` and ``diffuse_sigma``.
    series : brdfrig.fit.models.DiffuseBRDF or None
        The SH series in bands >= 1 (None: no series).
    """

    model = "microfacet"

    def __init__(self, analytic: GGX, series: DiffuseBRDF | None = None) -> None:
        if series is not None:
            if 0 in series.spec.bands:
                raise ValueError("the microfacet series starts at band 1 (band 0 is the base's albedo)")
            if series.channels != analytic.channels:
                raise ValueError(f"series has {series.channels} channels, the analytic part {analytic.channels}")
        self.analytic = analytic
        self.series = series

    @property
    def channels(self) -> int:
        return self.analytic.channels

    @property
    def stacks_lightings(self) -> bool:
        """:meth:`predict` renders under stacked lightings (:func:`brdfrig.fit.scene.stack_lightings`): without a series."""
        return self.series is None

    def predict(self, env: Environment, normals: np.ndarray) -> np.ndarray:
        """Radiance (N, C) seen from ``v = (0, 0, 1)``: the analytic part by quadrature, the series through SH.

        The quadrature runs over ``env`` binned into cells of about ``alpha / 2`` radians for the
        smallest roughness (at least :data:`PREDICT_MIN_ROWS` rows; finer maps only): measured
        1.7e-4 / 8e-5 relative RMS against the full 256 x 128 map at alpha = 0.1 / 0.3, 3-5x faster
        there and ~16x on 512 x 256 maps (cost is pixels x samples).  A map no finer than that is integrated
        over its cells, 2 x 2 blocks of them merged beyond :data:`brdfrig.fit.quadrature.MERGE_CONE_DEG` of the
        mirror direction.
        """
        rows = max(PREDICT_MIN_ROWS, math.ceil(2 * math.pi / float(np.min(self.analytic.alpha))))
        lobe_env = coarsen_environment(env, rows) if len(env.solid_angle) > 2 * rows * rows else env
        out = render_sharp(self.analytic, normals, lobe_env, 0.0, 1, merge_cone(lobe_env))
        return out if self.series is None else out + self.series.predict(env, normals)

    def evaluate(self, theta_i, theta_o, delta_phi) -> np.ndarray:
        """BRDF ``rho`` (1/sr), shape ``broadcast(theta_i, theta_o, delta_phi).shape + (C,)``."""
        out = self.analytic.evaluate(theta_i, theta_o, delta_phi)
        return out if self.series is None else out + self.series.evaluate(theta_i, theta_o, delta_phi)

    def to_dict(self) -> dict:
        return {"model": self.model, "analytic": self.analytic.to_dict(), "series": None if self.series is None else self.series.to_dict()}

    @classmethod
    def from_dict(cls, d: dict) -> "MicrofacetBRDF":
        if "analytic" not in d:
            raise ValueError("microfacet BRDF without an 'analytic' entry (written by an older brdfrig?): refit it")
        return cls(GGX.from_dict(d["analytic"]), None if d.get("series") is None else DiffuseBRDF.from_dict(d["series"]))


def coarsen_environment(env: Environment, rows: int = DEFAULT_ENV_ROWS) -> Environment:
    """Bin an environment's samples into a ``rows x 2 rows`` lat-long grid of cells, preserving energy.

    Each non-empty cell becomes one sample: its solid angle is the sum of its
    samples' solid angles, its radiance the solid-angle-weighted mean and its
    direction the normalised solid-angle-weighted mean direction.  Works for
    any sample layout (lat-long, mirror ball, ...).

    Parameters
    ----------
    env : Environment
        Lighting samples (M, 3) / (M, C) / (M,).
    rows : int
        Number of latitude rows (cells of ``180 / rows`` degrees).

    Returns
    -------
    Environment with at most ``2 rows^2`` samples; unseen samples (zero solid angle) are dropped.
    """
    if rows < 1:
        raise ValueError(f"rows must be >= 1, got {rows}")
    omega = np.asarray(env.solid_angle, dtype=np.float64)
    keep = omega > 0
    dirs = np.asarray(env.dirs, dtype=np.float64)[keep]
    omega = omega[keep]
    rad = np.asarray(env.radiance, dtype=np.float64)[keep]
    lat = np.arcsin(np.clip(dirs[:, 1], -1, 1))
    lon = np.arctan2(dirs[:, 0], dirs[:, 2])
    i = np.minimum(((lat + math.pi / 2) / math.pi * rows).astype(np.int64), rows - 1)
    j = np.minimum(((lon + math.pi) / (2 * math.pi) * 2 * rows).astype(np.int64), 2 * rows - 1)
    cell = i * 2 * rows + j
    cells, inverse = np.unique(cell, return_inverse=True)
    k = len(cells)
    w = np.bincount(inverse, weights=omega, minlength=k)
    d = np.stack([np.bincount(inverse, weights=omega * dirs[:, a], minlength=k) for a in range(3)], axis=1)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    e = np.stack([np.bincount(inverse, weights=omega * rad[:, c], minlength=k) for c in range(rad.shape[1])], axis=1)
    return Environment(d, e / w[:, None], w, lightings=env.lightings)


def _subsample(scenes: list[Scene], max_pixels: int, rng: np.random.Generator) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Pixel indices per scene of the fit set (at most ``max_pixels``) and the disjoint check set (a quarter of that).

    Both are uniform over all weighted pixels of all scenes; with few pixels, three quarters fit and a quarter check.
    """
    valid = [np.flatnonzero(np.asarray(s.weights) > 0) for s in scenes]
    total = sum(len(v) for v in valid)
    if total == 0:
        raise InputError("no pixel has a positive weight: nothing to fit")
    n_fit = min(max_pixels, total - total // 4)
    take = rng.permutation(total)[: n_fit + min(max_pixels // 4, total - n_fit)]
    flat = np.concatenate(valid)
    owner = np.concatenate([np.full(len(v), k) for k, v in enumerate(valid)])

    def split(t: np.ndarray) -> list[np.ndarray]:
        return [np.sort(flat[t[owner[t] == k]]) for k in range(len(scenes))]

    return split(take[:n_fit]), split(take[n_fit:])


def _check_scenes(scenes: list[Scene]) -> int:
    """Validate shapes and finiteness; return the channel count."""
    if not scenes:
        raise ValueError("fit_microfacet needs at least one scene")
    channels = scenes[0].radiance.shape[1]
    for k, s in enumerate(scenes):
        if s.env.channels != channels or s.radiance.shape[1] != channels:
            raise ValueError(f"scene {k}: channel counts disagree (image {s.radiance.shape[1]}, lighting {s.env.channels}, first image {channels})")
        if not (len(s.normals) == len(s.radiance) == len(s.weights)):
            raise ValueError(f"scene {k}: normals, radiance and weights differ in length")
        w = np.asarray(s.weights) > 0
        if not np.all(np.isfinite(np.asarray(s.radiance)[w])):
            raise InputError(f"scene {k}: non-finite radiance at a pixel with positive weight")
    return channels


class _Channel:
    """One channel's variable-projection problem: the free series columns projected out once.

    ``u`` (N, r), ``s`` (r,), ``vt`` (r, nb): the kept SVD of the weighted series columns (nb may be 0).
    """

    def __init__(self, series_cols: np.ndarray, target: np.ndarray) -> None:
        u, s, vt = np.linalg.svd(series_cols, full_matrices=False)
        keep = s > SERIES_RTOL * s[0] if s.size and s[0] > 0 else np.zeros(s.size, bool)
        self.u, self.s, self.vt = u[:, keep], s[keep], vt[keep]
        self.y = target
        self.y_perp = target - self.u @ (self.u.T @ target)

    def solve(self, cols: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
        """(squared residual, amplitudes >= 0 (k,), series coefficients (nb,)) for weighted non-negative columns (N, k)."""
        perp = cols - self.u @ (self.u.T @ cols)
        r2, amps = polytope_lsq(perp, self.y_perp, AMPLITUDE_G, AMPLITUDE_H)
        a = self.vt.T @ ((self.u.T @ (self.y - cols @ amps)) / self.s)
        return r2, amps, a


def _base_columns(normals: np.ndarray, env: Environment) -> np.ndarray:
    """Renders (N, C, 2) of the base's linear parts: a Lambertian of albedo 1 and the retro term ``retro / pi``.

    The retro column is ``(OrenNayar(1, s) - A(s) Lambertian(1)) / B(s)`` for any ``s > 0`` (exact: the
    Oren-Nayar BRDF is ``(A + B retro) / pi``), rendered by the ground truth's own quadrature; kept in
    :data:`brdfrig.fit.memo.RENDERS` (read-only).
    """
    def render() -> np.ndarray:
        lam = render_groundtruth(Lambertian(1.0), normals, env)
        a, b = oren_nayar_ab(1.0)
        retro = (render_groundtruth(OrenNayar(1.0, 1.0), normals, env) - a * lam) / b
        return np.stack([lam, retro], axis=2)

    return RENDERS.get(("base columns", content_digest(normals, env)), render)


def _oren_nayar(lam: float, retro: float) -> tuple[float, float, bool]:
    """Base albedo and slope deviation ``(d, s)`` with ``d A(s) = lam`` and ``d B(s) = retro``; clamped flag.

    ``B/A`` grows monotonically with ``s``; a ratio beyond ``B/A`` at :data:`SIGMA_MAX` is clamped there
    (``d`` then keeps the Lambertian part).
    """
    if retro <= 0 or lam <= 0:
        return max(lam, 0.0), 0.0, bool(retro > 0)
    ratio = retro / lam

    def excess(s: float) -> float:
        a, b = oren_nayar_ab(s)
        return b / a - ratio

    if excess(SIGMA_MAX) <= 0:
        return lam / oren_nayar_ab(SIGMA_MAX)[0], SIGMA_MAX, True
    s = brentq(excess, 0.0, SIGMA_MAX, xtol=1e-10)
    return lam / oren_nayar_ab(s)[0], s, False


class _Pixels:
    """A pixel set's weighted data: target (N, C), base columns (N, C, 2), series columns (N, nb, C).

    :meth:`columns` adds the lobe's columns for a roughness, rendered for every channel and kept in
    :data:`brdfrig.fit.memo.RENDERS` (the per-channel searches, the final solves and other fits on the same
    pixels and lighting visit the same roughnesses).
    """

    def __init__(self, scenes, picks, coarse, base_envs, spec: ModelSpec | None, lmax: int) -> None:
        self.normals = [np.asarray(s.normals, dtype=np.float64)[p] for s, p in zip(scenes, picks)]
        self.coarse = coarse
        self.sqrt_w = np.sqrt(np.concatenate([np.asarray(s.weights, dtype=np.float64)[p] for s, p in zip(scenes, picks)]))
        self.target = np.concatenate([np.asarray(s.radiance, dtype=np.float64)[p] for s, p in zip(scenes, picks)]) * self.sqrt_w[:, None]
        self.base = np.concatenate([_base_columns(n, e) for n, e in zip(self.normals, base_envs)]) * self.sqrt_w[:, None, None]
        channels = self.target.shape[1]
        self.series = np.zeros((len(self.target), 0, channels))
        if spec is not None:
            self.series = np.concatenate([design_block(spec, project_environment(s.env, lmax), n) for s, n in zip(scenes, self.normals)])
            self.series *= self.sqrt_w[:, None, None]
        self.renders = 0
        self._geometry = [content_digest(n, e) for n, e in zip(self.normals, coarse)]

    def _lobe(self, alpha: float, normals: np.ndarray, env: Environment) -> np.ndarray:
        self.renders += 1
        return render_ggx_basis(alpha, normals, env)

    def columns(self, log_alpha: float, chans: list[int]) -> np.ndarray:
        """Weighted non-negative columns (N, len(chans), 4): base (Lambertian, retro), lobe (f0, f90) at exp(log_alpha)."""
        alpha = math.exp(log_alpha)
        lobe = np.concatenate([RENDERS.get(("ggx basis", g, alpha), lambda n=n, e=e: self._lobe(alpha, n, e))
                               for n, e, g in zip(self.normals, self.coarse, self._geometry)])
        return np.concatenate([self.base[:, chans], lobe[:, chans] * self.sqrt_w[:, None, None]], axis=2)


def fit_microfacet(
    scenes: list[Scene],
    *,
    lmax: int = DEFAULT_LMAX,
    bands: tuple[int, ...] | None = None,
    max_pixels: int = DEFAULT_MAX_PIXELS,
    env_rows: int = DEFAULT_ENV_ROWS,
    alpha_range: tuple[float, float] = DEFAULT_ALPHA_RANGE,
    series: bool = False,
    seed: int = 0,
    progress: bool = True,
) -> tuple[MicrofacetBRDF, dict]:
    """Fit the microfacet model to one or more scenes.

    Parameters
    ----------
    scenes : list of Scene
        Lighting and observed sphere pixels (any number; channel counts must agree).
    lmax : int
        Band limit ``L`` of the SH series (with ``series=True``; 0: the Oren-Nayar base alone).
    bands : tuple of int, optional
        Bands of the series to keep (default ``1..lmax``; the fitter passes the
        bands the lighting excites; band 0 is always the base's).
    max_pixels : int
        Size of the pixel subsample used by the fit (see module docstring).
    env_rows : int
        Resolution of the coarsened environments (:func:`coarsen_environment`).
    alpha_range : (float, float)
        Search interval of the GGX roughness.
    series : bool
        Offer the SH diffuse series in bands ``1..lmax`` (kept only when the check pixels gain).  Off by
        default: from one image the series absorbs what base and lobe do not fit and extrapolates it
        (standard case, 96 px, grace -> ennis: relit rgl/acrylic_felt_green at 40.7% with it, 14.3%
        without; rgl/colodur_azure_4e 12.1% / 6.3%; a roughplastic-like analytic sphere 2.9% / 3.5%).
    seed : int
        Seed of the pixel subsample.
    progress : bool
        Show a tqdm bar (stderr) over lobe renders.

    Returns
    -------
    brdf : MicrofacetBRDF
    report : dict
        JSON-able, per-channel lists where noted: ``alpha``, ``f0``, ``f90``,
        ``diffuse_albedo`` and ``diffuse_sigma`` (the Oren-Nayar base),
        ``sigma_clamped``, ``series_bands``, ``alpha_at_bound`` (optimum on
        the search interval's edge), ``lobe_fraction`` (share of the fitted
        radiance in the lobe), ``alpha_determined`` (a lobe is present and its
        optimum is inside the interval), ``relative_rms_residual`` (weighted, on
        the fit subsample), ``pixels_used``, ``env_samples`` per scene,
        ``lobe_renders`` (quadrature passes), ``seconds``.
    """
    t0 = time.perf_counter()
    channels = _check_scenes(scenes)
    series_bands = _series_bands(lmax, bands, alpha_range, series)
    spec = ModelSpec("diffuse", lmax, bands=series_bands) if series_bands else None
    data, check = _pixel_sets(scenes, spec, lmax, max_pixels, env_rows, seed)
    problems = [_Channel(data.series[:, :, c], data.target[:, c]) for c in range(channels)]
    search = _search_roughness(data, problems, alpha_range, progress)
    # The series stays only if it predicts the check pixels better by more than SERIES_MIN_GAIN
    # (else it fits noise and extrapolates it).
    solutions, check_err = _solve_variants(data, check, problems, search.log_alpha)
    keep_series = spec is not None and len(check.target) > 0 and check_err["with_series"] < (1 - SERIES_MIN_GAIN) * check_err["base_only"]
    amplitudes = _final_amplitudes(data, solutions, search.log_alpha, keep_series, len(series_bands))
    analytic, base_params = _analytic_part(search.log_alpha, amplitudes.amps)
    brdf = MicrofacetBRDF(analytic, DiffuseBRDF(spec, amplitudes.coef) if keep_series else None)
    series_check = {
        "candidate_bands": list(series_bands),
        "check_pixels": int(len(check.target)),
        "check_relative_rms": check_err,
        "kept": keep_series,
    }
    report = _report(analytic, base_params, search, amplitudes, series_check, data, check)
    report["seconds"] = time.perf_counter() - t0
    return brdf, report


def _series_bands(lmax: int, bands: tuple[int, ...] | None, alpha_range: tuple[float, float], series: bool) -> tuple[int, ...]:
    """Validate the options of :func:`fit_microfacet`; the series bands it offers (``bands`` within ``1..lmax``, none
    unless ``series``)."""
    lo, hi = alpha_range
    if not 0 < lo < hi:
        raise ValueError(f"alpha_range must satisfy 0 < low < high, got {alpha_range}")
    if lmax < 0:
        raise ValueError(f"lmax must be >= 0, got {lmax}")
    if not series:
        return ()
    return tuple(b for b in (range(1, lmax + 1) if bands is None else bands) if 1 <= b <= lmax)


def _pixel_sets(scenes: list[Scene], spec: ModelSpec | None, lmax: int, max_pixels: int, env_rows: int,
                seed: int) -> tuple[_Pixels, _Pixels]:
    """The fit and check pixel sets (:func:`_subsample`), lobes rendered under ``env_rows``-row environments.

    The base is smooth and rendered once, under environments coarsened to :data:`BASE_ENV_ROWS` rows at most:
    near-full resolution keeps its quadrature error out of the series decision (rendered on the lobe's 48-row
    cells, its error made the series look useful: kept, it relit at 0.6% instead of 0.1%).
    """
    fit_picks, check_picks = _subsample(scenes, max_pixels, np.random.default_rng(seed))
    coarse = [coarsen_environment(s.env, env_rows) for s in scenes]
    base_envs = [coarsen_environment(s.env, BASE_ENV_ROWS) if len(s.env.solid_angle) > 2 * BASE_ENV_ROWS**2 else s.env for s in scenes]
    data = _Pixels(scenes, fit_picks, coarse, base_envs, spec, lmax)
    return data, _Pixels(scenes, check_picks, coarse, base_envs, spec, lmax)


@dataclass
class _Roughness:
    """The roughness search's outcome per channel: ``log_alpha`` (C,), optimum on the interval's edge, Brent converged."""

    log_alpha: np.ndarray
    at_bound: list[bool]
    converged: list[bool]


def _search_roughness(data: _Pixels, problems: list[_Channel], alpha_range: tuple[float, float],
                      progress: bool) -> _Roughness:
    """Every channel's roughness: a shared log-spaced grid pass, then a bounded Brent search per channel."""
    from tqdm import tqdm

    channels = len(problems)
    bar = tqdm(desc="microfacet fit", unit="channel", total=channels, disable=not progress, leave=False)
    grid = np.linspace(math.log(alpha_range[0]), math.log(alpha_range[1]), GRID_POINTS)
    costs = _grid_costs(data, problems, grid)
    out = _Roughness(np.empty(channels), [], [])
    for c in range(channels):
        out.log_alpha[c], at_bound, converged = _refine_roughness(data, problems[c], c, grid, costs[:, c])
        out.at_bound.append(at_bound)
        out.converged.append(converged)
        bar.update(1)
    bar.close()
    return out


def _grid_costs(data: _Pixels, problems: list[_Channel], grid: np.ndarray) -> np.ndarray:
    """Squared residuals (len(grid), C) of every channel at each log roughness of ``grid`` (one render per point)."""
    channels = len(problems)
    costs = np.empty((len(grid), channels))
    for g, log_alpha in enumerate(grid):
        cols = data.columns(log_alpha, list(range(channels)))
        costs[g] = [problems[c].solve(cols[:, c])[0] for c in range(channels)]
    return costs


def _refine_roughness(data: _Pixels, problem: _Channel, c: int, grid: np.ndarray,
                      costs: np.ndarray) -> tuple[float, bool, bool]:
    """Channel ``c``'s log roughness by a bounded Brent search between the neighbours of its best grid point.

    Returns (log alpha, on the search interval's edge, Brent converged); the grid point stays when Brent does worse.
    """
    b = int(np.argmin(costs))
    last = len(grid) - 1
    res = minimize_scalar(
        lambda g: problem.solve(data.columns(g, [c])[:, 0])[0],
        bounds=(grid[max(b - 1, 0)], grid[min(b + 1, last)]),
        method="bounded",
        options={"xatol": ALPHA_XTOL},
    )
    log_alpha = res.x if res.fun <= costs[b] else grid[b]
    return log_alpha, bool(b in (0, last) and abs(log_alpha - grid[b]) < 1e-2), bool(res.success)


def _solve_variants(data: _Pixels, check: _Pixels, problems: list[_Channel],
                    log_alpha: np.ndarray) -> tuple[list[dict], dict[str, float]]:
    """Amplitudes at the chosen roughness with the series and without, and how well each predicts the check pixels.

    Returns per channel ``{"with_series" | "base_only": (squared residual, amplitudes (4,), series coefficients)}``
    and each variant's relative RMS error over the check pixels of all channels.
    """
    channels = len(problems)
    no_series = [_Channel(data.series[:, :0, c], data.target[:, c]) for c in range(channels)]
    squared = {"with_series": 0.0, "base_only": 0.0}
    solutions = []
    for c in range(channels):
        cols, check_cols = data.columns(log_alpha[c], [c])[:, 0], check.columns(log_alpha[c], [c])[:, 0]
        sol = {"with_series": problems[c].solve(cols), "base_only": no_series[c].solve(cols)}
        for variant, (_, a, x) in sol.items():
            squared[variant] += float(np.sum((check_cols @ a + check.series[:, : len(x), c] @ x - check.target[:, c]) ** 2))
        solutions.append(sol)
    norm = max(float(np.sum(check.target**2)), 1e-300)
    return solutions, {k: math.sqrt(v / norm) for k, v in squared.items()}


@dataclass
class _Amplitudes:
    """The chosen variant's linear unknowns: ``amps`` (C, 4) ``(dA, dB, f0, f90)`` on their constraints, series
    ``coef`` (nb, C), the fit set's summed squared residual ``cost`` and each channel's ``lobe_share``."""

    amps: np.ndarray
    coef: np.ndarray
    cost: float
    lobe_share: list[float]


def _final_amplitudes(data: _Pixels, solutions: list[dict], log_alpha: np.ndarray, keep_series: bool,
                      n_series: int) -> _Amplitudes:
    """The chosen variant's amplitudes (:func:`_solve_variants`), its residual and each channel's lobe share."""
    channels = len(solutions)
    amps, coef = np.empty((channels, 4)), np.zeros((n_series, channels))
    cost, lobe_share = 0.0, []
    for c in range(channels):
        cols = data.columns(log_alpha[c], [c])[:, 0]
        r2, amps[c], x = solutions[c]["with_series" if keep_series else "base_only"]
        coef[:, c] = x if keep_series else 0.0
        cost += r2
        lobe = cols[:, 2:] @ amps[c, 2:]
        fitted = cols @ amps[c] + data.series[:, :, c] @ coef[:, c]
        lobe_share.append(float(np.linalg.norm(lobe) / max(float(np.linalg.norm(fitted)), 1e-300)))
    # The exact solve meets its constraints to rounding (1e-15): put the amplitudes back on them.
    amps = np.maximum(amps, 0.0)
    amps[:, 3] = np.minimum(amps[:, 3], 1.0)
    amps[:, 2] = np.minimum(amps[:, 2], amps[:, 3])
    return _Amplitudes(amps, coef, cost, lobe_share)


def _analytic_part(log_alpha: np.ndarray, amps: np.ndarray) -> tuple[GGX, list[tuple[float, float, bool]]]:
    """The GGX lobe over its Oren-Nayar base, and the base's ``(albedo, sigma, clamped)`` per channel."""
    base_params = [_oren_nayar(a[0], a[1]) for a in amps]
    analytic = GGX(
        alpha=np.exp(log_alpha),
        f0=amps[:, 2],
        diffuse=[p[0] for p in base_params],
        f90=amps[:, 3],
        diffuse_sigma=[p[1] for p in base_params],
    )
    return analytic, base_params


def _report(analytic: GGX, base_params: list, search: _Roughness, amplitudes: _Amplitudes, series_check: dict,
            data: _Pixels, check: _Pixels) -> dict:
    """The fit report of :func:`fit_microfacet` (its docstring), ``seconds`` aside."""
    has_lobe = [share >= LOBE_MIN_FRACTION for share in amplitudes.lobe_share]
    at_bound = search.at_bound
    return {
        "model": "microfacet",
        "alpha": np.exp(search.log_alpha).tolist(),
        "f0": amplitudes.amps[:, 2].tolist(),
        "f90": amplitudes.amps[:, 3].tolist(),
        "diffuse_albedo": analytic.diffuse.tolist(),
        "diffuse_sigma": analytic.diffuse_sigma.tolist(),
        "sigma_clamped": [p[2] for p in base_params],
        "series_bands": list(series_check["candidate_bands"]) if series_check["kept"] else [],
        "series_check": series_check,
        "alpha_at_bound": at_bound,
        "lobe_fraction": amplitudes.lobe_share,
        "alpha_determined": [h and not b for h, b in zip(has_lobe, at_bound)],
        "determined": not any(h and b for h, b in zip(has_lobe, at_bound)),
        "optimizer_converged": all(search.converged),
        "relative_rms_residual": float(math.sqrt(amplitudes.cost / max(float(np.sum(data.target**2)), 1e-300))),
        "pixels_used": int(len(data.target)),
        "env_samples": [int(len(e.solid_angle)) for e in data.coarse],
        "lobe_renders": data.renders + check.renders,
    }
