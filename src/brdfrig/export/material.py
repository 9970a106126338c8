"""A BRDF as a renderer's material: the closest physically based family, and the error of any approximation.

The error an export introduces is measured where it matters, in rendered radiance:
the original BRDF and the exported material each render a sphere under the three
standard lightings (:func:`brdfrig.lighting.standard_lightings`), and the error is
the relative RMS difference over all their pixels (per lighting and overall).

A BRDF that is not already one of the renderer families (``dielectric``,
``conductor``, ``sheen``, and the Lambertian ``diffuse`` as a dielectric without
specular) is projected onto them by fitting each family
(:func:`brdfrig.fit.pbr_fit.fit_pbr`) to those standard renders; the family with the
lowest error is the material.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from brdfrig.fit.metrics import relative_rms
from brdfrig.fit.scene import Scene

__all__ = ["FAMILY_MODELS", "Fidelity", "standard_scenes", "fidelity", "renderer_material"]

FAMILY_MODELS = ("dielectric", "conductor", "sheen")
"""Models a renderer material is made of (parameters named as in OpenPBR, :mod:`brdfrig.fit.pbr`)."""
SPHERE_SIZE = 32
"""Side (pixels) of the spheres the errors are measured on (about 750 pixels each)."""
FIT_PIXELS = 1500
"""Pixels of the standard renders a family is fitted to (the rest check it)."""


@dataclass(frozen=True)
class Fidelity:
    """Relative RMS error of an approximation in rendered radiance: overall and per standard lighting."""

    error: float
    per_lighting: dict

    def to_dict(self) -> dict:
        return {"relative_rms": self.error, "per_lighting": dict(self.per_lighting),
                "measured_on": f"{SPHERE_SIZE} px spheres under brdfrig's standard lightings "
                               f"({', '.join(self.per_lighting)})"}


def _normals(size: int = SPHERE_SIZE) -> np.ndarray:
    r, c = np.mgrid[0:size, 0:size]
    dx = (c + 0.5 - size / 2) / (size / 2)
    dy = (size / 2 - (r + 0.5)) / (size / 2)
    inside = dx**2 + dy**2 < 0.97  # away from the grazing limb, where every renderer is least reliable
    return np.stack([dx[inside], dy[inside], np.sqrt(1.0 - dx[inside] ** 2 - dy[inside] ** 2)], axis=1)


def standard_scenes(brdf, size: int = SPHERE_SIZE) -> list[Scene]:
    """The BRDF's spheres under the standard lightings, as fitter scenes (radiance clamped to >= 0)."""
    from brdfrig.lighting import standard_lightings

    n = _normals(size)
    out = []
    for env in standard_lightings().values():
        rad = np.maximum(np.nan_to_num(np.asarray(brdf.predict(env, n), dtype=np.float64)), 0.0)
        out.append(Scene(env, n, rad, np.ones(len(n))))
    return out


def fidelity(exported, reference_scenes: list[Scene]) -> Fidelity:
    """Error of ``exported`` against the reference renders ``reference_scenes`` (from :func:`standard_scenes`)."""
    from brdfrig.lighting import standard_lightings

    names = list(standard_lightings())
    per, preds, truths = {}, [], []
    for name, s in zip(names, reference_scenes):
        pred = np.asarray(exported.predict(s.env, s.normals), dtype=np.float64)
        per[name] = relative_rms(pred, s.radiance)
        preds.append(pred)
        truths.append(s.radiance)
    return Fidelity(relative_rms(np.concatenate(preds), np.concatenate(truths)), per)


def renderer_material(brdf, *, families=FAMILY_MODELS, progress: bool = False):
    """The closest renderer material to ``brdf`` and its error.

    Returns
    -------
    material : DielectricBRDF, ConductorBRDF or SheenBRDF
        ``brdf`` itself when it already is one.
    fidelity : Fidelity
        Its error against ``brdf`` in rendered radiance (0 for ``brdf`` itself).
    tried : dict
        Family -> overall error of every family fitted (empty when ``brdf`` was one already).
    """
    from brdfrig.fit.pbr_fit import fit_pbr

    scenes = standard_scenes(brdf)
    if getattr(brdf, "model", None) in FAMILY_MODELS:
        return brdf, fidelity(brdf, scenes), {}
    best, tried = None, {}
    for family in families:
        candidate, _ = fit_pbr(scenes, family, max_pixels=FIT_PIXELS, progress=progress)
        f = fidelity(candidate, scenes)
        tried[family] = f.error
        if best is None or f.error < best[1].error:
            best = (candidate, f)
    return best[0], best[1], tried
