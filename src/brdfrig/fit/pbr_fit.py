"""Fitting the physically based families of :mod:`brdfrig.fit.pbr` from one (or more) sphere images.

Variable projection as in :func:`brdfrig.fit.microfacet.fit_microfacet`: for fixed shape parameters the
rendered sphere is linear in the amplitudes, solved in closed form by bounded least squares
(BVLS / exact small QP); the shape parameters are found by a bounded one-dimensional search
(a log-spaced grid, then Brent in the best bracket), nested where there are two.

==============  ====================================================  ===========================================
family          linear amplitudes (bounds)                            shape parameters (search)
==============  ====================================================  ===========================================
``dielectric``  per channel ``dA = base A(s)``, ``dB = base B(s)``;   ``alpha`` (outer), ``specular_ior`` in
                shared ``specular_weight`` in [0, 1]                  :data:`IOR_BOUNDS` (inner, per alpha)
``conductor``   per channel ``base_color`` in [0, 1] and the edge     ``alpha``
                term ``(1 - specular_color) S(1/7)`` in
                ``[0, S(1/7)]`` (exact 2-variable QP)
``sheen``       per channel ``dA``, ``dB``, ``fuzz_weight fuzz_color``  ``fuzz alpha``, ``fuzz_weight`` in [0, 1]
                in [0, fuzz_weight] (+ shared ``specular_weight``     (inner, no renders); with ``coat=True``
                with ``coat``)                                        ``fuzz_weight`` 1, then ``alpha`` and ``ior``
                                                                      as for ``dielectric``
==============  ====================================================  ===========================================

The Oren-Nayar slope deviation follows from ``dB / dA`` (:func:`brdfrig.fit.microfacet._oren_nayar`).
Nothing else is free: no SH series and no free grazing reflectance, so no term can absorb
another's signal (Schlick's ``f90 = specular_weight``, the dielectric's grazing reflectance
follows from its IOR).

Speed: every column is the ground-truth quadrature (the sample rule of :mod:`brdfrig.fit.groundtruth`,
the environments binned to at most ``env_rows`` rows) on a pixel subsample, assembled from parts
that are rendered once and recombined for free:

- the base: the transmission ``t(cos_i)`` is a piecewise-linear table, so the base's render is
  ``t(cos_o) / N sum_k t_k H_k`` with ``H_k`` the renders of the table's hat functions (one pass
  per fit, exact);
- the specular lobe of one ``alpha``: its Fresnel enters through ``cos_d = h.wi`` only, expanded in
  Legendre polynomials of ``2 cos_d - 1`` to degree :data:`FRESNEL_DEGREE` (exact for Schlick and
  F82, whose degree is 5 and 7; 2e-5 absolute for the dielectric Fresnel at IOR 1.3-2), so one
  pass per ``alpha`` renders the moments and every IOR or conductor colour is a matrix product.
  Lobes narrower than a cell use the sharp-lobe quadrature (:mod:`brdfrig.fit.quadrature`,
  :func:`brdfrig.fit.pbr.lobe_rule` with :data:`FIT_SUBCELL_WIDTH`; MATH.md pitfall 9), and the cells
  beyond :data:`brdfrig.fit.quadrature.MERGE_CONE_DEG` of the mirror direction merge in 2 x 2 blocks, as
  in ``predict``.
  The renders (moments, hats, fuzz columns) are kept by the content of the pixels and the lighting in
  :data:`brdfrig.fit.memo.RENDERS`, so the dielectric and conductor searches of one ``auto`` fit share their
  ``alpha`` grid's passes, and fits of other images on the same pixels and lighting reuse them.

Search bounds: ``alpha`` in :data:`ALPHA_BOUNDS`, fuzz alpha in :data:`FUZZ_ALPHA_BOUNDS`, IOR in
:data:`IOR_BOUNDS`; an optimum on a bound is reported (``at_bound``, ``determined``).
"""

from __future__ import annotations

import math
import time

import numba
import numpy as np
from scipy.optimize import minimize_scalar

