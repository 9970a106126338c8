"""The one list of the fitter's model and solver names, and where each model's fit lives.

Every other layer (session config, command line, benchmarks) imports these names.

Kinds of model:

``linear``  an SH model streamed through the QR factor (:mod:`brdfrig.fit.stream`) and solved by the
            chosen solver (:mod:`brdfrig.fit.solvers`): ``diffuse``, ``lobe``, ``full``;
``prior``   ``full`` solved by Tikhonov toward the projection of another fit (``full+prior``);
``single``  a fit function with the signature of :func:`brdfrig.fit.microfacet.fit_microfacet`,
            ``fit(scenes, lmax=..., bands=..., progress=...) -> (brdf, report)`` with
            ``report["determined"]`` a bool; the scenes hold only the training pixels.  A single model
            with ``prior_parametric`` also takes ``prior=brdf``: the fitter passes the parametric
            candidate with the smallest held-out error (``bivariate+prior``); one with ``prior_references``
            takes ``references=`` measured materials' tables (``bivariate+measured``:
            :mod:`brdfrig.fit.references`);
``blend``   the fitted tables averaged with weights from their relighting estimates (one image) or
            stacked on their leave-one-scene-out predictions (several scenes) (``bivariate+blend``:
            :mod:`brdfrig.fit.blend`), built after the estimates.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Callable


__all__ = ["ModelInfo", "REGISTRY", "RICHNESS", "MODELS", "SOLVERS", "LINEAR_SH", "PARAMETRIC", "PRIOR_OF", "single_fit"]


@dataclass(frozen=True)
class ModelInfo:
    """A fittable model: its name, kind (module docstring), for ``single`` models ``module:function``,
    whether it is a parametric family of a few parameters per channel (``parametric``), and whether its
    fit takes the best parametric candidate (``prior_parametric``) or measured reference tables
    (``prior_references``) as a prior."""

    name: str
    kind: str
    fit: str | None = None
    parametric: bool = False
    prior_parametric: bool = False
    prior_references: bool = False


SOLVERS: tuple[str, ...] = ("paper", "joint", "tikhonov")
"""Solvers of the linear models (:mod:`brdfrig.fit.solvers`)."""

REGISTRY: dict[str, ModelInfo] = {m.name: m for m in (
    ModelInfo("diffuse", "linear"),
    ModelInfo("lobe", "linear"),
    ModelInfo("dielectric", "single", "brdfrig.fit.pbr_fit:fit_dielectric", parametric=True),
    ModelInfo("conductor", "single", "brdfrig.fit.pbr_fit:fit_conductor", parametric=True),
    ModelInfo("sheen", "single", "brdfrig.fit.pbr_fit:fit_sheen", parametric=True),
    ModelInfo("microfacet", "single", "brdfrig.fit.microfacet:fit_microfacet", parametric=True),
    ModelInfo("bivariate", "single", "brdfrig.fit.bivariate:fit_bivariate"),
    ModelInfo("bivariate+prior", "single", "brdfrig.fit.bivariate:fit_bivariate", prior_parametric=True),
    ModelInfo("bivariate+measured", "single", "brdfrig.fit.bivariate:fit_bivariate", prior_references=True),
    ModelInfo("bivariate+blend", "blend"),
    ModelInfo("full", "linear"),
    ModelInfo("full+prior", "prior"),
)}
"""Every model ``fit_brdf`` fits, in order of richness (the tie-break of ``auto``)."""

RICHNESS: tuple[str, ...] = tuple(REGISTRY)
"""The candidates of ``auto``, simplest first."""
MODELS: tuple[str, ...] = ("auto",) + RICHNESS
"""Values of ``fit_brdf(model=...)``, the ``--model`` option and the ``[fit] model`` key."""
LINEAR_SH: tuple[str, ...] = tuple(m.name for m in REGISTRY.values() if m.kind == "linear")
"""The SH models solved by every solver in :data:`SOLVERS`."""
PARAMETRIC: tuple[str, ...] = tuple(m.name for m in REGISTRY.values() if m.parametric)
"""Parametric families (a few parameters per channel): the anchors of the relighting estimate."""
PRIOR_OF = {"full+prior": "microfacet"}
"""The fit a ``prior`` model is regularised toward."""


def single_fit(name: str) -> Callable:
    """The fit function of the ``single`` model ``name`` (imported on first use)."""
    info = REGISTRY[name]
    if info.kind != "single":
        raise ValueError(f"{name!r} is a {info.kind} model, not a single-model fit")
    module, func = info.fit.split(":")
    return getattr(importlib.import_module(module), func)
