"""The fitted linear BRDF models (``diffuse``, ``lobe``, ``full``) and the projection of any BRDF onto ``full``.

Each model holds its :class:`brdfrig.fit.system.ModelSpec` and coefficients ``x``
(n, C) and implements :class:`brdfrig.fit.brdf.FittedBRDF`:

- ``predict(env, normals)`` relights: the environment is projected onto SH up
  to the model's ``lmax`` (``brdfrig.fit.shproject``) and ``B = A(n) @ x``
  (:func:`brdfrig.fit.system.design_block`);
- ``evaluate(theta_i, theta_o, delta_phi)`` returns ``rho = T / cos(theta_i)``
  from the model's transfer function ``T = rho * max(cos theta_i, 0)``:
  ``diffuse`` ``T = sum_l a_l (2l+1)/(4 pi) P_l(cos theta_i)`` (Funk-Hecke, so
  ``a_l = Lambda_l t_l``), ``lobe`` adds the same series in ``s_l`` of
  ``wi . r`` with ``r`` the mirror of ``wo``, ``full``
  ``T = sum tau[l,p,k] (Y_lk(wi) Y_pk(wo) + [k>0] Y_l,-k(wi) Y_p,-k(wo))``.
  The truncated series ring (MATH.md pitfall 3) and are not clamped.

:func:`project_to_full` writes any BRDF's transfer function on the ``tau``
basis by quadrature; it is the prior of the regularised full fit.
"""

from __future__ import annotations

import numpy as np
from scipy.special import eval_legendre

from brdfrig.fit.brdf import register_model
from brdfrig.fit.scene import Environment
from brdfrig.fit.sh import sh_eval, sh_index
from brdfrig.fit.shproject import project_environment
from brdfrig.fit.rotation import local_lighting
from brdfrig.fit.system import ModelSpec, design_block, outgoing_directions

__all__ = ["LinearBRDF", "DiffuseBRDF", "LobeBRDF", "FullBRDF", "make_linear_brdf", "project_to_full", "plausibility"]

PREDICT_BLOCK = 4096
"""Pixels per design block when relighting (memory ~ PREDICT_BLOCK x unknowns x channels x 8 bytes)."""

MIN_COS = 1e-6
"""``evaluate`` divides the transfer function by ``max(cos theta_i, MIN_COS)``."""