from brdfrig.fit.analytic import (
    F82_COS,
    LAYERED_HEAD,
    TABLE_SIZE,
    f82_q,
    table_lookup,
)
from brdfrig.fit.columns import render_fuzz
from brdfrig.fit.groundtruth import kernel_inputs
from brdfrig.fit.lsq import box_lsq, polytope_lsq
from brdfrig.fit.memo import RENDERS
from brdfrig.fit.quadrature import lobe_quadrature, lobe_samples, merge_cone
from brdfrig.fit.rho import ggx_lobe_given, smith_lambda
from brdfrig.fit.microfacet import _check_scenes, _oren_nayar, _subsample, coarsen_environment
from brdfrig.fit.pbr import (
    FRESNEL_DEGREE,
    _legendre_fit,
    fresnel_coefficients,
    legendre_into,
    ConductorBRDF,
    DielectricBRDF,
    SheenBRDF,
    _base_norm,
    _upper_table,
    coat_moments,
    layered_rows,
    lobe_rule,
    sheen_albedo,
    table_values,
)
from brdfrig.fit.scene import Environment, Scene, content_digest

__all__ = ["FAMILIES", "fit_pbr", "fit_dielectric", "fit_conductor", "fit_sheen", "fresnel_coefficients", "shared_solve"]

FAMILIES = ("dielectric", "conductor", "sheen")
DEFAULT_MAX_PIXELS = 2000
DEFAULT_ENV_ROWS = 64
ALPHA_BOUNDS = (0.01, 1.0)
"""GGX alpha search interval (specular_roughness 0.1-1)."""
FUZZ_ALPHA_BOUNDS = (0.01, 1.0)
IOR_BOUNDS = (1.3, 2.0)
GRID_POINTS = 7
LOG_XTOL = 1e-2
IOR_XTOL = 2e-3
FIT_SUBCELL_WIDTH = 1.0
"""Sub-cells of the fit's lobe renders at most ``alpha`` wide (``predict``: ``alpha / 2``); 4x fewer samples
for the sharpest lobes, the renders differing by about 1e-3 (the search's own tolerance)."""
DB_MAX = 0.45
"""Upper bound of the retro amplitude ``dB = base B(s)`` (``B < 0.45`` for every ``s``)."""
LOBE_MIN_FRACTION = 1e-3


_SCHLICK = (_legendre_fit(lambda c: 1 - (1 - c) ** 5), _legendre_fit(lambda c: (1 - c) ** 5),
            _legendre_fit(lambda c: np.array([f82_q(x) for x in c])))


@numba.njit(cache=True, fastmath=False, parallel=True)
def _lobe_moments_kernel(alpha, fuzz_t, q, normals, degree):
    """``sum_j L_j m(i,o) lobe(alpha) P_d(2 cos_d - 1) cos_i`` per pixel, channel and degree ``d``, view +z.

    Samples: :func:`brdfrig.fit.quadrature.lobe_samples` of ``q``; ``m = min(fuzz_t(cos_i), fuzz_t(cos_o))``
    with ``fuzz_t`` the fuzz transmission table (:data:`TABLE_SIZE` nodes).
    """
    n_pix, nc = normals.shape[0], q.wrad.shape[1]
    out = np.zeros((n_pix, nc, degree + 1))
    for i in numba.prange(n_pix):
        nx, ny, nz = normals[i, 0], normals[i, 1], normals[i, 2]
        if nz <= 0.0:
            continue
        dirs, wrad = lobe_samples(q, nx, ny, nz, True)
        m_o = table_lookup(fuzz_t, 0, nz)
        lambda_o = smith_lambda(nz, alpha)
        acc = np.zeros((nc, degree + 1))
        leg = np.empty(degree + 1)
        for j in range(dirs.shape[0]):
            cos_i = nx * dirs[j, 0] + ny * dirs[j, 1] + nz * dirs[j, 2]
            lobe, cos_d = ggx_lobe_given(cos_i, nz, dirs[j, 2], alpha, lambda_o)
            val = lobe * cos_i * min(m_o, table_lookup(fuzz_t, 0, cos_i))
            if val == 0.0:
                continue
            legendre_into(2.0 * cos_d - 1.0, leg)
            for c in range(nc):
                lw = wrad[j, c] * val
                for d in range(degree + 1):
                    acc[c, d] += lw * leg[d]
        out[i] = acc
    return out


