"""The compiled BRDF formulas of the analytic families: one numba implementation shared by every caller.

An isotropic BRDF depends on the directions only through ``cos_i = n.wi``,
``cos_o = n.wo`` and ``cos_io = wi.wo``; :func:`rho_channel` takes exactly
those, with a model given as an integer ``kind`` and a parameter row per
channel (:data:`NUM_PARAMS`, :data:`LAYERED_HEAD`, :data:`CONDUCTOR_PARAMS`).
The classes of :mod:`brdfrig.fit.analytic` and :mod:`brdfrig.fit.pbr`, the
ground-truth renderer (:mod:`brdfrig.fit.groundtruth`) and the parametric fits
all call these kernels; this module imports nothing else of brdfrig, so each of
them can import it at module level.

Conventions (``docs/MATH.md``): ``rho`` in 1/sr without the cosine factor,
``rho = 0`` when either direction is at or below the horizon of the normal.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = [
    "KIND_LAMBERTIAN",
    "KIND_BLINN_PHONG",
    "KIND_GGX",
    "KIND_LAYERED",
    "KIND_CONDUCTOR",
    "NUM_PARAMS",
    "TABLE_SIZE",
    "LAYERED_HEAD",
    "LAYERED_SHEEN",
    "LAYERED_PARAMS",
    "CONDUCTOR_PARAMS",
    "F82_COS",
    "ggx_ndf",
    "smith_lambda",
    "ggx_lobe",
    "ggx_lobe_given",
    "oren_nayar_ab",
    "oren_nayar_factor",
    "table_lookup",
    "fresnel_dielectric",
    "charlie_sheen",
    "charlie_sheen_given",
    "sheen_lambda",
    "SHEEN_NODES",
    "sheen_table",
    "sheen_visibility",
    "f82_q",
    "layered_rho",
    "conductor_rho",
    "rho_channel",
    "rho_view",
    "rho_channels",
    "shares_shape",
    "kernel_rows",
    "LAYERED_AMPLITUDES",
    "CONDUCTOR_AMPLITUDES",
    "rho_from_cosines",
]

KIND_LAMBERTIAN = 0
KIND_BLINN_PHONG = 1
KIND_GGX = 2
NUM_PARAMS = 5
"""Length of one channel's parameter row: diffuse only (albedo, 0, 0, 0, sigma); Blinn-Phong
(diffuse, specular, exponent, 0, sigma); GGX (diffuse, f0, f90, alpha, sigma), with ``sigma``
the Oren-Nayar roughness of the diffuse base (0 = Lambertian)."""


@numba.njit(cache=True, fastmath=False)
def ggx_ndf(cos_h: float, alpha: float) -> float:
    """GGX normal distribution ``D`` (1/sr) at ``cos_h = n.h``; ``int D (n.h) dw_h = 1`` over the hemisphere."""
    if cos_h <= 0.0:
        return 0.0
    a2 = alpha * alpha
    t = cos_h * cos_h * (a2 - 1.0) + 1.0
    return a2 / (math.pi * t * t)


@numba.njit(cache=True, fastmath=False)
def smith_lambda(cos_t: float, alpha: float) -> float:
    """Smith ``Lambda`` of GGX for a direction at ``cos_t = n.w > 0``: ``(sqrt(1 + alpha^2 tan^2) - 1) / 2``."""
    c2 = cos_t * cos_t
    tan2 = max(1.0 - c2, 0.0) / c2
    return 0.5 * (math.sqrt(1.0 + alpha * alpha * tan2) - 1.0)


@numba.njit(cache=True, fastmath=False)
def ggx_lobe(cos_i: float, cos_o: float, cos_io: float, alpha: float) -> tuple[float, float]:
    """The GGX lobe without Fresnel, ``D G2 / (4 cos_i cos_o)`` (1/sr), and ``cos_d = h.wi``.

    Both directions must be above the horizon (``cos_i, cos_o > 0``); returns
    (0, 1) when ``wi = -wo`` (no half vector).
    """
    return ggx_lobe_given(cos_i, cos_o, cos_io, alpha, smith_lambda(cos_o, alpha))


@numba.njit(cache=True, fastmath=False)
def ggx_lobe_given(cos_i: float, cos_o: float, cos_io: float, alpha: float, lambda_o: float) -> tuple[float, float]:
    """:func:`ggx_lobe` with ``lambda_o = smith_lambda(cos_o, alpha)`` given (one per pixel, not per light sample)."""
    # Half vector h = (wi + wo) / |wi + wo|; |wi + wo|^2 = 2 + 2 wi.wo.
    norm2 = 2.0 + 2.0 * cos_io
    if norm2 <= 1e-300:
        return 0.0, 1.0
    inv = 1.0 / math.sqrt(norm2)
    cos_h = (cos_i + cos_o) * inv
    cos_d = min((1.0 + cos_io) * inv, 1.0)  # h.wi = h.wo
    g2 = 1.0 / (1.0 + smith_lambda(cos_i, alpha) + lambda_o)
    return ggx_ndf(cos_h, alpha) * g2 / (4.0 * cos_i * cos_o), cos_d


@numba.njit(cache=True, fastmath=False)
def oren_nayar_ab(sigma: float) -> tuple[float, float]:
    """Oren-Nayar coefficients ``(A, B)`` for facet slope deviation ``sigma`` (radians)."""
    s2 = sigma * sigma
    return 1.0 - 0.5 * s2 / (s2 + 0.33), 0.45 * s2 / (s2 + 0.09)


@numba.njit(cache=True, fastmath=False)
def oren_nayar_factor(sigma: float, cos_i: float, cos_o: float, cos_io: float) -> float:
    """Oren-Nayar factor ``A + B max(0, cos dphi) sin(a) tan(b)`` (1 for ``sigma = 0``); both cosines > 0."""
    if sigma == 0.0:
        return 1.0
    a, b = oren_nayar_ab(sigma)
    # cos(dphi) sin_i sin_o = cos_io - cos_i cos_o;  sin(a) tan(b) = sin_i sin_o / max(cos_i, cos_o).
    return a + b * max(cos_io - cos_i * cos_o, 0.0) / max(cos_i, cos_o)


# --- physically based families (classes and tables in brdfrig.fit.pbr) -----------------------------

KIND_LAYERED = 3
KIND_CONDUCTOR = 4
TABLE_SIZE = 32
"""Nodes of the layered kind's directional tables, at ``cos = (k / (TABLE_SIZE - 1))^2`` (dense at grazing)."""
LAYERED_HEAD = 8
"""Leading scalars of a layered row: ``dA, dB, specular_weight, alpha, ior, fuzz_color, fuzz_alpha, 1/norm``;
then two tables of :data:`TABLE_SIZE` nodes: the base's transmission ``t(cos)`` and the fuzz's ``1 - E_fuzz(cos)``;
then, from :data:`LAYERED_SHEEN`, the fuzz's :func:`sheen_table`."""
SHEEN_NODES = 2048
"""Nodes of each half of a :func:`sheen_table`: ``cos = d`` below 1/2 and ``cos = 1 - d`` above, with
``d = t^4`` and ``t`` uniform on ``[0, 2^(-1/4)]`` (dense at both ends, where ``Lambda`` has a ``d^c`` cusp)."""
LAYERED_SHEEN = LAYERED_HEAD + 2 * TABLE_SIZE
LAYERED_PARAMS = LAYERED_SHEEN + 2 * (SHEEN_NODES + 1)
CONDUCTOR_PARAMS = 4
"""A conductor row: ``a0, a1, a2, alpha`` with ``F = a0 (1 - (1-c)^5) + a1 (1-c)^5 - a2 q(c)`` (see :func:`f82_q`)."""
F82_COS = 1.0 / 7.0
"""``cos`` at which the F82 tint is specified (82 degrees; OpenPBR, Hoffman 2019)."""


