"""Sharp-lobe quadrature over lat-long maps (fit/quadrature.py): solid angles, directions, convergence."""

from __future__ import annotations

import math

import numba
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from brdfrig.fit.quadrature import lobe_quadrature, lobe_samples, quadrature_samples
from brdfrig.fit.scene import Environment
from brdfrig.hdr.envmap import latlong_directions, latlong_pixels
from brdfrig.lighting import environment_from_latlong


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def _mirror(n: np.ndarray) -> np.ndarray:
    return 2 * n[2] * n - np.array([0.0, 0.0, 1.0])


NORMALS = [_unit([0.0, 0.0, 1.0]), _unit([0.3, -0.5, 0.8]), _unit([0.0, 1.0, 1.0]), _unit([-0.9, 0.1, 0.3])]


@pytest.mark.parametrize("normal", NORMALS)
def test_solid_angles_sum_to_four_pi_and_radiance_is_conserved(normal):
    rng = np.random.default_rng(0)
    image = rng.uniform(0.0, 2.0, (16, 32, 2))
    rot = Rotation.from_euler("y", 40, degrees=True).as_matrix()
    _, omega = latlong_directions(16, 32)
    exact = np.einsum("hwc,hw->c", image, omega)
    for env in (environment_from_latlong(image), environment_from_latlong(image, rot)):
        for cone, s in [(180.0, 5), (30.0, 7), ((10.0, 40.0), (9, 3))]:
            ones = Environment(env.dirs, np.ones((len(env.dirs), 1)), env.solid_angle, type(env.latlong)(np.ones((16, 32, 1)), env.latlong.rotation))
            _, w1 = quadrature_samples(lobe_quadrature(ones, cone, s), normal, horizon=False)
            assert w1.sum() == pytest.approx(4 * math.pi, rel=1e-13)
            dirs, wrad = quadrature_samples(lobe_quadrature(env, cone, s), normal, horizon=False)
            np.testing.assert_allclose(wrad.sum(axis=0), exact, rtol=1e-13)
            np.testing.assert_allclose(np.linalg.norm(dirs, axis=1), 1.0, rtol=1e-14)


def test_cell_centres_at_s1_and_sub_cells_inside_their_cell():
    image = np.random.default_rng(1).uniform(0.5, 1.5, (32, 64, 3))
    centres, omega = latlong_directions(32, 64)
    rot = Rotation.from_euler("y", 75, degrees=True).as_matrix()
    for r, env in ((np.eye(3), environment_from_latlong(image)), (rot, environment_from_latlong(image, rot))):
        dirs, wrad = quadrature_samples(lobe_quadrature(env, 20.0, 1), NORMALS[1], horizon=False)
        np.testing.assert_array_equal(dirs, centres.reshape(-1, 3) @ r.T)
        np.testing.assert_array_equal(wrad, image.reshape(-1, 3) * omega.reshape(-1, 1))
        dirs, wrad = quadrature_samples(lobe_quadrature(env, 20.0, 6), NORMALS[1], horizon=False)
        x, y = latlong_pixels(dirs @ r, 32, 64)  # back to the map frame
        row, col = np.floor(y).astype(int), np.floor(x).astype(int) % 64
        frac = wrad / image[row, col]  # each sample carries its own cell's radiance
        np.testing.assert_allclose(frac, frac[:, :1].repeat(3, axis=1), rtol=1e-12)
        split = frac[:, 0] < omega[row, col] * (1 - 1e-9)
        near = np.degrees(np.arccos(np.clip((centres[row, col] @ r.T) @ _mirror(NORMALS[1]), -1, 1)))
        assert split.sum() > 100 and np.all(near[split] <= 20.0 + 1e-9) and np.all(near[~split] > 20.0 - 1e-9)


def test_horizon_leaves_out_samples_behind_the_normal():
    env = environment_from_latlong(np.ones((32, 64)))
    for n in NORMALS:
        dirs, wrad = quadrature_samples(lobe_quadrature(env, 20.0, 8), n)
        assert np.all(dirs @ n > 0)
        assert wrad.sum() == pytest.approx(2 * math.pi, rel=0.02)  # half the sphere, to the cells' resolution


