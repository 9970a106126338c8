"""Physically based parametric BRDFs as renderers use them, with parameters named as in OpenPBR.

Three families, each energy-conserving (directional albedo <= 1 at every angle) and reciprocal:

- ``dielectric`` (:class:`DielectricBRDF`, plastic-like): a GGX coating of index of refraction
  ``specular_ior`` with the exact unpolarised dielectric Fresnel and white ``specular_color``,
  over a diffuse base of colour ``base_color`` (Oren-Nayar of slope deviation
  ``base_diffuse_roughness``, 0 = Lambertian)::

      rho = w F_ior(h.wi) D G2 / (4 cos_i cos_o) + base_color t(cos_i) t(cos_o) / (pi N) (A + B retro)

  ``t = 1 - E_coat`` is the coating's transmission (one minus the directional albedo of its
  lobe at ``w = 1``, tabulated) and ``N = 2 int_0^1 t(mu) mu dmu`` normalises the base so that a
  Lambertian base of colour 1 returns exactly what the coating transmits: albedo
  ``w E_coat + base_color (1 - E_coat) <= 1``: OpenPBR's albedo scaling.  Mitsuba's ``roughplastic``
  layers differently (its rough interface loses energy to shadowing, and it divides by
  ``eta^2 (1 - F_dr,internal)``): its own evaluation is :mod:`brdfrig.export.mitsuba_bsdf`.  ``specular_weight`` ``w`` in [0, 1] scales the
  coating's reflection; the transmission is that of the unscaled coating (the rest is absorbed),
  so ``w`` enters linearly.
- ``conductor`` (:class:`ConductorBRDF`): GGX with OpenPBR's F82-tint Fresnel
  (Hoffman 2019; Kutz et al. 2021): ``F = S(c) - c (1-c)^6 (1 - specular_color) S(1/7) / ((1/7)(6/7)^6)``,
  ``S(c) = base_color + (1 - base_color)(1 - c)^5`` (Schlick), ``c = h.wi``; ``base_color`` is
  the reflectance at normal incidence, ``specular_color`` the tint at 82 degrees; no diffuse term.
- ``sheen`` (:class:`SheenBRDF`, fabrics and felts): OpenPBR's ``fuzz`` as a Charlie sheen lobe
  (Estevez & Kulla 2017, with the glTF ``KHR_materials_sheen`` Lambda fit) of colour
  ``fuzz_color`` and roughness ``fuzz_roughness``, weighted by ``fuzz_weight`` (OpenPBR's mix), over the
  dielectric model above (``coat=False``: over the diffuse base alone).  The fuzz layer reflects
  ``fuzz_weight fuzz_color`` times the lobe and transmits ``1 - fuzz_weight E_fuzz``: the base is
  attenuated by ``t = (1 - fuzz_weight E_fuzz)(1 - E_coat)`` on both sides (normalised as above) and
  the coating's lobe by ``min(1 - fuzz_weight E_fuzz(cos_i), 1 - fuzz_weight E_fuzz(cos_o))``, which keeps
  the albedo ``fw fuzz E_fuzz + (1 - fw E_fuzz)(w E_coat + base (1 - E_coat)) <= 1``; ``fuzz_weight = 0``
  is the model without fuzz.

Roughness convention (OpenPBR, glTF): GGX ``alpha = specular_roughness^2``, Charlie
``alpha = fuzz_roughness^2``.  Oren-Nayar: the qualitative model of :mod:`brdfrig.fit.analytic`
with ``base_diffuse_roughness`` its slope deviation ``sigma`` in radians (OpenPBR 1.0's
Oren-Nayar roughness parameter is a different mapping; ``to_dict`` records the convention).

The directional tables are integrated numerically when a BRDF is built (:func:`coat_albedo`,
:func:`sheen_albedo`) and travel in the kernel rows of :mod:`brdfrig.fit.analytic`
(``KIND_LAYERED``, ``KIND_CONDUCTOR``), so rendering, ``evaluate`` and the fits share one formula.
Fitting: :mod:`brdfrig.fit.pbr_fit`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numba
import numpy as np

from brdfrig.fit.analytic import (
    CONDUCTOR_PARAMS,
    F82_COS,
    KIND_CONDUCTOR,
    KIND_LAYERED,
    LAYERED_HEAD,
    LAYERED_PARAMS,
    TABLE_SIZE,
    AnalyticBRDF,
    _per_channel,
    _set_channels,
    charlie_sheen,
    fresnel_dielectric,
    oren_nayar_ab,
    smith_lambda,
)
from brdfrig.fit.brdf import register_model
from brdfrig.fit.groundtruth import render_sharp
from brdfrig.fit.quadrature import merge_cone
from brdfrig.fit.rho import LAYERED_SHEEN, sheen_table

__all__ = [
    "COS_NODES",
    "SIGMA_MAX",
    "FRESNEL_DEGREE",
    "fresnel_coefficients",
    "legendre_into",
    "coat_moments",
    "coat_albedo",
    "sheen_albedo",
    "layered_rows",
    "lobe_rule",
    "DielectricBRDF",
    "SheenBRDF",
    "ConductorBRDF",
]

COS_NODES = (np.arange(TABLE_SIZE) / (TABLE_SIZE - 1)) ** 2
"""Cosines of the directional tables' nodes (dense toward grazing, where the albedos change fastest)."""
SIGMA_MAX = math.pi / 2
"""Largest Oren-Nayar slope deviation (radians)."""
ALPHA_MIN = 1e-4
"""Smallest GGX / Charlie alpha (roughness 0.01)."""
IOR_RANGE = (1.0, 3.0)
"""Accepted ``specular_ior``."""
_GL_U = np.polynomial.legendre.leggauss(48)
_N_PHI = 64