@numba.njit(cache=True, fastmath=False)
def table_lookup(p: np.ndarray, start: int, cos_t: float) -> float:
    """Piecewise-linear value of the table ``p[start:start+TABLE_SIZE]`` (nodes ``(k/(K-1))^2``) at ``cos_t``."""
    x = math.sqrt(min(max(cos_t, 0.0), 1.0)) * (TABLE_SIZE - 1)
    k = min(int(x), TABLE_SIZE - 2)
    f = x - k
    return (1.0 - f) * p[start + k] + f * p[start + k + 1]


@numba.njit(cache=True, fastmath=False)
def fresnel_dielectric(cos_d: float, eta: float) -> float:
    """Unpolarised Fresnel reflectance of light arriving from outside a dielectric of relative IOR ``eta >= 1``."""
    c = min(max(cos_d, 0.0), 1.0)
    g = math.sqrt(eta * eta - 1.0 + c * c)
    a = (g - c) / (g + c)
    b = (c * (g + c) - 1.0) / (c * (g - c) + 1.0)
    return 0.5 * a * a * (1.0 + b * b)


@numba.njit(cache=True, fastmath=False)
def charlie_sheen(cos_i: float, cos_o: float, cos_io: float, alpha: float) -> float:
    """Charlie sheen lobe ``D V`` (1/sr) with the Estevez-Kulla Lambda fit (glTF KHR_materials_sheen).

    ``D = (2 + 1/alpha) sin(theta_h)^(1/alpha) / (2 pi)``, ``V = 1 / ((1 + L(cos_i) + L(cos_o)) 4 cos_i cos_o)``;
    ``alpha = fuzz_roughness^2``; both cosines > 0.
    """
    vis_i = 1.0 / (1.0 + sheen_lambda(cos_i, alpha))
    vis_o = 1.0 / (1.0 + sheen_lambda(cos_o, alpha))
    return charlie_sheen_given(cos_i, cos_o, cos_io, alpha, vis_i, vis_o)


