"""brdfrig's evaluation of Mitsuba 3's BSDFs (:mod:`brdfrig.export.mitsuba_bsdf`) against Mitsuba's own ``bsdf.eval``.

Oracle: Mitsuba 3 itself (``scalar_rgb``), each BSDF loaded from the XML element the exporter writes, evaluated
at seeded random direction pairs over the whole upper hemisphere (grazing included).  Tolerance: 1e-4 relative
(Mitsuba computes in float32; its roughplastic tables are quadratures that brdfrig reproduces node for node).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import mitsuba_scene as ms
from brdfrig.export.mitsuba_bsdf import MitsubaDiffuse, MitsubaPrincipled, MitsubaRoughPlastic

PAIRS = 400
RTOL = 1e-4
CASES = {
    "roughplastic": MitsubaRoughPlastic([0.6, 0.35, 0.2], alpha=0.2025, int_ior=1.5, ext_ior=1.0),
    "roughplastic glossy": MitsubaRoughPlastic([0.73, 0.43, 0.25], alpha=0.03, int_ior=1.8, ext_ior=1.0,
                                               specular_reflectance=0.7),
    "roughplastic rough nonlinear": MitsubaRoughPlastic([0.9, 0.5, 0.05], alpha=0.7, int_ior=1.3, ext_ior=1.0,
                                                        nonlinear=True),
    "roughplastic eta < 1": MitsubaRoughPlastic([0.4, 0.4, 0.4], alpha=0.3, int_ior=1.2, ext_ior=1.5),
    "principled metal": MitsubaPrincipled([0.95, 0.7, 0.35], roughness=0.4, metallic=1.0),
    "principled mixed": MitsubaPrincipled([0.5, 0.3, 0.35], roughness=0.6, metallic=0.3, specular=0.7),
    "principled dielectric": MitsubaPrincipled([0.2, 0.5, 0.8], roughness=0.25, metallic=0.0, specular=0.5),
    "diffuse": MitsubaDiffuse([0.3, 0.4, 0.5]),
}


def _hemisphere(rng, n):
    v = rng.normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2])
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _mitsuba_values(mi, bsdf, view, light) -> np.ndarray:
    """Mitsuba's ``eval`` (it includes the light's cosine) with ``si.wi`` toward the viewer, local frame = world."""
    ctx = mi.BSDFContext()
    out = np.empty((len(view), 3))
    for k, (v, l) in enumerate(zip(view, light)):
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(*map(float, v))
        si.sh_frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
        value = bsdf.eval(ctx, si, mi.Vector3f(*map(float, l)))
        out[k] = [value[0], value[1], value[2]]
    return out


@pytest.mark.parametrize("name", list(CASES))
def test_brdfrig_evaluates_the_mitsuba_bsdf_as_mitsuba_does(name):
    mi = ms.require_mitsuba("scalar_rgb")
    ours_bsdf = CASES[name]
    theirs_bsdf = mi.load_string(ours_bsdf.xml().replace("<bsdf ", '<bsdf version="3.0.0" ', 1))
    rng = np.random.default_rng(sum(map(ord, name)))
    view, light = _hemisphere(rng, PAIRS), _hemisphere(rng, PAIRS)
    theirs = _mitsuba_values(mi, theirs_bsdf, view, light)
    ours = ours_bsdf.rho(light, view, np.array([0.0, 0.0, 1.0])) * light[:, 2:3]
    assert np.all(theirs > 0)  # every pair above both horizons reflects something
    np.testing.assert_allclose(ours, theirs, rtol=RTOL, atol=0)


def test_mitsuba_dict_is_the_xml_element():
    mi = ms.require_mitsuba("scalar_rgb")
    rng = np.random.default_rng(7)
    view, light = _hemisphere(rng, 50), _hemisphere(rng, 50)
    for bsdf in CASES.values():
        a = _mitsuba_values(mi, mi.load_dict(bsdf.mitsuba_dict()), view, light)
        b = _mitsuba_values(mi, mi.load_string(bsdf.xml().replace("<bsdf ", '<bsdf version="3.0.0" ', 1)), view, light)
        np.testing.assert_allclose(a, b, rtol=1e-5)


def test_evaluate_is_rho_in_the_local_frame():
    """``evaluate(theta_i, theta_o, delta_phi)`` against ``rho`` of the same directions built by hand."""
    bsdf = CASES["roughplastic"]
    ti, to, dp = 0.4, 1.1, 2.5
    wi = np.array([[math.sin(ti), 0.0, math.cos(ti)]])
    wo = np.array([[math.sin(to) * math.cos(dp), math.sin(to) * math.sin(dp), math.cos(to)]])
    np.testing.assert_allclose(bsdf.evaluate(ti, to, dp), bsdf.rho(wi, wo, np.array([0.0, 0.0, 1.0]))[0], rtol=1e-12)


def test_bad_parameters_raise_value_errors_naming_them():
    with pytest.raises(ValueError, match="diffuse_reflectance"):
        MitsubaRoughPlastic([0.5, float("nan"), 0.5])
    with pytest.raises(ValueError, match="int_ior"):
        MitsubaRoughPlastic(0.5, int_ior=1.0, ext_ior=1.0)
    with pytest.raises(ValueError, match="roughness"):
        MitsubaPrincipled(0.5, roughness=1.5)