FRESNEL_DEGREE = 11
"""Degree of the Legendre expansion of a Fresnel term in ``2 cos_d - 1`` (exact for Schlick and F82;
2e-5 absolute for the dielectric Fresnel at IOR 1.3-2)."""


_FIT_COS = np.linspace(0.0, 1.0, 2001)
_FIT_PINV = np.linalg.pinv(np.polynomial.legendre.legvander(2 * _FIT_COS - 1, FRESNEL_DEGREE))


def _legendre_fit(f) -> np.ndarray:
    """Legendre coefficients (FRESNEL_DEGREE + 1,) of ``f(c)`` in ``x = 2c - 1``, least squares on a fine grid."""
    return _FIT_PINV @ f(_FIT_COS)


@numba.njit(cache=True, fastmath=False)
def _fresnel_array(c: np.ndarray, eta: float) -> np.ndarray:
    out = np.empty(c.size)
    for k in range(c.size):
        out[k] = fresnel_dielectric(c[k], eta)
    return out


@lru_cache(maxsize=512)
def fresnel_coefficients(ior: float) -> np.ndarray:
    """Legendre coefficients of the dielectric Fresnel ``F(c; ior)`` (:data:`FRESNEL_DEGREE`)."""
    out = _legendre_fit(lambda c: _fresnel_array(c, float(ior)))
    out.setflags(write=False)
    return out


_RECURSION = np.array([[(2 * j - 1) / max(j, 1), (j - 1) / max(j, 1)] for j in range(FRESNEL_DEGREE + 1)])
"""Bonnet's recursion ``P_j = a_j x P_{j-1} - b_j P_{j-2}``: rows ``(a_j, b_j) = ((2j - 1) / j, (j - 1) / j)``,
precomputed so that a step multiplies instead of dividing (the lobe-moment kernels run it at every light sample)."""


@numba.njit(cache=True, fastmath=False)
def legendre_into(x: float, out: np.ndarray) -> None:
    """Legendre polynomials ``P_0 .. P_{size-1}(x)`` into ``out`` (three-term recursion; ``size`` at most
    ``FRESNEL_DEGREE + 1``)."""
    out[0] = 1.0
    if out.size > 1:
        out[1] = x
    before, last = 1.0, x
    for j in range(2, out.size):
        before, last = last, _RECURSION[j, 0] * x * last - _RECURSION[j, 1] * before
        out[j] = last


