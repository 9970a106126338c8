"""Mitsuba 3's own BSDFs as brdfrig evaluates them: what a ``--format mitsuba`` export renders in Mitsuba.

Each class has the interface of :mod:`brdfrig.fit.pbr`'s BRDFs (``channels``, ``rho(wi, wo, n)`` in 1/sr
without the cosine, ``evaluate(theta_i, theta_o, delta_phi)``, ``predict(env, normals)``) and writes
itself as a Mitsuba ``<bsdf>`` element (``xml()``) or plugin dictionary (``mitsuba_dict()``).
The formulas are those of Mitsuba 3.x's plugins (``diffuse.cpp``, ``roughplastic.cpp``,
``principled.cpp`` with ``principledhelpers.h``, ``microfacet.h``), written from their maths:

- ``diffuse`` (:class:`MitsubaDiffuse`): ``rho = reflectance / pi``;
- ``roughplastic`` (:class:`MitsubaRoughPlastic`, GGX, ``nonlinear`` false unless set)::

      rho = s F(wi.h; eta) D(h) G1(wi) G1(wo) / (4 cos_i cos_o)
            + R / (1 - F_dr,int) t(cos_i) t(cos_o) / (pi eta^2)

  with ``s`` = ``specular_reflectance`` (1 when absent), ``R`` = ``diffuse_reflectance``
  (``nonlinear``: ``R / (1 - R F_dr,int)``), the separable Smith ``G1``, the exact unpolarised
  Fresnel ``F`` at ``eta = int_ior / ext_ior``, ``t`` the rough interface's transmittance
  tabulated at 64 cosines ``linspace(0, 1, 64)`` (first node 1e-6) and linearly interpolated,
  ``F_dr,int = 2 mean_k(R_int(mu_k) mu_k)`` over the same nodes (the rough interface's
  reflectance from inside, at ``1 / eta``).  Both are Mitsuba's quadratures, reproduced node for
  node: Gauss-Legendre (32 x 32 outside, 128 x 128 inside) on the unit square mapped by
  Mitsuba's GGX visible-normal sampler, the integrand ``(1 - F) G1(wt)`` (refracted ``wt``) or
  ``F G1(wr)`` (reflected ``wr``);
- ``principled`` (:class:`MitsubaPrincipled`, without sheen, clearcoat, transmission, tint,
  anisotropy or flatness)::

      rho = F_p(wi.h) D G1(wi) G1(wo) / (4 cos_i cos_o)
            + (1 - metallic) base_color / pi ((1 - Fi/2)(1 - Fo/2) + Rr (Fo + Fi + Fo Fi (Rr - 1)))

  ``F_p = (1 - metallic) F(wi.h; eta) + metallic Schlick(base_color)``, ``Fx = (1 - cos_x)^5``,
  ``Rr = 2 roughness (wo.h)^2``, GGX ``alpha = max(0.001, roughness^2)``,
  ``eta = 2 / (1 - sqrt(0.08 specular)) - 1``.

All are reciprocal, so ``wi`` (light) and ``wo`` (view) may be swapped against Mitsuba's naming.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numba
import numpy as np

__all__ = ["TRANSMITTANCE_RES", "rough_interface", "MitsubaDiffuse", "MitsubaRoughPlastic", "MitsubaPrincipled"]

TRANSMITTANCE_RES = 64
"""Cosine nodes of roughplastic's transmittance table (Mitsuba's ``MI_ROUGH_TRANSMITTANCE_RES``)."""
ALPHA_MIN = 1e-4
"""Mitsuba's smallest microfacet alpha."""


