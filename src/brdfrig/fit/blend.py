"""The ``bivariate+blend`` model: the one-image table fits averaged, each weighted by its estimated error.

From one image the three tables (``bivariate``, ``bivariate+prior``, ``bivariate+measured``) fill what the
lighting leaves unobserved from different priors (smoothness, the best parametric family, measured
materials), and the rotated-lighting spread (:mod:`brdfrig.fit.relight`) estimates each one's relighting
error ``e_k`` assuming their errors are independent.  Under that same assumption the combination with the
smallest expected error is the inverse-variance average::

    rho = sum_k w_k rho_k,   w_k = e_k^-2 / sum_j e_j^-2

A sum of tables is not a table on one grid (``bivariate+measured`` fits on the reference set's grid, the
others on the default one; resampling one grid onto the other moved relit spheres by 0.6-9%), so
:class:`BlendBRDF` keeps the parts and their weights.  Its rendered radiance is the same sum of the parts'
(linear in ``rho``).  Measured in docs/DESIGN.md (History: blending the one-image tables).
"""

from __future__ import annotations

import math

import numpy as np

from brdfrig.fit.bivariate import BivariateBRDF, predict_tables
from brdfrig.fit.brdf import register_model
from brdfrig.fit.scene import Environment

__all__ = ["BlendBRDF", "PARTS", "inverse_variance_weights", "blend_estimate"]

PARTS = ("bivariate", "bivariate+prior", "bivariate+measured")
"""The candidates a blend averages (those fitted, with a finite positive estimate)."""


def inverse_variance_weights(errors) -> np.ndarray:
    """Weights ``e_k^-2 / sum_j e_j^-2`` of estimated relative errors ``e_k > 0`` (finite)."""
    e = np.asarray(errors, dtype=np.float64)
    if e.ndim != 1 or len(e) == 0 or not np.all(np.isfinite(e)) or np.any(e <= 0):
        raise ValueError(f"blend weights need finite positive error estimates, got {e.tolist()}")
    w = e**-2.0
    return w / w.sum()


@register_model("blend")
class BlendBRDF:
    """``rho = sum_k w_k rho_k`` of tabulated BRDFs (grids may differ); weights non-negative, summing to 1.

    Implements :class:`brdfrig.fit.brdf.FittedBRDF`.

    Parameters
    ----------
    parts : sequence of BivariateBRDF
        The tables, all with the same number of colour channels.
    weights : array_like
        One weight per part, finite, >= 0, summing to 1 (within 1e-9).
    """

    model = "blend"

    def __init__(self, parts, weights) -> None:
        self.parts = list(parts)
        w = np.asarray(weights, dtype=np.float64)
        if not self.parts or not all(isinstance(p, BivariateBRDF) for p in self.parts):
            raise ValueError("a blend needs one or more bivariate tables as parts")
        if len({p.channels for p in self.parts}) != 1:
            raise ValueError(f"blend parts have different channel counts {[p.channels for p in self.parts]}")
        if w.shape != (len(self.parts),) or not np.all(np.isfinite(w)) or np.any(w < 0) or abs(w.sum() - 1) > 1e-9:
            raise ValueError(f"blend weights must be {len(self.parts)} finite values >= 0 summing to 1, got {w.tolist()}")
        self.weights = w

    @property
    def channels(self) -> int:
        return self.parts[0].channels

    def combine(self, values) -> np.ndarray:
        """``sum_k w_k values[k]`` of one array per part (their radiance or BRDF values)."""
        return sum(w * np.asarray(v, dtype=np.float64) for w, v in zip(self.weights, values))

    def evaluate(self, theta_i, theta_o, delta_phi) -> np.ndarray:
        """BRDF ``rho`` (1/sr), shape ``broadcast(theta_i, theta_o, delta_phi).shape + (C,)``; 0 below the horizon."""
        return self.combine([p.evaluate(theta_i, theta_o, delta_phi) for p in self.parts])

    def predict(self, env: Environment, normals: np.ndarray) -> np.ndarray:
        """Radiance (N, C) seen from ``v = (0, 0, 1)``: the weighted sum of the parts' (one quadrature pass)."""
        return self.combine(predict_tables(self.parts, env, normals))

    def to_dict(self) -> dict:
        return {"model": self.model, "weights": self.weights.tolist(), "parts": [p.to_dict() for p in self.parts]}

    @classmethod
    def from_dict(cls, d: dict) -> "BlendBRDF":
        parts = d["parts"]
        if not isinstance(parts, list) or any(not isinstance(p, dict) or p.get("model") != "bivariate" for p in parts):
            raise ValueError("blend 'parts' must be a list of bivariate BRDF descriptions")
        return cls([BivariateBRDF.from_dict(p) for p in parts], d["weights"])


def blend_estimate(errors) -> float:
    """Reported relighting estimate of a blend: the smallest of its parts' estimates ``e_k``.

    The blend's weights favour that part, and on measured materials the blend relit about as well as it:
    docs/DESIGN.md (History: blending the one-image tables) compares this with the triangle inequality's
    bound ``sum_k w_k e_k`` and the independent-error value ``(sum_k e_k^-2)^-1/2``.
    """
    return float(min(errors))
