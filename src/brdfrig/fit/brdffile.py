"""The BRDF file: versioned, self-describing JSON.

Layout (``format`` and ``version`` are checked on reading)::

    {
      "format": "brdfrig-brdf",
      "version": 1,
      "brdf": {...},            # the model's to_dict(): model, coefficients, band limits
      "conventions": {...},     # frames, SH basis, units (see CONVENTIONS)
      "colour_space": "camera", # RGB of rho: "camera" (camera RGB), "rec709" or "acescg" (linear)
      "report": {...},          # identifiability, fit statistics, chosen model and why
      "provenance": {...}       # writer, time, inputs
    }

Written atomically by :mod:`brdfrig._atomic`.
"""

from __future__ import annotations

import datetime as _dt
import json
from pathlib import Path

import numpy as np

from brdfrig._atomic import write_text
from brdfrig.errors import InputError
from brdfrig.fit.brdf import FittedBRDF, brdf_from_dict
from brdfrig.ranges import COLOUR_SPACES

__all__ = ["FORMAT_NAME", "FORMAT_VERSION", "CONVENTIONS", "jsonable", "save_brdf", "load_brdf", "open_brdf",
           "brdf_colour_space"]

FORMAT_NAME = "brdfrig-brdf"
FORMAT_VERSION = 1

CONVENTIONS = {
    "document": "docs/MATH.md of the brdfrig source tree (conventions and pitfalls)",
    "world_frame": "right-handed; orthographic camera on +z, view direction v = (0, 0, 1)",
    "local_frame": "R_n = Rz(phi_N) Ry(theta_N); w_o' = (-sin theta_N, 0, cos theta_N)",
    "sh_basis": "real orthonormal, no Condon-Shortley phase, index l*l + l + m; m > 0 ~ cos(m phi)",
    "rho_units": "1/sr, no cosine factor; evaluate(theta_i, theta_o, delta_phi = phi_o - phi_i)",
    "radiance_units": "linear, same units and channels as the lighting",
    "diffuse_lobe": "B = sum_l a_l sum_m L_lm Y_lm(n) + s_l sum_m L_lm Y_lm(r), r = 2(n.v)n - v",
    "full": "B = sum tau[l,p,k] L'_{l,k}(n) Y_{p,k}(w_o'), 0 <= k <= min(l, p)",
}


def jsonable(obj):
    """Convert numpy scalars/arrays, non-finite floats (as text), objects with ``to_dict()`` (a fit report) and
    other objects (as text) to plain JSON values."""
    if hasattr(obj, "to_dict"):
        return jsonable(obj.to_dict())
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return jsonable(obj.item())
    if isinstance(obj, float) and not np.isfinite(obj):
        return str(obj)
    if isinstance(obj, (str, int, float, bool)) or obj is None:
        return obj
    return str(obj)  # paths and other objects in a report or provenance: their text


def _non_finite(obj, where: str = "brdf") -> str | None:
    """The key path of the first NaN/inf number in a nested dict/list/array (None if all are finite)."""
    if isinstance(obj, dict):
        return next((w for k, v in obj.items() if (w := _non_finite(v, f"{where}.{k}"))), None)
    if isinstance(obj, np.ndarray) and obj.dtype.kind in "fc":
        return None if np.isfinite(obj).all() else f"{where}[flat {int(np.flatnonzero(~np.isfinite(obj))[0])}]"
    if isinstance(obj, (list, tuple, np.ndarray)):
        return next((w for i, v in enumerate(obj) if (w := _non_finite(v, f"{where}[{i}]"))), None)
    if isinstance(obj, (float, np.floating)) and not np.isfinite(obj):
        return where
    return None


def save_brdf(path, brdf: FittedBRDF, report=None, provenance: dict | None = None, *,
              colour_space: str = "camera", overwrite: bool = True) -> Path:
    """Write ``brdf`` and its fit ``report`` to ``path`` (JSON), atomically (``overwrite=False``: never replace a file).

    ``colour_space`` is the RGB space of the images it was fitted to (one of
    :data:`brdfrig.ranges.COLOUR_SPACES`).

    Returns
    -------
    Path
        The path written.

    Raises
    ------
    InputError
        The BRDF has a NaN or infinite parameter (nothing is written).
    """
    path = Path(path)
    if colour_space not in COLOUR_SPACES:
        raise InputError(f"{path}: unknown colour space {colour_space!r} (expected one of {', '.join(COLOUR_SPACES)})")
    description = brdf.to_dict()
    bad = _non_finite(description)
    if bad:
        raise InputError(f"{path}: refusing to write a BRDF with a non-finite parameter ({bad}): nothing written")
    doc = {
        "format": FORMAT_NAME,
        "version": FORMAT_VERSION,
        "brdf": jsonable(description),
        "conventions": CONVENTIONS,
        "colour_space": colour_space,
        "report": jsonable(report or {}),
        "provenance": jsonable(
            {"writer": "brdfrig.fit.brdffile", "written_utc": _dt.datetime.now(_dt.timezone.utc).isoformat()}
            | (provenance or {})
        ),
    }
    return write_text(path, json.dumps(doc, indent=1, allow_nan=False), overwrite=overwrite)


def load_brdf(path) -> tuple[FittedBRDF, dict]:
    """Read a BRDF file; returns ``(brdf, report)``.

    Raises
    ------
    InputError (a ValueError)
        Not a brdfrig BRDF file, another format version, or corrupt content.
    OSError
        The file cannot be read.
    """
    path = Path(path)
    try:
        doc = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not a brdfrig BRDF file (corrupt JSON: {exc})") from exc
    if not isinstance(doc, dict) or doc.get("format") != FORMAT_NAME:
        raise InputError(f"{path}: not a brdfrig BRDF file (format {doc.get('format') if isinstance(doc, dict) else None!r})")
    if doc.get("version") != FORMAT_VERSION:
        raise InputError(f"{path}: BRDF file version {doc.get('version')!r} is not supported (this brdfrig reads {FORMAT_VERSION})")
    try:
        brdf = brdf_from_dict(doc["brdf"])
    except (KeyError, ValueError, TypeError, AttributeError, IndexError) as exc:
        raise InputError(f"{path}: corrupt BRDF file: {exc}") from exc
    return brdf, doc.get("report", {})


def brdf_colour_space(path) -> str | None:
    """The colour space a BRDF file records (``"camera"`` for files written before it was recorded); None for a
    measured material (``.h5``, ``.binary``: its own RGB)."""
    if Path(path).suffix.lower() in MEASURED_SUFFIXES:
        return None
    try:
        doc = json.loads(Path(path).read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not a brdfrig BRDF file (corrupt JSON: {exc})") from exc
    space = doc.get("colour_space", "camera") if isinstance(doc, dict) else "camera"
    if space not in COLOUR_SPACES:
        raise InputError(f"{path}: unknown colour_space {space!r} (expected one of {', '.join(COLOUR_SPACES)})")
    return space


MEASURED_SUFFIXES = (".h5", ".binary")
"""Suffixes of measured materials (neural fits, MERL tables) that :func:`open_brdf` also reads."""


def open_brdf(path):
    """Any BRDF a user may name: a brdfrig BRDF file (JSON) or a measured material (``.h5``, ``.binary``).

    Returns the BRDF (a :class:`~brdfrig.fit.brdf.FittedBRDF`); errors as :func:`load_brdf` and
    :func:`brdfrig.fit.measured.load_measured`.
    """
    if Path(path).suffix.lower() in MEASURED_SUFFIXES:
        from brdfrig.fit.measured import load_measured

        return load_measured(path)
    return load_brdf(path)[0]

