"""Mitsuba 3 BSDFs fitted to a BRDF's standard renders: the candidates of ``--format mitsuba``.

Each candidate (:mod:`brdfrig.export.mitsuba_bsdf`) is fitted to the reference renders
(:func:`brdfrig.export.material.standard_scenes`) by variable projection: for fixed shape parameters the
render is affine in the colour parameters, solved in closed form by bounded least squares
(:func:`brdfrig.fit.pbr_fit.shared_solve`); the shape parameters are found by bounded one-dimensional
searches (Brent) started from the renderer material's values.

================  ===============================================  ==========================================
type              amplitudes (bounds)                              shape parameters (search)
================  ===============================================  ==========================================
``diffuse``       per channel ``reflectance`` in [0, 1]            none
``roughplastic``  per channel ``diffuse_reflectance`` in [0, 1];   ``alpha`` within a factor
                  shared ``specular_reflectance`` in [0, 1]        :data:`ALPHA_FACTOR` of the material's
                  (``ext_ior = 1``, ``nonlinear`` false)           (>= 1e-3), then ``int_ior`` in
                                                                   :data:`IOR_BOUNDS`
``principled``    per channel ``base_color`` in [0, 1]             ``roughness`` within a factor
                  (``metallic = 1``)                               ``sqrt(ALPHA_FACTOR)`` of the material's
                                                                   (>= 0.03)
================  ===============================================  ==========================================

The fit uses every :data:`FIT_STRIDE`-th pixel of the reference spheres; roughplastic's diffuse column
is assembled from the renders of its transmittance table's 64 hat functions (one pass per fit, cell
centres), so a shape evaluation costs one table and one specular render.  The error the caller states
is that of the fitted BSDF's own :meth:`predict` over every reference pixel.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import minimize_scalar

from brdfrig.export.mitsuba_bsdf import (
    TRANSMITTANCE_RES,
    MitsubaDiffuse,
    MitsubaPrincipled,
    MitsubaRoughPlastic,
    rough_interface,
)
from brdfrig.fit.pbr_fit import shared_solve

__all__ = ["FIT_STRIDE", "ALPHA_FACTOR", "IOR_BOUNDS", "fit_candidates"]

FIT_STRIDE = 3
"""Every third reference pixel is fitted (about 260 per lighting)."""
ALPHA_FACTOR = 3.0
"""The GGX alpha search spans the material's alpha divided and multiplied by this (within [1e-3, 1])."""
IOR_BOUNDS = (1.05, 2.5)
"""Search interval of roughplastic's ``int_ior`` (``ext_ior = 1``)."""
LOG_XTOL = 0.03
IOR_XTOL = 0.01


class _Target:
    """The fit pixels of the reference scenes and the renders shared by every evaluation."""

    def __init__(self, scenes) -> None:
        self.scenes = scenes
        self.normals = [np.asarray(s.normals, dtype=np.float64)[::FIT_STRIDE] for s in scenes]
        self.target = np.concatenate([np.asarray(s.radiance, dtype=np.float64)[::FIT_STRIDE] for s in scenes])
        self.cos_o = np.concatenate([n[:, 2] for n in self.normals])
        self._hats = None

    def render(self, bsdf) -> np.ndarray:
        """Radiance (N, C) of ``bsdf`` at the fit pixels (its own ``predict``)."""
        return np.concatenate([bsdf.predict(s.env, n) for n, s in zip(self.normals, self.scenes)])

    def hats(self) -> np.ndarray:
        """``sum_j L_j omega_j cos_i phi_k(cos_i)`` (N, C, TRANSMITTANCE_RES) of the table's hat functions ``phi_k``."""
        if self._hats is None:
            parts = []
            for n, s in zip(self.normals, self.scenes):
                wrad = np.asarray(s.env.radiance, dtype=np.float64) * np.asarray(s.env.solid_angle, dtype=np.float64)[:, None]
                cos = n @ np.asarray(s.env.dirs, dtype=np.float64).T
                pix, j = np.nonzero(cos > 0)
                c = cos[pix, j]
                x = np.minimum(c, 1.0) * (TRANSMITTANCE_RES - 1)
                k = np.minimum(x.astype(np.int64), TRANSMITTANCE_RES - 2)
                f = x - k
                size = len(n) * TRANSMITTANCE_RES
                h = np.stack([np.bincount(pix * TRANSMITTANCE_RES + k, (1 - f) * c * wrad[j, ch], size)
                              + np.bincount(pix * TRANSMITTANCE_RES + k + 1, f * c * wrad[j, ch], size)
                              for ch in range(wrad.shape[1])], axis=1)
                parts.append(h.reshape(len(n), TRANSMITTANCE_RES, -1).transpose(0, 2, 1))
            self._hats = np.concatenate(parts)
        return self._hats


