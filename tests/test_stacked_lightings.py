"""Lightings stacked side by side in one environment's channels (brdfrig.fit.scene.stack_lightings).

Oracle: the render under each lighting alone.  Each lighting's channels of the stacked render must equal it to the
last bit (the BRDF value at a sample is shared by the lightings; each channel's sum is the same sum, in the same
order).  A measured table's stacked render is also checked against the table looked up in numpy
(:func:`brdfrig.fit.groundtruth.render_rho`), to 1e-9.  Lightings on other samples (a map turned by a fraction of a
cell) must not stack; a map turned by whole cells keeps its samples, and renders as the turned samples do (the
environment built by hand from the turned directions), to 1e-9.
"""

from __future__ import annotations

import numpy as np
import pytest

from brdfrig.evaluate.cache import CachedGroundTruth
from brdfrig.fit.analytic import GGX
from brdfrig.fit.bivariate import BivariateBRDF, predict_tables
from brdfrig.fit.groundtruth import render_groundtruth, render_rho
from brdfrig.fit.microfacet import MicrofacetBRDF
from brdfrig.fit.pbr import ConductorBRDF, DielectricBRDF, SheenBRDF
from brdfrig.fit.relight import other_lightings, predict_under
from brdfrig.fit.rotation import axis_rotation
from brdfrig.fit.scene import Environment, LatLongMap, group_by_samples, same_samples, stack_lightings
from brdfrig.hdr.sphere import sphere_pixels
from brdfrig.lighting import environment_from_latlong


