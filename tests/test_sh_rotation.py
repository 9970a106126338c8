"""Real Wigner-D rotations (brdfrig.fit.rotation) checked against SH values, group laws and definitions."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from brdfrig.fit.rotation import axis_rotation, euler_zyz, local_lighting, normal_frames, rotate_coeffs, wigner_d_real
from brdfrig.fit.sh import sh_eval
from brdfrig.fit.shproject import reconstruct


def random_dirs(n: int, seed: int = 0) -> np.ndarray:
    d = np.random.default_rng(seed).normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def random_rotations(k: int, seed: int = 1) -> np.ndarray:
    return Rotation.random(k, random_state=seed).as_matrix()


def band(a: np.ndarray, l: int) -> np.ndarray:
    return a[..., l * l : (l + 1) ** 2]


LMAX_HIGH = 100


@pytest.fixture(scope="module")
def high_degree():
    r = random_rotations(3)
    return r, wigner_d_real(r, LMAX_HIGH)


def test_rotates_sh_values_to_l100(high_degree):
    r, d = high_degree
    w = random_dirs(40)
    y = sh_eval(w, LMAX_HIGH)
    err = 0.0
    for k in range(r.shape[0]):
        yr = sh_eval(w @ r[k].T, LMAX_HIGH)  # Y(R w)
        err = max(err, max(np.abs(band(yr, l) - band(y, l) @ d[l][k].T).max() for l in range(LMAX_HIGH + 1)))
    assert err <= 1e-10


def test_homomorphism_and_orthogonality_to_l100(high_degree):
    r, d = high_degree
    d12 = wigner_d_real(r[:1] @ r[1:2], LMAX_HIGH)
    comp = max(np.abs(d12[l][0] - d[l][0] @ d[l][1]).max() for l in range(LMAX_HIGH + 1))
    orth = max(np.abs(d[l][k] @ d[l][k].T - np.eye(2 * l + 1)).max() for l in range(LMAX_HIGH + 1) for k in range(3))
    assert comp <= 1e-10
    assert orth <= 1e-10


def test_identity_and_inverse():
    r = random_rotations(2, seed=7)
    d = wigner_d_real(np.concatenate([np.eye(3)[None], r[:1], r[:1].transpose(0, 2, 1)]), 12)
    for l in range(13):
        assert np.abs(d[l][0] - np.eye(2 * l + 1)).max() <= 1e-13
        assert np.abs(d[l][2] - d[l][1].T).max() <= 1e-13


@pytest.mark.parametrize("beta", [0.0, 1e-13, 1e-9, 1e-5, np.pi - 1e-9, np.pi])
def test_nearly_degenerate_euler_angles(beta):
    r = Rotation.from_euler("ZYZ", [0.7, beta, -2.1]).as_matrix()[None]
    w = random_dirs(30, seed=2)
    lmax = 40
    d = wigner_d_real(r, lmax)
    y, yr = sh_eval(w, lmax), sh_eval(w @ r[0].T, lmax)
    assert max(np.abs(band(yr, l) - band(y, l) @ d[l][0].T).max() for l in range(lmax + 1)) <= 1e-12


def test_euler_zyz_recomposes():
    r = random_rotations(50, seed=4)
    a, b, g = euler_zyz(r)
    back = Rotation.from_euler("ZYZ", np.stack([a, b, g], -1)).as_matrix()
    assert np.abs(back - r).max() <= 1e-13


def test_rotate_coeffs_is_the_rotated_function():
    lmax = 10
    rng = np.random.default_rng(3)
    c = rng.normal(size=((lmax + 1) ** 2, 2))
    r = random_rotations(5, seed=9)
    rc = rotate_coeffs(c, r)
    assert rc.shape == (5, c.shape[0], 2)
    w = random_dirs(64, seed=4)
    for k in range(5):  # coefficients of w -> f(R^T w)
        assert np.abs(reconstruct(rc[k], w) - reconstruct(c, w @ r[k])).max() <= 1e-12


@pytest.mark.parametrize("axis", ["x", "y", "z"])
@pytest.mark.parametrize("degrees", [0.0, 45.0, -45.0, 90.0, 137.0])
def test_axis_rotation_matches_scipy(axis, degrees):
    expected = Rotation.from_euler(axis, degrees, degrees=True).as_matrix()
    assert np.abs(axis_rotation(axis, degrees) - expected).max() < 1e-15


def test_axis_rotation_refuses_an_unknown_axis():
    with pytest.raises(ValueError, match="axis must be 'x', 'y' or 'z', got 'w'"):
        axis_rotation("w", 10.0)


def test_normal_frames():
    n = np.concatenate([random_dirs(20, seed=6), [[0, 0, 1.0], [0, 0, -1.0], [1.0, 0, 0]]])
    f = normal_frames(n)
    assert np.abs(f[:, :, 2] - n).max() <= 1e-15
    assert np.abs(f @ f.transpose(0, 2, 1) - np.eye(3)).max() <= 1e-14
    assert np.linalg.det(f).min() > 0.999999
    phi, theta = np.arctan2(n[:, 1], n[:, 0]), np.arccos(n[:, 2])
    ref = Rotation.from_euler("ZY", np.stack([phi, theta], -1)).as_matrix()  # intrinsic: Rz(phi) Ry(theta)
    assert np.abs(f - ref).max() <= 1e-14
    # the view in every local frame: theta_o' = theta_N, phi_o' = pi (MATH.md)
    vloc = np.einsum("nji,j->ni", f, [0, 0, 1.0])
    assert np.abs(vloc[:, 1]).max() <= 1e-15
    assert np.all(vloc[:, 0] <= 1e-15)


def test_local_lighting_is_the_lighting_in_the_local_frame():
    lmax = 8
    c = np.random.default_rng(5).normal(size=((lmax + 1) ** 2, 3))
    n = random_dirs(30, seed=8)
    local = local_lighting(c, n)
    frames = normal_frames(n)
    w = random_dirs(40, seed=9)
    for k in range(n.shape[0]):  # L'(w') = L(R_n w')
        assert np.abs(reconstruct(local[k], w) - reconstruct(c, w @ frames[k].T)).max() <= 1e-12
    # and it is the transpose of the Wigner-D of the frame
    d = wigner_d_real(frames, lmax)
    for l in range(lmax + 1):
        assert np.abs(band(local.transpose(0, 2, 1), l) - np.einsum("kji,jc->kci", d[l], c[l * l : (l + 1) ** 2])).max() <= 1e-12


@pytest.mark.parametrize(
    "rotations",
    [np.eye(3), np.diag([1.0, 1.0, -1.0])[None], 1.01 * np.eye(3)[None], np.full((1, 3, 3), np.nan)],
)
def test_bad_rotations(rotations):
    with pytest.raises(ValueError, match="rotations"):
        wigner_d_real(rotations, 3)
    with pytest.raises(ValueError, match="rotations"):
        rotate_coeffs(np.ones((4, 1)), rotations)


def test_bad_coeffs_and_normals():
    with pytest.raises(ValueError, match="coeffs"):
        rotate_coeffs(np.ones((5, 1)), np.eye(3)[None])
    with pytest.raises(ValueError, match="coeffs"):
        local_lighting(np.full((4, 1), np.inf), [[0, 0, 1.0]])
    with pytest.raises(ValueError, match="normals"):
        local_lighting(np.ones((4, 1)), [[0, 0, 2.0]])
    with pytest.raises(ValueError, match="lmax"):
        wigner_d_real(np.eye(3)[None], 201)


def test_large_batches_split_over_threads_give_the_same_result():
    from brdfrig.fit import rotation

    lmax = 10
    c = np.random.default_rng(11).normal(size=((lmax + 1) ** 2, 1))
    k = rotation._PARALLEL_MIN_WORK // c.size + 50  # just above the threshold for two workers
    r = random_rotations(k, seed=12)
    big = rotate_coeffs(c, r)
    picks = [0, k // 2 - 1, k // 2, k - 1]  # both sides of the split
    np.testing.assert_allclose(big[picks], rotate_coeffs(c, r[picks]), rtol=0, atol=1e-14)