@numba.njit(cache=True, fastmath=False, parallel=True)
def _hat_kernel(normals, dirs, weighted, view):
    """Renders ``sum_j L_j phi_k(cos_i) {1, retro} cos_i / pi`` of the table's hat functions: (N, C, K, 2)."""
    n_pix, n_env, nc = normals.shape[0], dirs.shape[0], weighted.shape[1]
    out = np.zeros((n_pix, nc, TABLE_SIZE, 2))
    cos_io = dirs[:, 0] * view[0] + dirs[:, 1] * view[1] + dirs[:, 2] * view[2]
    for i in numba.prange(n_pix):
        nx, ny, nz = normals[i, 0], normals[i, 1], normals[i, 2]
        cos_o = nx * view[0] + ny * view[1] + nz * view[2]
        if cos_o <= 0.0:
            continue
        for j in range(n_env):
            cos_i = nx * dirs[j, 0] + ny * dirs[j, 1] + nz * dirs[j, 2]
            if cos_i <= 0.0:
                continue
            x = math.sqrt(min(cos_i, 1.0)) * (TABLE_SIZE - 1)
            k = min(int(x), TABLE_SIZE - 2)
            f = x - k
            retro = max(cos_io[j] - cos_i * cos_o, 0.0) / max(cos_i, cos_o)
            for c in range(nc):
                lw = weighted[j, c] * cos_i / math.pi
                out[i, c, k, 0] += (1.0 - f) * lw
                out[i, c, k + 1, 0] += f * lw
                out[i, c, k, 1] += (1.0 - f) * lw * retro
                out[i, c, k + 1, 1] += f * lw * retro
    return out


class _Data:
    """A pixel set's weighted target and the renders shared by every evaluation of the search."""

    def __init__(self, scenes: list[Scene], picks: list[np.ndarray], envs: list[Environment]) -> None:
        self.normals = [np.asarray(s.normals, dtype=np.float64)[p] for s, p in zip(scenes, picks)]
        self.envs = envs
        self.sqrt_w = np.sqrt(np.concatenate([np.asarray(s.weights, dtype=np.float64)[p] for s, p in zip(scenes, picks)]))
        self.target = np.concatenate([np.asarray(s.radiance, dtype=np.float64)[p] for s, p in zip(scenes, picks)]) * self.sqrt_w[:, None]
        self.cos_o = np.concatenate([n[:, 2] for n in self.normals])
        self.geometry = [content_digest(n, e) for n, e in zip(self.normals, envs)]
        self.renders = 0
        self.hats = np.concatenate([self._kept(("hats", g), _hat_kernel, *kernel_inputs(n, e, (0.0, 0.0, 1.0)))
                                    for n, e, g in zip(self.normals, envs, self.geometry)]) * self.sqrt_w[:, None, None, None]
        self._quadratures: dict = {}

    def base(self, t: np.ndarray) -> np.ndarray:
        """Weighted base columns (N, C, 2) (Lambertian part, retro part) for transmission table ``t``."""
        scale = table_values(t, self.cos_o) / _base_norm(t)
        return np.einsum("nckr,k->ncr", self.hats, t) * scale[:, None, None]

    def _kept(self, key: tuple, kernel, *args) -> np.ndarray:
        """``kernel(*args)``, kept in :data:`brdfrig.fit.memo.RENDERS` under ``key`` (:attr:`renders` counts the passes)."""
        def render() -> np.ndarray:
            self.renders += 1
            return kernel(*args)

        return RENDERS.get(key, render)

    def moments(self, alpha: float, fuzz_row: np.ndarray) -> np.ndarray:
        """Weighted Fresnel moments (N, C, FRESNEL_DEGREE + 1) of the GGX lobe, kept by content."""
        fuzz_t = np.ascontiguousarray(fuzz_row[LAYERED_HEAD + TABLE_SIZE : LAYERED_HEAD + 2 * TABLE_SIZE])
        parts = [self._kept(("lobe moments", g, float(alpha), lobe_rule(alpha, e, FIT_SUBCELL_WIDTH), fuzz_t.tobytes()),
                            _lobe_moments_kernel, alpha, fuzz_t, self.quadrature(e, alpha), np.ascontiguousarray(n), FRESNEL_DEGREE)
                 for n, e, g in zip(self.normals, self.envs, self.geometry)]
        return np.concatenate(parts) * self.sqrt_w[:, None, None]

    def quadrature(self, env: Environment, alpha: float):
        """The sharp-lobe quadrature of ``env`` for a lobe of ``alpha`` (:func:`brdfrig.fit.pbr.lobe_rule`), cached."""
        rule = lobe_rule(alpha, env, FIT_SUBCELL_WIDTH)
        key = (id(env), rule)
        if key not in self._quadratures:
            self._quadratures[key] = lobe_quadrature(env, *(rule or (0.0, 1)), merge_cone(env))
        return self._quadratures[key]

    def fuzz(self, fuzz_alpha: float) -> np.ndarray:
        """Weighted fuzz column (N, C) of unit colour, kept by content."""
        return np.concatenate([self._kept(("fuzz", g, float(fuzz_alpha)), render_fuzz, fuzz_alpha, n, e)
                               for n, e, g in zip(self.normals, self.envs, self.geometry)]) * self.sqrt_w[:, None]


