"""Real Wigner-D rotation of spherical-harmonic coefficients, batched over many rotations.

Conventions (``fit.sh``; ``../shared/docs/MATH.md``):

- ``D_l(R)`` is the ``(2l+1, 2l+1)`` real matrix with ``Y_l(R w) = D_l(R) @ Y_l(w)``
  for band ``l`` of ``fit.sh.sh_eval`` (rows/columns ordered ``m = -l..l``).
  Then ``D(R1 R2) = D(R1) D(R2)`` and ``D(R^T) = D(R)^T`` (orthogonal).
- Coefficients ``c`` of ``f`` rotated by ``R`` (the function ``w -> f(R^T w)``)
  are ``D_l(R) @ c_l`` per band.
- ``normal_frames(n) = Rz(phi_N) Ry(theta_N)`` maps +z to ``n``; ``local_lighting``
  returns the coefficients of ``w' -> L(R_n w')``, i.e. ``D_l(R_n)^T @ L_l``.

Why hand-written: no library in reach rotates a batch of REAL coefficient
vectors by a batch of rotations in one call.  ``spherical`` gives complex Wigner
D only (about 140 us per rotation at l = 20 plus 5 s of numba compilation);
pyshtools' ``SHRotateRealCoef`` rotates one coefficient set per call (0.04 ms at
l = 20); sphericart only evaluates ``Y``.  ``python -m fit.bench_sh`` measures
this module against them in the same run.

Method (stable to l = 100 and beyond; no factorials anywhere): a rotation is
factored as ``R = Rz(alpha) Ry(beta) Rz(gamma)`` and ``Ry(beta) = Rx(-pi/2)
Rz(beta) Rx(pi/2)``, so ``D_l(R) = Z_l(alpha) X_l^T Z_l(beta) X_l Z_l(gamma)``
where ``Z_l`` (rotation about z) only mixes ``m`` with ``-m`` by
``cos(m angle), sin(m angle)`` and ``X_l = D_l(Rx(pi/2))`` is one fixed matrix per
band.  ``X_l`` is computed once (and cached) by the Ivanic-Ruedenberg recurrence
(J. Phys. Chem. 100, 6342 (1996), with the 1998 erratum), which builds band
``l`` from band ``l-1`` and band 1 by orthogonal-preserving three-term
combinations; measured: ``||X_l X_l^T - I||`` < 1e-13 at l = 200.  Applying
``X_l`` to many coefficient vectors is one BLAS matrix product per band
(``(2l+1)^2`` flops per vector), and the ``Z`` steps are element-wise, which is
what makes a batch of 1e5 rotations cheap.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from fit.sh import check_lmax, check_unit_dirs, sh_degree

__all__ = [
    "euler_zyz",
    "local_lighting",
    "normal_frames",
    "rotate_coeffs",
    "wigner_d_real",
]

#: Largest accepted deviation of ``R R^T`` from the identity for rotation inputs.
ORTHONORMAL_TOLERANCE = 1e-6


# ----------------------------------------------------------------------------- inputs


def _check_rotations(rotations, name: str = "rotations") -> np.ndarray:
    r = np.asarray(rotations, dtype=np.float64)
    if r.ndim != 3 or r.shape[1:] != (3, 3):
        raise ValueError(f"{name} must have shape (K, 3, 3), got {r.shape}")
    if not np.all(np.isfinite(r)):
        raise ValueError(f"{name} contains non-finite values")
    if r.shape[0]:
        err = np.abs(r @ r.transpose(0, 2, 1) - np.eye(3)).max()
        if err > ORTHONORMAL_TOLERANCE or np.linalg.det(r).min() < 0:
            raise ValueError(f"{name} must be proper rotation matrices (max |R R^T - I| = {err:.3g})")
    return r


def _check_coeffs(coeffs, name: str = "coeffs") -> tuple[np.ndarray, int]:
    c = np.asarray(coeffs, dtype=np.float64)
    if c.ndim != 2:
        raise ValueError(f"{name} must have shape (ncoef, C), got {c.shape}")
    if not np.all(np.isfinite(c)):
        raise ValueError(f"{name} contains non-finite values")
    return c, sh_degree(c.shape[0], name)


# ----------------------------------------------------------------------------- angles


def _wrap(a: np.ndarray) -> np.ndarray:
    """Angle in [-pi, pi)."""
    return (a + np.pi) % (2 * np.pi) - np.pi


def euler_zyz(rotations) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Euler angles with ``R = Rz(alpha) Ry(beta) Rz(gamma)``.

    Parameters
    ----------
    rotations : (K, 3, 3) array_like
        Proper rotation matrices.

    Returns
    -------
    alpha, beta, gamma : (K,) float64
        Radians; ``beta`` in [0, pi].

    Notes
    -----
    Near ``beta = 0`` only ``alpha + gamma`` matters (and near ``beta = pi`` only
    ``alpha - gamma``); the individual angles read from the third row/column are
    then inaccurate (error ~ eps / sin(beta)).  The sum is therefore taken from
    the upper-left 2x2 block (accurate where ``cos(beta) >= 0``) and the
    difference from it where ``cos(beta) < 0``, so that ``D(R)`` built from the
    angles stays accurate to rounding even for nearly degenerate rotations.
    """
    r = _check_rotations(rotations)
    beta = np.arctan2(np.hypot(r[:, 0, 2], r[:, 1, 2]), r[:, 2, 2])
    alpha_c = np.arctan2(r[:, 1, 2], r[:, 0, 2])
    gamma_c = np.arctan2(r[:, 2, 1], -r[:, 2, 0])
    s_c, d_c = alpha_c + gamma_c, gamma_c - alpha_c
    # upper-left block = (1+cb)/2 Rz2(alpha+gamma) + (cb-1)/2 diag(1,-1) Rz2(gamma-alpha)
    s_b = np.arctan2(r[:, 1, 0] - r[:, 0, 1], r[:, 0, 0] + r[:, 1, 1])
    d_b = np.arctan2(r[:, 1, 0] + r[:, 0, 1], r[:, 1, 1] - r[:, 0, 0])
    upper = r[:, 2, 2] >= 0
    s = np.where(upper, s_c + _wrap(s_b - s_c), s_c)
    d = np.where(upper, d_c, d_c + _wrap(d_b - d_c))
    return (s - d) / 2, beta, (s + d) / 2