@numba.njit(cache=True, fastmath=False)
def charlie_sheen_given(cos_i: float, cos_o: float, cos_io: float, alpha: float, vis_i: float, vis_o: float) -> float:
    """:func:`charlie_sheen` with ``vis = 1 / (1 + L(cos))`` of both directions given (exact, or from
    :func:`sheen_visibility`): ``V = vis_i vis_o / ((vis_i + vis_o - vis_i vis_o) 4 cos_i cos_o)``, symmetric in
    the two directions to the last bit."""
    norm2 = 2.0 + 2.0 * cos_io
    if norm2 <= 1e-300:
        return 0.0
    cos_h = (cos_i + cos_o) / math.sqrt(norm2)
    sin2 = max(1.0 - cos_h * cos_h, 0.0)
    inv = 1.0 / alpha
    d = (2.0 + inv) * sin2 ** (0.5 * inv) / (2.0 * math.pi)
    vv = vis_i * vis_o
    return d * vv / ((vis_i + vis_o - vv) * 4.0 * cos_i * cos_o)


@numba.njit(cache=True, fastmath=False)
def _sheen_l(x: float, alpha: float) -> float:
    t = (1.0 - alpha) * (1.0 - alpha)
    a = 21.5473 + (25.3245 - 21.5473) * t
    b = 3.82987 + (3.32435 - 3.82987) * t
    c = 0.19823 + (0.16801 - 0.19823) * t
    d = -1.97760 + (-1.27393 + 1.97760) * t
    e = -4.32054 + (-4.85967 + 4.32054) * t
    return a / (1.0 + b * x**c) + d * x + e


@numba.njit(cache=True, fastmath=False)
def sheen_lambda(cos_t: float, alpha: float) -> float:
    """Estevez-Kulla ``Lambda(cos_t)`` of the Charlie sheen lobe of ``alpha``."""
    if cos_t < 0.5:
        return math.exp(_sheen_l(cos_t, alpha))
    return math.exp(2.0 * _sheen_l(0.5, alpha) - _sheen_l(1.0 - cos_t, alpha))


@numba.njit(cache=True, fastmath=False)
def sheen_table(alpha: float) -> np.ndarray:
    """``1 / (1 + Lambda(cos))`` (:func:`sheen_lambda`) of the Charlie sheen of ``alpha`` at the nodes of
    :data:`SHEEN_NODES`, (2 (SHEEN_NODES + 1),): the half below ``cos = 1/2``, then the half above.

    Read with :func:`sheen_visibility`: linear interpolation there is within 2e-7 of the exact value for every
    ``alpha``, and within 3e-6 of it relative for ``cos >= 0.01`` (2e-4 below; tests/test_pbr.py).  So the
    sheen's ``V`` from the table is within 6e-6 of the exact one, relative, where both cosines are >= 0.01.
    """
    n = SHEEN_NODES + 1
    out = np.empty(2 * n)
    step = 0.5**0.25 / SHEEN_NODES
    for k in range(n):
        d = (k * step) ** 4
        out[k] = 1.0 / (1.0 + sheen_lambda(d, alpha))
        out[n + k] = 1.0 / (1.0 + sheen_lambda(1.0 - d, alpha))
    return out