@numba.njit(cache=True, fastmath=False)
def _fresnel_one(cos_i: float, eta: float) -> tuple[float, float, float]:
    """Unpolarised dielectric Fresnel at relative IOR ``eta`` for a signed ``cos_i`` (negative: from inside).

    Returns (reflectance, signed cosine of the transmitted ray, ``eta_ti``); total internal reflection
    and ``cos_i = 0`` give reflectance 1.
    """
    eta_it = eta if cos_i >= 0 else 1.0 / eta
    eta_ti = 1.0 / eta_it
    cos_t2 = 1.0 - (1.0 - cos_i * cos_i) * eta_ti * eta_ti
    ci = abs(cos_i)
    ct = math.sqrt(max(cos_t2, 0.0))
    if ci == 0.0:
        r = 1.0
    else:
        a_s = (ci - eta_it * ct) / (ci + eta_it * ct)
        a_p = (ct - eta_it * ci) / (ct + eta_it * ci)
        r = 0.5 * (a_s * a_s + a_p * a_p)
    return r, (-ct if cos_i >= 0 else ct), eta_ti


@numba.njit(cache=True, fastmath=False)
def _fresnel(cos_i: np.ndarray, eta: float) -> np.ndarray:
    """Reflectance of :func:`_fresnel_one` at each cosine of a 1-D array."""
    out = np.empty(cos_i.size)
    for k in range(cos_i.size):
        out[k] = _fresnel_one(cos_i[k], eta)[0]
    return out


def _ggx_d(cos_h: np.ndarray, alpha: float) -> np.ndarray:
    """GGX normal distribution at microfacet cosine ``cos_h`` (0 where Mitsuba cuts it: ``D cos_h <= 1e-20``)."""
    c2 = cos_h * cos_h
    d = 1.0 / (math.pi * alpha * alpha * ((1.0 - c2) / (alpha * alpha) + c2) ** 2)
    return np.where(d * cos_h > 1e-20, d, 0.0)


@numba.njit(cache=True, fastmath=False)
def _smith_g1_one(cos_v: float, v_dot_m: float, alpha: float) -> float:
    """Mitsuba's GGX ``smith_g1`` of a direction with normal cosine ``cos_v`` and microfacet cosine ``v_dot_m``."""
    if v_dot_m * cos_v <= 0.0:
        return 0.0
    c2 = cos_v * cos_v
    if c2 >= 1.0:
        return 1.0
    return 2.0 / (1.0 + math.sqrt(1.0 + alpha * alpha * (1.0 - c2) / c2))


@numba.njit(cache=True, fastmath=False)
def _smith_g1(cos_v: np.ndarray, v_dot_m: np.ndarray, alpha: float) -> np.ndarray:
    """:func:`_smith_g1_one` over 1-D arrays."""
    out = np.empty(cos_v.size)
    for k in range(cos_v.size):
        out[k] = _smith_g1_one(cos_v[k], v_dot_m[k], alpha)
    return out


@numba.njit(cache=True, fastmath=False)
def _concentric_disk(u: float, v: float) -> tuple[float, float]:
    """Shirley-Chiu concentric map of the unit square onto the unit disk."""
    x, y = 2.0 * u - 1.0, 2.0 * v - 1.0
    if abs(x) < abs(y):
        r, phi = y, 0.5 * math.pi - 0.25 * math.pi * x / y
    elif x == 0.0:
        r, phi = 0.0, 0.0
    else:
        r, phi = x, 0.25 * math.pi * y / x
    return r * math.cos(phi), r * math.sin(phi)


@numba.njit(cache=True, fastmath=False)
def _visible_normal(ct: float, st: float, cos_phi: float, alpha: float, px: float, py: float) -> tuple[float, float, float]:
    """Mitsuba's GGX visible normal for a view stretched by ``alpha`` to polar cosine/sine ``ct``, ``st``.

    ``(px, py)``: the square sample on the disk; it is warped toward the projected hemisphere of the
    stretched view, converted to a slope, turned by the view's azimuth (``cos_phi``, sine 0) and unstretched.
    """
    s = 0.5 * (1.0 + ct)
    py = (1.0 - s) * math.sqrt(max(1.0 - px * px, 0.0)) + s * py
    pz = math.sqrt(max(1.0 - px * px - py * py, 0.0))
    k = 1.0 / (st * py + ct * pz)
    sx, sy = (ct * py - st * pz) * k * cos_phi * alpha, px * k * cos_phi * alpha
    n = math.sqrt(sx * sx + sy * sy + 1.0)
    return -sx / n, -sy / n, 1.0 / n


