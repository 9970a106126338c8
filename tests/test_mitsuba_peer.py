"""The Mitsuba peer (``brdfrig.evaluate.mitsuba_peer``): its inputs, and that it recovers a principled material.

Oracle: a sphere Mitsuba rendered with known ``principled`` parameters; the peer, started from
its defaults, must find parameters that relight under another probe like the truth does.
"""

from __future__ import annotations

import numpy as np
import pytest

import mitsuba_scene as ms

pytestmark = pytest.mark.timeout(300)

TRUTH = {"base_color": [0.7, 0.3, 0.2], "roughness": 0.35, "metallic": 0.0, "specular": 0.5, "sheen": 0.0, "clearcoat": 0.0}
SIZE = 32


def test_principled_bsdf_checks_its_parameters():
    from brdfrig.errors import InputError
    from brdfrig.evaluate.mitsuba_peer import principled_bsdf

    bsdf = principled_bsdf({"roughness": 0.2, "base_color": [0.1, 0.2, 0.3]})
    assert bsdf["type"] == "principled" and bsdf["roughness"] == 0.2
    assert bsdf["base_color"]["value"] == [0.1, 0.2, 0.3] and bsdf["metallic"] == 0.0
    with pytest.raises(InputError, match="unknown principled parameter"):
        principled_bsdf({"roughnes": 0.2})
    with pytest.raises(InputError, match="metallic must be in"):
        principled_bsdf({"metallic": 1.5})
    with pytest.raises(InputError, match="base_color"):
        principled_bsdf({"base_color": [0.5, float("nan"), 0.5]})


def test_fit_principled_rejects_bad_images():
    from brdfrig.errors import InputError
    from brdfrig.evaluate.mitsuba_peer import fit_principled

    lat = np.ones((8, 16, 3))
    with pytest.raises(InputError, match="square"):
        fit_principled(np.ones((16, 24, 3)), lat)
    with pytest.raises(InputError, match="black"):
        fit_principled(np.zeros((16, 16, 3)), lat)
    with pytest.raises(InputError, match="latlong_fit"):
        fit_principled(np.ones((16, 16, 3)), np.full((8, 16, 3), np.nan))
    with pytest.raises(InputError, match="method"):
        fit_principled(np.ones((16, 16, 3)), lat, method="newton")


def test_peer_recovers_a_principled_sphere():
    """Fit under grace, relight under ennis (64x32, 32 px): within 3% of the truth's render.

    Measured (64 px, 60 iterations x 16 spp, ``l2`` loss): base colour within 0.015, roughness 0.348
    for 0.35, relighting 1.7-1.9% (Mitsuba noise of both renders included).  The default ``log`` loss
    relights this sphere at 3.6% (32 px, 120 iterations): the log of a noisy render is biased.
    """
    ms.require_ad_variant()
    from brdfrig.evaluate.mitsuba_peer import fit_principled, render_principled

    grace, ennis = ms.probe_latlong("grace"), ms.probe_latlong("ennis")
    image = render_principled(TRUTH, grace, SIZE, spp=512)
    params, seconds = fit_principled(image, grace, spp=16, iterations=60, seed=1, loss="l2")
    assert seconds > 0
    assert np.allclose(params["base_color"], TRUTH["base_color"], atol=0.05), params
    assert abs(params["roughness"] - TRUTH["roughness"]) < 0.06, params
    rows, cols, _ = ms.sphere_interior(SIZE)
    ref = render_principled(TRUTH, ennis, SIZE, spp=1024)[rows, cols]
    relit = render_principled(params, ennis, SIZE, spp=1024)[rows, cols]
    err = ms.relative_rms(relit, ref)
    assert err < 0.03, f"peer relighting {err:.2%}"
    # The comparison can fail: the starting point relights far off.
    start = render_principled({}, ennis, SIZE, spp=256)[rows, cols]
    assert ms.relative_rms(start, ref) > 5 * max(err, 0.01)