def shared_solve(per_channel: np.ndarray, shared: np.ndarray | None, target: np.ndarray, upper: np.ndarray):
    """Least squares over channels with per-channel columns (N, C, K) and one shared column (N, C) or None.

    Returns (squared residual, per-channel amplitudes (C, K), shared amplitude).
    """
    n, c, k = per_channel.shape
    if shared is None:
        sols = [box_lsq(per_channel[:, ch], target[:, ch], np.zeros(k), upper) for ch in range(c)]
        return sum(s[0] for s in sols), np.array([s[1] for s in sols]), 0.0
    big = np.zeros((n * c, c * k + 1))
    for ch in range(c):
        big[ch * n : (ch + 1) * n, ch * k : (ch + 1) * k] = per_channel[:, ch]
        big[ch * n : (ch + 1) * n, -1] = shared[:, ch]
    r2, x = box_lsq(big, target.T.reshape(-1), np.zeros(c * k + 1), np.r_[np.tile(upper, c), 1.0])
    return r2, x[:-1].reshape(c, k), float(x[-1])


_K5 = (1 - F82_COS) ** 5
_CONDUCTOR_G = np.array([[-1.0, 0.0], [1.0, 0.0], [0.0, -1.0], [-(1 - _K5), 1.0]])
_CONDUCTOR_H = np.array([0.0, 1.0, 0.0, _K5])
"""``0 <= base_color <= 1`` and ``0 <= e <= S(1/7) = base_color (1 - k5) + k5`` (specular_color in [0, 1])."""


def _conductor_solve(cols: np.ndarray, target: np.ndarray) -> tuple[float, np.ndarray]:
    """One channel's ``(base_color, e)`` for F82 columns (N, 3) (``F = base (1 - s5) + s5 - e q``)."""
    return polytope_lsq(np.stack([cols[:, 0], -cols[:, 2]], axis=1), target - cols[:, 1], _CONDUCTOR_G, _CONDUCTOR_H)


def _search(cost, bounds: tuple[float, float]) -> tuple[float, float, bool]:
    """Minimise ``cost(log x)`` over ``log`` of ``bounds``: grid then Brent in the best bracket.

    Returns (x, cost, at_bound).
    """
    grid = np.linspace(math.log(bounds[0]), math.log(bounds[1]), GRID_POINTS)
    costs = np.array([cost(g) for g in grid])
    b = int(np.argmin(costs))
    res = minimize_scalar(cost, bounds=(grid[max(b - 1, 0)], grid[min(b + 1, GRID_POINTS - 1)]), method="bounded",
                          options={"xatol": LOG_XTOL})
    x, fx = (res.x, res.fun) if res.fun <= costs[b] else (grid[b], costs[b])
    return math.exp(x), float(fx), bool(b in (0, GRID_POINTS - 1) and abs(x - grid[b]) < 2 * LOG_XTOL)