@numba.njit(cache=True, fastmath=False)
def _interface_quadrature(alpha: float, eta: float, mu: np.ndarray, nodes: np.ndarray, weights: np.ndarray,
                          transmit: bool) -> np.ndarray:
    """Mitsuba's ``eval_transmittance`` (``transmit``) or ``eval_reflectance`` of a rough interface at cosines ``mu``.

    Views ``(sqrt(1 - mu^2), 0, mu)``; Gauss-Legendre ``nodes``, ``weights`` on [-1, 1] in both square
    coordinates mapped through the visible-normal sampler; the integrand is ``(1 - F) G1(wt)`` for the
    refracted ``wt`` below the surface, or ``F G1(wr)`` for the reflected ``wr`` above it.
    """
    n = nodes.size
    disk = np.empty((n * n, 3))
    for i in range(n):
        for j in range(n):
            px, py = _concentric_disk(0.5 * nodes[j] + 0.5, 0.5 * nodes[i] + 0.5)
            disk[i * n + j] = px, py, weights[i] * weights[j] * 0.25
    out = np.zeros(mu.size)
    for a in range(mu.size):
        wix, wiz = math.sqrt(max(1.0 - mu[a] * mu[a], 0.0)), mu[a]
        norm = math.sqrt(alpha * alpha * wix * wix + wiz * wiz)
        ct = wiz / norm
        st2 = 1.0 - ct * ct
        cos_phi = 1.0 if st2 <= 4 * 1.1920929e-07 else min(alpha * wix / norm / math.sqrt(st2), 1.0)
        st = math.sqrt(max(st2, 0.0))
        acc = 0.0
        for q in range(n * n):
            mx, my, mz = _visible_normal(ct, st, cos_phi, alpha, disk[q, 0], disk[q, 1])
            c = wix * mx + wiz * mz
            f, cos_t, eta_ti = _fresnel_one(c, eta)
            if transmit:
                k = c * eta_ti + cos_t
                ox, oy, oz = mx * k - wix * eta_ti, my * k, mz * k - wiz * eta_ti
                val = 0.0 if oz * wiz >= 0.0 else _smith_g1_one(oz, ox * mx + oy * my + oz * mz, alpha) * (1.0 - f)
            else:
                ox, oy, oz = 2.0 * c * mx - wix, 2.0 * c * my, 2.0 * c * mz - wiz
                val = 0.0 if oz <= 0.0 or wiz <= 0.0 else _smith_g1_one(oz, ox * mx + oy * my + oz * mz, alpha) * f
            acc += val * disk[q, 2]
        out[a] = acc
    return out


@lru_cache(maxsize=64)
def rough_interface(alpha: float, eta: float) -> tuple[np.ndarray, float]:
    """roughplastic's transmittance table (TRANSMITTANCE_RES,) and internal diffuse reflectance ``F_dr,int``.

    ``alpha`` and ``eta`` as Mitsuba holds them (alpha >= :data:`ALPHA_MIN`); cached (the table is read-only).
    """
    mu = np.maximum(1e-6, np.linspace(0.0, 1.0, TRANSMITTANCE_RES))
    outside, inside = (np.polynomial.legendre.leggauss(32 if e > 1 else 128) for e in (eta, 1.0 / eta))
    table = _interface_quadrature(float(alpha), float(eta), mu, *outside, True)
    internal = 2.0 * float(np.mean(_interface_quadrature(float(alpha), 1.0 / eta, mu, *inside, False) * mu))
    table.setflags(write=False)
    return table, internal


def _table_at(table: np.ndarray, cos: np.ndarray) -> np.ndarray:
    """Mitsuba's ``lerp_gather``: the table's linear interpolant at cosines in [0, 1]."""
    x = np.clip(cos, 0.0, 1.0) * (len(table) - 1)
    k = np.minimum(x.astype(np.int64), len(table) - 2)
    return table[k] + (x - k) * (table[k + 1] - table[k])


