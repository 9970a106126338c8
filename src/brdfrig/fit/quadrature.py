"""Sharp-lobe quadrature of the rendering integral over a lat-long map (MATH.md pitfall 9).

A lat-long map is radiance constant over each cell.  For one surface normal
``n`` seen from ``v = (0, 0, 1)`` the samples of the rendering integral are

- the cell centres, each carrying ``L_cell * dOmega_cell`` (one sample per cell),
- except the cells whose centre lies within ``cone_deg`` of the mirror
  direction ``r = 2 (n.v) n - v``: each is split into ``s`` rows (equal steps
  of latitude) by ``s_lon = max(1, ceil(s * cos(phi_eq)))`` columns (equal
  steps of longitude; ``phi_eq`` the cell's latitude edge nearest the equator,
  so that sub-cells stay about square toward the poles and the equator row gets
  ``s x s``), each sub-cell carrying ``L_cell`` times its exact solid angle
  ``(dlam / s_lon) (sin phi_top - sin phi_bottom)`` at its centre direction.

Optionally (``merge_deg``, samples above the horizon only) the cells far from
the lobe are merged: each 2 x 2 block of cells lying wholly farther than
``merge_deg`` from ``r`` and wholly above the horizon of ``n`` becomes one
sample, at the normalised solid-angle-weighted mean ``b`` of its cell centres
(the same for every lighting, so stacked lightings render as each alone),
carrying per channel ``n.m / n.b`` with ``m = sum_j L_j dOmega_j w_j`` over its
cells.  So the block's cosine-weighted power ``sum_j L_j dOmega_j (n.w_j) = n.m``
is exact in every channel (a Lambertian renders as over the cells, to
rounding); what remains is the BRDF's own change across the block (a few
degrees): against the cell-centre rule, up to 0.17% for rough conductors
(:data:`MERGE_CONE_DEG`).  Blocks within the cone or across the horizon keep
their cells.

Samples below the horizon of ``n`` (``n.w <= 0``) are left out unless asked
for.  The map's rotation is respected: the cone test and the subdivision are done
in the map frame, directions are returned in the world frame.  An environment
without a lat-long map falls back to its own point samples (no subdivision).

:func:`lobe_quadrature` prepares the (numba-passable) :class:`LobeQuadrature`
once per environment; :func:`lobe_samples` is a numba function, callable from
other numba kernels (also inside ``prange``), that returns the samples of one
normal.  Defaults (:data:`DEFAULT_CONE_DEG`, :data:`DEFAULT_SUBDIV`) come from a
convergence study on the sharpest measured materials (in :data:`DEFAULT_SUBDIV`;
tests/test_quadrature.py checks that sub-cells converge on a narrow lobe);
:func:`brdfrig.fit.pbr.lobe_rule` sizes the rule to a GGX lobe of known roughness.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np

from brdfrig.errors import InputError
from brdfrig.fit.scene import Environment

__all__ = [
    "DEFAULT_CONE_DEG",
    "DEFAULT_SUBDIV",
    "MERGE_CONE_DEG",
    "MERGE_MIN_ROWS",
    "merge_cone",
    "LobeQuadrature",
    "lobe_quadrature",
    "lobe_samples",
    "lobe_sample_count",
    "quadrature_samples",
]

DEFAULT_CONE_DEG = (2.0, 5.0, 15.0)
"""Half-angles (degrees) of the nested cones around the mirror direction whose cells are subdivided."""

DEFAULT_SUBDIV = (48, 16, 4)
"""Sub-cells per cell side (``s``) in each of those cones.

