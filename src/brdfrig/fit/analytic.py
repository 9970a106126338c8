"""Analytic isotropic BRDFs: the materials of the ground truth, the simulator and the microfacet fit.

Four families, each with one parameter value per colour channel (scalars
broadcast to every channel):

- :class:`Lambertian` ``rho = albedo / pi``;
- :class:`OrenNayar` ``rho = albedo / pi (A + B max(0, cos(phi_i - phi_o)) sin(a) tan(b))``,
  ``a = max(theta_i, theta_o)``, ``b = min(...)``, ``A = 1 - 0.5 s^2 / (s^2 + 0.33)``,
  ``B = 0.45 s^2 / (s^2 + 0.09)`` for facet slope deviation ``s`` (radians): the
  qualitative rough-diffuse model of Oren & Nayar (SIGGRAPH 1994, eq. 30), a
  non-Lambertian diffuse base (brighter toward the light at grazing view;
  ``s = 0`` is Lambertian).  In cosines the angular factor is
  ``max(0, cos_io - cos_i cos_o) / max(cos_i, cos_o)``;
- :class:`BlinnPhong` ``rho = diffuse/pi + specular * (e + 8) / (8 pi) * (n.h)^e``
  (the energy-normalised Blinn-Phong lobe, Akenine-Moller et al., *Real-Time
  Rendering*, 3rd ed., eq. 7.49);
- :class:`GGX` ``rho = diffuse base + F(h.wi) D(n.h) G2(wi, wo) / (4 (n.wi)(n.wo))``
  with the GGX / Trowbridge-Reitz distribution ``D`` (Walter et al. 2007,
  roughness ``alpha``), the height-correlated Smith shadowing-masking
  ``G2 = 1 / (1 + Lambda(wi) + Lambda(wo))`` (Heitz 2014, eq. 99) and Schlick's
  Fresnel ``F = f0 + (f90 - f0) (1 - h.wi)^5`` (``f90 = 1`` is the physical
  Schlick form; other values let the microfacet fit keep its amplitudes linear).

Every family's diffuse base is Oren-Nayar with its own ``diffuse_sigma``
(default 0: Lambertian).

Conventions (``docs/MATH.md``): ``rho`` in 1/sr without the cosine
factor, world-frame unit vectors, ``rho = 0`` when either direction is below
the horizon of the normal.  ``evaluate`` uses the normal's local frame with
``delta_phi = phi_o - phi_i`` (``delta_phi = pi`` is the mirror configuration).

An isotropic BRDF depends on the directions only through ``cos_i = n.wi``,
``cos_o = n.wo`` and ``cos_io = wi.wo``; the numba function :func:`brdfrig.fit.rho.rho_channel`
takes exactly those, so the vectorised :meth:`AnalyticBRDF.rho`, the
ground-truth renderer (:mod:`brdfrig.fit.groundtruth`) and the microfacet fit share one
implementation of every formula (:mod:`brdfrig.fit.rho`, whose names this module re-exports).
A model's parameters travel to compiled code as an integer ``kind`` and a ``(C, NUM_PARAMS)``
float array (:meth:`AnalyticBRDF.kernel_params`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from brdfrig.fit import rho as _rho
from brdfrig.fit.brdf import register_model
from brdfrig.fit.groundtruth import render_groundtruth
from brdfrig.fit.rho import (  # the kernels, re-exported: callers may import them from here
    CONDUCTOR_PARAMS,
    F82_COS,
    KIND_BLINN_PHONG,
    KIND_CONDUCTOR,
    KIND_GGX,
    KIND_LAMBERTIAN,
    KIND_LAYERED,
    LAYERED_HEAD,
    LAYERED_PARAMS,
    NUM_PARAMS,
    TABLE_SIZE,
    charlie_sheen,
    conductor_rho,
    f82_q,
    fresnel_dielectric,
    ggx_lobe,
    ggx_ndf,
    layered_rho,
    oren_nayar_ab,
    oren_nayar_factor,
    rho_channel,
    rho_from_cosines,
    smith_lambda,
    table_lookup,
)
from brdfrig.fit.scene import Environment

__all__ = ["AnalyticBRDF", "Lambertian", "OrenNayar", "BlinnPhong", "GGX", *_rho.__all__]


def _per_channel(name: str, value, lower: float, upper: float = math.inf) -> np.ndarray:
    """Validate one parameter as a (C,) float64 array in [lower, upper] (scalar -> C = 1)."""
    arr = np.atleast_1d(np.asarray(value, dtype=np.float64))
    if arr.ndim != 1 or arr.size == 0:
        raise ValueError(f"{name} must be a scalar or a 1-D sequence of per-channel values, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)) or np.any(arr < lower) or np.any(arr > upper):
        raise ValueError(f"{name} must be finite and within [{lower}, {upper}], got {arr.tolist()}")
    return arr


def _set_channels(obj, **arrays: np.ndarray) -> None:
    """Set per-channel arrays of length 1 or C as attributes of the frozen dataclass ``obj``, broadcast to a common C."""
    sizes = {a.size for a in arrays.values()} - {1}
    if len(sizes) > 1:
        raise ValueError(f"per-channel parameters disagree on the channel count: { {k: v.size for k, v in arrays.items()} }")
    c = sizes.pop() if sizes else 1
    for k, v in arrays.items():
        object.__setattr__(obj, k, np.broadcast_to(v, (c,)).copy())


class AnalyticBRDF:
    """Shared behaviour of the analytic models (implements :class:`brdfrig.fit.brdf.FittedBRDF`).

    Subclasses define ``model``, ``kind`` and :meth:`kernel_params`.
    """

    model: str
    kind: int
    stacks_lightings = True
    """:meth:`predict` renders under stacked lightings (:func:`brdfrig.fit.scene.stack_lightings`)."""

    @property
    def channels(self) -> int:
        return self.kernel_params().shape[0]

    def kernel_params(self) -> np.ndarray:
        """Parameter rows (C, NUM_PARAMS) float64 for :func:`rho_channel`."""
        raise NotImplementedError

    def rho(self, wi: np.ndarray, wo: np.ndarray, n: np.ndarray) -> np.ndarray:
        """BRDF (1/sr) for world-frame unit directions ``wi``, ``wo`` and normals ``n``, each (N, 3) -> (N, C)."""
        wi, wo, n = (np.asarray(a, dtype=np.float64).reshape(-1, 3) for a in (wi, wo, n))
        cos_i = np.einsum("ij,ij->i", n, wi)
        cos_o = np.einsum("ij,ij->i", n, wo)
        cos_io = np.einsum("ij,ij->i", wi, wo)
        return rho_from_cosines(self.kind, self.kernel_params(), cos_i, cos_o, cos_io)

    def evaluate(self, theta_i, theta_o, delta_phi) -> np.ndarray:
        """BRDF (1/sr) at polar angles ``theta_i``, ``theta_o`` and ``delta_phi = phi_o - phi_i`` (radians).

        Returns shape ``broadcast(theta_i, theta_o, delta_phi).shape + (C,)``.
        """
        ti, to, dp = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (theta_i, theta_o, delta_phi)))
        shape = ti.shape
        ti, to, dp = ti.ravel(), to.ravel(), dp.ravel()
        cos_io = np.sin(ti) * np.sin(to) * np.cos(dp) + np.cos(ti) * np.cos(to)
        out = rho_from_cosines(self.kind, self.kernel_params(), np.cos(ti), np.cos(to), cos_io)
        return out.reshape(shape + (out.shape[1],))

    def predict(self, env: Environment, normals: np.ndarray) -> np.ndarray:
        """Radiance (N, C) seen from ``v = (0, 0, 1)``: brute-force quadrature over ``env`` (:mod:`brdfrig.fit.groundtruth`)."""
        return render_groundtruth(self, normals, env)

    def to_dict(self) -> dict:
        raise NotImplementedError


@register_model("lambertian")
@dataclass(frozen=True, eq=False)
class Lambertian(AnalyticBRDF):
    """Ideal diffuse reflector ``rho = albedo / pi``; ``albedo`` (C,) in [0, 1] (scalar = one channel)."""

    albedo: np.ndarray
    model = "lambertian"
    kind = KIND_LAMBERTIAN

    def __post_init__(self) -> None:
        object.__setattr__(self, "albedo", _per_channel("albedo", self.albedo, 0.0))

    def kernel_params(self) -> np.ndarray:
        p = np.zeros((self.albedo.size, NUM_PARAMS))
        p[:, 0] = self.albedo
        return p

    def to_dict(self) -> dict:
        return {"model": self.model, "albedo": self.albedo.tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> "Lambertian":
        return cls(albedo=d["albedo"])


@register_model("oren_nayar")
@dataclass(frozen=True, eq=False)
class OrenNayar(AnalyticBRDF):
    """Rough diffuse reflector (module docstring); ``albedo`` (C,) >= 0, ``sigma`` facet slope deviation in radians >= 0."""

    albedo: np.ndarray
    sigma: np.ndarray
    model = "oren_nayar"
    kind = KIND_LAMBERTIAN

    def __post_init__(self) -> None:
        _set_channels(self, albedo=_per_channel("albedo", self.albedo, 0.0), sigma=_per_channel("sigma", self.sigma, 0.0))

    def kernel_params(self) -> np.ndarray:
        p = np.zeros((self.albedo.size, NUM_PARAMS))
        p[:, 0], p[:, 4] = self.albedo, self.sigma
        return p

    def to_dict(self) -> dict:
        return {"model": self.model, "albedo": self.albedo.tolist(), "sigma": self.sigma.tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> "OrenNayar":
        return cls(albedo=d["albedo"], sigma=d["sigma"])


@register_model("blinn_phong")
@dataclass(frozen=True, eq=False)
class BlinnPhong(AnalyticBRDF):
    """Lambertian base plus the normalised Blinn-Phong lobe ``specular (e+8)/(8 pi) (n.h)^e``.

    Parameters (per channel, scalars broadcast): ``diffuse`` albedo >= 0,
    ``specular`` amplitude >= 0 (the lobe's albedo near normal incidence),
    ``exponent`` e >= 0.
    """

    diffuse: np.ndarray
    specular: np.ndarray
    exponent: np.ndarray
    model = "blinn_phong"
    kind = KIND_BLINN_PHONG

    def __post_init__(self) -> None:
        _set_channels(
            self,
            diffuse=_per_channel("diffuse", self.diffuse, 0.0),
            specular=_per_channel("specular", self.specular, 0.0),
            exponent=_per_channel("exponent", self.exponent, 0.0),
        )

    def kernel_params(self) -> np.ndarray:
        zero = np.zeros_like(self.diffuse)
        return np.stack([self.diffuse, self.specular, self.exponent, zero, zero], axis=1)

    def to_dict(self) -> dict:
        return {"model": self.model, "diffuse": self.diffuse.tolist(), "specular": self.specular.tolist(), "exponent": self.exponent.tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> "BlinnPhong":
        return cls(diffuse=d["diffuse"], specular=d["specular"], exponent=d["exponent"])


@register_model("ggx")
@dataclass(frozen=True, eq=False)
class GGX(AnalyticBRDF):
    """Lambertian base plus a GGX microfacet lobe with Schlick Fresnel and height-correlated Smith shadowing.

    Parameters (per channel, scalars broadcast): ``alpha`` GGX roughness in
    (0, inf) (``alpha = perceptual_roughness^2``), ``f0`` Fresnel reflectance
    at normal incidence >= 0, ``diffuse`` albedo of the base >= 0, ``f90``
    reflectance at grazing incidence (1 = Schlick), ``diffuse_sigma`` the
    base's Oren-Nayar roughness in radians (0 = Lambertian).  The sum of the
    diffuse albedo and the lobe's albedo can exceed 1: no energy coupling is imposed.
    """

    alpha: np.ndarray
    f0: np.ndarray
    diffuse: np.ndarray
    f90: np.ndarray = 1.0
    diffuse_sigma: np.ndarray = 0.0
    model = "ggx"
    kind = KIND_GGX

    def __post_init__(self) -> None:
        _set_channels(
            self,
            alpha=_per_channel("alpha", self.alpha, 1e-4),
            f0=_per_channel("f0", self.f0, 0.0),
            diffuse=_per_channel("diffuse", self.diffuse, 0.0),
            f90=_per_channel("f90", self.f90, 0.0),
            diffuse_sigma=_per_channel("diffuse_sigma", self.diffuse_sigma, 0.0),
        )

    def kernel_params(self) -> np.ndarray:
        return np.stack([self.diffuse, self.f0, self.f90, self.alpha, self.diffuse_sigma], axis=1)

    def to_dict(self) -> dict:
        return {
            "model": self.model,
            "alpha": self.alpha.tolist(),
            "f0": self.f0.tolist(),
            "diffuse": self.diffuse.tolist(),
            "f90": self.f90.tolist(),
            "diffuse_sigma": self.diffuse_sigma.tolist(),
        }

    @classmethod
    def from_dict(cls, d: dict) -> "GGX":
        return cls(alpha=d["alpha"], f0=d["f0"], diffuse=d["diffuse"], f90=d.get("f90", 1.0), diffuse_sigma=d.get("diffuse_sigma", 0.0))