def _rgb(v: np.ndarray) -> str:
    return ", ".join(f"{x:.6g}" for x in v)


def _colour(name: str, value) -> np.ndarray:
    """An RGB colour (3,) from 1 or 3 finite values >= 0 (Mitsuba's ``rgb``)."""
    arr = np.atleast_1d(np.asarray(value, dtype=np.float64)).ravel()
    if arr.size not in (1, 3) or not np.all(np.isfinite(arr)) or np.any(arr < 0):
        raise ValueError(f"{name} must be 1 or 3 finite values >= 0, got {np.asarray(value).tolist()}")
    return np.broadcast_to(arr, (3,)).copy()


class _MitsubaBSDF:
    """Shared interface: the cosines of ``rho``, ``evaluate`` in the local frame, ``predict`` by quadrature."""

    model: str
    lobe_alpha: float | None = None

    @property
    def channels(self) -> int:
        return self._colour().size

    def _colour(self) -> np.ndarray:
        raise NotImplementedError

    def _rho(self, cos_i, cos_o, cos_h, cos_d) -> np.ndarray:
        raise NotImplementedError

    def rho(self, wi, wo, n) -> np.ndarray:
        """BRDF (M, C) in 1/sr for world-frame unit ``wi``, ``wo``, ``n`` (each (M, 3) or (3,)); 0 below either horizon."""
        wi, wo, n = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64).reshape(-1, 3) for a in (wi, wo, n)))
        h = wi + wo
        h = h / np.maximum(np.linalg.norm(h, axis=1, keepdims=True), 1e-300)
        cos_i, cos_o = np.einsum("ij,ij->i", wi, n), np.einsum("ij,ij->i", wo, n)
        cos_h, cos_d = np.einsum("ij,ij->i", h, n), np.einsum("ij,ij->i", h, wi)
        ok = (cos_i > 0) & (cos_o > 0)
        out = np.zeros((len(wi), self.channels))
        if np.any(ok):
            out[ok] = self._rho(cos_i[ok], cos_o[ok], cos_h[ok], cos_d[ok])
        return out

    def evaluate(self, theta_i, theta_o, delta_phi) -> np.ndarray:
        """BRDF at polar angles and ``delta_phi = phi_o - phi_i`` (radians, local frame): shape ``broadcast + (C,)``."""
        ti, to, dp = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (theta_i, theta_o, delta_phi)))
        wi = np.stack([np.sin(ti), np.zeros_like(ti), np.cos(ti)], -1).reshape(-1, 3)
        wo = np.stack([np.sin(to) * np.cos(dp), np.sin(to) * np.sin(dp), np.cos(to)], -1).reshape(-1, 3)
        return self.rho(wi, wo, np.array([0.0, 0.0, 1.0])).reshape(ti.shape + (self.channels,))

    def predict(self, env, normals: np.ndarray) -> np.ndarray:
        """Radiance (N, C) toward ``v = (0, 0, 1)``: quadrature over ``env``, the lobe rule of :func:`brdfrig.fit.pbr.lobe_rule`."""
        from brdfrig.fit.groundtruth import render_rho
        from brdfrig.fit.pbr import lobe_rule

        rule = None if self.lobe_alpha is None else lobe_rule(self.lobe_alpha, env)
        return render_rho(self, normals, env, *(rule or (0.0, 1)))

    def xml(self) -> str:
        """The Mitsuba 3 ``<bsdf>`` element (scene-description XML)."""
        raise NotImplementedError


