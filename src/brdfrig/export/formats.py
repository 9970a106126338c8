"""Writers of the export formats, each with the material it really expresses (for the error check).

Every writer takes the fitted BRDF and its renderer material (:func:`brdfrig.export.material.renderer_material`)
and returns the BRDF the written file stands for, as brdfrig evaluates it, and notes on the choices made: the error of the export is that
BRDF's renders against the fitted one's.  Parameters a format cannot express are dropped from that BRDF
(e.g. glTF's Lambertian base has no Oren-Nayar roughness), so their loss is in the stated error.

- ``merl``: MERL ``.binary`` (90 x 90 x 180 x RGB, Rusinkiewicz coordinates) of the fitted BRDF itself;
- ``table``: rho on a regular (theta_i, theta_o, delta_phi) grid in degrees, as CSV (one row per sample)
  or NPZ (arrays ``theta_i_deg``, ``theta_o_deg``, ``delta_phi_deg``, ``rho`` (I, O, P, C) in 1/sr);
- ``mitsuba``: a Mitsuba 3 scene-description XML with one ``<bsdf>`` (``diffuse``, ``roughplastic`` or
  ``principled``), or a whole scene with ``scene_env``.  Each type that suits the renderer material is
  fitted to the BRDF's standard renders as Mitsuba evaluates it (:mod:`brdfrig.export.mitsuba_fit`,
  :mod:`brdfrig.export.mitsuba_bsdf`), and the closest is written: the BRDF it stands for is Mitsuba's
  own model with those parameters;
- ``openpbr``: a MaterialX document with an ``open_pbr_surface`` and its ``surfacematerial``;
- ``gltf``: a glTF 2.0 file with one metallic-roughness material and the KHR extensions that apply
  (``KHR_materials_ior``, ``KHR_materials_specular``, ``KHR_materials_sheen``).

Colours are written as they are in the BRDF (the renderer's working space is the BRDF file's colour
space: linear Rec.709 unless the file says otherwise).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

__all__ = ["FORMATS", "SUFFIXES", "write"]

FORMATS = ("merl", "table", "mitsuba", "openpbr", "gltf")
SUFFIXES = {"merl": (".binary",), "table": (".csv", ".npz"), "mitsuba": (".xml",), "openpbr": (".mtlx",),
            "gltf": (".gltf",)}
TABLE_STEP_DEG = 2.0
"""Grid step of the ``table`` export (degrees; 46 x 46 x 91 samples per channel)."""


class _EvaluatedRho:
    """``rho(wi, wo, n)`` of any BRDF from its ``evaluate(theta_i, theta_o, delta_phi)`` (local frame, n = +z)."""

    def __init__(self, brdf) -> None:
        self.brdf, self.channels, self.model = brdf, brdf.channels, getattr(brdf, "model", "brdf")

    def rho(self, wi, wo, n) -> np.ndarray:
        wi, wo = np.asarray(wi, dtype=np.float64), np.asarray(wo, dtype=np.float64)
        ti = np.arccos(np.clip(wi[:, 2], -1.0, 1.0))
        to = np.arccos(np.clip(wo[:, 2], -1.0, 1.0))
        dphi = np.arctan2(wo[:, 1], wo[:, 0]) - np.arctan2(wi[:, 1], wi[:, 0])
        ok = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        out = np.zeros((len(wi), self.channels))
        out[ok] = self.brdf.evaluate(ti[ok], to[ok], dphi[ok])
        return out


def _merl(brdf, material, out: Path, **_) -> tuple[object, dict]:
    from brdfrig.fit.measured import tabulate, write_merl

    table = tabulate(brdf if hasattr(brdf, "rho") else _EvaluatedRho(brdf))
    write_merl(out, table)
    return table, {"grid": "MERL 90 x 90 x 180 (theta_h sqrt-spaced, theta_d, phi_d mod 180 deg)"}


class _GridBRDF:
    """The ``table`` export read back: trilinear interpolation on its grid (``rho`` for tabulation)."""

    def __init__(self, axes_deg, rho) -> None:
        from scipy.interpolate import RegularGridInterpolator

        self.channels, self.model = rho.shape[-1], "table"
        self._f = RegularGridInterpolator(tuple(np.radians(a) for a in axes_deg), rho, bounds_error=False, fill_value=None)

    def rho(self, wi, wo, n) -> np.ndarray:
        ti = np.arccos(np.clip(wi[:, 2], -1.0, 1.0))
        to = np.arccos(np.clip(wo[:, 2], -1.0, 1.0))
        dphi = np.abs(np.angle(np.exp(1j * (np.arctan2(wo[:, 1], wo[:, 0]) - np.arctan2(wi[:, 1], wi[:, 0])))))
        return np.maximum(self._f(np.stack([ti, to, dphi], axis=1)), 0.0)


def _table(brdf, material, out: Path, *, step_deg: float = TABLE_STEP_DEG, **_) -> tuple[object, dict]:
    from brdfrig._atomic import temp_path
    from brdfrig.fit.measured import tabulate

    n_theta = int(round(88.0 / step_deg)) + 1
    theta = np.linspace(0.0, 88.0, n_theta)  # grazing 90 deg is left out: rho there is a limit, not a value
    phi = np.linspace(0.0, 180.0, int(round(180.0 / step_deg)) + 1)
    ti, to, dp = np.meshgrid(np.radians(theta), np.radians(theta), np.radians(phi), indexing="ij")
    rho = np.maximum(np.asarray(brdf.evaluate(ti, to, dp), dtype=np.float64), 0.0)
    with temp_path(out) as tmp:
        if out.suffix.lower() == ".npz":
            with open(tmp, "wb") as f:
                np.savez_compressed(f, theta_i_deg=theta, theta_o_deg=theta, delta_phi_deg=phi, rho=rho)
        else:
            cols = ["theta_i_deg", "theta_o_deg", "delta_phi_deg"] + [f"rho_{c}" for c in "RGB"[: rho.shape[-1]]]
            grid = np.stack(np.meshgrid(theta, theta, phi, indexing="ij"), axis=-1).reshape(-1, 3)
            np.savetxt(tmp, np.concatenate([grid, rho.reshape(-1, rho.shape[-1])], axis=1), delimiter=",",
                       header=",".join(cols) + "  (rho in 1/sr; delta_phi = phi_o - phi_i, 180 = specular side)",
                       fmt="%.9g")
    return tabulate(_GridBRDF((theta, theta, phi), rho)), {"step_deg": step_deg, "samples": int(rho[..., 0].size)}


def _mitsuba(brdf, material, out: Path, *, scene_env: str | None = None, reference=None, **_) -> tuple[object, dict]:
    from brdfrig._atomic import write_text
    from brdfrig.export.material import fidelity, standard_scenes
    from brdfrig.export.mitsuba_fit import fit_candidates

    reference = standard_scenes(brdf) if reference is None else reference
    candidates = fit_candidates(material, reference)
    errors = {k: fidelity(b, reference).error for k, b in candidates.items()}
    chosen = min(errors, key=errors.get)
    bsdf = candidates[chosen].xml()
    if scene_env is None:
        text = f'<scene version="3.0.0">\n{bsdf}\n</scene>\n'
    else:
        text = (
            '<scene version="3.0.0">\n'
            '  <integrator type="direct"/>\n'
            '  <sensor type="orthographic">\n'
            '    <transform name="to_world"><lookat origin="0, 0, 10" target="0, 0, 0" up="0, 1, 0"/></transform>\n'
            '    <film type="hdrfilm"><integer name="width" value="256"/><integer name="height" value="256"/>'
            '<rfilter type="box"/></film>\n  </sensor>\n'
            f'  <emitter type="envmap"><string name="filename" value="{scene_env}"/></emitter>\n'
            f'  <shape type="sphere">\n    {bsdf.replace(chr(10), chr(10) + "    ")}\n  </shape>\n</scene>\n')
    write_text(out, text)
    return candidates[chosen], {"bsdf": chosen, "candidates_relative_rms": errors,
                                "parameters": candidates[chosen].mitsuba_dict(), "scene": scene_env is not None}


def _openpbr_values(material) -> dict:
    """OpenPBR Surface inputs of a renderer material (``base_diffuse_roughness``: sigma / (pi/2), clipped)."""
    d = material.to_dict()
    v = {"base_weight": 1.0, "base_color": d["base_color"], "base_metalness": d.get("base_metalness", 0.0),
         "specular_weight": d.get("specular_weight", 1.0), "specular_color": d.get("specular_color", 1.0),
         "specular_roughness": d["specular_roughness"], "specular_ior": d.get("specular_ior", 1.5)}
    if d["model"] != "conductor":
        sigma = float(np.mean(d.get("base_diffuse_roughness", 0.0)))
        v["base_diffuse_roughness"] = min(max(sigma / (math.pi / 2), 0.0), 1.0)
    if d.get("fuzz_weight", 0.0) > 0:
        v.update(fuzz_weight=d["fuzz_weight"], fuzz_color=d["fuzz_color"], fuzz_roughness=d["fuzz_roughness"])
    return v


def _openpbr(brdf, material, out: Path, **_) -> tuple[object, dict]:
    import MaterialX as mx

    from brdfrig._atomic import write_text

    doc = mx.createDocument()
    shader = doc.addNode("open_pbr_surface", "brdfrig_surface", "surfaceshader")
    for name, value in _openpbr_values(material).items():
        if np.ndim(value) == 0:
            shader.setInputValue(name, float(value), "float")
        else:
            rgb = np.broadcast_to(np.asarray(value, dtype=float), (3,))
            shader.setInputValue(name, mx.Color3(*map(float, rgb)), "color3")
    mat = doc.addMaterialNode("brdfrig_material", shader)
    mat.setDocString("exported by brdfrig from a measured BRDF")
    write_text(out, mx.writeToXmlString(doc))
    return material, {"node": "open_pbr_surface", "base_diffuse_roughness": "sigma / (pi/2), clipped to [0, 1]"}


def _gltf(brdf, material, out: Path, **_) -> tuple[object, dict]:
    import pygltflib

    from brdfrig._atomic import write_text
    from brdfrig.fit.pbr import ConductorBRDF, DielectricBRDF, SheenBRDF

    d = material.to_dict()
    base = [float(x) for x in np.broadcast_to(np.asarray(d["base_color"], dtype=float), (3,))] + [1.0]
    metal = d["model"] == "conductor"
    ext, used = {}, []
    if not metal:
        ext["KHR_materials_ior"] = {"ior": float(d["specular_ior"])}
        ext["KHR_materials_specular"] = {"specularFactor": float(d["specular_weight"])}
    if d.get("fuzz_weight", 0.0) > 0:
        ext["KHR_materials_sheen"] = {"sheenColorFactor": [float(x) for x in np.broadcast_to(d["fuzz_color"], (3,))],
                                      "sheenRoughnessFactor": float(d["fuzz_roughness"])}
    used = sorted(ext)
    gltf = pygltflib.GLTF2(asset=pygltflib.Asset(generator="brdfrig", version="2.0"), extensionsUsed=used,
                           materials=[pygltflib.Material(
                               name="brdfrig_material", extensions=ext,
                               pbrMetallicRoughness=pygltflib.PbrMetallicRoughness(
                                   baseColorFactor=base, metallicFactor=1.0 if metal else 0.0,
                                   roughnessFactor=float(d["specular_roughness"])))])
    write_text(out, gltf.to_json())
    notes = {"extensions": used, "dropped": "base_diffuse_roughness (glTF's base is Lambertian)"
             + (", specular_color edge tint (glTF metals are Schlick)" if metal else "")}
    if metal:
        return ConductorBRDF(base_color=d["base_color"], specular_color=1.0,
                             specular_roughness=d["specular_roughness"]), notes
    if d.get("fuzz_weight", 0.0) > 0:
        return SheenBRDF(base_color=d["base_color"], specular_weight=d["specular_weight"],
                         specular_roughness=d["specular_roughness"], specular_ior=d["specular_ior"],
                         fuzz_color=d["fuzz_color"], fuzz_roughness=d["fuzz_roughness"], coat=d.get("coat", True)), notes
    return DielectricBRDF(base_color=d["base_color"], specular_weight=d["specular_weight"],
                          specular_roughness=d["specular_roughness"], specular_ior=d["specular_ior"]), notes


WRITERS = {"merl": _merl, "table": _table, "mitsuba": _mitsuba, "openpbr": _openpbr, "gltf": _gltf}


def write(fmt: str, brdf, material, out: Path, **options) -> tuple[object, dict]:
    """Write ``brdf`` (as ``material`` for the renderer formats) in format ``fmt``.

    Returns the BRDF the file stands for (as brdfrig evaluates it) and notes on the choices made.
    """
    return WRITERS[fmt](brdf, material, out, **options)
