"""Ground-truth rendering of spheres: brute-force quadrature, no spherical harmonics.

For each surface normal ``n`` the reflected radiance toward the viewer ``v`` is
the rendering integral evaluated as a sum over the environment samples::

    B(n) = sum_j L_j rho(w_j, v, n) max(n.w_j, 0) dOmega_j

with the environment's own directions ``w_j``, radiances ``L_j`` and solid
angles ``dOmega_j`` (``brdfrig.fit.scene.Environment``).  This is independent of the SH
machinery of the fitter, which is what makes it a ground truth for tests,
benchmarks and the simulated camera.  Each sample acts as a point source of
power ``L_j dOmega_j`` at its centre direction; the accuracy is that of this
quadrature rule (exact on a rule aligned with the normal's horizon for
polynomial lighting, see the tests; for lat-long maps it converges as the map
is refined, with the error concentrated at the horizon of each normal).

The hot loop is numba-compiled, parallel over pixels, with ``fastmath`` off
(sums of up to ~10^5 terms per pixel; reassociation would cost accuracy).
Cost is ``O(N * M * C)``: 10^4 pixels x 3 channels under a 256x128 map take ~8 s
on two cores, so
tests and fits use downsampled maps and pixel subsets.

Measured BRDFs (:mod:`brdfrig.fit.measured`) render with the sharp-lobe
quadrature of :mod:`brdfrig.fit.quadrature` (cells near each mirror direction
integrated over sub-cells, MATH.md pitfall 9) and view ``v = (0, 0, 1)``:
:func:`render_tabulated` interpolates the MERL-grid table inside the kernel;
:func:`render_rho` evaluates any vectorised ``rho(wi, wo, n)`` in numpy (a
network directly, or an oracle).  The analytic path above samples cell centres.
"""

from __future__ import annotations

import numba
import numpy as np

from brdfrig.fit.rho import kernel_rows, rho_channels, rho_view
from brdfrig.fit.merl import half_diff, table_lookup
from brdfrig.fit.quadrature import DEFAULT_CONE_DEG, DEFAULT_SUBDIV, lobe_quadrature, lobe_samples
from brdfrig.fit.scene import Environment

__all__ = ["kernel_inputs", "render_groundtruth", "render_kernel", "render_sharp", "render_tabulated", "render_rho"]


@numba.njit(cache=True, fastmath=False, parallel=True)
def render_kernel(
    kind: int,
    params: np.ndarray,
    normals: np.ndarray,
    dirs: np.ndarray,
    weighted_radiance: np.ndarray,
    view: np.ndarray,
    shared: bool = False,
) -> np.ndarray:
    """Quadrature of the rendering integral.

    Parameters
    ----------
    kind, params : int, (R, NUM_PARAMS) float64
        The BRDF as :func:`brdfrig.fit.analytic.rho_channel` takes it; channel ``c`` of
        the output uses ``params[c mod R]`` and ``weighted_radiance[:, c]`` (:func:`brdfrig.fit.rho.kernel_rows`).
    normals : (N, 3) float64
        Unit normals.
    dirs : (M, 3) float64
        Unit directions light arrives from.
    weighted_radiance : (M, C) float64
        Radiance times solid angle of each sample.
    view : (3,) float64
        Unit direction toward the viewer.
    shared : bool
        The rows share their shape (:func:`brdfrig.fit.rho.shares_shape`): evaluated once per sample.

    Returns
    -------
    (N, C) float64 reflected radiance.
    """
    n_pix = normals.shape[0]
    n_env = dirs.shape[0]
    nr = params.shape[0]
    nc = weighted_radiance.shape[1]
    out = np.zeros((n_pix, nc))
    cos_io = dirs[:, 0] * view[0] + dirs[:, 1] * view[1] + dirs[:, 2] * view[2]
    for i in numba.prange(n_pix):
        nx, ny, nz = normals[i, 0], normals[i, 1], normals[i, 2]
        cos_o = nx * view[0] + ny * view[1] + nz * view[2]
        if cos_o <= 0.0:
            continue
        acc = np.zeros(nc)
        val = np.empty(nr)
        view_terms = rho_view(kind, params, shared, cos_o)
        for j in range(n_env):
            cos_i = nx * dirs[j, 0] + ny * dirs[j, 1] + nz * dirs[j, 2]
            if cos_i <= 0.0:
                continue
            rho_channels(kind, params, shared, cos_i, cos_o, cos_io[j], view_terms, val)
            for c in range(nc):
                acc[c] += weighted_radiance[j, c] * val[c % nr] * cos_i
        for c in range(nc):
            out[i, c] = acc[c]
    return out