@dataclass(frozen=True, eq=False)
class MitsubaDiffuse(_MitsubaBSDF):
    """Mitsuba's ``diffuse``: Lambertian of ``reflectance`` (1 or 3 values)."""

    reflectance: np.ndarray
    model = "diffuse"

    def __post_init__(self) -> None:
        object.__setattr__(self, "reflectance", _colour("reflectance", self.reflectance))

    def _colour(self) -> np.ndarray:
        return self.reflectance

    def _rho(self, cos_i, cos_o, cos_h, cos_d) -> np.ndarray:
        return np.broadcast_to(self.reflectance / math.pi, (len(cos_i), self.channels))

    def predict(self, env, normals: np.ndarray) -> np.ndarray:
        """Radiance (N, C) toward ``v = (0, 0, 1)`` (brdfrig's Lambertian kernel: the same BRDF)."""
        from brdfrig.fit.analytic import Lambertian

        return Lambertian(self.reflectance).predict(env, normals)

    def mitsuba_dict(self) -> dict:
        return {"type": "diffuse", "reflectance": {"type": "rgb", "value": self.reflectance.tolist()}}

    def xml(self) -> str:
        return f'<bsdf type="diffuse">\n  <rgb name="reflectance" value="{_rgb(self.reflectance)}"/>\n</bsdf>'


@dataclass(frozen=True, eq=False)
class MitsubaRoughPlastic(_MitsubaBSDF):
    """Mitsuba's ``roughplastic`` with the GGX distribution (module docstring).

    ``diffuse_reflectance`` (1 or 3 values), ``alpha`` (GGX, clamped to 1e-4 as Mitsuba does),
    ``int_ior`` / ``ext_ior`` (``eta = int_ior / ext_ior``), ``specular_reflectance`` (one value),
    ``nonlinear`` (Mitsuba's flag).
    """

    diffuse_reflectance: np.ndarray
    alpha: float = 0.1
    int_ior: float = 1.49
    ext_ior: float = 1.000277
    specular_reflectance: float = 1.0
    nonlinear: bool = False
    model = "roughplastic"

    def __post_init__(self) -> None:
        object.__setattr__(self, "diffuse_reflectance", _colour("diffuse_reflectance", self.diffuse_reflectance))
        for name in ("alpha", "int_ior", "ext_ior", "specular_reflectance"):
            v = float(getattr(self, name))
            if not math.isfinite(v) or v < 0:
                raise ValueError(f"roughplastic {name} must be finite and >= 0, got {v}")
            object.__setattr__(self, name, v)
        if self.int_ior <= 0 or self.ext_ior <= 0 or self.int_ior == self.ext_ior:
            raise ValueError(f"roughplastic int_ior and ext_ior must be positive and differ, got {self.int_ior}, {self.ext_ior}")
        object.__setattr__(self, "alpha", max(self.alpha, ALPHA_MIN))

    @property
    def eta(self) -> float:
        return self.int_ior / self.ext_ior

    @property
    def lobe_alpha(self) -> float:
        return self.alpha

    def _colour(self) -> np.ndarray:
        return self.diffuse_reflectance

    def transmittance(self, cos: np.ndarray) -> np.ndarray:
        """The interface's transmittance ``t`` at cosines ``cos`` (Mitsuba's linear interpolation of its table)."""
        return _table_at(rough_interface(self.alpha, self.eta)[0], cos)

    def diffuse_amplitude(self) -> np.ndarray:
        """(C,) ``R / (1 - F_dr,int) / (pi eta^2)`` (``nonlinear``: ``R / (1 - R F_dr,int) / (pi eta^2)``).

        The diffuse term is this times ``t(cos_i) t(cos_o)``.
        """
        internal, r = rough_interface(self.alpha, self.eta)[1], self.diffuse_reflectance
        return (r / (1.0 - r * internal) if self.nonlinear else r / (1.0 - internal)) / (math.pi * self.eta**2)

    def _rho(self, cos_i, cos_o, cos_h, cos_d) -> np.ndarray:
        diffuse = self.transmittance(cos_i) * self.transmittance(cos_o)
        f = _fresnel(cos_d, self.eta)
        g = _smith_g1(cos_i, cos_d, self.alpha) * _smith_g1(cos_o, cos_d, self.alpha)
        spec = self.specular_reflectance * f * _ggx_d(cos_h, self.alpha) * g / (4.0 * cos_i * cos_o)
        return spec[:, None] + diffuse[:, None] * self.diffuse_amplitude()[None, :]

    def mitsuba_dict(self) -> dict:
        return {"type": "roughplastic", "distribution": "ggx", "alpha": self.alpha, "int_ior": self.int_ior,
                "ext_ior": self.ext_ior, "nonlinear": self.nonlinear, "specular_reflectance": self.specular_reflectance,
                "diffuse_reflectance": {"type": "rgb", "value": self.diffuse_reflectance.tolist()}}

    def xml(self) -> str:
        return (f'<bsdf type="roughplastic">\n  <string name="distribution" value="ggx"/>\n'
                f'  <float name="alpha" value="{self.alpha:.6g}"/>\n  <float name="int_ior" value="{self.int_ior:.6g}"/>\n'
                f'  <float name="ext_ior" value="{self.ext_ior:.6g}"/>\n'
                f'  <boolean name="nonlinear" value="{"true" if self.nonlinear else "false"}"/>\n'
                f'  <rgb name="diffuse_reflectance" value="{_rgb(self.diffuse_reflectance)}"/>\n'
                f'  <float name="specular_reflectance" value="{self.specular_reflectance:.6g}"/>\n</bsdf>')


