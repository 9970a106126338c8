"""Physically based families: energy conservation, reciprocity, a peer's BSDF, and one-image fits that relight."""

from __future__ import annotations

import math

import numpy as np
import pytest

from brdfrig.fit.brdf import FittedBRDF, brdf_from_dict
from brdfrig.fit.metrics import relative_rms
from brdfrig.fit.pbr import ConductorBRDF, DielectricBRDF, SheenBRDF, coat_albedo, fresnel_coefficients
from brdfrig.fit.pbr_fit import fit_pbr
from brdfrig.fit.scene import Scene

from conftest import PROBE_DIR

FAMILIES = {
    "dielectric": DielectricBRDF([0.6, 0.4, 0.2], 0.4, 1.0, math.sqrt(0.2), 1.49),
    "conductor": ConductorBRDF([0.95, 0.7, 0.3], [0.9, 0.8, 0.6], 0.45),
    "sheen": SheenBRDF([0.5, 0.3, 0.2], 0.0, fuzz_color=[0.4, 0.5, 0.6], fuzz_roughness=0.6, coat=False),
    "sheen_coat": SheenBRDF([0.5, 0.3, 0.2], 0.3, 1.0, 0.5, 1.5, [0.3, 0.3, 0.4], 0.4, coat=True),
}


def _albedo(brdf, theta_o: float, n: int = 200) -> np.ndarray:
    """Directional albedo by brute-force midpoint quadrature over the incident hemisphere (dense at grazing)."""
    s = (np.arange(n) + 0.5) / n
    cos_i, w = s**2, 2 * s / n  # cos = s^2: d(cos) = 2 s ds
    phi = (np.arange(2 * n) + 0.5) / (2 * n) * 2 * math.pi
    c, p = np.meshgrid(cos_i, phi, indexing="ij")
    rho = brdf.evaluate(np.arccos(c), theta_o, p)
    return np.einsum("ijc,ij->c", rho, c * w[:, None]) * (math.pi / n)


@pytest.mark.parametrize("name", list(FAMILIES))
def test_energy_conservation_white_materials(name):
    # Brightest admissible colours: albedo <= 1 at every angle up to 89.9 degrees (quadrature error ~1e-3).
    white = {
        "dielectric": DielectricBRDF(1.0, [0.0, 1.0, 1.5], 1.0, 0.5, 2.0),
        "conductor": ConductorBRDF(1.0, [1.0, 0.5, 0.0], 0.4),
        "sheen": SheenBRDF(1.0, [0.0, 1.0, 1.5], fuzz_color=1.0, fuzz_roughness=0.3, coat=False),
        "sheen_coat": SheenBRDF(1.0, [0.0, 1.0, 1.5], 1.0, 0.5, 1.5, 1.0, 0.5, coat=True),
    }[name]
    for theta in (0.0, 30.0, 60.0, 80.0, 89.0, 89.9):
        a = _albedo(white, math.radians(theta))
        assert np.all(a <= 1.0 + 2e-3), (theta, a)  # measured max 1.000 (dielectric at normal incidence)
    if name == "dielectric":
        # A white Lambertian base under the coating: what the coating does not reflect comes back (no loss).
        assert _albedo(white, 0.5)[0] == pytest.approx(1.0, abs=5e-3)


@pytest.mark.parametrize("name", list(FAMILIES))
def test_finite_non_negative_reciprocal(name):
    brdf = FAMILIES[name]
    rng = np.random.default_rng(3)
    ti, to = rng.uniform(0, math.pi / 2, 500), rng.uniform(0, math.pi / 2, 500)
    dp = rng.uniform(-math.pi, math.pi, 500)
    ti[:50], to[50:100] = math.pi / 2, math.radians(89.9)  # the horizon and just above
    a, b = brdf.evaluate(ti, to, dp), brdf.evaluate(to, ti, dp)
    assert np.all(np.isfinite(a)) and np.all(a >= 0)
    np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-14)
    # Light at 89.9 degrees seen away from the mirror direction: of the order of the albedo / pi, no blow-up
    # (the series of the old microfacet model gave 5-15 there).
    grazing = brdf.evaluate(math.radians(89.9), np.radians([0.0, 30.0, 60.0])[:, None], np.array([0.0, math.pi / 2]))
    assert np.all(grazing < 0.5), grazing.max()