@numba.njit(cache=True, fastmath=False)
def _coat_moments_kernel(alpha: float, cos_nodes: np.ndarray, u: np.ndarray, wu: np.ndarray, n_phi: int, degree: int) -> np.ndarray:
    """Fresnel moments of the GGX lobe's directional albedo at each cosine, integrated over half vectors.

    With ``tan^2 theta_h = alpha^2 u / (1 - u)`` (the GGX sampling map) ``D cos_h dw_h = du dphi / (2 pi)``, so
    ``E = int F(wo.h) G2 (wo.h) / (cos_o cos_h) du dphi / (2 pi)`` (Gauss-Legendre in ``u``, midpoints in
    ``phi``); moment ``d`` has ``P_d(2 wo.h - 1)`` in place of ``F``.
    """
    out = np.zeros((cos_nodes.size, degree + 1))
    leg = np.empty(degree + 1)
    for m in range(cos_nodes.size):
        mu = max(cos_nodes[m], 1e-3)
        so = math.sqrt(1.0 - mu * mu)
        lam_o = smith_lambda(mu, alpha)
        for a in range(u.size):
            t2 = alpha * alpha * u[a] / (1.0 - u[a])
            ch = 1.0 / math.sqrt(1.0 + t2)
            sh = math.sqrt(t2) * ch
            for b in range(n_phi):
                phi = (b + 0.5) * math.pi / n_phi  # symmetric in phi: integrate [0, pi]
                d = so * sh * math.cos(phi) + mu * ch
                if d <= 0.0:
                    continue
                ci = 2.0 * d * ch - mu
                if ci <= 0.0:
                    continue
                val = wu[a] * d / ((1.0 + lam_o + smith_lambda(ci, alpha)) * mu * ch * n_phi)
                legendre_into(2.0 * d - 1.0, leg)
                for k in range(degree + 1):
                    out[m, k] += val * leg[k]
    return out


_FINE = 4
_FINE_NODES = (np.arange(_FINE * (TABLE_SIZE - 1) + 1) / (_FINE * (TABLE_SIZE - 1))) ** 2


def _upper_table(fine: np.ndarray) -> np.ndarray:
    """Node values whose piecewise-linear interpolant lies on or above every fine sample.

    The nodes take the true values, each raised by the largest excess of the fine samples over the
    chord in the two intervals beside it; a transmission ``1 - E`` drawn from the table then never
    exceeds the true one (energy conservation holds at every angle, including 89.9 degrees where
    the albedos curve fastest), at a cost of at most that excess (< 0.01 measured).
    """
    nodes = fine[::_FINE].copy()
    f = np.arange(_FINE + 1) / _FINE
    excess = np.array([np.max(fine[_FINE * k : _FINE * k + _FINE + 1] - ((1 - f) * nodes[k] + f * nodes[k + 1])) for k in range(TABLE_SIZE - 1)])
    excess = np.maximum(excess, 0.0)
    return nodes + np.maximum(np.r_[0.0, excess], np.r_[excess, 0.0])


@lru_cache(maxsize=64)
def coat_moments(alpha: float) -> np.ndarray:
    """Fresnel moments (fine nodes, FRESNEL_DEGREE + 1) of the GGX directional albedo (see :func:`coat_albedo`)."""
    x, w = _GL_U
    out = _coat_moments_kernel(float(alpha), _FINE_NODES, 0.5 * (x + 1), 0.5 * w, _N_PHI, FRESNEL_DEGREE)
    out.setflags(write=False)
    return out


def coat_albedo(alpha: float, ior: float) -> np.ndarray:
    """Directional albedo ``E_coat(cos)`` (TABLE_SIZE,) at :data:`COS_NODES` of the unit-weight GGX dielectric lobe.

    The Fresnel moments of :func:`coat_moments` times :func:`fresnel_coefficients`; node values bound
    the albedo from above between nodes (:func:`_upper_table`).
    """
    return _upper_table(coat_moments(float(alpha)) @ fresnel_coefficients(float(ior)))


@numba.njit(cache=True, fastmath=False)
def _sheen_albedo_kernel(alpha: float, cos_nodes: np.ndarray, x: np.ndarray, wx: np.ndarray, n_phi: int) -> np.ndarray:
    """Directional albedo of the Charlie lobe: Gauss-Legendre in ``cos_i``, midpoints in ``phi``."""
    out = np.zeros(cos_nodes.size)
    for m in range(cos_nodes.size):
        mu = max(cos_nodes[m], 1e-3)
        so = math.sqrt(1.0 - mu * mu)
        acc = 0.0
        for a in range(x.size):
            ci = x[a]
            si = math.sqrt(1.0 - ci * ci)
            for b in range(n_phi):
                phi = (b + 0.5) * math.pi / n_phi
                cos_io = si * so * math.cos(phi) + ci * mu
                acc += wx[a] * charlie_sheen(ci, mu, cos_io, alpha) * ci
        out[m] = acc * 2.0 * math.pi / n_phi
    return out