class _Dielectric:
    """Layered fits: the dielectric family (``fuzz=False``) and the sheen family (``fuzz=True``)."""

    def __init__(self, data: _Data, coat: bool, fuzz: bool, ior: float | None) -> None:
        self.data, self.coat, self.fuzz, self.fixed_ior = data, coat, fuzz, ior

    def fuzz_row(self, fuzz_alpha: float) -> np.ndarray:
        """A layered row carrying only the fuzz transmission table (what the lobe moments read)."""
        return layered_rows(np.zeros((1, 4)), 0.1, 1.5, fuzz_alpha, False, float(self.fuzz))[0]

    def solve(self, alpha: float, ior: float, fuzz_alpha: float, fuzz_col=None, fuzz_weight: float = 1.0):
        """(squared residual, per-channel amplitudes (C, 2 or 3), specular weight) at fixed shapes.

        The fuzz amplitude (``fuzz_weight * fuzz_color``) is bounded by ``fuzz_weight``.
        """
        d = self.data
        t_fuzz = 1.0 - fuzz_weight * sheen_albedo(fuzz_alpha) if self.fuzz else np.ones(TABLE_SIZE)
        t = t_fuzz.copy()
        spec = None
        if self.coat:
            mom = d.moments(alpha, self.fuzz_row(fuzz_alpha))
            spec = mom @ fresnel_coefficients(round(ior, 6))
            t = t * (1.0 - _upper_table(coat_moments(alpha) @ fresnel_coefficients(round(ior, 6))))
        cols = d.base(np.clip(t, 0.0, 1.0))
        upper = np.array([1.0, DB_MAX])
        if self.fuzz:
            cols = np.concatenate([cols, fuzz_col[:, :, None]], axis=2)
            upper = np.r_[upper, max(fuzz_weight, 1e-12)]
        return shared_solve(cols, spec, d.target, upper)

    def profile_ior(self, alpha: float, fuzz_alpha: float, fuzz_col=None) -> tuple[float, float]:
        """(cost, best IOR) at one alpha: IOR fixed, or a bounded Brent search (cheap: no renders)."""
        if self.fixed_ior is not None or not self.coat:
            ior = 1.5 if self.fixed_ior is None else self.fixed_ior
            return self.solve(alpha, ior, fuzz_alpha, fuzz_col)[0], ior
        res = minimize_scalar(lambda e: self.solve(alpha, e, fuzz_alpha, fuzz_col)[0], bounds=IOR_BOUNDS,
                              method="bounded", options={"xatol": IOR_XTOL})
        return float(res.fun), float(res.x)


def _base_params(amps: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[bool], list[bool]]:
    """``base_color``, ``base_diffuse_roughness`` from per-channel ``(dA, dB)``; sigma-clamped and colour-clamped flags."""
    params = [_oren_nayar(float(a), float(b)) for a, b in amps[:, :2]]
    color = np.array([p[0] for p in params])
    return np.minimum(color, 1.0), np.array([p[1] for p in params]), [p[2] for p in params], (color > 1.0).tolist()