def test_legendre_polynomials_match_numpys():
    from brdfrig.fit.pbr import FRESNEL_DEGREE, legendre_into

    x = np.linspace(-1, 1, 201)
    mine = np.empty((x.size, FRESNEL_DEGREE + 1))
    for k, v in enumerate(x):
        legendre_into(v, mine[k])
    np.testing.assert_allclose(mine, np.polynomial.legendre.legvander(x, FRESNEL_DEGREE), rtol=0, atol=1e-14)
    short = np.empty(1)
    legendre_into(0.3, short)
    assert short[0] == 1.0


def test_fresnel_expansion_and_coat_albedo_closed_forms():
    from brdfrig.fit.analytic import fresnel_dielectric

    # Legendre expansion of the dielectric Fresnel: 2e-5 absolute (module docstring); F(1) = ((n-1)/(n+1))^2.
    c = np.linspace(0, 1, 101)
    for ior in (1.3, 1.5, 2.0):
        approx = np.polynomial.legendre.legval(2 * c - 1, fresnel_coefficients(ior))
        exact = np.array([fresnel_dielectric(x, ior) for x in c])
        assert np.max(np.abs(approx - exact)) < 3e-5
        assert exact[-1] == pytest.approx(((ior - 1) / (ior + 1)) ** 2, rel=1e-12)
    # A nearly smooth coating reflects F(cos) of its own angle: directional albedo -> Fresnel (1% at alpha 1e-3).
    e = coat_albedo(1e-3, 1.5)
    from brdfrig.fit.pbr import COS_NODES

    for k in (8, 16, 31):
        assert e[k] == pytest.approx(fresnel_dielectric(COS_NODES[k], 1.5), rel=0.02)


