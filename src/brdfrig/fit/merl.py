"""The MERL-grid kernels shared by the measured BRDFs and the ground-truth renderer (numba, scalar).

:func:`half_diff` gives the Rusinkiewicz coordinates of a pair of directions and
:func:`table_lookup` interpolates a filled ``log1p`` table on MERL's grid; the
frame and the interpolation rule are those of :mod:`brdfrig.fit.measured`
(its module docstring).  This module imports nothing else of brdfrig, so
:mod:`brdfrig.fit.measured` and :mod:`brdfrig.fit.groundtruth` both import it
at module level.
"""

from __future__ import annotations

import math

import numba

__all__ = ["CUBIC_NODES", "half_diff", "table_lookup"]

_HALF_PI = 0.5 * math.pi


@numba.njit(cache=True, fastmath=False)
def half_diff(wix, wiy, wiz, wox, woy, woz, nx, ny, nz):
    """Rusinkiewicz ``(theta_h, theta_d, phi_d)`` (radians, ``phi_d`` in [0, 2 pi)) of unit ``wi``, ``wo``, ``n``.

    Scalar version for compiled kernels; see the module docstring for the frame.
    """
    hx, hy, hz = wix + wox, wiy + woy, wiz + woz
    norm = math.sqrt(hx * hx + hy * hy + hz * hz)
    if norm < 1e-300:  # wi = -wo: no half vector; take h = n
        hx, hy, hz = nx, ny, nz
    else:
        hx, hy, hz = hx / norm, hy / norm, hz / norm
    cos_h = min(max(hx * nx + hy * ny + hz * nz, -1.0), 1.0)
    tx, ty, tz = hx - cos_h * nx, hy - cos_h * ny, hz - cos_h * nz
    sin_h = math.sqrt(tx * tx + ty * ty + tz * tz)
    if sin_h < 1e-12:  # h = n: any tangent
        if abs(ny) < 0.9:
            tx, ty, tz = nz, 0.0, -nx  # e_y x n (= +x for n = +z, the phi_h = 0 tangent of tabulation)
        else:
            tx, ty, tz = 0.0, -nz, ny  # e_x x n
        tn = math.sqrt(tx * tx + ty * ty + tz * tz)
        tx, ty, tz = tx / tn, ty / tn, tz / tn
        sin_h = 0.0
    else:
        tx, ty, tz = tx / sin_h, ty / sin_h, tz / sin_h
    bx, by, bz = ny * tz - nz * ty, nz * tx - nx * tz, nx * ty - ny * tx
    ex, ey, ez = cos_h * tx - sin_h * nx, cos_h * ty - sin_h * ny, cos_h * tz - sin_h * nz
    dx = wix * ex + wiy * ey + wiz * ez
    dy = wix * bx + wiy * by + wiz * bz
    dz = min(max(wix * hx + wiy * hy + wiz * hz, -1.0), 1.0)
    phi_d = math.atan2(dy, dx)
    if phi_d < 0.0:
        phi_d += 2.0 * math.pi
    return math.atan2(sin_h, cos_h), math.acos(dz), phi_d


CUBIC_NODES = 12
"""``theta_h`` nodes (below ``(12/90)^2 90 = 1.6`` deg) within which interpolation along ``theta_h`` is cubic."""


@numba.njit(cache=True, fastmath=False)
def table_lookup(log_table, theta_h, theta_d, phi_d, out):
    """BRDF (1/sr) from a filled ``log1p`` MERL-grid table (90, 90, 180, C) into ``out`` (C,).

    Interpolates ``log1p(rho)`` in index space (module docstring): along the
    sqrt-spaced ``theta_h`` index Catmull-Rom below node :data:`CUBIC_NODES`
    (nodes clamped at 0), linear above; linear in ``theta_d`` and in
    ``phi_d mod pi`` (periodic); returns ``max(expm1(.), 0)``.
    """
    uh = min(math.sqrt(min(max(theta_h, 0.0), _HALF_PI) / _HALF_PI) * 90.0, 89.0)
    ud = min(min(max(theta_d, 0.0), _HALF_PI) / _HALF_PI * 90.0, 89.0)
    pd = phi_d - math.pi * math.floor(phi_d / math.pi)  # phi_d mod pi
    up = pd / math.pi * 180.0
    ih = min(int(uh), 88)
    jd = min(int(ud), 88)
    kp = min(int(up), 179)
    t, fd, fp = uh - ih, ud - jd, up - kp
    kp1 = kp + 1 if kp < 179 else 0
    w00, w01, w10, w11 = (1.0 - fd) * (1.0 - fp), (1.0 - fd) * fp, fd * (1.0 - fp), fd * fp
    nc = out.shape[0]
    for c in range(nc):
        out[c] = 0.0
    if ih < CUBIC_NODES:
        t2 = t * t
        t3 = t2 * t
        first, count = ih - 1, 4
        wh = (-0.5 * t3 + t2 - 0.5 * t, 1.5 * t3 - 2.5 * t2 + 1.0, -1.5 * t3 + 2.0 * t2 + 0.5 * t, 0.5 * t3 - 0.5 * t2)
    else:
        first, count = ih, 2
        wh = (1.0 - t, t, 0.0, 0.0)
    for m in range(count):
        i = max(first + m, 0)
        a, b, g, d = wh[m] * w00, wh[m] * w01, wh[m] * w10, wh[m] * w11
        for c in range(nc):
            out[c] += (a * log_table[i, jd, kp, c] + b * log_table[i, jd, kp1, c]
                       + g * log_table[i, jd + 1, kp, c] + d * log_table[i, jd + 1, kp1, c])
    for c in range(nc):
        out[c] = max(math.expm1(out[c]), 0.0)