def kernel_inputs(normals, env: Environment, view) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Contiguous float64 (normals, seen dirs, radiance * solid angle, view) for the kernels."""
    normals = np.ascontiguousarray(np.asarray(normals, dtype=np.float64).reshape(-1, 3))
    view = np.asarray(view, dtype=np.float64).reshape(3)
    omega = np.asarray(env.solid_angle, dtype=np.float64)
    keep = omega > 0
    dirs = np.ascontiguousarray(np.asarray(env.dirs, dtype=np.float64)[keep])
    weighted = np.ascontiguousarray(np.asarray(env.radiance, dtype=np.float64)[keep] * omega[keep, None])
    return normals, dirs, weighted, view


def render_groundtruth(brdf, normals: np.ndarray, env: Environment, view=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Radiance reflected toward ``view`` by surface points with ``normals`` under ``env``.

    Parameters
    ----------
    brdf : brdfrig.fit.analytic.AnalyticBRDF
        Any object with integer ``kind`` and ``kernel_params() -> (C, NUM_PARAMS)``
        (``C`` = 1 applies one parameter set to every channel of ``env``).
    normals : (N, 3) array_like
        Unit surface normals (world frame).
    env : brdfrig.fit.scene.Environment
        Lighting samples; samples with zero solid angle contribute nothing.
    view : (3,) array_like
        Unit direction from the surface toward the (orthographic) camera.

    Returns
    -------
    (N, C) float64 linear radiance, 0 where ``normal . view <= 0``.
    """
    normals, dirs, weighted, view = kernel_inputs(normals, env, view)
    params, shared = kernel_rows(brdf, env)
    return render_kernel(int(brdf.kind), params, normals, dirs, weighted, view, shared)


@numba.njit(cache=True, fastmath=False, parallel=True)
def _sharp_kernel(kind: int, params: np.ndarray, q, normals: np.ndarray, shared: bool) -> np.ndarray:
    """Sharp-lobe quadrature (:func:`brdfrig.fit.quadrature.lobe_samples`) of an analytic kind, view +z; channel
    ``c`` of the lighting uses row ``c mod R`` of ``params`` (:func:`brdfrig.fit.rho.kernel_rows`; ``shared``:
    :func:`brdfrig.fit.rho.shares_shape`)."""
    n_pix = normals.shape[0]
    nr = params.shape[0]
    nc = q.wrad.shape[1]
    out = np.zeros((n_pix, nc))
    for i in numba.prange(n_pix):
        nx, ny, nz = normals[i, 0], normals[i, 1], normals[i, 2]
        if nz <= 0.0:
            continue
        dirs, wrad = lobe_samples(q, nx, ny, nz, True)
        acc = np.zeros(nc)
        val = np.empty(nr)
        view_terms = rho_view(kind, params, shared, nz)
        for k in range(dirs.shape[0]):
            cos_i = nx * dirs[k, 0] + ny * dirs[k, 1] + nz * dirs[k, 2]
            rho_channels(kind, params, shared, cos_i, nz, dirs[k, 2], view_terms, val)
            for c in range(nc):
                acc[c] += wrad[k, c] * val[c % nr] * cos_i
        out[i] = acc
    return out


def render_sharp(brdf, normals: np.ndarray, env: Environment, cone_deg: float, subdiv: int,
                 merge_deg: float | None = None) -> np.ndarray:
    """Radiance (N, C) toward ``v = (0, 0, 1)`` of an analytic BRDF (``kind``, ``kernel_params``), sharp-lobe quadrature.

    :func:`render_groundtruth`'s rule with the cells within ``cone_deg`` of each mirror direction split
    ``subdiv x subdiv``, and, with ``merge_deg``, the 2 x 2 blocks of cells beyond it merged
    (:func:`brdfrig.fit.quadrature.lobe_quadrature`).
    """
    params, shared = kernel_rows(brdf, env)
    normals = np.ascontiguousarray(np.asarray(normals, dtype=np.float64).reshape(-1, 3))
    return _sharp_kernel(int(brdf.kind), params, lobe_quadrature(env, cone_deg, subdiv, merge_deg), normals, shared)


# ----------------------------------------------------------------------------- measured BRDFs


@numba.njit(cache=True, fastmath=False, parallel=True)
def _table_kernel(log_table: np.ndarray, q, normals: np.ndarray, n_out: int) -> np.ndarray:
    """Sharp-lobe quadrature (:func:`brdfrig.fit.quadrature.lobe_samples`) of a filled log1p MERL-grid table, view +z;
    ``n_out`` output channels, channel ``c`` lit by the lighting's channel ``c`` and the table's ``c mod C``
    (stacked lightings: :attr:`~brdfrig.fit.scene.Environment.lightings`)."""
    n_pix = normals.shape[0]
    nc = log_table.shape[3]
    out = np.zeros((n_pix, n_out))
    for i in numba.prange(n_pix):
        nx, ny, nz = normals[i, 0], normals[i, 1], normals[i, 2]
        if nz <= 0.0:
            continue
        dirs, wrad = lobe_samples(q, nx, ny, nz, True)
        val = np.empty(nc)
        acc = np.zeros(n_out)
        for k in range(dirs.shape[0]):
            wx, wy, wz = dirs[k, 0], dirs[k, 1], dirs[k, 2]
            cos_i = nx * wx + ny * wy + nz * wz
            th, td, pd = half_diff(wx, wy, wz, 0.0, 0.0, 1.0, nx, ny, nz)
            table_lookup(log_table, th, td, pd, val)
            for c in range(n_out):
                acc[c] += wrad[k, c] * val[c % nc] * cos_i
        for c in range(n_out):
            out[i, c] = acc[c]
    return out


