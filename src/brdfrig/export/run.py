"""Export one BRDF: choose the renderer material, write the format, measure and record the error.

The error record is written beside the export as ``OUT.error.json`` (and returned): the format, the
source and its colour space (the RGB of the exported values: ``camera``, ``rec709`` or ``acescg``
as the BRDF file records it, None for a measured material), the renderer material (its parameters), the
approximation error of what the file holds in rendered radiance under the standard lightings (overall and
per lighting), and the notes of the format writer (for ``mitsuba``: the BSDF type written, its Mitsuba
parameters and every candidate type's error, each evaluated as Mitsuba evaluates it).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from brdfrig.export import formats
from brdfrig.export.material import fidelity, renderer_material, standard_scenes

__all__ = ["ExportResult", "export_brdf"]

RENDERER_FORMATS = ("mitsuba", "openpbr", "gltf")
"""Formats that hold a renderer material (the others tabulate the BRDF itself)."""


@dataclass(frozen=True)
class ExportResult:
    """What one export wrote and how far it is from the fitted BRDF."""

    format: str
    path: Path
    record_path: Path
    relative_rms: float
    per_lighting: dict
    material: dict | None
    notes: dict
    colour_space: str | None = None

    def to_dict(self) -> dict:
        return {"format": self.format, "path": str(self.path), "record": str(self.record_path),
                "relative_rms": self.relative_rms, "per_lighting": self.per_lighting, "material": self.material,
                "notes": self.notes, "colour_space": self.colour_space}


def export_brdf(brdf, fmt: str, out, *, source: str = "", colour_space: str | None = None, progress: bool = False,
                **options) -> ExportResult:
    """Write ``brdf`` as ``fmt`` to ``out`` and its error record to ``out + '.error.json'`` (both atomic).

    Parameters
    ----------
    brdf : FittedBRDF
        Any brdfrig BRDF (fitted, analytic or measured).
    fmt : str
        One of :data:`brdfrig.export.formats.FORMATS`.
    out : path-like
        The export file (its suffix chooses CSV or NPZ for ``table``).
    source : str
        Where ``brdf`` came from (recorded).
    colour_space : str or None
        The RGB space of ``brdf`` (recorded; the export's values are in it).
    **options
        ``step_deg`` (table), ``scene_env`` (mitsuba: the lat-long file of a whole scene).
    """
    from brdfrig._atomic import write_text
    from brdfrig.fit.brdffile import jsonable

    out = Path(out)
    reference = standard_scenes(brdf)
    material, notes = None, {}
    if fmt in RENDERER_FORMATS:
        material, _, tried = renderer_material(brdf, progress=progress)
        notes["families_relative_rms"] = tried
    written, writer_notes = formats.write(fmt, brdf, material, out, reference=reference, **options)
    notes.update(writer_notes)
    f = fidelity(written, reference)
    record = out.with_name(out.name + ".error.json")
    result = ExportResult(fmt, out, record, f.error, f.per_lighting,
                          None if material is None else material.to_dict(), notes, colour_space)
    doc = {**result.to_dict(), "source": source, "fidelity": f.to_dict()}
    write_text(record, json.dumps(jsonable(doc), indent=1))
    return result
