"""brdfrig export: every format read back by an independent reader, and the error it states."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from brdfrig.fit.brdffile import save_brdf
from brdfrig.fit.pbr import ConductorBRDF, DielectricBRDF
from brdfrig.session.library import Library

PLASTIC = DielectricBRDF(base_color=[0.6, 0.35, 0.2], base_diffuse_roughness=0.4, specular_weight=1.0,
                         specular_roughness=0.45, specular_ior=1.5)
METAL = ConductorBRDF(base_color=[0.95, 0.7, 0.35], specular_color=1.0, specular_roughness=0.4)


def _export(tmp_path, brdf, fmt, name, *extra):
    src = tmp_path / "in.brdf.json"
    save_brdf(src, brdf)
    out = tmp_path / name
    r = subprocess.run([sys.executable, "-m", "brdfrig", "export", str(src), "--format", fmt, "-o", str(out),
                        "--no-progress", "--json", *extra], capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr
    record = json.loads(r.stdout)
    assert json.loads((tmp_path / (name + ".error.json")).read_text())["relative_rms"] == record["relative_rms"]
    with Library(os.environ["BRDFRIG_LIBRARY"]) as lib:  # the test session's catalogue (tests/conftest.py)
        assert [e["format"] for e in lib.exports(src)][:1] == [fmt]
    return out, record


def _merl_reader(path):
    """An independent MERL reader, from the documented layout (../shared/data/measured/README.md)."""
    raw = path.read_bytes()
    dims = np.frombuffer(raw[:12], dtype="<i4")
    assert tuple(dims) == (90, 90, 180)
    vals = np.frombuffer(raw[12:], dtype="<f8").reshape(3, 90, 90, 180)
    return vals * np.array([1 / 1500, 1.15 / 1500, 1.66 / 1500])[:, None, None, None]


def test_merl_export_equals_the_brdf_at_the_grid_points(tmp_path):
    out, record = _export(tmp_path, PLASTIC, "merl", "plastic.binary")
    table = _merl_reader(out)
    ith, itd, ipd = np.meshgrid(np.arange(90), np.arange(90), np.arange(180), indexing="ij")
    th, td, pd = (ith / 90) ** 2 * math.pi / 2, itd / 90 * math.pi / 2, ipd / 180 * math.pi
    # the grid point's directions (Rusinkiewicz, n = +z, phi_h = 0), independently of brdfrig
    dx, dy, dz = np.sin(td) * np.cos(pd), np.sin(td) * np.sin(pd), np.cos(td)
    wi = np.stack([np.cos(th) * dx + np.sin(th) * dz, dy, -np.sin(th) * dx + np.cos(th) * dz], -1)
    wo = np.stack([np.cos(th) * -dx + np.sin(th) * dz, -dy, np.sin(th) * dx + np.cos(th) * dz], -1)
    ok = (wi[..., 2] > 1e-3) & (wo[..., 2] > 1e-3)
    ti, to = np.arccos(wi[..., 2][ok]), np.arccos(wo[..., 2][ok])
    dphi = np.arctan2(wo[..., 1][ok], wo[..., 0][ok]) - np.arctan2(wi[..., 1][ok], wi[..., 0][ok])
    pick = np.random.default_rng(0).choice(len(ti), 20000, replace=False)
    want = PLASTIC.evaluate(ti[pick], to[pick], dphi[pick])
    got = np.moveaxis(table, 0, -1)[ok][pick]
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-12)
    below = (wi[..., 2] < -1e-9) | (wo[..., 2] < -1e-9)
    assert np.all(table[:, below] < 0)  # a direction below the horizon: written as missing (negative)
    assert record["relative_rms"] < 0.01  # the table's interpolation, rendered


def test_openpbr_export_validates_in_materialx_and_is_exact_for_its_family(tmp_path):
    mx = pytest.importorskip("MaterialX")
    out, record = _export(tmp_path, PLASTIC, "openpbr", "plastic.mtlx")
    doc = mx.createDocument()
    mx.readFromXmlFile(doc, str(out))
    lib = mx.createDocument()
    mx.loadLibraries(mx.getDefaultDataLibraryFolders(), mx.getDefaultDataSearchPath(), lib)
    doc.importLibrary(lib)
    valid, message = doc.validate()
    assert valid, message
    shader = doc.getNode("brdfrig_surface")
    assert shader.getCategory() == "open_pbr_surface"
    assert shader.getInputValue("specular_ior") == pytest.approx(1.5)
    assert list(shader.getInputValue("base_color").asTuple()) == pytest.approx([0.6, 0.35, 0.2])
    assert record["relative_rms"] < 1e-9  # the material is the BRDF itself


def test_gltf_export_loads_in_two_readers_and_states_what_it_drops(tmp_path):
    pygltflib = pytest.importorskip("pygltflib")
    gltflib = pytest.importorskip("gltflib")
    out, record = _export(tmp_path, PLASTIC, "gltf", "plastic.gltf")
    a = pygltflib.GLTF2().load(str(out))
    m = a.materials[0]
    assert m.pbrMetallicRoughness.metallicFactor == 0.0 and m.pbrMetallicRoughness.roughnessFactor == pytest.approx(0.45)
    assert m.extensions["KHR_materials_ior"]["ior"] == pytest.approx(1.5)
    b = gltflib.GLTF.load(str(out))
    assert b.model.materials[0].pbrMetallicRoughness.baseColorFactor[:3] == pytest.approx([0.6, 0.35, 0.2])
    # glTF's base is Lambertian: the Oren-Nayar roughness is dropped, and that costs something, stated
    assert "base_diffuse_roughness" in record["notes"]["dropped"] and 1e-4 < record["relative_rms"] < 0.2
    out, record = _export(tmp_path, METAL, "gltf", "metal.gltf")
    assert pygltflib.GLTF2().load(str(out)).materials[0].pbrMetallicRoughness.metallicFactor == 1.0
    assert record["relative_rms"] < 1e-9  # Schlick metal: exactly glTF's


def test_mitsuba_export_names_the_closest_bsdf(tmp_path):
    out, record = _export(tmp_path, METAL, "mitsuba", "metal.xml")
    bsdf = ET.parse(out).getroot().find("bsdf")
    assert bsdf.get("type") == "principled" and record["notes"]["bsdf"] == "principled"
    out, record = _export(tmp_path, PLASTIC, "mitsuba", "plastic.xml")
    bsdf = ET.parse(out).getroot().find("bsdf")
    assert bsdf.get("type") == "roughplastic"
    errors = record["notes"]["candidates_relative_rms"]
    assert errors["roughplastic"] < errors["diffuse"]
    assert record["relative_rms"] == pytest.approx(errors["roughplastic"], rel=1e-9)  # the written BSDF's own error
    # the file holds the parameters the error was stated for
    params = record["notes"]["parameters"]
    values = {e.get("name"): e.get("value") for e in bsdf}
    for key in ("alpha", "int_ior", "ext_ior", "specular_reflectance"):
        assert float(values[key]) == pytest.approx(params[key], rel=1e-5)
    rgb = [float(x) for x in values["diffuse_reflectance"].split(",")]
    assert rgb == pytest.approx(params["diffuse_reflectance"]["value"], rel=1e-5)
    # the Oren-Nayar base is beyond roughplastic: the error says so (fit: 3.9%)
    assert 0.01 < record["relative_rms"] < 0.06


def test_table_export_holds_the_brdf_values(tmp_path):
    out, record = _export(tmp_path, PLASTIC, "table", "plastic.npz", "--step", "5")
    with np.load(out) as z:
        ti, to, dp = np.meshgrid(*(np.radians(z[k]) for k in ("theta_i_deg", "theta_o_deg", "delta_phi_deg")),
                                 indexing="ij")
        np.testing.assert_allclose(z["rho"], PLASTIC.evaluate(ti, to, dp), rtol=1e-12)
    assert record["notes"]["step_deg"] == 5.0 and record["relative_rms"] < 0.1