# ----------------------------------------------------------------------------- building blocks


def _band_m(lmax: int) -> tuple[np.ndarray, np.ndarray]:
    """Order ``m`` of every coefficient index up to ``lmax`` and the index of ``(l, -m)``."""
    l = np.repeat(np.arange(lmax + 1), 2 * np.arange(lmax + 1) + 1)
    idx = np.arange((lmax + 1) ** 2)
    m = idx - l * l - l
    return m, idx - 2 * m


def _z_apply(a: np.ndarray, angle: np.ndarray, m: np.ndarray, partner: np.ndarray) -> np.ndarray:
    """Left-multiply by ``Z(angle)`` (rotation about z) along axis 0.

    ``a`` has shape ``(n, K, ...)`` with axis 0 indexed by coefficients of orders
    ``m`` (``partner[i]`` = row of order ``-m[i]``, same band); ``angle`` is (K,).
    Row m of the result is ``cos(m angle) a_m - sin(m angle) a_-m`` (from
    ``Y_l,+-m ~ cos/sin(m phi)`` and ``phi -> phi + angle``).
    """
    phase = m[:, None] * angle[None, :]
    extra = (None,) * (a.ndim - 2)
    cos = np.cos(phase)[(...,) + extra]
    sin = np.sin(phase)[(...,) + extra]
    return cos * a - sin * a[partner]