Convergence study (sharpest measured materials, 96 px sphere, 128x64 probes,
every 17th pixel, relative RMS against nested cones (3, 8, 30) deg at
(96, 32, 16), whose difference from (2, 6, 30) at (64, 24, 12) is 0.035%):
``cc_amber_citrine`` under grace: cell centres 70%, 20 deg at 12x12 1.1%
(28k samples per pixel), 20 deg at 24x24 0.24% (99k), these defaults 0.15%
(11.6k; cell centres alone are 4.1k).  Over cc_amber_citrine (grace, ennis),
cc_blue_agat, chm_orange, cc_green_malachite (grace) and cg_sunflower (pisa):
cell centres 9-110%, 20 deg at 12x12 0.1-1.1%, these defaults 0.01-0.15%.
"""


class LobeQuadrature(NamedTuple):
    """Arrays of the sharp-lobe quadrature of one environment (pass to :func:`lobe_samples`).

    Attributes
    ----------
    dirs : (M, 3) float64
        World directions of the cell centres (or of the point samples).
    wrad : (M, C) float64
        Radiance times solid angle of each cell (or point sample).
    map_dirs : (M, 3) float64
        Cell-centre directions in the map frame (unused for point samples).
    image : (H, W, C) float64
        The map's radiance per cell ((0, 0, C) for point samples).
    rotation : (3, 3) float64
        World direction of a map direction ``d``: ``rotation @ d``.
    cos_cones : (T,) float64
        Cosines of the cone half-angles, decreasing (widening cones; empty: no subdivision).
    subdivs : (T,) int64
        ``s`` of each cone: a cell takes the ``s`` of the narrowest cone holding its centre.
    block_dirs : (B, 3) float64
        World directions of the merged 2 x 2 blocks of cells (solid-angle-weighted mean of their centres,
        normalised), row-major over the ``H/2 x W/2`` blocks; empty when no cells merge.
    block_map_dirs : (B, 3) float64
        The same in the map frame.
    block_moments : (B, C, 3) float64
        ``sum_j L_j dOmega_j w_j`` over each block's cells ``j`` (world frame), per channel: a merged sample
        for normal ``n`` carries ``n . moment / n . block_dir`` (module docstring).
    block_cos_far : (B,) float64
        Cosine of ``merge_deg`` plus the block's angular radius: a block whose direction is farther than that
        from the mirror direction lies wholly outside the ``merge_deg`` cone.
    block_sin_radius : (B,) float64
        Sine of the block's angular radius about its direction.
    """

    dirs: np.ndarray
    wrad: np.ndarray
    map_dirs: np.ndarray
    image: np.ndarray
    rotation: np.ndarray
    cos_cones: np.ndarray
    subdivs: np.ndarray
    block_dirs: np.ndarray
    block_map_dirs: np.ndarray
    block_moments: np.ndarray
    block_cos_far: np.ndarray
    block_sin_radius: np.ndarray


MERGE_CONE_DEG = 30.0
"""Cone (degrees) about the mirror direction outside which analytic renders merge 2 x 2 blocks of cells.