@dataclass(frozen=True, eq=False)
class MitsubaPrincipled(_MitsubaBSDF):
    """Mitsuba's ``principled`` restricted to ``base_color``, ``roughness``, ``metallic``, ``specular`` (module docstring)."""

    base_color: np.ndarray
    roughness: float = 0.5
    metallic: float = 0.0
    specular: float = 0.5
    model = "principled"

    def __post_init__(self) -> None:
        object.__setattr__(self, "base_color", _colour("base_color", self.base_color))
        for name in ("roughness", "metallic", "specular"):
            v = float(getattr(self, name))
            if not 0.0 <= v <= 1.0:
                raise ValueError(f"principled {name} must be within [0, 1], got {v}")
            object.__setattr__(self, name, v)

    @property
    def eta(self) -> float:
        return 2.0 / (1.0 - math.sqrt(0.08 * self.specular)) - 1.0

    @property
    def lobe_alpha(self) -> float:
        return max(0.001, self.roughness**2)

    def _colour(self) -> np.ndarray:
        return self.base_color

    def _rho(self, cos_i, cos_o, cos_h, cos_d) -> np.ndarray:
        alpha, c, m = self.lobe_alpha, self.base_color[None, :], self.metallic
        f_diel = _fresnel(cos_d, self.eta)
        w_d = ((1.0 - np.clip(cos_d, 0.0, 1.0)) ** 5)[:, None]
        f = (1.0 - m) * f_diel[:, None] + m * (c + (1.0 - c) * w_d)
        g = _smith_g1(cos_i, cos_d, alpha) * _smith_g1(cos_o, cos_d, alpha)
        spec = f * np.where(f_diel > 0, _ggx_d(cos_h, alpha) * g / (4.0 * cos_i * cos_o), 0.0)[:, None]
        if m >= 1.0:
            return spec
        fi, fo = (1.0 - cos_i) ** 5, (1.0 - cos_o) ** 5
        rr = 2.0 * self.roughness * cos_d**2
        shape = (1.0 - 0.5 * fi) * (1.0 - 0.5 * fo) + rr * (fo + fi + fo * fi * (rr - 1.0))
        return spec + (1.0 - m) * c / math.pi * shape[:, None]

    def mitsuba_dict(self) -> dict:
        return {"type": "principled", "base_color": {"type": "rgb", "value": self.base_color.tolist()},
                "roughness": self.roughness, "metallic": self.metallic, "specular": self.specular}

    def xml(self) -> str:
        return (f'<bsdf type="principled">\n  <rgb name="base_color" value="{_rgb(self.base_color)}"/>\n'
                f'  <float name="metallic" value="{self.metallic:.6g}"/>\n  <float name="roughness" value="{self.roughness:.6g}"/>\n'
                f'  <float name="specular" value="{self.specular:.6g}"/>\n</bsdf>')
