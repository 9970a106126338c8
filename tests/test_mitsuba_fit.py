"""Issue 10 must-show: Mitsuba materials fitted from one Mitsuba render, relit against Mitsuba: <= 3% each.

Mitsuba 3 renders a 48 px sphere of ``diffuse``, ``roughplastic`` (GGX alpha 0.2 under a dielectric
coating) and ``roughconductor`` gold (alpha 0.2) under grace (64x32); brdfrig fits it with
``fit_brdf(model="auto")`` from that one image and relights it under ennis; the reference is
Mitsuba's render under ennis.  Error: relative RMS over the sphere pixels at least 2 px inside the
limb (:mod:`mitsuba_scene`).  Mitsuba's own noise in the references is ~0.6% per pixel (1024 spp).

Measured (48 px): diffuse 0.54% (auto -> microfacet), roughplastic 1.96% (auto -> dielectric; 3.3%
with microfacet before the physically based families), gold 0.82% (auto -> conductor).
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

import mitsuba_scene as ms

pytestmark = pytest.mark.timeout(600)

FIT_PROBE, RELIGHT_PROBE = "grace", "ennis"
SIZE = ms.SIZE
SPP_RELIGHT = 1024
THRESHOLD = 0.03


@functools.lru_cache(maxsize=4)
def _fit(material: str):
    from brdfrig.fit.fitter import fit_brdf
    from brdfrig.lighting import environment_from_latlong, scene_from_image

    image = ms.render(material, FIT_PROBE, size=SIZE, spp=ms.SPP_FIT)
    env = environment_from_latlong(ms.probe_latlong(FIT_PROBE), name=FIT_PROBE)
    scene = scene_from_image(env, image, (SIZE / 2, SIZE / 2, SIZE / 2), margin_px=ms.LIMB_MARGIN_PX)
    return fit_brdf([scene], model="auto", progress=False, seed=0)


def relight_error(material: str) -> tuple[float, str]:
    """Relative RMS error of brdfrig's relighting under :data:`RELIGHT_PROBE`, and the model ``auto`` chose."""
    from brdfrig.lighting import environment_from_latlong

    result = _fit(material)
    rows, cols, normals = ms.sphere_interior(SIZE)
    env = environment_from_latlong(ms.probe_latlong(RELIGHT_PROBE), name=RELIGHT_PROBE)
    pred = np.asarray(result.brdf.predict(env, normals), dtype=np.float64)
    ref = ms.render(material, RELIGHT_PROBE, size=SIZE, spp=SPP_RELIGHT)[rows, cols]
    assert np.all(np.isfinite(pred)) and np.all(pred >= 0), "relit radiance must be finite and non-negative"
    return ms.relative_rms(pred, ref), result.report.chosen_model


@pytest.mark.parametrize("material", ["diffuse", "roughplastic", "gold"])
def test_mitsuba_material_relights_within_3_percent(material):
    ms.require_mitsuba_and_probes()
    err, model = relight_error(material)
    assert err <= THRESHOLD, f"{material}: fit under {FIT_PROBE}, relit under {RELIGHT_PROBE}: {err:.2%} (auto chose {model})"


@pytest.mark.parametrize("material", ["diffuse", "roughplastic", "gold"])
def test_pixel_noise_of_a_mitsuba_render(material):
    """The fit's pixel-noise estimate against Mitsuba's own noise: the RMS difference of two renders with
    different seeds (512 spp), over sqrt(2), relative to the RMS radiance (measured 0.9-1.3%; the estimate
    1.1-1.8%, the glossy ones above it): within a factor 2."""
    ms.require_mitsuba_and_probes()
    rows, cols, _ = ms.sphere_interior(SIZE)
    a = ms.render(material, FIT_PROBE, size=SIZE, spp=ms.SPP_FIT)[rows, cols]
    b = ms.render(material, FIT_PROBE, size=SIZE, spp=ms.SPP_FIT, seed=7)[rows, cols]
    true = np.sqrt(np.mean((a - b) ** 2) / 2 / np.mean(((a + b) / 2) ** 2))
    nu = _fit(material).report.pixel_noise
    print(f"{material}: Mitsuba's noise {true:.4f}, estimated {nu:.4f}")
    assert 0.5 * true <= nu <= 2.0 * true
