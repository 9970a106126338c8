"""Renders of the columns of the parametric fits that enter linearly, for one roughness at a time.

The microfacet fit's GGX basis (:func:`render_ggx_basis`) and the sheen fit's fuzz column
(:func:`render_fuzz`) are the rendering integral of :mod:`brdfrig.fit.groundtruth` (a sum over the
environment's samples, view-only factors once per pixel) with a fixed unit-amplitude integrand, so a fit
solves for the amplitudes by linear least squares and searches over the roughness only.  They live apart
from the ground truth so that a change here does not invalidate cached ground-truth renders
(:mod:`brdfrig.evaluate.cache`).
"""

from __future__ import annotations

import numba
import numpy as np

from brdfrig.fit.groundtruth import kernel_inputs
from brdfrig.fit.rho import charlie_sheen_given, ggx_lobe_given, sheen_table, sheen_visibility, smith_lambda
from brdfrig.fit.scene import Environment

__all__ = ["render_ggx_basis", "render_fuzz"]


@numba.njit(cache=True, fastmath=False, parallel=True)
def _ggx_basis_kernel(
    alpha: float, normals: np.ndarray, dirs: np.ndarray, weighted_radiance: np.ndarray, view: np.ndarray
) -> np.ndarray:
    """Quadrature of the two linear parts of the GGX lobe (see :func:`render_ggx_basis`)."""
    n_pix = normals.shape[0]
    n_env = dirs.shape[0]
    nc = weighted_radiance.shape[1]
    out = np.zeros((n_pix, nc, 2))
    cos_io = dirs[:, 0] * view[0] + dirs[:, 1] * view[1] + dirs[:, 2] * view[2]
    for i in numba.prange(n_pix):
        nx, ny, nz = normals[i, 0], normals[i, 1], normals[i, 2]
        cos_o = nx * view[0] + ny * view[1] + nz * view[2]
        if cos_o <= 0.0:
            continue
        acc = np.zeros((nc, 2))
        lambda_o = smith_lambda(cos_o, alpha)
        for j in range(n_env):
            cos_i = nx * dirs[j, 0] + ny * dirs[j, 1] + nz * dirs[j, 2]
            if cos_i <= 0.0:
                continue
            lobe, cos_d = ggx_lobe_given(cos_i, cos_o, cos_io[j], alpha, lambda_o)
            b1 = lobe * (1.0 - cos_d) ** 5 * cos_i
            b0 = lobe * cos_i - b1
            for c in range(nc):
                lw = weighted_radiance[j, c]
                acc[c, 0] += lw * b0
                acc[c, 1] += lw * b1
        out[i] = acc
    return out


@numba.njit(cache=True, fastmath=False, parallel=True)
def _fuzz_kernel(
    alpha: float, normals: np.ndarray, dirs: np.ndarray, weighted_radiance: np.ndarray, view: np.ndarray
) -> np.ndarray:
    """Quadrature of the unit-colour Charlie sheen lobe (see :func:`render_fuzz`)."""
    n_pix = normals.shape[0]
    n_env = dirs.shape[0]
    nc = weighted_radiance.shape[1]
    out = np.zeros((n_pix, nc))
    cos_io = dirs[:, 0] * view[0] + dirs[:, 1] * view[1] + dirs[:, 2] * view[2]
    table = sheen_table(alpha)
    for i in numba.prange(n_pix):
        nx, ny, nz = normals[i, 0], normals[i, 1], normals[i, 2]
        cos_o = nx * view[0] + ny * view[1] + nz * view[2]
        if cos_o <= 0.0:
            continue
        vis_o = sheen_visibility(table, 0, cos_o)
        acc = np.zeros(nc)
        for j in range(n_env):
            cos_i = nx * dirs[j, 0] + ny * dirs[j, 1] + nz * dirs[j, 2]
            if cos_i <= 0.0:
                continue
            val = charlie_sheen_given(cos_i, cos_o, cos_io[j], alpha, sheen_visibility(table, 0, cos_i), vis_o) * cos_i
            for c in range(nc):
                acc[c] += weighted_radiance[j, c] * val
        out[i] = acc
    return out


def render_ggx_basis(alpha: float, normals: np.ndarray, env: Environment, view=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Renders of the two parts of a GGX lobe that enter linearly, for one roughness ``alpha``.

    The lobe of ``GGX(alpha, f0, diffuse=0, f90)`` renders to
    ``f0 * B[..., 0] + f90 * B[..., 1]``: basis 0 is the lobe weighted by
    ``1 - (1 - h.wi)^5``, basis 1 the lobe weighted by ``(1 - h.wi)^5``.  One
    pass computes both (the microfacet fit's inner loop), sharing the lobe evaluation.

    Parameters and conventions as :func:`brdfrig.fit.groundtruth.render_groundtruth`.

    Returns
    -------
    (N, C, 2) float64.
    """
    normals, dirs, weighted, view = kernel_inputs(normals, env, view)
    return _ggx_basis_kernel(float(alpha), normals, dirs, weighted, view)


def render_fuzz(alpha: float, normals: np.ndarray, env: Environment, view=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Renders of the unit-colour Charlie sheen lobe of roughness ``alpha`` (:func:`brdfrig.fit.rho.charlie_sheen`),
    the fuzz column of the sheen fit, reading ``1 / (1 + Lambda)`` from a :func:`brdfrig.fit.rho.sheen_table` as the
    layered kind does (its value at ``cos_o`` once per pixel).

    Parameters and conventions as :func:`brdfrig.fit.groundtruth.render_groundtruth`.

    Returns
    -------
    (N, C) float64.
    """
    normals, dirs, weighted, view = kernel_inputs(normals, env, view)
    return _fuzz_kernel(float(alpha), normals, dirs, weighted, view)
