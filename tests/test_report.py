"""The HTML report of a fit, opened in a real browser (headless Chromium): it renders, shows its images and text."""

from __future__ import annotations

import base64
import re
import subprocess
import sys

import numpy as np
import pytest

from brdfrig.fit.analytic import GGX
from brdfrig.fit.groundtruth import render_groundtruth
from brdfrig.hdr.exr import write_exr
from brdfrig.hdr.sphere import sphere_pixels
from brdfrig.lighting import standard_lightings


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    """``brdfrig fit --report`` of a glossy sphere rendered under the studio lighting."""
    d = tmp_path_factory.mktemp("report")
    env = standard_lightings(height=32)["studio"]
    write_exr(d / "env.exr", env.latlong.image.astype(np.float32), latlong=True)
    n = 48
    px = sphere_pixels((n, n), (n / 2, n / 2, n / 2), margin_px=0.0)
    img = np.zeros((n, n, 3), np.float32)
    truth = GGX(alpha=np.array([0.25]), f0=np.array([0.04]), diffuse=np.array([0.6]))
    img[px.rows, px.cols] = render_groundtruth(truth, px.normals, env)
    write_exr(d / "sphere.exr", img)
    r = subprocess.run([sys.executable, "-m", "brdfrig", "fit", "--scene", str(d / "env.exr"), str(d / "sphere.exr"),
                        "--circle", f"{n / 2},{n / 2},{n / 2}", "--model", "microfacet", "--lmax", "4",
                        "--no-progress", "--report", str(d / "report.html"), "-o", str(d / "fit.brdf.json")],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    return d / "report.html"


def test_the_report_is_one_self_contained_file(report):
    text = report.read_text()
    assert "src=\"http" not in text and "<link" not in text and "<script" not in text
    images = re.findall(r'src="data:image/png;base64,([^"]+)"', text)
    assert len(images) >= 5  # fitted scenes, three relit spheres, BRDF plots
    assert all(base64.b64decode(b)[:8] == b"\x89PNG\r\n\x1a\n" for b in images)
    for words in ("estimated relighting error", "Relit under the standard lightings", "What the lighting determines",
                  "overcast", "studio", "sunset", "microfacet"):
        assert words in text


def test_the_report_renders_in_chromium(report, browser):
    pixels, dom = browser(report)
    assert pixels.shape[:2] == (1400, 1200)
    ink = np.mean(np.any(pixels < 0.9, axis=-1))  # not a blank page: headings, spheres and plots take room
    assert ink > 0.05, ink
    colourful = np.mean(np.ptp(pixels, axis=-1) > 0.15)  # the relit spheres and plot lines are in colour
    assert colourful > 0.005, colourful
    assert "estimated relighting error under other lighting" in dom and dom.count("<img") >= 5