@pytest.mark.parametrize("normal", [NORMALS[1], NORMALS[2]])  # a generic mirror direction, and one at the +y pole
def test_narrow_normalised_lobe_converges_in_s(normal):
    # von Mises-Fisher lobe about r, sigma = 0.4 deg (a seventh of a 64x32 cell): integral over the sphere = 1.
    r = _mirror(normal)
    kappa = 1.0 / math.radians(0.4) ** 2
    lobe = lambda w: kappa / (2 * math.pi * -math.expm1(-2 * kappa)) * np.exp(kappa * (w @ r - 1.0))
    env = environment_from_latlong(np.ones((32, 64)))
    err = {}
    for s in (1, 4, 8, 16, 32):
        dirs, wrad = quadrature_samples(lobe_quadrature(env, 10.0, s), normal, horizon=False)
        err[s] = abs(float(wrad[:, 0] @ lobe(dirs)) - 1.0)
    assert err[1] > 0.5  # cell centres miss or overweight the lobe
    if r[1] < 0.99:  # measured: 1.5e-3, 1.6e-6, 3.9e-7 (second order, with sub-cells 0.7, 0.35, 0.18 deg)
        assert err[8] < 5e-3 and err[16] < 5e-6 and err[32] < 1e-6 and 3.5 < err[16] / err[32] < 4.5
    else:  # the lobe on the pole, sampled in rings of latitude: measured 0.19, 0.035, 0.0082
        assert err[8] < 0.3 and err[16] < 0.05 and err[32] < 0.012 and 3.5 < err[16] / err[32] < 4.5


