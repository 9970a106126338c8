"""brdfrig.orientation: a mirrored or turned lat-long map is recognised against the sphere image taken under it."""

from __future__ import annotations

import numpy as np
import pytest

from brdfrig.fit.analytic import GGX, Lambertian
from brdfrig.fit.groundtruth import render_groundtruth
from brdfrig.fit.scene import Scene
from brdfrig.hdr.sphere import sphere_pixels
from brdfrig.lighting import environment_from_latlong, read_latlong
from brdfrig.orientation import AS_GIVEN, VARIANTS, check_orientation


@pytest.mark.parametrize("brdf", [Lambertian(albedo=[0.7, 0.6, 0.5]), GGX(alpha=0.3, f0=0.04, diffuse=[0.3, 0.4, 0.5])],
                         ids=["lambertian", "ggx"])
def test_mistakes_are_named_and_the_right_map_is_not(real_probes, brdf):
    """Sphere rendered (independent quadrature renderer) under the true map; the fit is given a wrong one."""
    px = sphere_pixels((48, 48), (24, 24, 23))
    for path in real_probes:
        full = read_latlong(path).latlong.image
        true = environment_from_latlong(full.reshape(full.shape[0] // 2, 2, full.shape[1] // 2, 2, -1).mean(axis=(1, 3)))
        radiance = render_groundtruth(brdf, px.normals, true)
        image = true.latlong.image
        for given, undo in ((AS_GIVEN, None), ("mirrored left-right", "mirrored left-right"),
                            ("turned 90 deg", "turned 270 deg")):
            env = environment_from_latlong(VARIANTS[given](image))
            check = check_orientation(Scene(env, px.normals, radiance, px.weights))
            warning = check.warning(path.name)
            if undo is None:
                assert warning is None and check.best == AS_GIVEN, (path.name, check.residuals)
                assert check.residuals[AS_GIVEN] < 0.05  # the cheap lobe fit at lmax 4: 0.2-4.2% here
            else:
                assert check.best == undo, (path.name, given, check.residuals)
                assert warning is not None and warning.startswith(f"{path.name}: ") and undo in warning, warning
                # undoing the mistake fits as well as the true map did (same cells, reordered)
                assert check.residuals[undo] == pytest.approx(
                    check_orientation(Scene(true, px.normals, radiance, px.weights)).residuals[AS_GIVEN], rel=1e-6)


def test_no_lat_long_map_no_check():
    from brdfrig.fit.scene import Environment

    env = Environment(np.array([[0.0, 0.0, 1.0]]), np.ones((1, 3)), np.array([4 * np.pi]))
    assert check_orientation(Scene(env, np.array([[0.0, 0.0, 1.0]]), np.ones((1, 3)), np.ones(1))) is None


def test_brdfrig_fit_warns_about_a_mirrored_map(tmp_path, monkeypatch, capsys):
    """Through the command: a sphere rendered under a map, fitted with the mirrored map, gets a warning line."""
    import brdfrig.fit.fitter as fitter
    from brdfrig.cli.main import main
    from brdfrig.errors import InputError
    from brdfrig.fit.brdffile import save_brdf
    from brdfrig.fit.models import DiffuseBRDF
    from brdfrig.fit.system import ModelSpec
    from brdfrig.hdr.envmap import latlong_directions
    from brdfrig.hdr.exr import write_exr

    d, _ = latlong_directions(32, 64)
    sun = np.clip(d @ np.array([0.6, 0.5, 0.62]), 0, None)[..., None] ** 8  # off to one side: not mirror-symmetric
    env = ((0.2 + 0.3 * (d[..., 1:2] + 1) + 4 * sun) * [1.0, 0.85, 0.7]).astype(np.float32)
    write_exr(tmp_path / "env.exr", env, latlong=True)
    write_exr(tmp_path / "mirrored.exr", np.ascontiguousarray(env[:, ::-1]), latlong=True)
    save_brdf(tmp_path / "b.json", DiffuseBRDF(ModelSpec("diffuse", 2, 0), np.outer([1, 2 / 3, 0.25], [0.8, 0.6, 0.4])))
    assert main(["render", str(tmp_path / "b.json"), "--lighting", str(tmp_path / "env.exr"), "--size", "48",
                 "-o", str(tmp_path / "s.exr")]) == 0

    def stop(*args, **kwargs):  # the warning comes before the fit; the fit itself is not what is tested
        raise InputError("fit skipped")

    monkeypatch.setattr(fitter, "fit_brdf", stop)
    for lighting, warned in (("env.exr", False), ("mirrored.exr", True)):
        main(["fit", "--scene", str(tmp_path / lighting), str(tmp_path / "s.exr"), "--lmax", "2", "-o",
              str(tmp_path / "o.json")])
        err = capsys.readouterr().err
        assert ("brdfrig fit: warning: " in err and "mirrored left-right" in err and lighting in err) == warned, err