def _lobe_inputs(normals, env: Environment, channels: int, cone_deg, subdiv):
    """Contiguous normals and the prepared :class:`~brdfrig.fit.quadrature.LobeQuadrature`; checks channels
    (``channels`` per lighting of ``env``, :attr:`~brdfrig.fit.scene.Environment.lightings`)."""
    normals = np.ascontiguousarray(np.asarray(normals, dtype=np.float64).reshape(-1, 3))
    env.check_channels(channels)
    cone = DEFAULT_CONE_DEG if cone_deg is None else cone_deg
    s = DEFAULT_SUBDIV if subdiv is None else subdiv
    return normals, lobe_quadrature(env, cone, s)


def render_tabulated(brdf, normals: np.ndarray, env: Environment, cone_deg: float | None = None, subdiv: int | None = None) -> np.ndarray:
    """Radiance toward ``v = (0, 0, 1)`` of a tabulated BRDF: sharp-lobe quadrature, table interpolated in the kernel.

    Parameters
    ----------
    brdf : brdfrig.fit.measured.TabulatedBRDF
        Any object with ``log_filled``, ``log1p`` of a filled ``(90, 90, 180, C)`` MERL-grid table.
    normals : (N, 3) array_like
        Unit surface normals (world frame).
    env : Environment
        Lighting; its lat-long map (when kept) is integrated over the cells near
        each mirror direction (:mod:`brdfrig.fit.quadrature`).  Stacked lightings
        (:func:`~brdfrig.fit.scene.stack_lightings`) render in one pass.
    cone_deg, subdiv : float, int, optional
        Cone and subdivision of the quadrature (defaults
        :data:`~brdfrig.fit.quadrature.DEFAULT_CONE_DEG`, :data:`~brdfrig.fit.quadrature.DEFAULT_SUBDIV`).

    Returns
    -------
    (N, env.channels) float64 linear radiance, 0 where ``n_z <= 0``.
    """
    log_table = np.ascontiguousarray(brdf.log_filled)
    normals, q = _lobe_inputs(normals, env, log_table.shape[3], cone_deg, subdiv)
    return _table_kernel(log_table, q, normals, env.channels)


def render_rho(brdf, normals: np.ndarray, env: Environment, cone_deg: float | None = None, subdiv: int | None = None,
               block: int = 1 << 20) -> np.ndarray:
    """Radiance toward ``v = (0, 0, 1)`` of any BRDF with vectorised ``rho(wi, wo, n) -> (M, C)``.

    The same sharp-lobe quadrature as :func:`render_tabulated`, with the BRDF
    evaluated in numpy over blocks of about ``block`` samples (several pixels at
    a time): slower, for BRDFs without a compiled kernel (a network rendered
    directly) and as an oracle.  Parameters and result as :func:`render_tabulated`.
    """
    normals, q = _lobe_inputs(normals, env, brdf.channels, cone_deg, subdiv)
    out = np.zeros((normals.shape[0], env.channels))
    view = np.array([0.0, 0.0, 1.0])
    pending: list[tuple[int, np.ndarray, np.ndarray]] = []

    def flush():
        pix = [i for i, d, _ in pending if len(d)]
        counts = [len(d) for _, d, _ in pending if len(d)]
        if pix:
            wi = np.concatenate([d for _, d, _ in pending])
            wrad = np.concatenate([w for _, _, w in pending])
            n = np.repeat(normals[pix], counts, axis=0)
            terms = wrad * np.tile(brdf.rho(wi, view, n), env.lightings) * np.einsum("ij,ij->i", wi, n)[:, None]
            out[pix] = np.add.reduceat(terms, np.concatenate([[0], np.cumsum(counts)[:-1]]), axis=0)
        pending.clear()

    size = 0
    for i, (nx, ny, nz) in enumerate(normals):
        if nz <= 0.0:
            continue
        d, w = lobe_samples(q, float(nx), float(ny), float(nz), True)
        pending.append((i, d, w))
        size += len(d)
        if size >= block:
            flush()
            size = 0
    if pending:
        flush()
    return out