@lru_cache(maxsize=64)
def sheen_albedo(alpha: float) -> np.ndarray:
    """Directional albedo ``E_fuzz(cos)`` (TABLE_SIZE,) at :data:`COS_NODES` of the unit-colour Charlie lobe (upper bound as above)."""
    x, w = _GL_U
    out = _upper_table(_sheen_albedo_kernel(float(alpha), _FINE_NODES, 0.5 * (x + 1), 0.5 * w, _N_PHI))
    out.setflags(write=False)
    return out


def table_values(table: np.ndarray, mu: np.ndarray) -> np.ndarray:
    """The piecewise-linear table of :func:`brdfrig.fit.analytic.table_lookup` evaluated at cosines ``mu``."""
    x = np.sqrt(np.clip(mu, 0.0, 1.0)) * (TABLE_SIZE - 1)
    k = np.minimum(x.astype(np.int64), TABLE_SIZE - 2)
    f = x - k
    return (1 - f) * table[k] + f * table[k + 1]


def _base_norm(t: np.ndarray) -> float:
    """``N = 2 int_0^1 t(mu) mu dmu`` of the tabulated transmission (fine trapezoid on the interpolant)."""
    mu = np.linspace(0.0, 1.0, 4097)
    return float(np.trapezoid(2 * table_values(t, mu) * mu, mu))


def layered_rows(
    amplitudes: np.ndarray, alpha: float, ior: float, fuzz_alpha: float, coat: bool, fuzz_weight: float
) -> np.ndarray:
    """Kernel rows (K, LAYERED_PARAMS) of ``KIND_LAYERED`` for amplitude rows ``(dA, dB, w, fuzz)`` (K, 4).

    The shape parameters (``alpha``, ``ior``, ``fuzz_alpha``), whether the coating exists and the fuzz
    layer's ``fuzz_weight`` (0: none) fix the tables; the amplitudes enter the BRDF linearly (a fit
    renders unit rows as its columns).  ``fuzz`` is the fuzz lobe's amplitude ``fuzz_weight * fuzz_color``.
    """
    amplitudes = np.atleast_2d(np.asarray(amplitudes, dtype=np.float64))
    t_coat = 1.0 - coat_albedo(alpha, ior) if coat else np.ones(TABLE_SIZE)
    t_fuzz = 1.0 - fuzz_weight * sheen_albedo(fuzz_alpha) if fuzz_weight > 0 else np.ones(TABLE_SIZE)
    t = np.clip(t_coat * t_fuzz, 0.0, 1.0)
    rows = np.zeros((len(amplitudes), LAYERED_PARAMS))
    rows[:, 0:3] = amplitudes[:, 0:3]
    rows[:, 5] = amplitudes[:, 3]
    rows[:, 3], rows[:, 4], rows[:, 6], rows[:, 7] = alpha, ior, fuzz_alpha, 1.0 / _base_norm(t)
    rows[:, LAYERED_HEAD : LAYERED_HEAD + TABLE_SIZE] = t
    rows[:, LAYERED_HEAD + TABLE_SIZE : LAYERED_SHEEN] = np.clip(t_fuzz, 0.0, 1.0)
    rows[:, LAYERED_SHEEN:] = sheen_table(fuzz_alpha)
    if not coat:
        rows[:, 2] = 0.0
    if fuzz_weight <= 0:
        rows[:, 5] = 0.0
    return rows


SHARP_CONE_MAX_DEG = 20.0
SHARP_SUBDIV_MAX = 12


def lobe_rule(alpha: float, env, width: float = 0.5) -> tuple[float, int] | None:
    """Cone (degrees) and subdivision of the sharp-lobe quadrature for a GGX lobe of ``alpha`` under ``env``.

    Sub-cells at most ``width * alpha`` radians wide (``width = 0.5``: the spacing that kept the cell-centre
    renders of :mod:`brdfrig.fit.microfacet` within 2e-4; measured 4e-4 against 24 x 24 sub-cells at
    alpha = 0.01 on a 128 x 64 map), within ``6 alpha`` radians of the mirror direction
    (at least 2.5 cells, at most :data:`SHARP_CONE_MAX_DEG`); None when the map's cells are already
    that fine (or ``env`` keeps no lat-long map): cell centres suffice.
    """
    if getattr(env, "latlong", None) is None:
        return None
    cell = math.pi / env.latlong.image.shape[0]
    s = min(SHARP_SUBDIV_MAX, math.ceil(cell / (width * alpha)))
    if s <= 1:
        return None
    cone = min(SHARP_CONE_MAX_DEG, max(math.degrees(6 * alpha), 2.5 * math.degrees(cell)))
    return cone, s