def _fit_layered(data: _Data, family: str, coat: bool, ior: float | None, bar) -> tuple:
    """Shape search and final amplitudes of the dielectric or sheen family: (brdf, report entries)."""
    fuzz = family == "sheen"
    prob = _Dielectric(data, coat, fuzz, ior)

    def fuzz_col(fa: float):
        return data.fuzz(fa) if fuzz else None

    at_bound = {}
    fuzz_alpha, alpha, e, fw = 0.25, 0.1, 1.5 if ior is None else ior, 1.0
    if fuzz:
        # Fuzz roughness first with the coating absent (its lobe is far narrower), the fuzz weight profiled
        # out at each (no renders: it only changes the tables); then the coating's roughness (weight 1).
        plain = _Dielectric(data, False, True, None)
        weights: dict[float, float] = {}

        def fuzz_cost(g: float) -> float:
            fa = math.exp(g)
            cost = lambda v: plain.solve(0.1, 1.5, fa, fuzz_col(fa), v)[0]  # noqa: E731
            res = minimize_scalar(cost, bounds=(0.0, 1.0), method="bounded", options={"xatol": 1e-3})
            best = min([(float(res.fun), float(res.x)), (cost(0.0), 0.0), (cost(1.0), 1.0)])
            weights[fa] = best[1]
            return best[0]

        fuzz_alpha, _, at_bound["fuzz_roughness"] = _search(fuzz_cost, FUZZ_ALPHA_BOUNDS)
        fw = 1.0 if coat else weights[fuzz_alpha]  # _search returns an evaluated point
        bar.update(1)
    if coat:
        alpha, _, at_bound["specular_roughness"] = _search(lambda g: prob.profile_ior(math.exp(g), fuzz_alpha, fuzz_col(fuzz_alpha))[0], ALPHA_BOUNDS)
        e = prob.profile_ior(alpha, fuzz_alpha, fuzz_col(fuzz_alpha))[1]
        if ior is None:
            at_bound["specular_ior"] = min(abs(e - IOR_BOUNDS[0]), abs(e - IOR_BOUNDS[1])) < 5 * IOR_XTOL
        bar.update(1)
    r2, amps, w = prob.solve(alpha, e, fuzz_alpha, fuzz_col(fuzz_alpha), fw)
    base, sigma, sigma_clamped, color_clamped = _base_params(amps)
    kw = dict(base_color=base, base_diffuse_roughness=sigma, specular_weight=min(max(w, 0.0), 1.0) if coat else 0.0,
              specular_roughness=math.sqrt(alpha), specular_ior=e, coat=coat)
    if fuzz:
        color = np.clip(amps[:, 2] / fw, 0, 1) if fw > 0 else np.zeros(len(amps))
        brdf = SheenBRDF(fuzz_color=color, fuzz_roughness=math.sqrt(fuzz_alpha), fuzz_weight=fw, **kw)
    else:
        brdf = DielectricBRDF(**kw)
    extra = {"sigma_clamped": sigma_clamped, "base_color_clamped": color_clamped}
    return brdf, r2, at_bound, extra


def _fit_conductor(data: _Data, bar) -> tuple:
    """Roughness search and per-channel F82 amplitudes of the conductor family: (brdf, report entries)."""
    flat = layered_rows(np.zeros((1, 4)), 0.1, 1.5, 0.5, False, 0.0)[0]

    def solve(alpha: float):
        mom = data.moments(alpha, flat)
        cols = np.stack([mom @ s for s in _SCHLICK], axis=2)
        sols = [_conductor_solve(cols[:, c], data.target[:, c]) for c in range(data.target.shape[1])]
        return sum(s[0] for s in sols), np.array([s[1] for s in sols])

    alpha, _, bound = _search(lambda g: solve(math.exp(g))[0], ALPHA_BOUNDS)
    bar.update(1)
    r2, amps = solve(alpha)
    f0 = np.clip(amps[:, 0], 0.0, 1.0)
    s82 = f0 + (1 - f0) * (1 - F82_COS) ** 5
    tint = np.clip(1.0 - amps[:, 1] / s82, 0.0, 1.0)
    brdf = ConductorBRDF(base_color=f0, specular_color=tint, specular_roughness=math.sqrt(alpha))
    return brdf, r2, {"specular_roughness": bound}, {}