def _lighting(seed: int, rows: int = 16):
    """A seeded lat-long map, 2 rows x 4 rows, 3 channels, with one bright cell (a sharp source)."""
    rng = np.random.default_rng(seed)
    image = rng.uniform(0.0, 1.0, (rows, 2 * rows, 3))
    image[rows // 3, (5 * seed) % (2 * rows)] = 200.0
    return environment_from_latlong(image)


def _normals(size: int = 20) -> np.ndarray:
    px = sphere_pixels((size, size), (size / 2, size / 2, size / 2))
    return np.ascontiguousarray(px.normals[px.weights > 0])


def _brdfs():
    ggx = GGX(alpha=0.2, f0=0.04, diffuse=(0.5, 0.3, 0.2))
    return {
        "dielectric": DielectricBRDF([0.6, 0.3, 0.1], specular_roughness=0.3),  # the sharp-lobe rule at 32 x 16
        "conductor": ConductorBRDF([0.9, 0.6, 0.3], specular_roughness=0.5),
        "sheen": SheenBRDF([0.2, 0.4, 0.6], fuzz_color=[0.6, 0.2, 0.1], fuzz_roughness=0.7, specular_roughness=0.4),
        "ggx": ggx,  # cell centres
        "microfacet": MicrofacetBRDF(ggx),
        "microfacet, roughness per channel": MicrofacetBRDF(GGX(alpha=(0.2, 0.35, 0.5), f0=0.04, diffuse=(0.5, 0.3, 0.2))),
        "ggx, one row for every channel": GGX(alpha=0.3, f0=0.04, diffuse=0.4),
    }


@pytest.mark.parametrize("name", list(_brdfs()))
def test_stacked_render_is_each_lightings_render(name):
    brdf, normals = _brdfs()[name], _normals()
    envs = [_lighting(1), _lighting(2), _lighting(3)]
    stacked = brdf.predict(stack_lightings(envs), normals)
    assert stacked.shape == (len(normals), 9) and brdf.stacks_lightings
    for k, env in enumerate(envs):
        alone = brdf.predict(env, normals)
        assert np.all(alone > 0)
        np.testing.assert_array_equal(stacked[:, 3 * k:3 * k + 3], alone)


def test_stacked_render_of_a_measured_table():
    from brdfrig.fit.measured import tabulate

    table = tabulate(SheenBRDF([0.2, 0.4, 0.6], fuzz_color=[0.6, 0.2, 0.1], fuzz_roughness=0.7, specular_roughness=0.3))
    normals = _normals(12)
    envs = [_lighting(4), _lighting(5)]
    stacked = table.predict(stack_lightings(envs), normals)
    in_numpy = render_rho(table, normals, stack_lightings(envs))  # the table looked up in numpy, not in the kernel
    for k, env in enumerate(envs):
        alone = table.predict(env, normals)
        np.testing.assert_array_equal(stacked[:, 3 * k:3 * k + 3], alone)
        np.testing.assert_allclose(in_numpy[:, 3 * k:3 * k + 3], alone, rtol=1e-9, atol=0)


def test_lightings_on_other_samples_do_not_stack():
    a, b = _lighting(1), _lighting(2)
    turned = b.rotated(axis_rotation("x", 30.0))
    assert same_samples(a, b) and not same_samples(a, turned)
    assert not same_samples(a, _lighting(1, rows=8))
    assert group_by_samples([a, turned, b, turned]) == [[0, 2], [1, 3]]
    with pytest.raises(ValueError, match="same samples"):
        stack_lightings([a, turned])
    # a one-lighting environment of six channels is not two lightings: a three-channel BRDF is refused
    six = stack_lightings([a, b])
    lone = type(six)(six.dirs, six.radiance, six.solid_angle, six.latlong)
    with pytest.raises(ValueError, match="3 channels but the environment has 6"):
        DielectricBRDF([0.6, 0.3, 0.1]).predict(lone, _normals(8))


class _Counted:
    """A BRDF whose renders are counted by the number of lightings they were asked under."""

    def __init__(self, brdf, calls: list):
        self.brdf, self.calls = brdf, calls
        self.stacks_lightings = brdf.stacks_lightings

    def predict(self, env, normals):
        self.calls.append(env.lightings)
        return self.brdf.predict(env, normals)


def test_predict_under_stacks_the_lightings_that_share_samples():
    normals = _normals(16)
    envs = [_lighting(1), _lighting(2).rotated(axis_rotation("y", 40.0)), _lighting(3)]
    calls: list[int] = []
    brdf = _brdfs()["dielectric"]
    preds = predict_under({"d": _Counted(brdf, calls)}, envs, normals)["d"]
    assert sorted(calls) == [1, 2]
    for k, env in enumerate(envs):
        np.testing.assert_array_equal(preds[k], brdf.predict(env, normals))


def test_cache_renders_missing_lightings_stacked(tmp_path):
    brdf, normals = GGX(alpha=0.3, f0=0.04, diffuse=(0.6, 0.4, 0.2)), _normals(12)
    envs = [_lighting(1), _lighting(2).rotated(axis_rotation("y", 40.0)), _lighting(3)]
    calls: list[int] = []

    def render(b, n, env):
        calls.append(env.lightings)
        return render_groundtruth(b, n, env)

    cache = CachedGroundTruth(tmp_path / "gt", render=render)
    images = cache.renders(brdf, normals, envs)
    assert sorted(calls) == [1, 2] and (cache.misses, cache.hits) == (3, 0)
    assert len(list((tmp_path / "gt").glob("gt-*.npy"))) == 3
    for image, env in zip(images, envs):
        np.testing.assert_array_equal(image, render_groundtruth(brdf, normals, env))
    np.testing.assert_array_equal(cache(brdf, normals, envs[2]), images[2])  # each lighting is its own entry
    cache.renders(brdf, normals, envs)
    assert len(calls) == 2 and (cache.misses, cache.hits) == (3, 4)


def _tables():
    """Two seeded tables on different grids."""
    rng = np.random.default_rng(7)
    return [BivariateBRDF(rng.uniform(0, 1, (3, 6, 4)), rng.uniform(0, 1, (3, 6, 4))),
            BivariateBRDF(rng.uniform(0, 1, (3, 9, 5)), rng.uniform(0, 1, (3, 9, 5)))]


def _turned_samples(env, rotation):
    """``env`` turned by moving its samples (and its map's frame): the oracle of a turn by whole cells."""
    return Environment(env.dirs @ rotation.T, env.radiance, env.solid_angle,
                       LatLongMap(env.latlong.image, rotation @ env.latlong.rotation))


@pytest.mark.parametrize("axis, degrees", [("y", 45.0), ("y", 90.0), ("y", -180.0), ("x", 180.0), ("z", 180.0)])
def test_a_turn_by_whole_cells_keeps_the_samples(axis, degrees):
    env, normals, rotation = _lighting(1), _normals(16), axis_rotation(axis, degrees)  # 32 columns: 45 degrees is 4
    turned = env.rotated(rotation)
    assert same_samples(env, turned) and not np.array_equal(turned.radiance, env.radiance)
    bright = np.argmax(env.radiance[:, 0])  # the bright cell's light now arrives from its turned direction
    np.testing.assert_allclose(turned.dirs[np.argmax(turned.radiance[:, 0])], rotation @ env.dirs[bright], atol=1e-12)
    oracle = _turned_samples(env, rotation)
    for brdf in (_brdfs()["dielectric"], _tables()[0]):
        np.testing.assert_allclose(brdf.predict(turned, normals), brdf.predict(oracle, normals), rtol=1e-9, atol=0)


@pytest.mark.parametrize("axis, degrees", [("y", 40.0), ("y", 360 / 64), ("x", 90.0), ("z", 90.0)])
def test_other_turns_move_the_samples(axis, degrees):
    env, rotation = _lighting(1), axis_rotation(axis, degrees)
    turned = env.rotated(rotation)
    assert not same_samples(env, turned)
    np.testing.assert_array_equal(turned.dirs, env.dirs @ rotation.T)


def test_the_estimates_turns_about_the_vertical_share_samples():
    assert group_by_samples(other_lightings(_lighting(1))) == [[0, 1, 2], [3], [4]]


def test_tables_render_stacked_lightings_in_one_pass():
    tables, normals = _tables(), _normals(14)
    envs = [_lighting(1), _lighting(2), _lighting(3)]
    alone = [predict_tables(tables, env, normals) for env in envs]
    for sight in range(3):  # a pass (the same sums: to the last bit), then the design built and kept (to rounding)
        stacked = predict_tables(tables, stack_lightings(envs), normals)
        for t in range(len(tables)):
            assert stacked[t].shape == (len(normals), 9)
            for k in range(len(envs)):
                np.testing.assert_allclose(stacked[t][:, 3 * k:3 * k + 3], alone[k][t], rtol=1e-12 if sight else 0, atol=0)
    with pytest.raises(ValueError, match="3 channels but the environment has 6"):
        predict_tables(tables, Environment(envs[0].dirs, np.hstack([envs[0].radiance] * 2), envs[0].solid_angle), normals)


def test_predict_under_renders_tables_stacked(monkeypatch):
    from brdfrig.fit import bivariate
    from brdfrig.fit.memo import RenderMemo

    tables, normals = _tables(), _normals(12)
    envs = [_lighting(2), _lighting(2).rotated(axis_rotation("x", 90.0)), _lighting(4)]
    channels: list[int] = []  # of each pass over the quadrature
    kernel = bivariate._render_kernel
    monkeypatch.setattr(bivariate, "_DESIGNS", RenderMemo(bivariate.DESIGN_CACHE_BYTES, second_sight=True))
    monkeypatch.setattr(bivariate, "_render_kernel", lambda n, q, *rest: channels.append(q.wrad.shape[1]) or kernel(n, q, *rest))
    preds = predict_under({"a": tables[0], "b": tables[1]}, envs, normals)
    assert channels == [6, 3]
    for k, env in enumerate(envs):  # the turned lighting's second sight is predicted from its design: to rounding
        alone = predict_tables(tables, env, normals)
        np.testing.assert_allclose(preds["a"][k], alone[0], rtol=1e-12, atol=0)
        np.testing.assert_allclose(preds["b"][k], alone[1], rtol=1e-12, atol=0)