def _render(brdf, alpha: float, env, normals) -> np.ndarray:
    """Quadrature of ``brdf`` whose sharpest lobe has ``alpha``: :func:`lobe_rule` within the lobe, cells merged in
    2 x 2 blocks beyond :data:`brdfrig.fit.quadrature.MERGE_CONE_DEG` of the mirror direction where the map allows."""
    cone, subdiv = lobe_rule(alpha, env) or (0.0, 1)
    return render_sharp(brdf, normals, env, cone, subdiv, merge_cone(env))


def _scalar(name: str, value, lower: float, upper: float) -> float:
    arr = _per_channel(name, value, lower, upper)
    if arr.size != 1:
        raise ValueError(f"{name} is one value shared by all channels, got {arr.tolist()}")
    return float(arr[0])


@dataclass(frozen=True, eq=False)
class _Layered(AnalyticBRDF):
    """Shared body of :class:`DielectricBRDF` and :class:`SheenBRDF` (module docstring)."""

    base_color: np.ndarray
    base_diffuse_roughness: np.ndarray = 0.0
    specular_weight: float = 1.0
    specular_roughness: float = 0.3
    specular_ior: float = 1.5
    fuzz_color: np.ndarray = 0.0
    fuzz_roughness: float = 0.5
    coat: bool = True
    fuzz_weight: float = 1.0
    kind = KIND_LAYERED

    def __post_init__(self) -> None:
        _set_channels(
            self,
            base_color=_per_channel("base_color", self.base_color, 0.0, 1.0),
            base_diffuse_roughness=_per_channel("base_diffuse_roughness", self.base_diffuse_roughness, 0.0, SIGMA_MAX),
            fuzz_color=_per_channel("fuzz_color", self.fuzz_color, 0.0, 1.0),
        )
        object.__setattr__(self, "specular_weight", _scalar("specular_weight", self.specular_weight, 0.0, 1.0))
        object.__setattr__(self, "specular_roughness", _scalar("specular_roughness", self.specular_roughness, math.sqrt(ALPHA_MIN), 1.0))
        object.__setattr__(self, "specular_ior", _scalar("specular_ior", self.specular_ior, *IOR_RANGE))
        object.__setattr__(self, "fuzz_roughness", _scalar("fuzz_roughness", self.fuzz_roughness, math.sqrt(ALPHA_MIN), 1.0))
        object.__setattr__(self, "coat", bool(self.coat))
        object.__setattr__(self, "fuzz_weight", _scalar("fuzz_weight", self.fuzz_weight, 0.0, 1.0) if self.model == "sheen" else 0.0)
        ab = np.array([oren_nayar_ab(float(s)) for s in self.base_diffuse_roughness]).reshape(-1, 2)
        amps = np.stack([self.base_color * ab[:, 0], self.base_color * ab[:, 1],
                         np.full(self.base_color.size, self.specular_weight), self.fuzz_weight * self.fuzz_color], axis=1)
        rows = layered_rows(amps, self.specular_roughness**2, self.specular_ior, self.fuzz_roughness**2,
                            self.coat, self.fuzz_weight)
        object.__setattr__(self, "_rows", rows)

    def kernel_params(self) -> np.ndarray:
        return self._rows

    def predict(self, env, normals: np.ndarray) -> np.ndarray:
        """Radiance (N, C) seen from ``v = (0, 0, 1)``: quadrature over ``env`` (:func:`lobe_rule` for the coating's lobe)."""
        return _render(self, self.specular_roughness**2 if self.coat and self.specular_weight > 0 else 1.0, env, normals)

    def to_dict(self) -> dict:
        return {
            "model": self.model,
            "base_color": self.base_color.tolist(),
            "base_diffuse_roughness": self.base_diffuse_roughness.tolist(),
            "specular_weight": self.specular_weight if self.coat else 0.0,
            "specular_color": [1.0] * self.base_color.size,
            "specular_roughness": self.specular_roughness,
            "specular_ior": self.specular_ior,
            "coat": self.coat,
            "fuzz_weight": self.fuzz_weight,
            "fuzz_color": self.fuzz_color.tolist(),
            "fuzz_roughness": self.fuzz_roughness,
            "conventions": {
                "specular_alpha": "specular_roughness**2 (GGX, height-correlated Smith)",
                "base_diffuse_roughness": "qualitative Oren-Nayar slope deviation sigma, radians",
                "fuzz": "Charlie sheen, alpha = fuzz_roughness**2, Estevez-Kulla Lambda",
                "specular_weight": "scales the coating's reflection; transmission is that of weight 1",
            },
        }

    @classmethod
    def from_dict(cls, d: dict):
        keys = ("base_color", "base_diffuse_roughness", "specular_weight", "specular_roughness", "specular_ior",
                "fuzz_color", "fuzz_roughness", "coat", "fuzz_weight")
        return cls(**{k: d[k] for k in keys if k in d})