def fit_pbr(
    scenes: list[Scene],
    family: str = "dielectric",
    *,
    lmax: int = 8,
    bands: tuple[int, ...] | None = None,
    max_pixels: int = DEFAULT_MAX_PIXELS,
    env_rows: int = DEFAULT_ENV_ROWS,
    coat: bool | None = None,
    specular_ior: float | None = None,
    seed: int = 0,
    progress: bool = True,
) -> tuple:
    """Fit one physically based family (:mod:`brdfrig.fit.pbr`) to one or more scenes.

    Parameters
    ----------
    scenes : list of Scene
        Lighting and observed sphere pixels (channel counts must agree).
    family : {"dielectric", "conductor", "sheen"}
    lmax, bands
        Accepted for the common single-model signature; these families have no SH part.
    max_pixels : int
        Pixel subsample of the fit (a quarter as many more are kept out to check the result).
    env_rows : int
        Environments with more samples than ``env_rows x 2 env_rows`` are binned to that grid
        (:func:`brdfrig.fit.microfacet.coarsen_environment`) for the fit's renders.
    coat : bool, optional
        Sheen only: put the dielectric coating between fuzz and base (default False).
    specular_ior : float, optional
        Fix the coating's IOR instead of fitting it within :data:`IOR_BOUNDS`.
    seed : int
        Seed of the pixel subsample.
    progress : bool
        tqdm bar (stderr) over the searches.

    Returns
    -------
    brdf : DielectricBRDF, ConductorBRDF or SheenBRDF
    report : dict
        JSON-able: ``model``, the BRDF's parameters (``to_dict`` names), ``determined`` (no shape
        parameter on a search bound: roughnesses and a fitted IOR), ``at_bound`` per shape parameter,
        ``relative_rms_residual`` (fit pixels), ``check_relative_rms`` (held-out pixels of the same
        scenes, rendered by ``predict``), ``pixels_used``, ``renders``, ``seconds``.
    """
    from tqdm import tqdm

    if family not in FAMILIES:
        raise ValueError(f"unknown physically based family {family!r} (known: {', '.join(FAMILIES)})")
    if coat is not None and family != "sheen":
        raise ValueError("coat= applies to the sheen family only")
    if specular_ior is not None and not IOR_BOUNDS[0] / 1.3 <= specular_ior <= 3.0:
        raise ValueError(f"specular_ior must be within [1.0, 3.0], got {specular_ior}")
    t0 = time.perf_counter()
    _check_scenes(scenes)
    fit_picks, check_picks = _subsample(scenes, max_pixels, np.random.default_rng(seed))
    envs = [coarsen_environment(s.env, env_rows) if len(s.env.solid_angle) > 2 * env_rows**2 else s.env for s in scenes]
    data = _Data(scenes, fit_picks, envs)
    bar = tqdm(desc=f"{family} fit", unit="search", total=2 if family == "sheen" and coat else 1, disable=not progress, leave=False)
    if family == "conductor":
        brdf, r2, at_bound, extra = _fit_conductor(data, bar)
    else:
        brdf, r2, at_bound, extra = _fit_layered(data, family, family == "dielectric" or bool(coat), specular_ior, bar)
    bar.close()
    check = _check_error(brdf, scenes, check_picks)
    report = {k: v for k, v in brdf.to_dict().items() if k != "conventions"}
    report.update(extra)
    report.update({
        "at_bound": at_bound,
        "determined": not any(at_bound.values()),
        "relative_rms_residual": float(math.sqrt(r2 / max(float(np.sum(data.target**2)), 1e-300))),
        "check_relative_rms": check,
        "pixels_used": int(len(data.target)),
        "env_samples": [int(len(e.solid_angle)) for e in envs],
        "renders": data.renders,
        "seconds": time.perf_counter() - t0,
    })
    return brdf, report


def _check_error(brdf, scenes: list[Scene], picks: list[np.ndarray]) -> float | None:
    """Weighted relative RMS of ``brdf.predict`` on the held-out pixels (None when there are none)."""
    num = den = 0.0
    for s, p in zip(scenes, picks):
        if len(p) == 0:
            continue
        w = np.asarray(s.weights, dtype=np.float64)[p, None]
        obs = np.asarray(s.radiance, dtype=np.float64)[p]
        pred = brdf.predict(s.env, np.asarray(s.normals, dtype=np.float64)[p])
        num += float(np.sum(w * (pred - obs) ** 2))
        den += float(np.sum(w * obs**2))
    return None if den == 0 else math.sqrt(num / den)


def fit_dielectric(scenes: list[Scene], *, lmax: int = 8, bands=None, progress: bool = True, **kw) -> tuple:
    """:func:`fit_pbr` with ``family="dielectric"`` (the single-model fit signature)."""
    return fit_pbr(scenes, "dielectric", lmax=lmax, bands=bands, progress=progress, **kw)


def fit_conductor(scenes: list[Scene], *, lmax: int = 8, bands=None, progress: bool = True, **kw) -> tuple:
    """:func:`fit_pbr` with ``family="conductor"``."""
    return fit_pbr(scenes, "conductor", lmax=lmax, bands=bands, progress=progress, **kw)


def fit_sheen(scenes: list[Scene], *, lmax: int = 8, bands=None, progress: bool = True, **kw) -> tuple:
    """:func:`fit_pbr` with ``family="sheen"``."""
    return fit_pbr(scenes, "sheen", lmax=lmax, bands=bands, progress=progress, **kw)