def test_against_mitsuba_bsdf_eval():
    # Peer oracle: Mitsuba 3's roughplastic (specular part) and roughconductor evaluated pointwise.
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")

    def mitsuba_rho(bsdf, ti, to, dp):
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(math.sin(to), 0.0, math.cos(to))  # Mitsuba's wi points to the viewer
        si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
        wo = mi.Vector3f(math.sin(ti) * math.cos(dp), math.sin(ti) * math.sin(dp), math.cos(ti))
        v = bsdf.eval(mi.BSDFContext(), si, wo)
        return np.array([v[0], v[1], v[2]]) / math.cos(ti)  # Mitsuba includes the cosine

    plastic = mi.load_dict({"type": "roughplastic", "distribution": "ggx", "alpha": 0.2, "int_ior": 1.49, "ext_ior": 1.0,
                            "diffuse_reflectance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}})
    ours = DielectricBRDF(0.0, 0.0, 1.0, math.sqrt(0.2), 1.49)
    # Plain Schlick conductor (specular_color 1) equals Mitsuba's roughconductor with that Fresnel? Mitsuba has
    # complex-IOR Fresnel only; a perfect conductor (eta=0, k=inf) has F = 1: ours with base_color 1.
    mirror = mi.load_dict({"type": "roughconductor", "distribution": "ggx", "alpha": 0.2, "material": "none"})
    ours_mirror = ConductorBRDF(1.0, 1.0, math.sqrt(0.2))
    for ti, to, dp in [(0.1, 0.2, math.pi), (0.5, 0.5, math.pi), (0.8, 0.3, 2.0), (0.9, 0.9, 2.8), (0.3, 1.0, 0.5)]:
        # Mitsuba's Smith term is separable, ours height-correlated: equal to 0.3% at these angles (measured 1e-5).
        np.testing.assert_allclose(ours.evaluate(ti, to, dp)[0], mitsuba_rho(plastic, ti, to, dp), rtol=3e-3)
        np.testing.assert_allclose(ours_mirror.evaluate(ti, to, dp)[0], mitsuba_rho(mirror, ti, to, dp), rtol=3e-3)


def _case(rows: int = 32, size: int = 32):
    from brdfrig.evaluate.probes import probe_environment

    if not PROBE_DIR.is_dir():
        pytest.skip("../shared/data/probes is absent")
    y, x = np.mgrid[0:size, 0:size] + 0.5
    dx, dy = (x - size / 2) / (size / 2), (size / 2 - y) / (size / 2)
    inside = dx**2 + dy**2 < 0.95**2
    normals = np.stack([dx[inside], dy[inside], np.sqrt(1 - dx[inside] ** 2 - dy[inside] ** 2)], axis=1)
    return probe_environment("grace", rows, PROBE_DIR), probe_environment("pisa", rows, PROBE_DIR), normals


@pytest.mark.parametrize("name", ["dielectric", "conductor", "sheen"])
def test_one_noisy_image_recovers_parameters_and_relights(name):
    fit_env, test_env, normals = _case(size=24)
    truth = FAMILIES[name]
    observed = truth.predict(fit_env, normals)
    noisy = observed * (1 + 0.01 * np.random.default_rng(0).standard_normal(observed.shape))
    brdf, report = fit_pbr([Scene(fit_env, normals, noisy, np.ones(len(normals)))], name, progress=False)
    assert isinstance(brdf, FittedBRDF) and brdf.model == name and report["determined"]
    assert not any(report["at_bound"].values())
    want = truth.to_dict()
    np.testing.assert_allclose(report["base_color"], want["base_color"], rtol=0.03, atol=0.01)
    np.testing.assert_allclose(report["specular_roughness" if name != "sheen" else "fuzz_roughness"],
                               want["specular_roughness" if name != "sheen" else "fuzz_roughness"], rtol=0.05)
    if name == "dielectric":
        assert report["specular_ior"] == pytest.approx(1.49, abs=0.08)
        np.testing.assert_allclose(report["base_diffuse_roughness"], 0.4, atol=0.1)
    if name == "conductor":
        np.testing.assert_allclose(report["specular_color"], want["specular_color"], atol=0.1)
    if name == "sheen":
        np.testing.assert_allclose(report["fuzz_color"], want["fuzz_color"], rtol=0.05, atol=0.02)
    relit = brdf.predict(test_env, normals)
    assert np.all(np.isfinite(relit)) and np.all(relit >= 0)
    assert relative_rms(relit, truth.predict(test_env, normals)) < 0.01
    back = brdf_from_dict(brdf.to_dict())
    np.testing.assert_array_equal(back.evaluate(0.3, 0.5, 2.0), brdf.evaluate(0.3, 0.5, 2.0))


@pytest.mark.parametrize("ior, bound", [(1.1, 1.3), (2.6, 2.0)])
def test_ior_beyond_the_search_bounds_is_not_determined(ior, bound):
    """A coating whose IOR lies outside :data:`IOR_BOUNDS` fits at the bound, and the fit says it is not determined
    (``auto`` then does not choose the family); the IOR 1.49 image of the test above fits inside."""
    fit_env, _, normals = _case(size=16)
    truth = DielectricBRDF([0.3, 0.2, 0.1], 0.2, 1.0, math.sqrt(0.05), ior)
    scene = Scene(fit_env, normals, truth.predict(fit_env, normals), np.ones(len(normals)))
    _, report = fit_pbr([scene], "dielectric", progress=False)
    assert report["specular_ior"] == pytest.approx(bound, abs=0.01)
    assert report["at_bound"] == {"specular_roughness": False, "specular_ior": True} and not report["determined"]


def test_families_share_lobe_renders_without_changing_the_fit():
    """The conductor's search after a dielectric fit of the same image renders only the points the dielectric's
    did not (the alpha grid is shared) and returns the fit it returns with an empty memo."""
    from brdfrig.fit import pbr_fit
    from brdfrig.fit.memo import RENDERS

    fit_env, _, normals = _case(size=16)
    scene = Scene(fit_env, normals, FAMILIES["conductor"].predict(fit_env, normals), np.ones(len(normals)))
    RENDERS.clear()
    alone, rep_alone = fit_pbr([scene], "conductor", progress=False)
    RENDERS.clear()
    fit_pbr([scene], "dielectric", progress=False)
    shared, rep_shared = fit_pbr([scene], "conductor", progress=False)
    assert rep_shared["renders"] <= rep_alone["renders"] - pbr_fit.GRID_POINTS
    assert shared.to_dict() == alone.to_dict()


def test_bad_values_raise():
    with pytest.raises(ValueError, match="base_color"):
        DielectricBRDF([1.2, 0.5, 0.5])
    with pytest.raises(ValueError, match="specular_ior"):
        DielectricBRDF(0.5, specular_ior=0.8)
    with pytest.raises(ValueError, match="specular_color"):
        ConductorBRDF(0.9, float("nan"))
    with pytest.raises(ValueError, match="fuzz"):
        DielectricBRDF(0.5, fuzz_color=0.3)
    with pytest.raises(ValueError, match="family"):
        fit_pbr([], "plastic")


def test_sharp_lobe_quadrature_converges():
    # MATH.md pitfall 9: a lobe narrower than a cell. predict's rule (lobe_rule) against a finer subdivision.
    from brdfrig.fit.groundtruth import render_groundtruth
    from brdfrig.fit.groundtruth import render_sharp
    from brdfrig.fit.pbr import lobe_rule

    env, _, normals = _case(rows=32, size=16)
    sharp = DielectricBRDF([0.3, 0.2, 0.1], 0.0, 1.0, 0.12, 1.5)  # alpha 0.0144, cells 0.098 rad
    assert lobe_rule(0.0144, env) == (pytest.approx(14.0625), 12)
    reference = render_sharp(sharp, normals, env, 20.0, 20)
    assert relative_rms(sharp.predict(env, normals), reference) < 0.005  # measured 4e-4 at 128 x 64
    assert relative_rms(render_groundtruth(sharp, normals, env), reference) > 0.02  # cell centres: 13% at 128 x 64


@pytest.mark.parametrize("name", list(FAMILIES))
def test_channels_share_the_shape_to_the_last_bit(name):
    """``rho_channels`` with the shape evaluated once, and the view's factors once per pixel (``rho_view``), equals
    ``rho_channel`` per channel exactly (the renders' speed-up must not change a value), also where a channel's
    amplitude is 0."""
    from brdfrig.fit.rho import rho_channel, rho_channels, rho_view, shares_shape

    brdf = FAMILIES[name]
    params = np.array(brdf.kernel_params(), dtype=np.float64)
    params[1, 0] = 0.0  # one channel without its first amplitude
    assert shares_shape(brdf.kind, params)
    rng = np.random.default_rng(5)
    wi, wo = rng.normal(size=(2, 400, 3))
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    out = np.empty(params.shape[0])
    for a, b in zip(wi, wo):
        rho_channels(brdf.kind, params, True, a[2], b[2], float(a @ b), rho_view(brdf.kind, params, True, b[2]), out)
        assert out.tolist() == [rho_channel(brdf.kind, p, a[2], b[2], float(a @ b)) for p in params]
    other = params.copy()
    other[2, 3] *= 1.5  # another roughness in one channel: not shared
    assert not shares_shape(brdf.kind, other)


def test_sheen_visibility_table():
    """``1 / (1 + Lambda)`` read from the sheen table is within 2e-7 of the Estevez-Kulla formula at every cosine
    (2 x 10^6 + 1 of them, both ends included), and within 3e-6 of it relative from ``cos = 0.01`` up, over the
    roughnesses a fit may take."""
    import numba

    from brdfrig.fit.rho import sheen_lambda, sheen_table, sheen_visibility

    @numba.njit
    def worst(alpha, cosines):
        table = sheen_table(alpha)
        absolute = relative = 0.0
        for c in cosines:
            exact = 1.0 / (1.0 + sheen_lambda(c, alpha))
            err = abs(sheen_visibility(table, 0, c) - exact)
            absolute = max(absolute, err)
            if c >= 0.01:
                relative = max(relative, err / exact)
        return absolute, relative

    cosines = np.linspace(0.0, 1.0, 2_000_001)
    for alpha in (1e-4, 0.01, 0.1, 0.3, 0.6, 1.0):
        absolute, relative = worst(alpha, cosines)
        assert absolute <= 2e-7 and relative <= 3e-6, (alpha, absolute, relative)


def test_sheen_lobe_is_the_gltf_charlie_sheen():
    """A bare fuzz layer (no base, no coating, unit colour) is the glTF Charlie sheen, written here from
    KHR_materials_sheen (the Estevez-Kulla ``Lambda``), within 6e-6 relative where both cosines are >= 0.01 (the
    sheen table's bound, :func:`brdfrig.fit.rho.sheen_table`)."""

    def lam(c, a):
        def l(x):
            t = (1 - a) ** 2
            return ((21.5473 + 3.7772 * t) / (1 + (3.82987 - 0.50552 * t) * x ** (0.19823 - 0.03022 * t))
                    + (-1.97760 + 0.70367 * t) * x + (-4.32054 - 0.53913 * t))
        return np.where(c < 0.5, np.exp(l(c)), np.exp(2 * l(0.5) - l(1 - c)))

    rng = np.random.default_rng(5)
    ti, to = np.arccos(rng.uniform(0.01, 1, 4000)), np.arccos(rng.uniform(0.01, 1, 4000))
    dp = rng.uniform(-math.pi, math.pi, 4000)
    for roughness in (0.1, 0.4, 0.8, 1.0):
        brdf = SheenBRDF(0.0, 0.0, fuzz_color=1.0, fuzz_roughness=roughness, coat=False)
        a = roughness**2
        ci, co = np.cos(ti), np.cos(to)
        cos_io = ci * co + np.sin(ti) * np.sin(to) * np.cos(dp)
        cos_h = (ci + co) / np.sqrt(2 + 2 * cos_io)
        d = (2 + 1 / a) * (1 - cos_h**2) ** (0.5 / a) / (2 * math.pi)
        want = d / ((1 + lam(ci, a) + lam(co, a)) * 4 * ci * co)
        np.testing.assert_allclose(brdf.evaluate(ti, to, dp)[:, 0], want, rtol=6e-6, atol=0)


def test_fuzz_column_is_the_sheen_lobe():
    """The sheen fit's fuzz column equals the unit-colour fuzz layer rendered by the generic kernel (to rounding:
    the two multiply the cosine in another order)."""
    from brdfrig.fit.columns import render_fuzz
    from brdfrig.fit.groundtruth import kernel_inputs, render_kernel
    from brdfrig.fit.pbr import layered_rows
    from brdfrig.fit.rho import KIND_LAYERED

    env, _, normals = _case(size=16)
    row = layered_rows(np.array([[0.0, 0.0, 0.0, 1.0]]), 0.1, 1.5, 0.3, False, 1.0)
    n, dirs, weighted, view = kernel_inputs(normals, env, (0.0, 0.0, 1.0))
    generic = render_kernel(KIND_LAYERED, np.repeat(row, env.channels, axis=0), n, dirs, weighted, view)
    fuzz = render_fuzz(0.3, normals, env)
    assert np.abs(fuzz).max() > 0
    np.testing.assert_allclose(fuzz, generic, rtol=1e-13, atol=0)