@numba.njit(cache=True, fastmath=False, inline="always")
def sheen_visibility(table: np.ndarray, start: int, cos_t: float) -> float:
    """``1 / (1 + Lambda(cos_t))`` interpolated in the :func:`sheen_table` at ``table[start:]``, ``0 <= cos_t <= 1``."""
    if cos_t < 0.5:
        d = max(cos_t, 0.0)
    else:
        d = max(1.0 - cos_t, 0.0)
        start += SHEEN_NODES + 1
    x = math.sqrt(math.sqrt(d)) * (SHEEN_NODES / 0.5**0.25)
    k = min(int(x), SHEEN_NODES - 1)
    f = x - k
    return (1.0 - f) * table[start + k] + f * table[start + k + 1]


@numba.njit(cache=True, fastmath=False)
def f82_q(cos_d: float) -> float:
    """Shape of the F82-tint correction ``c (1-c)^6 / (cb (1-cb)^6)`` with ``cb = 1/7`` (1 at 82 degrees)."""
    cb = F82_COS
    return cos_d * (1.0 - cos_d) ** 6 / (cb * (1.0 - cb) ** 6)


LAYERED_AMPLITUDES = (0, 1, 2, 5)
"""Columns of a layered row that enter the BRDF linearly (``dA, dB, specular_weight, fuzz_color``); the others
are its shape."""


@numba.njit(cache=True, fastmath=False)
def _layered_view(p: np.ndarray, cos_o: float, base: bool, spec: bool, fuzz: bool):
    """The factors of :func:`_layered_terms` that depend on the view alone: ``(base, spec, fuzz,
    t(cos_o), 1 - E_fuzz(cos_o), Lambda_GGX(cos_o), 1 / (1 + Lambda_sheen(cos_o)))``, those of the parts not asked
    for 0."""
    t_o = m_o = lam_o = vis_o = 0.0
    if base:
        t_o = table_lookup(p, LAYERED_HEAD, cos_o)
    if spec:
        m_o = table_lookup(p, LAYERED_HEAD + TABLE_SIZE, cos_o)
        lam_o = smith_lambda(cos_o, p[3])
    if fuzz:
        vis_o = sheen_visibility(p, LAYERED_SHEEN, cos_o)
    return base, spec, fuzz, t_o, m_o, lam_o, vis_o


@numba.njit(cache=True, fastmath=False)
def _layered_terms(p: np.ndarray, cos_i: float, cos_o: float, cos_io: float, view):
    """The shape factors ``(retro, t, lobe, m, fresnel, sheen)`` of :func:`layered_rho`, those of the parts not asked for 0
    (``view``: :func:`_layered_view` at ``cos_o``)."""
    base, spec, fuzz, t_o, m_o, lam_o, vis_o = view
    retro = t = lobe = m = fres = sheen = 0.0
    if base:
        retro = max(cos_io - cos_i * cos_o, 0.0) / max(cos_i, cos_o)
        t = table_lookup(p, LAYERED_HEAD, cos_i) * t_o * p[7]
    if spec:
        lobe, cos_d = ggx_lobe_given(cos_i, cos_o, cos_io, p[3], lam_o)
        m = min(table_lookup(p, LAYERED_HEAD + TABLE_SIZE, cos_i), m_o)
        fres = fresnel_dielectric(cos_d, p[4])
    if fuzz:
        vis_i = sheen_visibility(p, LAYERED_SHEEN, cos_i)
        sheen = charlie_sheen_given(cos_i, cos_o, cos_io, p[6], vis_i, vis_o)
    return retro, t, lobe, m, fres, sheen


@numba.njit(cache=True, fastmath=False)
def _layered_combine(p: np.ndarray, retro: float, t: float, lobe: float, m: float, fres: float, sheen: float) -> float:
    """:func:`layered_rho` from the shape factors of :func:`_layered_terms` and the amplitudes of ``p``."""
    out = 0.0
    if p[0] != 0.0 or p[1] != 0.0:
        out += t * (p[0] + p[1] * retro) / math.pi
    if p[2] != 0.0:
        out += p[2] * m * fres * lobe
    if p[5] != 0.0:
        out += p[5] * sheen
    return out