Against the cell-centre rule (or :func:`brdfrig.fit.pbr.lobe_rule`'s) on a 96 px sphere under ennis / pisa at
128 x 64, relative RMS: dielectric (Oren-Nayar base, roughness 0.2-1) 0.02-0.03% / 0.006-0.02%, sheen 0.05% /
0.03%, conductor 0.008% / 0.007% at roughness 0.2, 0.04% / 0.03% at 0.3, 0.17% / 0.09% at 0.5 (45 degrees: 0.06% /
0.03%), 0.07-0.10% / 0.04% at 0.7-1.  Samples a pixel under ennis: 4096 -> 1739 on average (20 degrees: 1487, 45:
2227); a dielectric's render of the sphere under both probes stacked, one thread: 1.9-2.1 s against 4.1-5.3 s unmerged
(measured side by side), 0.3-0.4 s of it writing the samples (the loops visit the cells of kept blocks only)."""


MERGE_MIN_ROWS = 64
"""Fewest rows of a lat-long map whose cells :func:`merge_cone` merges: blocks of at most 5.6 degrees, as studied
(on a 64 x 32 map, blocks of 11 degrees, ``auto`` chose the blend over the conductor for Mitsuba's gold:
tests/test_mitsuba_fit.py)."""


def merge_cone(env: Environment) -> float | None:
    """:data:`MERGE_CONE_DEG` when ``env``'s cells merge (a lat-long map of even width and an even height of at least
    :data:`MERGE_MIN_ROWS`), else None."""
    if env.latlong is None:
        return None
    h, w = env.latlong.image.shape[:2]
    return MERGE_CONE_DEG if h >= MERGE_MIN_ROWS and h % 2 == 0 and w % 2 == 0 else None


def _tiers(cone_deg, subdiv) -> tuple[np.ndarray, np.ndarray]:
    """Validated cone cosines (decreasing) and subdivisions of one or several nested cones."""
    cones = np.atleast_1d(np.asarray(cone_deg, dtype=np.float64))
    subs = np.atleast_1d(np.asarray(subdiv))
    if cones.ndim != 1 or subs.shape != cones.shape:
        raise InputError(f"cone_deg and subdiv must be scalars or sequences of one length, got {cone_deg!r}, {subdiv!r}")
    if not np.all((cones >= 0) & (cones <= 180)):
        raise InputError(f"cone_deg must be within [0, 180], got {cone_deg!r}")
    if subs.dtype == bool or not np.all(np.mod(subs, 1) == 0) or np.any(subs < 1):
        raise InputError(f"subdiv must be integers >= 1, got {subdiv!r}")
    order = np.argsort(cones, kind="stable")
    cones, subs = cones[order], subs[order].astype(np.int64)
    keep = subs > 1
    return np.cos(np.radians(cones[keep])), np.ascontiguousarray(subs[keep])


def lobe_quadrature(env: Environment, cone_deg=DEFAULT_CONE_DEG, subdiv=DEFAULT_SUBDIV,
                    merge_deg: float | None = None) -> LobeQuadrature:
    """Prepare the sharp-lobe quadrature of ``env`` (see the module docstring).

    Parameters
    ----------
    env : Environment
        With ``env.latlong`` set, its cells are integrated; otherwise its
        samples with positive solid angle are used as they are.
    cone_deg : float or sequence of float
        Cone half-angle(s) in degrees, in [0, 180].  Several nested cones grade the
        subdivision: a cell takes the ``subdiv`` of the narrowest cone holding its centre.
    subdiv : int or sequence of int
        ``s >= 1`` per cone (1: cell centres).
    merge_deg : float or None
        Merge each 2 x 2 block of cells lying wholly farther than ``merge_deg`` degrees from the mirror
        direction and wholly above the horizon into one sample (module docstring); at least the widest
        subdivided cone.  None: no merging.  Needs a lat-long map of even height and width.
    """
    cos_cones, subdivs = _tiers(cone_deg, subdiv)
    if env.latlong is None:
        if merge_deg is not None:
            raise InputError("merge_deg needs an environment with a lat-long map")
        omega = np.asarray(env.solid_angle, dtype=np.float64)
        keep = omega > 0
        dirs = np.ascontiguousarray(np.asarray(env.dirs, dtype=np.float64)[keep])
        wrad = np.ascontiguousarray(np.asarray(env.radiance, dtype=np.float64)[keep] * omega[keep, None])
        c = wrad.shape[1]
        return LobeQuadrature(dirs, wrad, dirs, np.zeros((0, 0, c)), np.eye(3), cos_cones[:0], subdivs[:0],
                              *_no_blocks(c))
    image = np.ascontiguousarray(np.asarray(env.latlong.image, dtype=np.float64))
    rot = np.ascontiguousarray(np.asarray(env.latlong.rotation, dtype=np.float64))
    c = image.shape[2]
    # the Environment's samples are the map's cell centres (row-major) turned by the rotation, with exact solid angles
    dirs = np.ascontiguousarray(np.asarray(env.dirs, dtype=np.float64))
    map_dirs = np.ascontiguousarray(dirs @ rot)
    omega = np.asarray(env.solid_angle, dtype=np.float64)
    wrad = np.ascontiguousarray(image.reshape(-1, c) * omega.reshape(-1, 1))
    blocks = _no_blocks(c) if merge_deg is None else _blocks(map_dirs, wrad, omega, image.shape, rot, cos_cones, merge_deg)
    return LobeQuadrature(dirs, wrad, map_dirs, image, rot, cos_cones, subdivs, *blocks)


def _no_blocks(c: int) -> tuple[np.ndarray, ...]:
    """Empty block arrays: no cells merge."""
    return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, c, 3)), np.zeros(0), np.zeros(0)


def _blocks(map_dirs, wrad, omega, shape, rot, cos_cones, merge_deg) -> tuple[np.ndarray, ...]:
    """Block arrays of :class:`LobeQuadrature` for the 2 x 2 blocks of an ``(H, W, C)`` map."""
    h, w = shape[:2]
    merge = float(merge_deg)
    if not 0.0 <= merge <= 180.0:
        raise InputError(f"merge_deg must be within [0, 180], got {merge_deg!r}")
    if len(cos_cones) and math.cos(math.radians(merge)) > cos_cones[-1] + 1e-12:
        raise InputError(f"merge_deg ({merge}) must be at least the widest subdivided cone "
                         f"({math.degrees(math.acos(cos_cones[-1])):.6g} degrees)")
    if h % 2 or w % 2:
        raise InputError(f"merging 2 x 2 blocks needs a map of even height and width, got {h} x {w}")
    cells, power, area = (_by_block(a, h, w) for a in (map_dirs, wrad, omega))
    centre = (area[:, :, None] * cells).sum(axis=1)
    centre /= np.linalg.norm(centre, axis=1, keepdims=True)
    radius = _block_radius(centre, h, w)
    moments = (power[:, :, :, None] * (cells @ rot.T)[:, :, None, :]).sum(axis=1)
    return (np.ascontiguousarray(centre @ rot.T), np.ascontiguousarray(centre), np.ascontiguousarray(moments),
            np.cos(np.minimum(math.radians(merge) + radius, math.pi)), np.sin(np.minimum(radius, 0.5 * math.pi)))


def _by_block(a: np.ndarray, h: int, w: int) -> np.ndarray:
    """Rows of ``a`` (one per cell of an ``h x w`` map, row-major) grouped by 2 x 2 block: (h w / 4, 4, ...)."""
    return a.reshape(h // 2, 2, w // 2, 2, *a.shape[1:]).swapaxes(1, 2).reshape(h * w // 4, 4, *a.shape[1:])


def _block_radius(centre: np.ndarray, h: int, w: int, points: int = 9) -> np.ndarray:
    """Largest angle (radians) from each block's ``centre`` (map frame, row-major blocks) to its boundary.

    Measured at ``points`` points along each edge of the block's latitude-longitude rectangle, widened by 1%
    for the curvature between them (the blocks are at most a few degrees across).
    """
    rows, cols = np.divmod(np.arange(h * w // 4), w // 2)
    t = np.linspace(0.0, 1.0, points)
    u = np.concatenate([t, t, np.zeros(points), np.ones(points)])
    v = np.concatenate([np.zeros(points), np.ones(points), t, t])
    lat = 0.5 * math.pi - math.pi * (2 * rows[:, None] + 2 * v[None]) / h
    lam = -2.0 * math.pi * ((2 * cols[:, None] + 2 * u[None]) / w - 0.5)
    edge = np.stack([np.sin(lam) * np.cos(lat), np.sin(lat), np.cos(lam) * np.cos(lat)], axis=2)
    cos_max = np.clip(np.einsum("bpd,bd->bp", edge, centre).min(axis=1), -1.0, 1.0)
    return 1.01 * np.arccos(cos_max)


@numba.njit(cache=True, fastmath=False)
def _mirror_in_map(q, nx, ny, nz):
    """Mirror direction ``r = 2 (n.v) n - v`` of ``v = (0, 0, 1)``, in the map frame (``rotation^T r``)."""
    rx, ry, rz = 2.0 * nz * nx, 2.0 * nz * ny, 2.0 * nz * nz - 1.0
    rt = q.rotation
    return (
        rt[0, 0] * rx + rt[1, 0] * ry + rt[2, 0] * rz,
        rt[0, 1] * rx + rt[1, 1] * ry + rt[2, 1] * rz,
        rt[0, 2] * rx + rt[1, 2] * ry + rt[2, 2] * rz,
    )


@numba.njit(cache=True, fastmath=False)
def _cell_columns(row, h, s):
    """Sub-columns of a cone cell in ``row``: ``max(1, ceil(s cos(phi_eq)))``."""
    top = 0.5 * math.pi - math.pi * row / h
    bottom = top - math.pi / h
    cos_eq = 1.0 if top * bottom <= 0.0 else max(math.cos(top), math.cos(bottom))
    return max(1, min(s, int(math.ceil(s * cos_eq - 1e-9))))


@numba.njit(cache=True, fastmath=False, inline="always")
def _cell_subdiv(q, rx, ry, rz, j):
    """``s`` of cell ``j`` for the mirror direction ``r`` (map frame): 1 outside every cone."""
    if q.image.shape[0] == 0 or q.cos_cones.shape[0] == 0:
        return 1
    cos_r = rx * q.map_dirs[j, 0] + ry * q.map_dirs[j, 1] + rz * q.map_dirs[j, 2]
    if cos_r < q.cos_cones[-1]:
        return 1
    for t in range(q.cos_cones.shape[0]):
        if cos_r >= q.cos_cones[t]:
            return q.subdivs[t]
    return 1


@numba.njit(cache=True, fastmath=False)
def _block_states(q, rx, ry, rz, nx, ny, nz, horizon):
    """Per block of ``q`` for mirror ``r`` (map frame) and normal ``n``: 1 one merged sample, 0 its cells, -1 none
    (wholly below the horizon).  Empty when no cells merge (no blocks, or not ``horizon``)."""
    nb = q.block_dirs.shape[0] if horizon else 0
    states = np.zeros(nb, dtype=np.int8)
    for b in range(nb):
        cos_n = nx * q.block_dirs[b, 0] + ny * q.block_dirs[b, 1] + nz * q.block_dirs[b, 2]
        if cos_n < -q.block_sin_radius[b]:
            states[b] = -1
        elif cos_n > q.block_sin_radius[b]:
            cos_m = rx * q.block_map_dirs[b, 0] + ry * q.block_map_dirs[b, 1] + rz * q.block_map_dirs[b, 2]
            if cos_m < q.block_cos_far[b]:
                states[b] = 1
    return states


@numba.njit(cache=True, fastmath=False, inline="always")
def _unit_cell(u, t, w, merging):
    """Cell index of cell ``t`` of unit ``u`` of the sample loops on a map ``w`` cells wide: cell ``u`` itself, or,
    when blocks merge, cell ``t`` (row-major, 0-3) of 2 x 2 block ``u`` (blocks row-major)."""
    if not merging:
        return u
    return 2 * (u // (w // 2)) * w + 2 * (u % (w // 2)) + (t & 1) + (t >> 1) * w


@numba.njit(cache=True, fastmath=False)
def _count(q, states, rx, ry, rz, nx, ny, nz, horizon):
    """Number of samples for mirror ``r`` (map frame), normal ``n`` and block ``states`` (upper bound if ``horizon``)."""
    h = q.image.shape[0]
    w = max(q.image.shape[1], 1)
    count = 0
    merging = states.shape[0] > 0
    for u in range(states.shape[0] if merging else q.dirs.shape[0]):
        if merging:
            if states[u] == 1:
                count += 1
            if states[u] != 0:
                continue
        for t in range(4 if merging else 1):
            j = _unit_cell(u, t, w, merging)
            s = _cell_subdiv(q, rx, ry, rz, j)
            if s > 1:
                count += s * _cell_columns(j // w, h, s)
            elif not horizon or nx * q.dirs[j, 0] + ny * q.dirs[j, 1] + nz * q.dirs[j, 2] > 0.0:
                count += 1
    return count


@numba.njit(cache=True, fastmath=False)
def lobe_sample_count(q, nx, ny, nz, horizon):
    """Number of samples :func:`lobe_samples` returns for unit normal ``n`` (upper bound if ``horizon``)."""
    rx, ry, rz = _mirror_in_map(q, nx, ny, nz)
    return _count(q, _block_states(q, rx, ry, rz, nx, ny, nz, horizon), rx, ry, rz, nx, ny, nz, horizon)


@numba.njit(cache=True, fastmath=False)
def lobe_samples(q, nx, ny, nz, horizon=True):
    """Quadrature samples for unit normal ``(nx, ny, nz)`` and view ``v = (0, 0, 1)``.

    Parameters
    ----------
    q : LobeQuadrature
    nx, ny, nz : float
        Unit surface normal (world frame).
    horizon : bool
        Leave out samples with ``n.w <= 0``.  Blocks merge (``q.block_dirs``) only with ``horizon``.

    Returns
    -------
    dirs : (K, 3) float64
        World directions the light arrives from: the cells row-major, or, with blocks merging, block by block
        (row-major over the blocks; a kept block's cells row-major).
    wrad : (K, C) float64
        Radiance times solid angle of each sample; of a merged block, the weight that makes its
        cosine-weighted power exact (module docstring): only integrands carrying ``n.w`` may use it.
    """
    rx, ry, rz = _mirror_in_map(q, nx, ny, nz)
    states = _block_states(q, rx, ry, rz, nx, ny, nz, horizon)
    cap = _count(q, states, rx, ry, rz, nx, ny, nz, horizon)
    nc = q.wrad.shape[1]
    dirs = np.empty((cap, 3))
    wrad = np.empty((cap, nc))
    h = q.image.shape[0]
    w = max(q.image.shape[1], 1)
    rt = q.rotation
    k = 0
    merging = states.shape[0] > 0
    for u in range(states.shape[0] if merging else q.dirs.shape[0]):
        if merging:  # unit u: block u, else cell u
            if states[u] == 1:  # one sample for the block
                bx, by, bz = q.block_dirs[u, 0], q.block_dirs[u, 1], q.block_dirs[u, 2]
                dirs[k, 0], dirs[k, 1], dirs[k, 2] = bx, by, bz
                cos_n = nx * bx + ny * by + nz * bz
                for c in range(nc):
                    wrad[k, c] = (nx * q.block_moments[u, c, 0] + ny * q.block_moments[u, c, 1]
                                  + nz * q.block_moments[u, c, 2]) / cos_n
                k += 1
            if states[u] != 0:
                continue
        for t in range(4 if merging else 1):
            j = _unit_cell(u, t, w, merging)
            s = _cell_subdiv(q, rx, ry, rz, j)
            if s > 1:
                row, col = j // w, j % w
                s_lon = _cell_columns(row, h, s)
                dlam = 2.0 * math.pi / (w * s_lon)
                top = 0.5 * math.pi - math.pi * row / h
                for a in range(s):
                    p0 = top - math.pi * a / (h * s)
                    p1 = top - math.pi * (a + 1) / (h * s)
                    pc = top - math.pi * (a + 0.5) / (h * s)
                    omega = dlam * (math.sin(p0) - math.sin(p1))
                    cp, sp = math.cos(pc), math.sin(pc)
                    for b in range(s_lon):
                        lam = -2.0 * math.pi * ((col + (b + 0.5) / s_lon) / w - 0.5)
                        mx, my, mz = math.sin(lam) * cp, sp, math.cos(lam) * cp
                        wx = rt[0, 0] * mx + rt[0, 1] * my + rt[0, 2] * mz
                        wy = rt[1, 0] * mx + rt[1, 1] * my + rt[1, 2] * mz
                        wz = rt[2, 0] * mx + rt[2, 1] * my + rt[2, 2] * mz
                        if horizon and nx * wx + ny * wy + nz * wz <= 0.0:
                            continue
                        dirs[k, 0], dirs[k, 1], dirs[k, 2] = wx, wy, wz
                        for c in range(nc):
                            wrad[k, c] = q.image[row, col, c] * omega
                        k += 1
            elif not horizon or nx * q.dirs[j, 0] + ny * q.dirs[j, 1] + nz * q.dirs[j, 2] > 0.0:
                dirs[k, 0], dirs[k, 1], dirs[k, 2] = q.dirs[j, 0], q.dirs[j, 1], q.dirs[j, 2]
                for c in range(nc):
                    wrad[k, c] = q.wrad[j, c]
                k += 1
    return dirs[:k], wrad[:k]


def quadrature_samples(q: LobeQuadrature, normal, horizon: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Python entry to :func:`lobe_samples` for one unit ``normal`` (3,): ``(dirs (K, 3), wrad (K, C))``."""
    n = np.asarray(normal, dtype=np.float64).reshape(3)
    return lobe_samples(q, float(n[0]), float(n[1]), float(n[2]), bool(horizon))