@register_model("dielectric")
@dataclass(frozen=True, eq=False)
class DielectricBRDF(_Layered):
    """GGX dielectric coating over an Oren-Nayar base (module docstring); ``fuzz_color`` must be 0."""

    model = "dielectric"

    def __post_init__(self) -> None:
        super().__post_init__()
        if np.any(self.fuzz_color > 0) or not self.coat:
            raise ValueError("a dielectric BRDF has a coating and no fuzz (use SheenBRDF for fuzz)")


@register_model("sheen")
@dataclass(frozen=True, eq=False)
class SheenBRDF(_Layered):
    """Charlie fuzz over the dielectric model (``coat=True``) or over the diffuse base alone (module docstring)."""

    model = "sheen"


@register_model("conductor")
@dataclass(frozen=True, eq=False)
class ConductorBRDF(AnalyticBRDF):
    """GGX conductor with the F82-tint Fresnel (module docstring).

    Parameters (per channel unless noted): ``base_color`` reflectance at normal incidence in [0, 1],
    ``specular_color`` edge tint in [0, 1] (1 = plain Schlick), ``specular_roughness`` (one value,
    ``alpha = specular_roughness^2``), ``specular_weight`` (one value in [0, 1]).
    """

    base_color: np.ndarray
    specular_color: np.ndarray = 1.0
    specular_roughness: float = 0.3
    specular_weight: float = 1.0
    model = "conductor"
    kind = KIND_CONDUCTOR

    def __post_init__(self) -> None:
        _set_channels(
            self,
            base_color=_per_channel("base_color", self.base_color, 0.0, 1.0),
            specular_color=_per_channel("specular_color", self.specular_color, 0.0, 1.0),
        )
        object.__setattr__(self, "specular_roughness", _scalar("specular_roughness", self.specular_roughness, math.sqrt(ALPHA_MIN), 1.0))
        object.__setattr__(self, "specular_weight", _scalar("specular_weight", self.specular_weight, 0.0, 1.0))

    def kernel_params(self) -> np.ndarray:
        f0, w = self.base_color, self.specular_weight
        k5 = (1 - F82_COS) ** 5
        edge = (1 - self.specular_color) * (f0 + (1 - f0) * k5)
        rows = np.zeros((f0.size, CONDUCTOR_PARAMS))
        rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3] = w * f0, w, w * edge, self.specular_roughness**2
        return rows

    def predict(self, env, normals: np.ndarray) -> np.ndarray:
        """Radiance (N, C) seen from ``v = (0, 0, 1)``: quadrature over ``env`` (:func:`lobe_rule`)."""
        return _render(self, self.specular_roughness**2, env, normals)

    def to_dict(self) -> dict:
        return {
            "model": self.model,
            "base_metalness": 1.0,
            "base_color": self.base_color.tolist(),
            "specular_color": self.specular_color.tolist(),
            "specular_roughness": self.specular_roughness,
            "specular_weight": self.specular_weight,
            "conventions": {"specular_alpha": "specular_roughness**2 (GGX, height-correlated Smith)",
                            "fresnel": "OpenPBR F82-tint (Schlick base_color, specular_color tint at 1/7)"},
        }

    @classmethod
    def from_dict(cls, d: dict) -> "ConductorBRDF":
        return cls(base_color=d["base_color"], specular_color=d.get("specular_color", 1.0),
                   specular_roughness=d["specular_roughness"], specular_weight=d.get("specular_weight", 1.0))