@numba.njit(cache=True, fastmath=False)
def layered_rho(p: np.ndarray, cos_i: float, cos_o: float, cos_io: float) -> float:
    """Fuzz over a GGX dielectric coating over a diffuse base (row layout :data:`LAYERED_HEAD`); cosines > 0.

    ``rho = fuzz_color sheen + m(i,o) w F_ior(h.wi) D G2 / (4 cos_i cos_o)
    + t(cos_i) t(cos_o) / norm (dA + dB retro) / pi`` with ``m = min(1 - E_fuzz(cos_i), 1 - E_fuzz(cos_o))``.
    """
    view = _layered_view(p, cos_o, p[0] != 0.0 or p[1] != 0.0, p[2] != 0.0, p[5] != 0.0)
    return _layered_combine(p, *_layered_terms(p, cos_i, cos_o, cos_io, view))


@numba.njit(cache=True, fastmath=False)
def conductor_rho(p: np.ndarray, cos_i: float, cos_o: float, cos_io: float) -> float:
    """GGX conductor with the F82-tint Fresnel in its linear form (:data:`CONDUCTOR_PARAMS`); cosines > 0."""
    lobe, cos_d = ggx_lobe(cos_i, cos_o, cos_io, p[3])
    return _conductor_combine(p, lobe, cos_d)


@numba.njit(cache=True, fastmath=False)
def _conductor_combine(p: np.ndarray, lobe: float, cos_d: float) -> float:
    """:func:`conductor_rho` from its GGX lobe and ``cos_d`` (shared by the channels) and the amplitudes of ``p``."""
    s5 = (1.0 - cos_d) ** 5
    return (p[0] * (1.0 - s5) + p[1] * s5 - p[2] * f82_q(cos_d)) * lobe


@numba.njit(cache=True, fastmath=False)
def rho_channel(kind: int, p: np.ndarray, cos_i: float, cos_o: float, cos_io: float) -> float:
    """BRDF value (1/sr) of one channel with parameter row ``p`` (see :data:`NUM_PARAMS`, :data:`LAYERED_HEAD`,
    :data:`CONDUCTOR_PARAMS`).

    ``cos_i = n.wi``, ``cos_o = n.wo``, ``cos_io = wi.wo``; 0 when either
    direction is at or below the horizon.
    """
    if cos_i <= 0.0 or cos_o <= 0.0:
        return 0.0
    if kind == KIND_LAYERED:
        return layered_rho(p, cos_i, cos_o, cos_io)
    if kind == KIND_CONDUCTOR:
        return conductor_rho(p, cos_i, cos_o, cos_io)
    diffuse = p[0] / math.pi * oren_nayar_factor(p[4], cos_i, cos_o, cos_io)
    if kind == KIND_LAMBERTIAN:
        return diffuse
    if kind == KIND_BLINN_PHONG:
        norm2 = 2.0 + 2.0 * cos_io
        if norm2 <= 1e-300:
            return diffuse
        cos_h = (cos_i + cos_o) / math.sqrt(norm2)
        e = p[2]
        return diffuse + p[1] * (e + 8.0) / (8.0 * math.pi) * cos_h**e
    # KIND_GGX: Schlick F = f0 + (f90 - f0) (1 - h.wi)^5
    lobe, cos_d = ggx_lobe(cos_i, cos_o, cos_io, p[3])
    return diffuse + (p[1] + (p[2] - p[1]) * (1.0 - cos_d) ** 5) * lobe


CONDUCTOR_AMPLITUDES = (0, 1, 2)
"""Columns of a conductor row that enter the BRDF linearly; the other (``alpha``) is its shape."""