def _local_dirs(theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    st = np.sin(theta)
    return np.stack([st * np.cos(phi), st * np.sin(phi), np.cos(theta)], axis=-1)


class LinearBRDF:
    """Shared behaviour of the linear SH models (see module docstring).

    Parameters
    ----------
    spec : ModelSpec
    x : (n_unknowns, C) float64
    """

    model = ""

    def __init__(self, spec: ModelSpec, x: np.ndarray) -> None:
        x = np.asarray(x, dtype=np.float64)
        if x.ndim != 2 or x.shape[0] != spec.n_unknowns:
            raise ValueError(f"{self.model} coefficients must have shape ({spec.n_unknowns}, C), got {x.shape}")
        if not np.all(np.isfinite(x)):
            raise ValueError(f"{self.model} coefficients contain NaN or inf")
        self.spec = spec
        self.x = x

    @property
    def channels(self) -> int:
        return self.x.shape[1]

    @property
    def lmax(self) -> int:
        return self.spec.lmax

    def predict_from_coeffs(self, coeffs: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """Radiance (N, C) at ``normals`` (N, 3) under lighting SH ``coeffs`` (ncoef, C)."""
        if coeffs.shape[1] != self.channels:
            raise ValueError(f"lighting has {coeffs.shape[1]} channels, the BRDF {self.channels}")
        out = np.empty((normals.shape[0], self.channels))
        for start in range(0, normals.shape[0], PREDICT_BLOCK):  # bounded memory: design rows per block
            a = design_block(self.spec, coeffs, normals[start : start + PREDICT_BLOCK])
            out[start : start + PREDICT_BLOCK] = np.einsum("inc,nc->ic", a, self.x)
        return out

    def predict(self, env: Environment, normals: np.ndarray) -> np.ndarray:
        """Radiance (N, C) seen from ``v = (0, 0, 1)`` at unit ``normals`` (N, 3) under ``env``."""
        return self.predict_from_coeffs(project_environment(env, self.lmax), np.asarray(normals, dtype=np.float64))

    def transfer(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """Transfer function ``T(wi, wo)`` (..., C) for local unit directions (..., 3) (normal = +z)."""
        raise NotImplementedError

    def evaluate(self, theta_i, theta_o, delta_phi) -> np.ndarray:
        """BRDF ``rho`` (1/sr), shape ``broadcast(theta_i, theta_o, delta_phi).shape + (C,)``."""
        ti, to, dp = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (theta_i, theta_o, delta_phi)))
        wi = _local_dirs(ti, np.zeros_like(ti))
        wo = _local_dirs(to, dp)
        t = self.transfer(wi.reshape(-1, 3), wo.reshape(-1, 3))
        rho = t / np.maximum(np.cos(ti.reshape(-1)), MIN_COS)[:, None]
        return rho.reshape(ti.shape + (self.channels,))

    def to_dict(self) -> dict:
        return {
            "model": self.model,
            "channels": self.channels,
            "lmax": self.spec.lmax,
            "pmax": self.spec.pmax,
            "bands": list(self.spec.bands),
            "unknowns": self.spec.column_labels,
            "coefficients": self.x.tolist(),
        }

    @classmethod
    def from_dict(cls, d: dict) -> "LinearBRDF":
        spec = ModelSpec(d["model"], int(d["lmax"]), int(d.get("pmax", 0)), bands=tuple(d["bands"]))
        x = np.asarray(d["coefficients"], dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != int(d["channels"]):
            raise ValueError(f"coefficients shape {x.shape} does not match channels={d['channels']}")
        return cls(spec, x)


def _zonal_series(coef: np.ndarray, bands: tuple[int, ...], cos: np.ndarray) -> np.ndarray:
    """``sum_l coef_l (2l+1)/(4 pi) P_l(cos)``: coef (nb, C), cos (N,) -> (N, C) (zero when ``bands`` is empty)."""
    cos = np.asarray(cos, dtype=np.float64)
    if not bands:
        return np.zeros(cos.shape + (np.shape(coef)[-1],))
    p = np.stack([(2 * l + 1) / (4 * np.pi) * eval_legendre(l, cos) for l in bands], axis=1)
    return p @ coef


@register_model("diffuse")
class DiffuseBRDF(LinearBRDF):
    """``B = sum_l a_l sum_m L_lm Y_lm(n)``; ``a_0`` is the hemispherical albedo."""

    model = "diffuse"

    def transfer(self, wi, wo):
        nb = len(self.spec.bands)
        return _zonal_series(self.x[:nb], self.spec.bands, np.clip(wi[:, 2], -1, 1))

    @property
    def albedo(self) -> np.ndarray:
        """(C,) hemispherical albedo ``a_0`` (0 if band 0 unobservable)."""
        if 0 not in self.spec.bands:
            return np.zeros(self.channels)
        return self.x[self.spec.bands.index(0)]


@register_model("lobe")
class LobeBRDF(DiffuseBRDF):
    """``diffuse`` plus ``sum_l s_l sum_m L_lm Y_lm(r)`` about the mirror direction ``r``."""

    model = "lobe"

    def transfer(self, wi, wo):
        nb = len(self.spec.bands)
        r = 2.0 * wo[:, 2:3] * np.array([0.0, 0.0, 1.0]) - wo
        cos_r = np.clip(np.sum(wi * r, axis=1), -1, 1)
        lobe_bands = tuple(b for b in self.spec.bands if b > 0)
        return super().transfer(wi, wo) + _zonal_series(self.x[nb:], lobe_bands, cos_r)


@register_model("full")
class FullBRDF(LinearBRDF):
    """The seed's isotropic model ``tau[l,p,k]`` (MATH.md real form)."""

    model = "full"

    def predict_from_coeffs(self, coeffs: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """As :meth:`LinearBRDF.predict_from_coeffs`, contracting over ``p`` first.

        ``B = sum_{l,k} L'_{l,k}(n) f_{l,k}(theta_N)`` with ``f_{l,k} = sum_p tau[l,p,k] Y_{p,k}(w_o')``:
        the (pixels x unknowns x channels) design is never formed.
        """
        if coeffs.shape[1] != self.channels:
            raise ValueError(f"lighting has {coeffs.shape[1]} channels, the BRDF {self.channels}")
        lc, pc, kc = self.spec.full_index
        lk = sh_index(lc, kc)
        used = np.unique(lk)  # lighting coefficients (l, k >= 0) the model reads
        slot = np.searchsorted(used, lk)
        weights = np.zeros(((self.spec.pmax + 1) ** 2, len(used), self.channels))
        np.add.at(weights, (sh_index(pc, kc), slot), self.x)
        coeffs = np.asarray(coeffs, dtype=np.float64)[: (self.lmax + 1) ** 2]
        out = np.empty((normals.shape[0], self.channels))
        for start in range(0, normals.shape[0], PREDICT_BLOCK):
            n = normals[start : start + PREDICT_BLOCK]
            f = np.einsum("np,pjc->njc", sh_eval(outgoing_directions(n), self.spec.pmax), weights)
            out[start : start + PREDICT_BLOCK] = np.einsum("njc,njc->nc", local_lighting(coeffs, n)[:, used, :], f)
        return out

    def transfer(self, wi, wo):
        lc, pc, kc = self.spec.full_index
        yi = sh_eval(wi, self.spec.lmax)
        yo = sh_eval(wo, self.spec.pmax)
        basis = yi[:, sh_index(lc, kc)] * yo[:, sh_index(pc, kc)]
        sine = kc > 0
        basis[:, sine] += yi[:, sh_index(lc[sine], -kc[sine])] * yo[:, sh_index(pc[sine], -kc[sine])]
        return basis @ self.x


_CLASSES = {"diffuse": DiffuseBRDF, "lobe": LobeBRDF, "full": FullBRDF}


def make_linear_brdf(spec: ModelSpec, x: np.ndarray) -> LinearBRDF:
    """The model object of ``spec.kind`` with coefficients ``x`` (n, C)."""
    return _CLASSES[spec.kind](spec, x)


def project_to_full(brdf, spec: ModelSpec, n_theta: int = 48, n_phi: int = 96, n_out: int = 40) -> np.ndarray:
    """Coefficients ``tau`` (n, C) of the full model ``spec`` closest to ``brdf``'s transfer function.

    ``T_lk(theta_o) = int Y_lk(w') rho(w', w_o') cos(theta') dw'`` over the upper
    hemisphere is computed by Gauss-Legendre quadrature in ``cos theta'`` (``n_theta``
    nodes) times ``n_phi`` equispaced azimuths, at ``n_out`` outgoing angles in
    ``(0, pi/2)`` with ``phi_o' = pi`` (every pixel of an orthographic view);
    then, per ``(l, k)``, ``tau[l, :, k]`` is the least-squares fit of
    ``sum_p tau[l,p,k] Y_pk(theta_o, pi)`` to it, weighted by the projected
    area of the sphere at ``theta_o`` (``sin cos``).  Bands not in ``spec.bands`` are absent.

    Parameters
    ----------
    brdf : FittedBRDF
        Any model with ``evaluate(theta_i, theta_o, delta_phi) -> (..., C)``.
    spec : ModelSpec
        A ``full`` spec.
    """
    if spec.kind != "full":
        raise ValueError(f"project_to_full needs a 'full' spec, got {spec.kind!r}")
    x, wx = np.polynomial.legendre.leggauss(n_theta)
    cos_i = 0.5 * (x + 1.0)
    w_i = 0.5 * wx * (2.0 * np.pi / n_phi)
    phi_i = 2.0 * np.pi * (np.arange(n_phi) + 0.5) / n_phi
    xo, wxo = np.polynomial.legendre.leggauss(n_out)
    theta_o = 0.25 * np.pi * (xo + 1.0)
    w_o = wxo * np.sin(theta_o) * np.cos(theta_o)

    ci, ph = np.meshgrid(cos_i, phi_i, indexing="ij")
    theta_i = np.arccos(ci).reshape(-1)
    wi = _local_dirs(theta_i, ph.reshape(-1))
    y_in = sh_eval(wi, spec.lmax) * (ci.reshape(-1) * np.repeat(w_i, n_phi))[:, None]  # (Q, ncoef) weighted
    # rho at every (w_i, theta_o): delta_phi = phi_o - phi_i with phi_o = pi.
    rho = brdf.evaluate(theta_i[None, :], theta_o[:, None], np.pi - ph.reshape(-1)[None, :])  # (n_out, Q, C)
    t_lm = np.einsum("oqc,qm->omc", rho, y_in)  # (n_out, ncoef, C)
    y_out = sh_eval(_local_dirs(theta_o, np.full_like(theta_o, np.pi)), spec.pmax)  # (n_out, (P+1)^2)

    lc, pc, kc = spec.full_index
    tau = np.zeros((spec.n_unknowns, t_lm.shape[2]))
    sw = np.sqrt(w_o)[:, None]
    for l in spec.bands:
        for k in range(min(l, spec.pmax) + 1):
            cols = np.flatnonzero((lc == l) & (kc == k))
            basis = y_out[:, sh_index(pc[cols], k)] * sw
            tau[cols] = np.linalg.lstsq(basis, t_lm[:, sh_index(l, k), :] * sw, rcond=None)[0]
    return tau


def plausibility(brdf, n_theta: int = 24, n_phi: int = 48) -> dict:
    """Physical sanity of a BRDF: directional albedo and sign of ``rho`` over the upper hemisphere.

    For outgoing polar angles 0, 30 and 60 degrees, ``albedo = int rho cos dw_i``
    and ``abs_ratio = int |rho| cos dw_i / |albedo|`` (1 for a non-negative BRDF;
    truncated SH series ring a little above 1) by Gauss-Legendre quadrature in
    ``cos theta_i`` (``n_theta`` nodes) times ``n_phi`` azimuths.  A fit that
    extrapolates wildly (e.g. lighting that excites only part of the BRDF's
    domain) shows up as ``abs_ratio`` >> 1 or an albedo outside [0, 1].

    Returns
    -------
    dict
        ``albedo_min``, ``albedo_max``, ``abs_ratio_max`` (over angles and channels) and
        ``plausible`` (albedo in [-0.02, 1.1] and ``abs_ratio_max <= 1.5``).
    """
    x, wx = np.polynomial.legendre.leggauss(n_theta)
    cos_i = 0.5 * (x + 1.0)
    w = 0.5 * wx[:, None] * cos_i[:, None] * (2.0 * np.pi / n_phi)
    phi = 2.0 * np.pi * (np.arange(n_phi) + 0.5) / n_phi
    albedo, ratio = [], []
    for theta_o in np.radians([0.0, 30.0, 60.0]):
        rho = np.asarray(brdf.evaluate(np.arccos(cos_i)[:, None], theta_o, phi[None, :]))  # (n_theta, n_phi, C)
        a = np.einsum("tpc,tp->c", rho, np.broadcast_to(w, rho.shape[:2]))
        a_abs = np.einsum("tpc,tp->c", np.abs(rho), np.broadcast_to(w, rho.shape[:2]))
        albedo.append(a)
        ratio.append(a_abs / np.maximum(np.abs(a), 1e-12))
    albedo, ratio = np.array(albedo), np.array(ratio)
    out = {
        "albedo_min": float(albedo.min()),
        "albedo_max": float(albedo.max()),
        "abs_ratio_max": float(ratio.max()) if np.any(np.abs(albedo) > 1e-12) else 1.0,
    }
    out["plausible"] = bool(-0.02 <= out["albedo_min"] and out["albedo_max"] <= 1.1 and out["abs_ratio_max"] <= 1.5)
    return out
