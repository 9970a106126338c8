"""The ``bivariate+blend`` model: the table fits averaged, with weights from how well each relights.

The three tables (``bivariate``, ``bivariate+prior``, ``bivariate+measured``) fill what the lighting leaves
unobserved from different priors (smoothness, the best parametric family, measured materials) on different
grids, and where they disagree their average relights better than any one of them.  The weights:

- one image: the rotated-lighting spread (:mod:`brdfrig.fit.relight`) estimates each table's relighting
  error ``e_k`` assuming their errors are independent; under that same assumption the combination with the
  smallest expected error is the inverse-variance average (:func:`inverse_variance_weights`)::

      rho = sum_k w_k rho_k,   w_k = e_k^-2 / sum_j e_j^-2

- several scenes: stacking (:func:`stacked_weights`): the convex weights whose combination of the tables'
  leave-one-scene-out predictions is closest to the left-out pixels.  Those weights are fitted to the pixels
  they are judged on; :func:`nested_stacking` gives the blend's out-of-sample prediction (weights stacked on
  the other folds), comparable with a single table's leave-one-scene-out error.

A sum of tables is not a table on one grid (``bivariate+measured`` fits on the reference set's grid, the
others on the default one; resampling one grid onto the other moved relit spheres by 0.6-9%), so
:class:`BlendBRDF` keeps the parts and their weights.  Its rendered radiance is the same sum of the parts'
(linear in ``rho``).  Measured in docs/DESIGN.md (History: blending the one-image tables; stacking the tables
of several scenes).
"""

from __future__ import annotations

import math

import numpy as np

from brdfrig.fit.bivariate import BivariateBRDF, predict_tables
from brdfrig.fit.brdf import register_model
from brdfrig.fit.lsq import polytope_lsq
from brdfrig.fit.scene import Environment

__all__ = ["BlendBRDF", "PARTS", "inverse_variance_weights", "stacked_weights", "nested_stacking", "blend_estimate"]

PARTS = ("bivariate", "bivariate+prior", "bivariate+measured")
"""The candidates a blend averages: those fitted with finite non-negative radiance and a finite positive estimate
(one image) or leave-one-scene-out predictions (several scenes)."""


def inverse_variance_weights(errors) -> np.ndarray:
    """Weights ``e_k^-2 / sum_j e_j^-2`` of estimated relative errors ``e_k > 0`` (finite)."""
    e = np.asarray(errors, dtype=np.float64)
    if e.ndim != 1 or len(e) == 0 or not np.all(np.isfinite(e)) or np.any(e <= 0):
        raise ValueError(f"blend weights need finite positive error estimates, got {e.tolist()}")
    w = e**-2.0
    return w / w.sum()


def stacked_weights(preds, target, weights) -> np.ndarray:
    """Convex weights ``a`` (``a_k >= 0``, ``sum_k a_k = 1``) minimising ``sum_n w_n |sum_k a_k p_kn - t_n|^2``.

    Stacking (Breiman 1996, "Stacked regressions") on predictions ``p_k`` of pixels the parts were not
    fitted to.  Solved exactly with ``a_K = 1 - sum_{k<K} a_k`` by :func:`brdfrig.fit.lsq.polytope_lsq`.

    Parameters
    ----------
    preds : sequence of (N, C) arrays
        Each part's prediction of the same pixels (finite).
    target : (N, C) array
        Their radiance.
    weights : (N,) array
        Pixel weights (>= 0).
    """
    ps = [np.asarray(p, dtype=np.float64) for p in preds]
    sw = np.sqrt(np.asarray(weights, dtype=np.float64))[:, None]
    t = np.asarray(target, dtype=np.float64)
    if len(ps) < 2 or any(p.shape != t.shape for p in ps) or not all(np.all(np.isfinite(p)) for p in ps):
        raise ValueError(f"stacking needs two or more finite predictions shaped like the target {t.shape}")
    k = len(ps) - 1
    cols = np.stack([((p - ps[-1]) * sw).ravel() for p in ps[:-1]], axis=1)
    g = np.vstack([-np.eye(k), np.ones((1, k))])
    a = polytope_lsq(cols, ((t - ps[-1]) * sw).ravel(), g, np.r_[np.zeros(k), 1.0])[1]
    a = np.clip(np.r_[a, 1.0 - a.sum()], 0.0, None)
    return a / a.sum()


def nested_stacking(preds, target, weights, fold) -> np.ndarray:
    """(N, C) out-of-sample prediction of the stacked blend: each fold's pixels combined with the weights
    :func:`stacked_weights` gives on the other folds' pixels.

    Parameters
    ----------
    preds : sequence of (N, C) arrays
        Each part's leave-one-scene-out prediction of the pixels (finite).
    target, weights : (N, C), (N,) arrays
        Their radiance and pixel weights, as in :func:`stacked_weights`.
    fold : (N,) int array
        Each pixel's fold; two or more folds.
    """
    fold = np.asarray(fold)
    labels = np.unique(fold)
    if len(labels) < 2:
        raise ValueError(f"nested stacking needs two or more folds, got {labels.tolist()}")
    out = np.empty(np.shape(target), dtype=np.float64)
    for f in labels:
        test = fold == f
        a = stacked_weights([p[~test] for p in preds], target[~test], weights[~test])
        out[test] = sum(x * p[test] for x, p in zip(a, preds))
    return out


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
