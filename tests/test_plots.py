"""BRDF plots: the numbers drawn (slices, directional albedo) against closed forms and brute-force quadrature."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest

from brdfrig.fit.analytic import GGX, Lambertian
from brdfrig.report.plots import directional_albedo, incidence_slices, theta_h_slices


def _brute_albedo(brdf, theta_i_deg: float, n: int = 1500) -> np.ndarray:
    """Midpoint rule on a fine (theta_o, phi) grid: the oracle for the directional albedo."""
    to = (np.arange(n) + 0.5) * (math.pi / 2 / n)
    ph = (np.arange(2 * n) + 0.5) * (math.pi / n)
    rho = brdf.evaluate(math.radians(theta_i_deg), to[:, None], ph[None, :])
    w = (np.cos(to) * np.sin(to))[:, None, None] * (math.pi / 2 / n) * (math.pi / n)
    return np.sum(rho * w, axis=(0, 1))


def test_lambertian_albedo_is_its_albedo():
    _, a = directional_albedo(Lambertian(np.array([0.2, 0.5, 0.9])))
    np.testing.assert_allclose(a, np.broadcast_to([0.2, 0.5, 0.9], a.shape), rtol=2e-3)


@pytest.mark.parametrize("alpha", [0.05, 0.3])
def test_glossy_albedo_matches_brute_force(alpha):
    ggx = GGX(alpha=np.array([alpha]), f0=np.array([0.9]), diffuse=np.array([0.1]))
    theta, a = directional_albedo(ggx, n_theta=4)
    for t, value in zip(theta[:3], a[:3, 0]):  # 0, 29.7, 59.3 deg
        assert value == pytest.approx(float(_brute_albedo(ggx, t)[0]), rel=0.01)


def test_slices_put_the_lobe_where_it_belongs():
    ggx = GGX(alpha=np.array([0.1]), f0=np.array([0.9]), diffuse=np.array([0.0]))
    t, rho = incidence_slices(ggx, theta_i_deg=(40.0,))
    assert abs(t[np.argmax(rho[0, :, 0])] - 40.0) <= 1.0  # peak at the mirror angle, specular side
    th, rh = theta_h_slices(Lambertian(np.array([0.5])), theta_d_deg=(30.0,))
    # at phi_d = pi/2 both directions stay above the horizon for every theta_h < 90 deg
    np.testing.assert_allclose(rh[0, :, 0], 0.5 / math.pi, rtol=1e-12)


def test_plot_command_writes_a_png(tmp_path):
    from brdfrig.fit.brdffile import save_brdf

    a, b = tmp_path / "a.brdf.json", tmp_path / "b.brdf.json"
    save_brdf(a, Lambertian(np.array([0.5])))
    save_brdf(b, GGX(alpha=np.array([0.2]), f0=np.array([0.5]), diffuse=np.array([0.2])))
    out = tmp_path / "cmp.png"
    r = subprocess.run([sys.executable, "-m", "brdfrig", "plot", str(a), str(b), "-o", str(out)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    r = subprocess.run([sys.executable, "-m", "brdfrig", "plot", str(a), "-o", str(a)], capture_output=True, text=True)
    assert r.returncode == 2 and "a.brdf.json" in r.stderr