def shares_shape(kind: int, params: np.ndarray) -> bool:
    """Whether the channels' rows (C, P) of a layered or conductor ``kind`` differ only in their amplitudes
    (:data:`LAYERED_AMPLITUDES`, :data:`CONDUCTOR_AMPLITUDES`): then :func:`rho_channels` evaluates the shape once
    for all channels."""
    amplitudes = {KIND_LAYERED: LAYERED_AMPLITUDES, KIND_CONDUCTOR: CONDUCTOR_AMPLITUDES}.get(kind)
    if amplitudes is None or params.shape[0] < 2:
        return False
    shape = np.ones(params.shape[1], dtype=bool)
    shape[list(amplitudes)] = False
    return bool(np.all(params[:, shape] == params[0, shape]))


def kernel_rows(brdf, env) -> tuple[np.ndarray, bool]:
    """``brdf.kernel_params()`` as contiguous float64 rows (R, P) and :func:`shares_shape` of them: what the render
    kernels take.  A kernel lights channel ``c`` of ``env`` with row ``c mod R``: one row serves every channel, R
    rows one lighting's channels, repeated over ``env.lightings`` (:func:`brdfrig.fit.scene.stack_lightings`), so
    each distinct row is evaluated once per sample.  ValueError if the channel counts differ
    (:meth:`brdfrig.fit.scene.Environment.check_channels`)."""
    params = np.ascontiguousarray(np.asarray(brdf.kernel_params(), dtype=np.float64))
    env.check_channels(env.channels // env.lightings if params.shape[0] == 1 else params.shape[0])
    return params, shares_shape(int(brdf.kind), params)


@numba.njit(cache=True, fastmath=False)
def rho_view(kind: int, params: np.ndarray, shared: bool, cos_o: float):
    """The factors of :func:`rho_channels` that depend on the view alone (``cos_o > 0``), computed once per pixel:
    :func:`_layered_view` of the shared shape (conductor: its ``Lambda(cos_o)`` in the same slot; neither shared
    nor layered or conductor: unused)."""
    if not shared or cos_o <= 0.0 or kind not in (KIND_LAYERED, KIND_CONDUCTOR):
        return False, False, False, 0.0, 0.0, 0.0, 0.0
    if kind == KIND_CONDUCTOR:
        return False, True, False, 0.0, 0.0, smith_lambda(cos_o, params[0, 3]), 0.0
    base = spec = fuzz = False
    for c in range(params.shape[0]):
        base = base or params[c, 0] != 0.0 or params[c, 1] != 0.0
        spec = spec or params[c, 2] != 0.0
        fuzz = fuzz or params[c, 5] != 0.0
    return _layered_view(params[0], cos_o, base, spec, fuzz)


@numba.njit(cache=True, fastmath=False)
def rho_channels(kind: int, params: np.ndarray, shared: bool, cos_i: float, cos_o: float, cos_io: float, view,
                 out: np.ndarray) -> None:
    """``out[c] = rho_channel(kind, params[c], ...)`` for every channel; with ``shared`` (:func:`shares_shape`) the
    shape factors are computed once for all channels, those of the view once per pixel (``view``:
    :func:`rho_view` at ``cos_o``): the same values to the last bit."""
    nc = params.shape[0]
    if not shared or cos_i <= 0.0 or cos_o <= 0.0:
        for c in range(nc):
            out[c] = rho_channel(kind, params[c], cos_i, cos_o, cos_io)
        return
    if kind == KIND_CONDUCTOR:
        lobe, cos_d = ggx_lobe_given(cos_i, cos_o, cos_io, params[0, 3], view[5])
        for c in range(nc):
            out[c] = _conductor_combine(params[c], lobe, cos_d)
        return
    retro, t, lobe, m, fres, sheen = _layered_terms(params[0], cos_i, cos_o, cos_io, view)
    for c in range(nc):
        out[c] = _layered_combine(params[c], retro, t, lobe, m, fres, sheen)


@numba.njit(cache=True, fastmath=False, parallel=True)
def rho_from_cosines(kind: int, params: np.ndarray, cos_i: np.ndarray, cos_o: np.ndarray, cos_io: np.ndarray) -> np.ndarray:
    """Vectorised :func:`rho_channel`: cosines (N,), ``params`` (C, NUM_PARAMS) -> rho (N, C)."""
    n = cos_i.shape[0]
    nc = params.shape[0]
    out = np.empty((n, nc))
    for i in numba.prange(n):
        for c in range(nc):
            out[i, c] = rho_channel(kind, params[c], cos_i[i], cos_o[i], cos_io[i])
    return out