def _bracket(x0: float, factor: float, lowest: float) -> tuple[float, float]:
    """``log`` of ``[x0 / factor, x0 * factor]`` clipped to ``[lowest, 1]`` (at least ``factor`` wide)."""
    lo = max(lowest, x0 / factor)
    return math.log(lo), math.log(min(1.0, max(x0 * factor, lo * factor)))


def _search(cost, lower: float, upper: float, xtol: float) -> float:
    """Bounded Brent minimiser of ``cost`` on [lower, upper]."""
    return float(minimize_scalar(cost, bounds=(lower, upper), method="bounded", options={"xatol": xtol}).x)


def _fit_diffuse(data: _Target) -> MitsubaDiffuse:

    col = data.render(MitsubaDiffuse(1.0))
    _, amps, _ = shared_solve(col[:, :, None], None, data.target, np.array([1.0]))
    return MitsubaDiffuse(amps[:, 0])


def _fit_roughplastic(data: _Target, alpha0: float, ior0: float) -> MitsubaRoughPlastic:

    def solve(alpha: float, ior: float):
        unit = MitsubaRoughPlastic(1.0, alpha, ior, 1.0, 0.0)  # unit linear diffuse_reflectance
        table = rough_interface(unit.alpha, unit.eta)[0]
        diffuse = data.hats() @ table * unit.transmittance(data.cos_o)[:, None] * unit.diffuse_amplitude()[None, :]
        spec = data.render(MitsubaRoughPlastic(0.0, alpha, ior, 1.0, 1.0))
        return shared_solve(diffuse[:, :, None], spec, data.target, np.array([1.0]))

    lo, hi = _bracket(alpha0, ALPHA_FACTOR, 1e-3)
    alpha = math.exp(_search(lambda g: solve(math.exp(g), ior0)[0], lo, hi, LOG_XTOL))
    ior = _search(lambda e: solve(alpha, e)[0], *IOR_BOUNDS, IOR_XTOL)
    _, amps, w = solve(alpha, ior)
    return MitsubaRoughPlastic(amps[:, 0], alpha, ior, 1.0, w)


def _fit_metal(data: _Target, roughness0: float) -> MitsubaPrincipled:

    def solve(r: float):
        black = data.render(MitsubaPrincipled(0.0, r, 1.0))
        white = data.render(MitsubaPrincipled(1.0, r, 1.0))
        return shared_solve((white - black)[:, :, None], None, data.target - black, np.array([1.0]))

    r = math.exp(_search(lambda g: solve(math.exp(g))[0], *_bracket(roughness0, math.sqrt(ALPHA_FACTOR), 0.03), LOG_XTOL))
    _, amps, _ = solve(r)
    return MitsubaPrincipled(amps[:, 0], r, 1.0)


def fit_candidates(material, reference) -> dict:
    """Mitsuba type -> BSDF fitted to ``reference`` (standard scenes), for the types that suit ``material``.

    ``principled`` (metallic) for a conductor; ``diffuse``, and ``roughplastic`` when the material has a
    specular lobe, otherwise.  ``material`` (a :mod:`brdfrig.fit.pbr` BRDF) gives the searches' start.
    """
    d = material.to_dict()
    data = _Target(reference)
    if d["model"] == "conductor":
        return {"principled": _fit_metal(data, d["specular_roughness"])}
    out = {"diffuse": _fit_diffuse(data)}
    if d.get("specular_weight", 0.0) > 0:
        ior0 = min(max(d["specular_ior"], IOR_BOUNDS[0]), IOR_BOUNDS[1])
        out["roughplastic"] = _fit_roughplastic(data, d["specular_roughness"] ** 2, ior0)
    return out