def _x_generator(l: int) -> np.ndarray:
    """Generator ``G`` of rotations about +x in band ``l``: ``D_l(Rx(t)) = expm(t G)``.

    Built from the textbook angular-momentum matrix ``L_x = (L_+ + L_-)/2``
    (``<l,m+1|L_+|l,m> = sqrt(l(l+1) - m(m+1))``) in the complex basis with the
    Condon-Shortley phase, mapped to the real basis of ``fit.sh`` by the unitary
    ``U`` with ``Y_real = U Y_complex``:
    ``Y_l,m = ((-1)^m Y^m + Y^-m)/sqrt(2)``,
    ``Y_l,-m = -i ((-1)^m Y^m - Y^-m)/sqrt(2)`` (m > 0).
    The result ``U (i L_x) U^H`` is real and antisymmetric.
    """
    size = 2 * l + 1
    m = np.arange(-l, l)
    lx = np.zeros((size, size))
    lx[m + l + 1, m + l] = 0.5 * np.sqrt(l * (l + 1) - m * (m + 1.0))
    lx = lx + lx.T
    u = np.zeros((size, size), dtype=complex)
    u[l, l] = 1.0
    k = np.arange(1, l + 1)
    sign = (-1.0) ** k / np.sqrt(2)
    u[l + k, l + k] = sign
    u[l + k, l - k] = 1 / np.sqrt(2)
    u[l - k, l + k] = -1j * sign
    u[l - k, l - k] = 1j / np.sqrt(2)
    return (u @ (1j * lx) @ u.conj().T).real


def _x_band(l: int) -> np.ndarray:
    """``X_l = D_l(Rx(pi/2)) = expm(pi/2 G)`` through the eigenvectors of the Hermitian ``i G``.

    The eigenvalues of ``i G`` are the integers ``-l..l``; they are snapped to
    those integers so that ``exp(-i lambda pi/2) = (-i)^lambda`` is exact, and the
    eigenvectors come from LAPACK's Hermitian solver (backward stable, unit
    gaps), so the error stays at rounding level for every band.
    """
    lam, vec = np.linalg.eigh(1j * _x_generator(l))
    phase = np.exp(-0.5j * np.pi * np.rint(lam))
    return ((vec * phase) @ vec.conj().T).real


@lru_cache(maxsize=4)
def _x_matrices(lmax: int) -> tuple[np.ndarray, ...]:
    """``X_l = D_l(Rx(pi/2))`` for ``l = 0..lmax`` (read-only arrays)."""
    mats = [_x_band(l) for l in range(lmax + 1)]
    for a in mats:
        a.setflags(write=False)
    return tuple(mats)


def _x_apply(a: np.ndarray, lmax: int, transpose: bool) -> np.ndarray:
    """Left-multiply each band of ``a`` (shape ``(ncoef, ...)``) by ``X_l`` (or ``X_l^T``)."""
    xs = _x_matrices(lmax)
    out = np.empty_like(a)
    tail = a.shape[1:]
    for l in range(lmax + 1):
        s, e = l * l, (l + 1) ** 2
        x = xs[l].T if transpose else xs[l]
        out[s:e] = (x @ a[s:e].reshape(e - s, -1)).reshape((e - s,) + tail)
    return out


# ----------------------------------------------------------------------------- public API


def wigner_d_real(rotations, lmax: int) -> list[np.ndarray]:
    """Real Wigner-D matrices of a batch of rotations.

    Parameters
    ----------
    rotations : (K, 3, 3) array_like
        Proper rotation matrices (checked to ``ORTHONORMAL_TOLERANCE``).
    lmax : int
        Band limit, ``0 <= lmax <= 200``.

    Returns
    -------
    list of (K, 2l+1, 2l+1) float64, for l = 0..lmax
        ``D_l(R)`` with ``sh_eval(R w)[band l] = D_l(R) @ sh_eval(w)[band l]``.
    """
    lmax = check_lmax(lmax)
    alpha, beta, gamma = euler_zyz(rotations)
    k = alpha.shape[0]
    xs = _x_matrices(lmax)
    out = []
    for l in range(lmax + 1):
        m = np.arange(-l, l + 1)
        partner = m[::-1] + l
        # (X Z(gamma))^T = Z(-gamma) X^T, with the row axis first: shape (n, K, n)
        b = _z_apply(np.broadcast_to(xs[l].T[:, None, :], (2 * l + 1, k, 2 * l + 1)), -gamma, m, partner)
        b = b.transpose(2, 1, 0)  # rows of X Z(gamma): (n, K, n)
        b = _z_apply(b, beta, m, partner)
        b = (xs[l].T @ b.reshape(2 * l + 1, -1)).reshape(b.shape)
        b = _z_apply(b, alpha, m, partner)
        out.append(np.ascontiguousarray(b.transpose(1, 0, 2)))
    return out


