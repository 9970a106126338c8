"""The contract every BRDF model of brdfrig implements, and the registry that reads them back.

A fitted (or analytic) BRDF is any object with the attributes and methods of
:class:`FittedBRDF`.  Conventions (``docs/MATH.md``): isotropic BRDF
``rho`` in 1/sr (no cosine factor), angles in radians, colour channels last,
orthographic view ``v = (0, 0, 1)``.

Serialisation: ``to_dict()`` returns a JSON-able dict whose ``"model"`` key
names the model; :func:`brdf_from_dict` dispatches on that key to the class
registered with :func:`register_model` (importing the providing module on
first use, so callers need not import every model module themselves).
"""

from __future__ import annotations

import importlib
from typing import Callable, Protocol, runtime_checkable

import numpy as np

from brdfrig.fit.scene import Environment

__all__ = ["FittedBRDF", "register_model", "brdf_from_dict"]


@runtime_checkable
class FittedBRDF(Protocol):
    """An isotropic BRDF that can relight a sphere and be evaluated pointwise.

    Attributes
    ----------
    model : str
        Registered model name (``"diffuse"``, ``"lobe"``, ``"full"``, ``"microfacet"``, ...).
    channels : int
        Number of colour channels C.
    """

    model: str
    channels: int

    def predict(self, env: Environment, normals: np.ndarray) -> np.ndarray:
        """Radiance (N, C) seen from ``v = (0, 0, 1)`` at sphere points with unit ``normals`` (N, 3) under ``env``."""
        ...

    def evaluate(self, theta_i: np.ndarray, theta_o: np.ndarray, delta_phi: np.ndarray) -> np.ndarray:
        """BRDF value rho (1/sr, no cosine), shape ``broadcast(theta_i, theta_o, delta_phi).shape + (C,)``.

        Angles in radians in the local frame of the normal: polar angles of the
        incident and outgoing directions in [0, pi/2], and ``delta_phi = phi_o - phi_i``.
        """
        ...

    def to_dict(self) -> dict:
        """JSON-able description with at least ``{"model": self.model, ...}``; inverse of :func:`brdf_from_dict`."""
        ...


_REGISTRY: dict[str, Callable[[dict], FittedBRDF]] = {}

# Modules that register the built-in models when imported (lazy: keeps imports light).
_PROVIDERS: dict[str, str] = {
    "diffuse": "brdfrig.fit.models",
    "lobe": "brdfrig.fit.models",
    "full": "brdfrig.fit.models",
    "microfacet": "brdfrig.fit.microfacet",
    "lambertian": "brdfrig.fit.analytic",
    "oren_nayar": "brdfrig.fit.analytic",
    "blinn_phong": "brdfrig.fit.analytic",
    "ggx": "brdfrig.fit.analytic",
    "dielectric": "brdfrig.fit.pbr",
    "conductor": "brdfrig.fit.pbr",
    "sheen": "brdfrig.fit.pbr",
    "tabulated": "brdfrig.fit.measured",
    "neural": "brdfrig.fit.measured",
    "bivariate": "brdfrig.fit.bivariate",
    "blend": "brdfrig.fit.blend",
}


def register_model(name: str) -> Callable[[type], type]:
    """Class decorator: make ``cls.from_dict(d)`` the reader of dicts with ``d["model"] == name``."""

    def decorate(cls: type) -> type:
        _REGISTRY[name] = cls.from_dict
        return cls

    return decorate


def brdf_from_dict(d: dict) -> FittedBRDF:
    """Rebuild a BRDF from the dict its ``to_dict()`` returned.

    Raises
    ------
    ValueError
        If ``d`` is not a dict with a known ``"model"`` or its content is malformed.
    """
    if not isinstance(d, dict) or not isinstance(d.get("model"), str):
        raise ValueError("BRDF description must be a dict with a string 'model' key")
    name = d["model"]
    if name not in _REGISTRY and name in _PROVIDERS:
        importlib.import_module(_PROVIDERS[name])
    if name not in _REGISTRY:
        raise ValueError(f"unknown BRDF model {name!r} (known: {sorted(set(_REGISTRY) | set(_PROVIDERS))})")
    try:
        return _REGISTRY[name](d)
    except (KeyError, TypeError, IndexError) as exc:
        raise ValueError(f"malformed {name!r} BRDF description: {exc!r}") from exc