def test_point_samples_without_a_map():
    rng = np.random.default_rng(2)
    dirs = rng.normal(size=(50, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    omega = rng.uniform(0, 0.3, 50)
    omega[:5] = 0.0
    env = Environment(dirs, rng.uniform(size=(50, 2)), omega)
    got_d, got_w = quadrature_samples(lobe_quadrature(env, 20.0, 12), NORMALS[1], horizon=False)
    np.testing.assert_array_equal(got_d, dirs[5:])
    np.testing.assert_array_equal(got_w, env.radiance[5:] * omega[5:, None])


@numba.njit(parallel=True)
def _weighted_sums(q, normals):
    out = np.zeros((normals.shape[0], q.wrad.shape[1]))
    for i in numba.prange(normals.shape[0]):
        dirs, wrad = lobe_samples(q, normals[i, 0], normals[i, 1], normals[i, 2], True)
        for k in range(dirs.shape[0]):
            cos_i = normals[i, 0] * dirs[k, 0] + normals[i, 1] * dirs[k, 1] + normals[i, 2] * dirs[k, 2]
            for c in range(wrad.shape[1]):
                out[i, c] += wrad[k, c] * cos_i
    return out


def test_usable_inside_a_prange_kernel():
    env = environment_from_latlong(np.random.default_rng(3).uniform(size=(16, 32, 2)))
    q = lobe_quadrature(env, (5.0, 20.0), (12, 4))
    normals = np.array(NORMALS)
    got = _weighted_sums(q, normals)
    for i, n in enumerate(normals):
        dirs, wrad = quadrature_samples(q, n)
        np.testing.assert_allclose(got[i], wrad.T @ (dirs @ n), rtol=1e-12)


def test_bad_parameters():
    env = environment_from_latlong(np.ones((8, 16)))
    for cone, s, msg in [(-1.0, 4, "cone_deg"), (200.0, 4, "cone_deg"), (20.0, 0, "subdiv"), (20.0, 2.5, "subdiv"), ((5.0, 10.0), 4, "one length")]:
        with pytest.raises(ValueError, match=msg):
            lobe_quadrature(env, cone, s)


def _merged_and_cells(image, rot, tiers=(0.0, 1), merge=30.0):
    env = environment_from_latlong(image, rot)
    return env, lobe_quadrature(env, *tiers, merge_deg=merge), lobe_quadrature(env, *tiers)


@pytest.mark.parametrize("tiers", [(0.0, 1), ((5.0, 20.0), (12, 4))])
@pytest.mark.parametrize("normal", NORMALS)
def test_merged_blocks_keep_every_channels_cosine_weighted_power(normal, tiers):
    """Sum of wrad (n.w) over the samples: the same with 2 x 2 blocks merged as over the cells, per channel."""
    image = np.random.default_rng(4).uniform(0.0, 2.0, (32, 64, 3)) ** 3  # strong contrast within blocks
    rot = Rotation.from_euler("xy", (25, 40), degrees=True).as_matrix()
    env, merged, cells = _merged_and_cells(image, rot, tiers)
    d1, w1 = quadrature_samples(merged, normal)
    d0, w0 = quadrature_samples(cells, normal)
    np.testing.assert_allclose(w1.T @ (d1 @ normal), w0.T @ (d0 @ normal), rtol=1e-12)
    assert np.all(d1 @ normal > 0) and len(d1) < 0.85 * len(d0)
    np.testing.assert_allclose(np.linalg.norm(d1, axis=1), 1.0, rtol=1e-14)


@pytest.mark.parametrize("normal", NORMALS)
def test_merged_blocks_leave_the_samples_within_the_cone_alone(normal):
    image = np.random.default_rng(5).uniform(0.0, 1.0, (32, 64, 2))
    rot = Rotation.from_euler("z", 70, degrees=True).as_matrix()
    _, merged, cells = _merged_and_cells(image, rot, (10.0, 6), merge=25.0)
    r = _mirror(normal)
    inside = []
    for q in (merged, cells):
        d, w = quadrature_samples(q, normal)
        near = d @ r >= math.cos(math.radians(25.0))
        order = np.lexsort(d[near].T)
        inside.append((d[near][order], w[near][order]))
    np.testing.assert_array_equal(inside[0][0], inside[1][0])
    np.testing.assert_array_equal(inside[0][1], inside[1][1])
    d, _ = quadrature_samples(merged, normal, horizon=False)  # blocks merge only above the horizon
    np.testing.assert_array_equal(d, quadrature_samples(cells, normal, horizon=False)[0])


def test_merged_render_of_a_lambertian_is_the_cell_centre_render_and_of_a_rough_lobe_within_a_tenth_percent():
    """Against :func:`render_groundtruth` (its own kernel, every cell centre): exact where the BRDF is constant over
    a block; the rough conductor changes across a block (MERGE_CONE_DEG's study: 0.09% at roughness 0.5)."""
    from brdfrig.fit.analytic import Lambertian
    from brdfrig.fit.groundtruth import render_groundtruth, render_sharp
    from brdfrig.fit.pbr import ConductorBRDF

    rng = np.random.default_rng(6)
    image = rng.uniform(0.0, 1.0, (64, 128, 3)) ** 4  # blocks of 5.6 degrees, as on the benchmark's maps
    image[8:14, 20:28] += 40.0  # a window: most of the light from a few blocks
    env = environment_from_latlong(image, Rotation.from_euler("x", 20, degrees=True).as_matrix())
    normals = np.array([_unit(v) for v in rng.normal(size=(300, 3)) * [1, 1, 0.1] + [0, 0, 0.3]])
    lamb = Lambertian(albedo=[0.2, 0.5, 0.8])
    np.testing.assert_allclose(render_sharp(lamb, normals, env, 0.0, 1, 30.0), render_groundtruth(lamb, normals, env), rtol=1e-12)
    metal = ConductorBRDF(base_color=[0.9, 0.6, 0.3], specular_roughness=0.7)
    got, ref = render_sharp(metal, normals, env, 0.0, 1, 30.0), render_groundtruth(metal, normals, env)
    err = np.sqrt(np.sum((got - ref) ** 2) / np.sum(ref**2))
    assert 1e-6 < err < 1e-3


def test_merging_needs_an_even_lat_long_map_and_a_cone_over_the_subdivided_ones():
    from brdfrig.fit.quadrature import MERGE_CONE_DEG, MERGE_MIN_ROWS, merge_cone

    env = environment_from_latlong(np.ones((8, 16)))
    assert merge_cone(environment_from_latlong(np.ones((MERGE_MIN_ROWS, 2 * MERGE_MIN_ROWS)))) == MERGE_CONE_DEG
    assert merge_cone(env) is None  # blocks wider than studied
    for bad, msg in [(environment_from_latlong(np.ones((9, 18))), "even height and width"),
                     (environment_from_latlong(np.ones((MERGE_MIN_ROWS + 1, 2 * MERGE_MIN_ROWS + 2))), "even height"),
                     (Environment(env.dirs, env.radiance, env.solid_angle), "lat-long map")]:
        with pytest.raises(ValueError, match=msg):
            lobe_quadrature(bad, merge_deg=30.0)
        assert merge_cone(bad) is None
    with pytest.raises(ValueError, match=r"merge_deg \(10.0\) must be at least the widest subdivided cone \(15"):
        lobe_quadrature(env, merge_deg=10.0)
    with pytest.raises(ValueError, match="merge_deg must be within"):
        lobe_quadrature(env, merge_deg=-1.0)