def rotate_coeffs(coeffs, rotations) -> np.ndarray:
    """Coefficients of ``w -> f(R^T w)`` (``f`` rotated by ``R``) for each rotation.

    Parameters
    ----------
    coeffs : (ncoef, C) array_like
        SH coefficients of ``f``, ``ncoef = (lmax + 1)**2``.
    rotations : (K, 3, 3) array_like
        Proper rotation matrices.

    Returns
    -------
    (K, ncoef, C) float64
        ``out[k, band l] = D_l(R_k) @ coeffs[band l]``.
    """
    c, lmax = _check_coeffs(coeffs)
    alpha, beta, gamma = euler_zyz(rotations)
    m, partner = _band_m(lmax)
    a = np.broadcast_to(c[:, None, :], (c.shape[0], alpha.shape[0], c.shape[1]))
    a = _z_apply(a, gamma, m, partner)
    a = _x_apply(a, lmax, transpose=False)
    a = _z_apply(a, beta, m, partner)
    a = _x_apply(a, lmax, transpose=True)
    a = _z_apply(a, alpha, m, partner)
    return np.ascontiguousarray(a.transpose(1, 0, 2))


def _normal_angles(normals) -> tuple[np.ndarray, np.ndarray]:
    n = check_unit_dirs(normals, "normals")
    if n.ndim != 2:
        raise ValueError(f"normals must have shape (N, 3), got {n.shape}")
    return np.arctan2(n[:, 1], n[:, 0]), np.arctan2(np.hypot(n[:, 0], n[:, 1]), n[:, 2])


def normal_frames(normals) -> np.ndarray:
    """Local frames ``R_n = Rz(phi_N) Ry(theta_N)`` of unit normals (``R_n @ z = n``).

    Parameters
    ----------
    normals : (N, 3) array_like
        Unit normals; ``phi_N = atan2(n_y, n_x)`` (0 at the pole), ``theta_N = acos(n_z)``.

    Returns
    -------
    (N, 3, 3) float64
    """
    phi, theta = _normal_angles(normals)
    cp, sp, ct, st = np.cos(phi), np.sin(phi), np.cos(theta), np.sin(theta)
    zero = np.zeros_like(phi)
    return np.stack(
        [
            np.stack([cp * ct, -sp, cp * st], axis=-1),
            np.stack([sp * ct, cp, sp * st], axis=-1),
            np.stack([-st, zero, ct], axis=-1),
        ],
        axis=-2,
    )


def local_lighting(coeffs, normals) -> np.ndarray:
    """Lighting coefficients in each normal's local frame.

    Parameters
    ----------
    coeffs : (ncoef, C) array_like
        World-frame lighting coefficients ``L_lm``.
    normals : (N, 3) array_like
        Unit normals.

    Returns
    -------
    (N, ncoef, C) float64
        ``L'_lm(n)``: coefficients of ``w' -> L(R_n w')`` with ``R_n = normal_frames(n)``,
        i.e. ``D_l(R_n)^T @ L_l = X_l^T Z(-theta) X_l Z(-phi) L_l``.
    """
    c, lmax = _check_coeffs(coeffs)
    phi, theta = _normal_angles(normals)
    m, partner = _band_m(lmax)
    a = np.broadcast_to(c[:, None, :], (c.shape[0], phi.shape[0], c.shape[1]))
    a = _z_apply(a, -phi, m, partner)
    a = _x_apply(a, lmax, transpose=False)
    a = _z_apply(a, -theta, m, partner)
    a = _x_apply(a, lmax, transpose=True)
    return np.ascontiguousarray(a.transpose(1, 0, 2))
