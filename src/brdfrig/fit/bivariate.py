"""The ``bivariate`` model: a data-driven isotropic BRDF tabulated in ``(theta_h, theta_d)`` that one image determines.

Model (after Romeiro, Vasilyev & Zickler 2008, "Passive reflectometry"; Romeiro & Zickler 2010): per
colour channel ``c`` two tables over Rusinkiewicz's half-angle ``theta_h`` (between the normal and the
half vector ``h = (wi + wo) / |wi + wo|``) and difference angle ``theta_d`` (between ``wi`` and ``h``),
joined over the difference azimuth ``phi_d`` (of ``wi`` about ``h``, from the plane of ``n`` and ``h``)::

    rho_c = P_c(theta_h, theta_d) cos^2 phi_d + Q_c(theta_h, theta_d) sin^2 phi_d,
    P_c = sum_{a, b} p_c[a, b] hat_a(u) hat_b(t),   Q_c likewise with q_c,
    u = sqrt(theta_h / (pi/2)) (nh - 1),   t = theta_d / (pi/2) (nd - 1)

``P`` (``table``) is the BRDF with the light in the plane of ``n`` and ``h``, ``Q`` (``cross``) across it;
``cos^2`` and ``sin^2`` are the lowest terms isotropy and reciprocity allow (``rho`` is even in ``phi_d``
and has period ``pi``), and ``P, Q >= 0`` make ``rho >= 0`` everywhere.  ``(P + Q) / 2`` is the mean over
``phi_d``: Romeiro's bivariate table.  Piecewise-linear hats on the integer nodes of ``u`` and ``t``:
``theta_h`` nodes are sqrt-spaced like MERL's (``(a / (nh - 1))^2 * 90`` degrees; at ``nh = 24`` the first
nodes are at 0.17, 0.68, 1.5 degrees: fine near the specular peak), ``theta_d`` nodes uniform.  In cosines
(isotropy): ``cos theta_d = sqrt((1 + wi.wo) / 2)`` and ``cos theta_h = (cos_i + cos_o) / (2 cos theta_d)``.

The rendered sphere is LINEAR in the node values ``x = [p, q]`` (``2 K``, ``K = nh nd``): pixel ``n``
(view ``v = (0, 0, 1)``) has the design row ``A[n, (a, b)] = sum_j L_jc dOmega_j cos_i cos^2(phi_d,j)
hat_a(u_j) hat_b(t_j)`` for ``p`` (``sin^2`` for ``q``) over the quadrature samples ``j`` of the lighting.
Per channel the fit solves::

    min_x ||W^(1/2) (A x - y)||^2 + lam x^T G x,   x >= 0,   (optionally) p[a, b] >= p[a + 1, b], q likewise

with the regulariser ``G`` (:func:`regulariser`): second differences ``D`` of the mean ``(p + q) / 2``
along both grid axes (in node index: the sqrt spacing lets a sharp peak stay smooth in ``u``; the
``theta_d`` rows weighted :data:`D_WEIGHT`), those of the ``phi_d`` term ``(p - q) / 2``
(:data:`PHI_SMOOTHING`), and a ridge on that term (:data:`PHI_RIDGE`; :data:`PHI_PIN` where ``theta_h`` or
``theta_d`` is 0 and ``phi_d`` is undefined).  Monotone decrease in ``theta_h`` is a reparametrisation,
``p[a, b] = sum_{a' >= a} z[a', b]`` with ``z >= 0`` (non-negative decrements: non-negativity follows;
``q`` likewise), solved as non-negative least squares on the regularised normal equations
(:func:`brdfrig.fit.lsq.nnls_normal`).

Why the ``phi_d`` term: a ``phi_d``-free table cannot reproduce the parts of a real material's image that
depend on ``phi_d`` (grazing light across the plane of incidence); fitted to them, it bends its peak rows
and relights badly.  Measured in docs/DESIGN.md (History).

Steps (:func:`fit_bivariate`):

- pixels: a subsample of at most ``max_pixels`` fit pixels plus a disjoint quarter as many check
  pixels (:func:`brdfrig.fit.microfacet._subsample`), streamed through the design in blocks of
  :data:`BLOCK_PIXELS`; each block updates a per-channel QR factor ``R`` (``2K x 2K``) of the
  weighted design and ``Q^T y``;
- smoothness ``lam``: ``lam_rel`` times the ratio of the data's and ``D^T D``'s traces for a
  ``phi_d``-free table (``p = q``), with ``lam_rel`` on a log grid
  (:data:`LAMBDA_GRID`); per channel, the unconstrained Tikhonov solution's weighted error on
  the check pixels picks ``lam_rel`` (floored at :data:`LAMBDA_MIN`);
- prior (optional, the ``bivariate+prior`` model): the regulariser applies to ``x - x0`` with ``x0``
  another fit's node values (:func:`project_to_nodes`), ``lam_rel`` from
  :data:`PRIOR_LAMBDA_GRID`: the nodes the image observes follow the data, the others the prior;
- reference prior (optional, the ``bivariate+measured`` model): ``x0`` is instead, per channel, the
  non-negative combination of measured materials' tables (:mod:`brdfrig.fit.references`) that best
  reproduces the pixels (:func:`_reference_prior`), at the fixed :data:`REFERENCE_LAMBDA`;
- constraints: the non-negative and the monotone (+ non-negative) solutions at that ``lam``;
  the monotone one is kept unless the check pixels prefer the other by more than
  :data:`MONOTONE_MAX_LOSS` (summed over channels: "where the data support it");
- identifiability: node ``(a, b)`` is *observed* in channel ``c`` when its data weight
  ``diag(R^T R)`` exceeds the regulariser's there, ``lam diag(G)`` (both summed over ``p`` and ``q``); the other nodes are
  filled by the regulariser (smooth continuation of the observed ones).  Reported per node.

Grazing ``theta_d``: the design weights of nodes near 90 degrees vanish with ``cos_i``; there the
second differences continue the table linearly and the constraints keep it non-negative (and
non-increasing in ``theta_h``); values are finite everywhere.

Measured (one scene, 96 px sphere, fit under grace 128 x 64, relit under ennis 128 x 64, noise-free,
relative RMS; defaults; all 59 measured materials): median 8.6%, 90th percentile 28.3% (``bivariate+prior``
7.7% / 19.3%; ``microfacet`` 10.5% / 31.4%); rgl/acrylic_felt_white 1.6%, rgl/paper_blue 6.0%,
rgl/satin_blue 6.9%, rgl/vch_silk_blue 6.8%.  One image leaves the table ill-determined where the lighting
is dim: with the smoothness at the check pixels' free choice (``lam_rel`` ~ 1e-6) a felt reproduced its own
image to 0.9% and relit at 65-135% (hence :data:`LAMBDA_MIN`).
"""

from __future__ import annotations

import math
import time

import numba
import numpy as np
from scipy.linalg import cho_factor, cho_solve
from tqdm import tqdm

from brdfrig.fit.brdf import register_model
from brdfrig.fit.lsq import nnls_normal
from brdfrig.fit.memo import RENDERS, RenderMemo
from brdfrig.fit.measured import _local_angles_to_dirs, rusinkiewicz_coordinates, rusinkiewicz_directions
from brdfrig.fit.metrics import relative_spread
from brdfrig.fit.microfacet import _check_scenes, _subsample
from brdfrig.fit.quadrature import LobeQuadrature, lobe_quadrature, lobe_samples
from brdfrig.fit.scene import Environment, Scene, content_digest

__all__ = ["BivariateBRDF", "fit_bivariate", "predict_tables", "project_to_nodes", "tables_spread", "DEFAULT_NH",
           "DEFAULT_ND", "RESAMPLES"]

DEFAULT_NH = 24
"""Nodes in ``theta_h`` (sqrt-spaced, 0..90 degrees)."""
DEFAULT_ND = 8
"""Nodes in ``theta_d`` (uniform, 0..90 degrees)."""
DEFAULT_MAX_PIXELS = 2000
FIT_CONE_DEG = 10.0
FIT_SUBDIV = 8
"""Sharp-lobe quadrature of the fit's design: cells within ``FIT_CONE_DEG`` of each mirror direction split
``FIT_SUBDIV`` x ``FIT_SUBDIV`` (relighting, :meth:`BivariateBRDF.predict`, uses the quadrature's defaults)."""
BLOCK_PIXELS = 512
"""Pixels per streamed design block (memory: ``BLOCK_PIXELS x C x nh nd`` doubles)."""
LAMBDA_GRID = tuple(10.0 ** np.arange(-7.0, 0.5, 0.5))
"""Candidate relative smoothness weights ``lam_rel`` (``lam = lam_rel ||R||_F^2 / ||D||_F^2``)."""
LAMBDA_MIN = 0.3
"""Smallest ``lam_rel`` the check pixels may choose.  Check pixels of the fit's own lighting always prefer
less smoothing (they cannot see the directions that lighting leaves weakly excited); relighting wants much
more.  Measured on rgl/acrylic_felt_green (96 px, grace -> ennis, 1500 px, 24 x 8 nodes, ``D_WEIGHT`` 1):
relighting error 65% / 52% / 34% / 18% / 14% at ``lam_rel`` = 1e-4 / 1e-3 / 1e-2 / 0.1 / 1, own-image
residual 0.9% -> 1.8%; with ``D_WEIGHT`` 10 at 0.1 / 0.3 / 1: felt 14.7% / 12.4% / 17.8%, rgl/paper_blue
14.9% / 11.3% / 11.5%, rgl/irid_flake_paint1 22.5% / 22.5% / 25.8%."""
PRIOR_LAMBDA_GRID = tuple(10.0 ** np.arange(-0.5, 3.0, 0.5))
"""Candidate ``lam_rel`` with a prior (smoothness of the deviation from it; the check pixels choose), from the
floor of the plain fit up.  Measured (96 px, grace -> ennis, ``bivariate+prior`` inside ``fit_brdf``), grid from
``lam_rel`` 3 / 0.3 / 0.03: rgl/vch_silk_blue 24.7% / 19.9% / 20.0%, rgl/acrylic_felt_white 6.6 / 3.1 / 5.9,
rgl/chm_orange 6.8 / 6.6 / 7.2, rgl/cc_amber_citrine 14.3 in all three."""
REFERENCE_LAMBDA = 3.0
"""``lam_rel`` of the smoothness of the table's deviation from the reference prior (``bivariate+measured``): fixed,
because the check pixels of the fit's own lighting always prefer the smallest (they cannot see what the lighting
leaves weakly excited).  Measured in docs/DESIGN.md (History: reference tables)."""
REFERENCE_RIDGE_GRID = tuple(10.0 ** np.arange(-6.0, 0.5, 1.0))
"""Candidate ridges ``mu`` of the reference weights (columns of unit rendered energy; the check pixels choose)."""
REFERENCE_REPORT_TOP = 5
"""References listed per channel in the fit report."""
RESAMPLES = 12
"""Bootstrap resamples of the reference materials (``resamples=`` of :func:`fit_bivariate`, one-image fits in
:func:`brdfrig.fit.fitter.fit_brdf`): about 0.5 s each for 58 references at their 32 x 12 nodes."""
RESAMPLE_SEED = 0
"""Seed of the materials drawn for each resample."""
PHI_SMOOTHING = 1.0
"""Weight of the second differences of the ``cos 2 phi_d`` term, ``(table - cross) / 2``, relative to those of the mean."""
PHI_RIDGE = 1e-2
"""Weight of ``||(table - cross) / 2||^2`` (relative to the mean diagonal of ``D^T D``): the two tables part only as far as
the pixels ask."""
PHI_PIN = 1e3
"""The same weight at the nodes of ``theta_h = 0`` and ``theta_d = 0``, where ``phi_d`` is undefined."""
PRIOR_PHI_SAMPLES = 36
"""``phi_d`` samples of :func:`project_to_nodes`."""
MONOTONE_MAX_LOSS = 0.02
"""The monotone table is kept unless dropping monotonicity lowers the check pixels' relative RMS error by more."""
DETERMINED_MIN_OBSERVED = 0.25
"""``report["determined"]``: at least this fraction of the nodes is observed (in every channel)."""
D_WEIGHT = 10.0
"""Weight of the ``theta_d`` second differences relative to the ``theta_h`` ones (rows scaled, so 100x in the
objective): a row of constant ``theta_d`` is probed only by the lights at ``2 theta_d`` from the view, so rows the
fit lighting leaves dim are carried over from their neighbours.  Measured (96 px, grace -> ennis, ``lam_rel`` 0.1):
relighting error 1 -> 10: rgl/acrylic_felt_green 17.5% -> 14.6%, rgl/paper_blue 17.7% -> 14.9%,
rgl/irid_flake_paint1 39.5% -> 22.5%."""
HALF_PI = 0.5 * math.pi
DESIGN_CACHE_BYTES = 1 << 30
"""Bytes of designs :func:`predict_tables` keeps per process (a 96 px sphere's 6668 pixels: 61 MB at 24 x 8
nodes, 123 MB at 32 x 12)."""
_DESIGNS = RenderMemo(DESIGN_CACHE_BYTES, second_sight=True)
"""The relight designs of :func:`predict_tables`, keyed by (lighting and pixels, grid)."""


@numba.njit(cache=True, fastmath=False)
def _hd_fractions(cos_i: float, cos_o: float, cos_io: float) -> tuple[float, float]:
    """``(sqrt(theta_h / (pi/2)), theta_d / (pi/2))``, each in [0, 1], of light and view at these cosines."""
    cd = math.sqrt(max(0.5 * (1.0 + cos_io), 0.0))
    if cd > 1e-12:
        ch = min(max((cos_i + cos_o) / (2.0 * cd), 0.0), 1.0)
    else:
        ch = 0.0
    return math.sqrt(math.acos(ch) / HALF_PI), math.acos(min(cd, 1.0)) / HALF_PI


@numba.njit(cache=True, fastmath=False)
def _cell(su: float, st: float, nh: int, nd: int) -> tuple[int, float, int, float]:
    """Lower node indices and fractions ``(a, fu, b, ft)`` of the bilinear cell holding :func:`_hd_fractions` ``(su, st)``."""
    u = su * (nh - 1)
    t = st * (nd - 1)
    a = min(int(u), nh - 2)
    b = min(int(t), nd - 2)
    return a, min(u - a, 1.0), b, min(t - b, 1.0)


@numba.njit(cache=True, fastmath=False)
def _cos2_phi_d(nx: float, ny: float, nz: float, wx: float, wy: float, wz: float) -> float:
    """``cos^2 phi_d`` of light ``w`` at normal ``n`` seen from ``v = (0, 0, 1)`` (0.5 where ``phi_d`` is undefined).

    ``phi_d`` is the azimuth of ``w`` about the half vector ``h`` from the plane of ``n`` and ``h``.  Its sine
    is ``w . b / sin theta_d`` with ``b = n x h / |n x h|``; since ``h`` is along ``u = w + v``,
    ``w . (n x u) = w . (n x v)``, ``|n x u|^2 = |u|^2 - (n . u)^2`` and ``sin^2 theta_d = (1 - w . v) / 2``.
    """
    sin2_d = 0.5 * (1.0 - wz)
    cross2 = 2.0 * (1.0 + wz) - (nx * wx + ny * wy + nz * wz + nz) ** 2
    if sin2_d < 1e-12 or cross2 < 1e-12:
        return 0.5
    t = wx * ny - wy * nx
    return min(max(1.0 - t * t / (cross2 * sin2_d), 0.0), 1.0)


@numba.njit(cache=True, fastmath=False, parallel=True)
def _design_kernel(normals: np.ndarray, q: LobeQuadrature, nh: int, nd: int) -> np.ndarray:
    """Design block (N, 2 nh nd, C): node ``a * nd + b`` of the in-plane table, then of the cross table.

    Quadrature samples per pixel from :func:`brdfrig.fit.quadrature.lobe_samples` (view ``(0, 0, 1)``).
    """
    n_pix = normals.shape[0]
    nc = q.wrad.shape[1]
    nk = nh * nd
    out = np.zeros((n_pix, 2 * nk, nc))
    for i in numba.prange(n_pix):
        nx, ny, nz = normals[i, 0], normals[i, 1], normals[i, 2]
        if nz <= 0.0:
            continue
        dirs, wrad = lobe_samples(q, nx, ny, nz, True)
        row = out[i]
        for j in range(dirs.shape[0]):
            cos_i = nx * dirs[j, 0] + ny * dirs[j, 1] + nz * dirs[j, 2]
            su, st = _hd_fractions(cos_i, nz, dirs[j, 2])
            a, fu, b, ft = _cell(su, st, nh, nd)
            c2 = _cos2_phi_d(nx, ny, nz, dirs[j, 0], dirs[j, 1], dirs[j, 2])
            k = a * nd + b
            w00 = (1.0 - fu) * (1.0 - ft) * cos_i
            w01 = (1.0 - fu) * ft * cos_i
            w10 = fu * (1.0 - ft) * cos_i
            w11 = fu * ft * cos_i
            kq = k + nk
            for c in range(nc):
                lp = wrad[j, c] * c2
                lq = wrad[j, c] - lp
                row[k, c] += lp * w00
                row[k + 1, c] += lp * w01
                row[k + nd, c] += lp * w10
                row[k + nd + 1, c] += lp * w11
                row[kq, c] += lq * w00
                row[kq + 1, c] += lq * w01
                row[kq + nd, c] += lq * w10
                row[kq + nd + 1, c] += lq * w11
    return out


@numba.njit(cache=True, fastmath=False, parallel=True)
def _render_kernel(normals: np.ndarray, q: LobeQuadrature, values: np.ndarray, grids: np.ndarray, tc: int) -> np.ndarray:
    """Radiance (M, N, C) of M tables of ``tc`` channels packed in ``values``: table ``m`` is
    ``values[o:o + 2 tc nh nd]`` laid out as (2, tc, nh, nd) (in-plane, cross) with ``(o, nh, nd) = grids[m]``
    (grids may differ); channel ``c`` of the lighting reads table channel ``c mod tc`` (stacked lightings).  Same
    quadrature as :func:`_design_kernel`: the samples and their angles are computed once for all tables.  One
    flat array, not a list of arrays: per light sample, a list item or an array view costs more than the lookup
    itself."""
    n_pix, n_tab = normals.shape[0], grids.shape[0]
    nc = q.wrad.shape[1]
    out = np.zeros((n_tab, n_pix, nc))
    for i in numba.prange(n_pix):
        nx, ny, nz = normals[i, 0], normals[i, 1], normals[i, 2]
        if nz <= 0.0:
            continue
        dirs, wrad = lobe_samples(q, nx, ny, nz, True)
        for j in range(dirs.shape[0]):
            cos_i = nx * dirs[j, 0] + ny * dirs[j, 1] + nz * dirs[j, 2]
            su, st = _hd_fractions(cos_i, nz, dirs[j, 2])
            c2 = _cos2_phi_d(nx, ny, nz, dirs[j, 0], dirs[j, 1], dirs[j, 2])
            for m in range(n_tab):
                o, nh, nd = grids[m, 0], grids[m, 1], grids[m, 2]
                a, fu, b, ft = _cell(su, st, nh, nd)
                w00 = (1.0 - fu) * (1.0 - ft)
                w01 = (1.0 - fu) * ft
                w10 = fu * (1.0 - ft)
                w11 = fu * ft
                plane = tc * nh * nd
                for c in range(nc):
                    p = o + ((c % tc) * nh + a) * nd + b
                    x = p + plane
                    rho_p = w00 * values[p] + w01 * values[p + 1] + w10 * values[p + nd] + w11 * values[p + nd + 1]
                    rho_q = w00 * values[x] + w01 * values[x + 1] + w10 * values[x + nd] + w11 * values[x + nd + 1]
                    out[m, i, c] += wrad[j, c] * (rho_q + c2 * (rho_p - rho_q)) * cos_i
    return out


def _normals(normals) -> np.ndarray:
    return np.ascontiguousarray(np.asarray(normals, dtype=np.float64).reshape(-1, 3))


def _design(env: Environment, q: LobeQuadrature, quad: dict, normals: np.ndarray, nh: int, nd: int) -> np.ndarray:
    """Design rows (N, 2 nh nd, C: the in-plane then the cross nodes) of sphere points with unit ``normals`` under
    ``q = lobe_quadrature(env, **quad)``, kept in :data:`brdfrig.fit.memo.RENDERS` (read-only; the tables of one
    ``auto`` fit share their pixels)."""
    normals = _normals(normals)
    key = ("bivariate design", content_digest(normals, env), tuple(sorted(quad.items())), nh, nd)
    return RENDERS.get(key, lambda: _design_kernel(normals, q, nh, nd))


def theta_h_nodes(nh: int) -> np.ndarray:
    """``theta_h`` of the nodes (radians): ``(a / (nh - 1))^2 * pi / 2``."""
    return (np.arange(nh) / (nh - 1)) ** 2 * HALF_PI


def theta_d_nodes(nd: int) -> np.ndarray:
    """``theta_d`` of the nodes (radians): ``b / (nd - 1) * pi / 2``."""
    return np.arange(nd) / (nd - 1) * HALF_PI


@register_model("bivariate")
class BivariateBRDF:
    """Isotropic BRDF tabulated on (theta_h, theta_d) nodes, bilinear in ``(sqrt theta_h, theta_d)``, with its
    ``phi_d`` dependence as ``rho = table cos^2 phi_d + cross sin^2 phi_d`` (module docstring).

    Implements :class:`brdfrig.fit.brdf.FittedBRDF`.

    Parameters
    ----------
    table : (C, nh, nd) array_like
        Node values of ``rho`` (1/sr) with the light in the plane of the normal and the half vector
        (``phi_d = 0``), finite and non-negative; ``nh, nd >= 2``.
    cross : (C, nh, nd) array_like, optional
        The same across that plane (``phi_d = 90`` degrees); default ``table`` (no ``phi_d`` dependence).
    """

    model = "bivariate"

    def __init__(self, table, cross=None) -> None:
        t = np.asarray(table, dtype=np.float64)
        x = t if cross is None else np.asarray(cross, dtype=np.float64)
        if t.ndim != 3 or t.shape[1] < 2 or t.shape[2] < 2 or t.shape[0] < 1:
            raise ValueError(f"bivariate table must have shape (C, nh >= 2, nd >= 2), got {t.shape}")
        if x.shape != t.shape:
            raise ValueError(f"bivariate cross table has shape {x.shape}, the table {t.shape}")
        for name, v in (("table", t), ("cross table", x)):
            if not np.all(np.isfinite(v)):
                raise ValueError(f"bivariate {name} has non-finite values")
            if np.any(v < 0):
                raise ValueError(f"bivariate {name} has {int(np.sum(v < 0))} negative value(s)")
        self.tables = np.ascontiguousarray(np.stack([t, x]))

    @property
    def table(self) -> np.ndarray:
        """In-plane node values (C, nh, nd) (1/sr)."""
        return self.tables[0]

    @property
    def cross(self) -> np.ndarray:
        """Cross-plane node values (C, nh, nd) (1/sr)."""
        return self.tables[1]

    @property
    def channels(self) -> int:
        return self.tables.shape[1]

    def rho_hd(self, theta_h, theta_d, phi_d=None) -> np.ndarray:
        """``rho`` (1/sr) at half and difference angles (radians, clipped to [0, pi/2]); shape ``broadcast + (C,)``.

        ``phi_d`` None: the mean over ``phi_d``, ``(table + cross) / 2``.
        """
        th, td = np.broadcast_arrays(*(np.clip(np.asarray(a, dtype=np.float64), 0.0, HALF_PI) for a in (theta_h, theta_d)))
        _, _, nh, nd = self.tables.shape
        u = np.sqrt(th / HALF_PI) * (nh - 1)
        t = td / HALF_PI * (nd - 1)
        a = np.minimum(u.astype(np.int64), nh - 2)
        b = np.minimum(t.astype(np.int64), nd - 2)
        fu, ft = (u - a)[..., None], (t - b)[..., None]

        def lookup(table):
            tab = np.moveaxis(table, 0, -1)  # (nh, nd, C)
            return (1 - fu) * ((1 - ft) * tab[a, b] + ft * tab[a, b + 1]) + fu * ((1 - ft) * tab[a + 1, b] + ft * tab[a + 1, b + 1])

        if phi_d is None:
            return lookup(0.5 * (self.tables[0] + self.tables[1]))
        c2 = (np.cos(np.asarray(phi_d, dtype=np.float64)) ** 2)[..., None]
        return c2 * lookup(self.tables[0]) + (1.0 - c2) * lookup(self.tables[1])

    def evaluate(self, theta_i, theta_o, delta_phi) -> np.ndarray:
        """BRDF ``rho`` (1/sr), shape ``broadcast(theta_i, theta_o, delta_phi).shape + (C,)``; 0 below the horizon."""
        wi, wo, shape = _local_angles_to_dirs(theta_i, theta_o, delta_phi)
        th, td, pd = rusinkiewicz_coordinates(wi, wo, np.array([0.0, 0.0, 1.0]))
        out = self.rho_hd(th, td, pd)
        below = (wi[:, 2] < -1e-12) | (wo[:, 2] < -1e-12)
        return np.where(below[:, None], 0.0, out).reshape(shape + (self.channels,))

    def predict(self, env: Environment, normals: np.ndarray) -> np.ndarray:
        """Radiance (N, C) seen from ``v = (0, 0, 1)``: the fit's own quadrature of the rendering integral
        (:func:`predict_tables`)."""
        return predict_tables([self], env, normals)[0]

    def to_dict(self) -> dict:
        return {"model": self.model, "nh": int(self.tables.shape[2]), "nd": int(self.tables.shape[3]),
                "table": self.table.tolist(), "cross": self.cross.tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> "BivariateBRDF":
        keys = ("table", "cross") if "cross" in d else ("table",)
        tables = [np.asarray(d[key], dtype=np.float64) for key in keys]
        for key, table in zip(keys, tables):
            if table.ndim != 3 or table.shape[1:] != (int(d["nh"]), int(d["nd"])):
                raise ValueError(f"bivariate {key!r} has shape {table.shape}, expected (C, nh={d['nh']}, nd={d['nd']})")
        return cls(*tables)


def predict_tables(brdfs, env: Environment, normals) -> list[np.ndarray]:
    """Radiance (N, C) of each :class:`BivariateBRDF` in ``brdfs`` at unit ``normals`` under ``env``, seen from
    ``v = (0, 0, 1)``, by the quadrature's defaults.  Under stacked lightings (:func:`~brdfrig.fit.scene.stack_lightings`)
    channel ``c`` is table channel ``c mod C``: one pass for all of them, each lighting's channels the same to the
    last bit as its own render.

    One pass over the quadrature samples serves every table (their grids may differ): the samples and their
    angles and one table cost about 1 ms per pixel on a 128 x 64 map, each further table about a fifth of that.
    The same lighting and pixels seen again with a grid (e.g. every material of a benchmark relit under one
    probe) are predicted from that grid's design, the fit's design under this quadrature: built on the second
    sight at the cost of one pass, kept (:data:`DESIGN_CACHE_BYTES`), then one matrix product per table.  The
    two ways agree to rounding (about 1e-14 relative).
    """
    brdfs = list(brdfs)
    for b in brdfs:
        env.check_channels(b.channels)
    if not brdfs:
        return []
    tc = brdfs[0].channels
    normals = _normals(normals)
    q = lobe_quadrature(env)
    where = content_digest(normals, env)
    out: list = [None] * len(brdfs)
    passes = []
    for grid in dict.fromkeys(b.tables.shape[2:] for b in brdfs):
        idx = [i for i, b in enumerate(brdfs) if b.tables.shape[2:] == grid]
        design = _known_design((where, grid), q, normals)
        if design is None:
            passes += idx
            continue
        nodes = np.stack([brdfs[i].tables.reshape(2, tc, -1).transpose(0, 2, 1).reshape(-1, tc) for i in idx])
        rad = np.stack([design[:, :, c] @ nodes[:, :, c % tc].T for c in range(env.channels)], axis=2)
        for i, r in zip(idx, rad.transpose(1, 0, 2)):
            out[i] = r
    if passes:
        values = np.concatenate([brdfs[i].tables.ravel() for i in passes])
        sizes = np.array([brdfs[i].tables.size for i in passes])
        grids = np.array([(o, *brdfs[i].tables.shape[2:]) for o, i in zip(np.cumsum(sizes) - sizes, passes)], dtype=np.int64)
        for i, r in zip(passes, _render_kernel(normals, q, values, grids, tc)):
            out[i] = r
    return out


def _known_design(key: tuple, q: LobeQuadrature, normals: np.ndarray) -> np.ndarray | None:
    """The design (N, 2 nh nd, C) of ``key = (content digest, (nh, nd))`` if seen before (built now on the second
    sight, kept in :data:`_DESIGNS`); None on the first, and for a design larger than the whole budget (it would
    be rebuilt at every call)."""
    nh, nd = key[1]
    if len(normals) * 2 * nh * nd * q.wrad.shape[1] * 8 > _DESIGNS.max_bytes or _DESIGNS.first_sight(key):
        return None
    return _DESIGNS.get(key, lambda: _design_kernel(normals, q, nh, nd))


def second_differences(nh: int, nd: int, d_weight: float = 1.0) -> np.ndarray:
    """Second-difference operator (rows, nh * nd) along ``theta_h`` then along ``theta_d`` (node index space).

    The ``theta_d`` rows are scaled by ``d_weight``.
    """
    rows = []
    for a in range(1, nh - 1):
        for b in range(nd):
            rows.append(((a - 1) * nd + b, a * nd + b, (a + 1) * nd + b))
    for a in range(nh):
        for b in range(1, nd - 1):
            rows.append((a * nd + b - 1, a * nd + b, a * nd + b + 1))
    d = np.zeros((len(rows), nh * nd))
    idx = np.arange(len(rows))
    cols = np.array(rows, dtype=np.int64).reshape(-1, 3)
    d[idx, cols[:, 0]] = 1.0
    d[idx, cols[:, 1]] = -2.0
    d[idx, cols[:, 2]] = 1.0
    d[(nh - 2) * nd :] *= d_weight
    return d


def cumulative_operator(nh: int, nd: int) -> np.ndarray:
    """``T`` (2 nh nd, 2 nh nd) with ``x = T z``: ``x[a, b] = sum_{a' >= a} z[a', b]`` in each of the two tables
    (monotone reparametrisation)."""
    upper = np.triu(np.ones((nh, nh)))
    return np.kron(np.eye(2), np.kron(upper, np.eye(nd)))


class _Channel:
    """One channel's regularised problem: ``G = R^T R``, ``g = R^T Q^T y``, data norm, the check pixels' rows.

    ``reg`` (2K, 2K): the regulariser (:func:`regulariser`), applied to ``x - prior`` with ``prior`` (2K,) the
    node values the table is pulled toward (:meth:`pull_toward`; zeros until then: plain smoothness).  ``lam = lam_rel * scale`` with ``scale``
    the ratio of the data's and ``D^T D``'s traces for a table without ``phi_d`` dependence (``dtd_trace``:
    the trace of ``D^T D``), so ``lam_rel`` weighs the mean table's smoothness as in a ``phi_d``-free fit.
    """

    def __init__(self, r: np.ndarray, z: np.ndarray, yy: float, check_rows: np.ndarray, check_y: np.ndarray,
                 reg: np.ndarray, dtd_trace: float) -> None:
        self.g_mat = r.T @ r
        self.g = r.T @ z
        self.yy = yy
        self.check_rows, self.check_y = check_rows, check_y
        self.reg = reg
        self.reg_prior = np.zeros(len(self.g))
        k = len(self.g) // 2
        mean_trace = np.trace(self.g_mat[:k, :k]) + np.trace(self.g_mat[k:, k:]) + 2.0 * np.trace(self.g_mat[:k, k:])
        self.scale = float(mean_trace / max(dtd_trace, 1e-300))

    def pull_toward(self, prior: np.ndarray) -> None:
        """Apply the regulariser to ``x - prior`` (node values (2K,)) instead of ``x``."""
        self.reg_prior = self.reg @ prior

    def hessian(self, lam_rel: float) -> np.ndarray:
        """Regularised normal matrix ``R^T R + lam reg`` (+ a 1e-12 ridge keeping it positive definite)."""
        lam = lam_rel * self.scale
        return self.g_mat + lam * self.reg + 1e-12 * max(self.scale, 1e-300) * np.eye(len(self.g))

    def rhs(self, lam_rel: float) -> np.ndarray:
        """Right-hand side of the regularised normal equations, ``g + lam reg prior``."""
        return self.g + lam_rel * self.scale * self.reg_prior

    def check_error(self, x: np.ndarray) -> float:
        """Weighted squared error of ``x`` on the check pixels."""
        return float(np.sum((self.check_rows @ x - self.check_y) ** 2))

    def tikhonov(self, lam_rel: float) -> np.ndarray:
        return cho_solve(cho_factor(self.hessian(lam_rel)), self.rhs(lam_rel))

    def constrained(self, lam_rel: float, transform: np.ndarray | None) -> np.ndarray:
        """Node values minimising the regularised objective with ``x = T z, z >= 0`` (``transform`` T; None: ``x >= 0``):
        :func:`~brdfrig.fit.lsq.nnls_normal` of ``T^T H T z = T^T b``."""
        hess, rhs = self.hessian(lam_rel), self.rhs(lam_rel)
        if transform is None:
            return nnls_normal(hess, rhs)
        return transform @ nnls_normal(transform.T @ hess @ transform, transform.T @ rhs)

    def residual(self, x: np.ndarray) -> float:
        """Weighted squared residual of ``x`` on the fit pixels."""
        return max(float(x @ self.g_mat @ x - 2.0 * self.g @ x + self.yy), 0.0)


def _stream(scenes: list[Scene], picks: list[np.ndarray], nh: int, nd: int, channels: int, quad: dict, bar) -> tuple:
    """Fold the fit pixels into per-channel QR factors, block by block.

    Returns (StreamedQR, ``sum w y^2`` per channel (C,)).
    """
    from brdfrig.fit.solvers import StreamedQR

    qr = StreamedQR(2 * nh * nd, channels)
    yy = np.zeros(channels)
    for s, p in zip(scenes, picks):
        q = lobe_quadrature(s.env, **quad)
        for start in range(0, len(p), BLOCK_PIXELS):
            rows = p[start : start + BLOCK_PIXELS]
            w = np.asarray(s.weights, dtype=np.float64)[rows]
            y = np.asarray(s.radiance, dtype=np.float64)[rows]
            qr.add(_design(s.env, q, quad, np.asarray(s.normals)[rows], nh, nd), y, w)
            yy += np.sum(w[:, None] * y**2, axis=0)
            bar.update(len(rows))
    return qr, yy


def _check_system(scenes: list[Scene], picks: list[np.ndarray], nh: int, nd: int, quad: dict) -> tuple[np.ndarray, np.ndarray]:
    """Weighted check-pixel design (Nc, K, C) and target (Nc, C)."""
    blocks, targets = [], []
    for s, p in zip(scenes, picks):
        if len(p) == 0:
            continue
        sw = np.sqrt(np.asarray(s.weights, dtype=np.float64)[p])
        design = _design(s.env, lobe_quadrature(s.env, **quad), quad, np.asarray(s.normals)[p], nh, nd)
        blocks.append(design * sw[:, None, None])
        targets.append(np.asarray(s.radiance, dtype=np.float64)[p] * sw[:, None])
    if not blocks:
        return np.zeros((0, 2 * nh * nd, scenes[0].radiance.shape[1])), np.zeros((0, scenes[0].radiance.shape[1]))
    return np.concatenate(blocks), np.concatenate(targets)


def _choose_lambda(ch: _Channel, grid: tuple[float, ...]) -> tuple[float, list[float]]:
    """``lam_rel`` of ``grid`` whose Tikhonov solution best predicts the check pixels."""
    if len(ch.check_y) == 0:
        return grid[0], []
    errors = [ch.check_error(ch.tikhonov(lam)) for lam in grid]
    return grid[int(np.argmin(errors))], errors


def project_to_nodes(brdf, nh: int, nd: int, phi_samples: int = PRIOR_PHI_SAMPLES) -> np.ndarray:
    """Node values (2, C, nh, nd) of any BRDF: in-plane and cross tables fitted to it over ``phi_d``.

    At each node's (theta_h, theta_d), ``brdf.evaluate(theta_i, theta_o, delta_phi)`` is sampled at
    ``phi_samples`` midpoints of [0, pi] (isotropy and reciprocity cover the rest), ``theta_d`` capped at
    89 degrees, and ``table cos^2 phi_d + cross sin^2 phi_d`` is fitted by least squares; directions within
    1e-3 of the horizon are left out.  A node whose samples leave the two apart (fewer than a quarter of
    them left) takes their mean for both, one with none left the values of the node below it in
    ``theta_h``.  Negative values are clipped to 0.
    """
    phi = (np.arange(phi_samples) + 0.5) / phi_samples * math.pi
    th, td, pd = np.meshgrid(theta_h_nodes(nh), np.minimum(theta_d_nodes(nd), math.radians(89.0)), phi, indexing="ij")
    wi, wo = rusinkiewicz_directions(th, td, pd)
    ok = (wi[..., 2] > 1e-3) & (wo[..., 2] > 1e-3)
    vals = np.zeros(th.shape + (brdf.channels,))
    dphi = np.arctan2(wo[..., 1], wo[..., 0]) - np.arctan2(wi[..., 1], wi[..., 0])
    vals[ok] = np.asarray(brdf.evaluate(np.arccos(wi[..., 2][ok]), np.arccos(wo[..., 2][ok]), dphi[ok]), dtype=np.float64)
    vals = np.nan_to_num(vals)
    count = ok.sum(axis=2)
    c2 = np.where(ok, np.cos(pd) ** 2, 0.0)
    s2 = np.where(ok, 1.0 - np.cos(pd) ** 2, 0.0)
    # normal equations of the two-term fit per node
    g11, g12, g22 = (c2 * c2).sum(2), (c2 * s2).sum(2), (s2 * s2).sum(2)
    r1, r2 = (c2[..., None] * vals).sum(2), (s2[..., None] * vals).sum(2)
    det = g11 * g22 - g12**2
    split = (count >= phi_samples // 4) & (det > 1e-9 * np.maximum(g11 + g22, 1e-300) ** 2)
    safe = np.where(split, det, 1.0)[..., None]
    mean = vals.sum(axis=2) / np.maximum(count, 1)[..., None]
    table = np.where(split[..., None], (g22[..., None] * r1 - g12[..., None] * r2) / safe, mean)
    cross = np.where(split[..., None], (g11[..., None] * r2 - g12[..., None] * r1) / safe, mean)
    for a in range(1, nh):
        empty = count[a] == 0
        table[a, empty], cross[a, empty] = table[a - 1, empty], cross[a - 1, empty]
    return np.ascontiguousarray(np.maximum(np.stack([np.moveaxis(table, -1, 0), np.moveaxis(cross, -1, 0)]), 0.0))


def _grid(nh: int | None, nd: int | None, max_pixels: int, prior, references) -> tuple[int, int]:
    """``(nh, nd)`` of a fit (default 24 x 8, or the references' grid), its options checked."""
    default = (DEFAULT_NH, DEFAULT_ND) if references is None else references.grid
    nh, nd = default[0] if nh is None else nh, default[1] if nd is None else nd
    if references is not None:
        if prior is not None:
            raise ValueError("a fit takes a prior or reference tables, not both")
        if references.grid != (nh, nd) or len(references) == 0:
            raise ValueError(f"reference tables on a {references.grid} grid ({len(references)} materials) cannot "
                             f"serve a {nh} x {nd} fit")
    if nh < 3 or nd < 3:
        raise ValueError(f"nh and nd must be >= 3, got nh={nh}, nd={nd}")
    if max_pixels < 1:
        raise ValueError(f"max_pixels must be >= 1, got {max_pixels}")
    if prior is not None and not hasattr(prior, "evaluate"):
        raise ValueError(f"prior must be a fitted BRDF with evaluate(), got {type(prior).__name__}")
    return nh, nd


def regulariser(dtd: np.ndarray, nd: int) -> np.ndarray:
    """Regulariser (2K, 2K) of the node values ``x = [table, cross]`` (``K = nh nd``; module docstring).

    With ``m = (table + cross) / 2`` (the mean over ``phi_d``) and ``r = (table - cross) / 2`` (its
    ``cos 2 phi_d`` term): ``||D m||^2 + PHI_SMOOTHING ||D r||^2 + PHI_RIDGE ||r||^2``, plus
    :data:`PHI_PIN` ``||r||^2`` on the nodes at ``theta_h = 0`` or ``theta_d = 0``, where ``phi_d`` is
    undefined (isotropy: ``r = 0`` there).  ``dtd``: ``D^T D`` (K, K) of :func:`second_differences`.
    """
    k = len(dtd)
    eye = np.eye(k)
    mean_op, diff_op = 0.5 * np.hstack([eye, eye]), 0.5 * np.hstack([eye, -eye])
    a, b = np.divmod(np.arange(k), nd)
    pin = np.where((a == 0) | (b == 0), PHI_PIN, 0.0) * (np.trace(dtd) / k)
    ridge = PHI_RIDGE * np.trace(dtd) / k + pin
    return mean_op.T @ dtd @ mean_op + diff_op.T @ (PHI_SMOOTHING * dtd + np.diag(ridge)) @ diff_op


def _problems(qr, yy: np.ndarray, check_rows: np.ndarray, check_y: np.ndarray, nh: int, nd: int):
    """The regulariser and the per-channel problems (:class:`_Channel`) of the streamed QR factors (no prior yet)."""
    channels = len(yy)
    diff = second_differences(nh, nd, D_WEIGHT)
    dtd = diff.T @ diff
    reg = regulariser(dtd, nd)
    return reg, [_Channel(qr.r[c], qr.z[c], float(yy[c]), check_rows[:, :, c], check_y[:, c], reg, float(np.trace(dtd)))
                 for c in range(channels)]


def _reference_prior(ch: _Channel, columns: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """The non-negative combination of reference ``columns`` (2K, M) that best reproduces one channel's pixels.

    Each column is scaled to unit rendered energy (``c^T G c = 1``; columns the pixels do not see are
    dropped), the weights ``w >= 0`` minimise ``||R (C w) - Q^T y||^2 + mu ||w||^2``
    (:func:`~brdfrig.fit.lsq.nnls_normal` on the normal equations), and the check pixels choose ``mu`` from
    :data:`REFERENCE_RIDGE_GRID`.  Returns the prior's node values (2K,), ``mu`` and the weights (M,) of the
    unit-energy columns (each column's share of the prior's rendered image; 0 for unseen columns).
    """
    energy = np.sqrt(np.maximum(np.einsum("km,km->m", ch.g_mat @ columns, columns), 0.0))
    seen = energy > 1e-12 * max(float(energy.max()), 1e-300)
    unit = columns[:, seen] / energy[seen]
    gram, rhs0 = unit.T @ ch.g_mat @ unit, unit.T @ ch.g
    best = None
    for mu in REFERENCE_RIDGE_GRID:
        w = nnls_normal(gram + mu * np.eye(len(rhs0)), rhs0)
        x = unit @ w
        err = ch.check_error(x) if len(ch.check_y) else 0.0
        if best is None or err < best[0]:
            best = (err, mu, x, w)
    weights = np.zeros(columns.shape[1])
    weights[seen] = best[3]
    return best[2], float(best[1]), weights


def _references_report(labels: list[tuple[str, int]], mus: list[float], weights: list[np.ndarray]) -> dict:
    """Report entry of the reference prior: per channel its ridge and the materials carrying most of its image
    (the unit-energy weights of :func:`_reference_prior`, summed over a material's channels)."""
    names = sorted({n for n, _ in labels})
    owner = np.array([names.index(n) for n, _ in labels])
    out = []
    for mu, w in zip(mus, weights):
        share = np.bincount(owner, w, minlength=len(names))
        share = share / max(float(share.sum()), 1e-300)
        top = np.argsort(share)[::-1][:REFERENCE_REPORT_TOP]
        out.append({"ridge": mu, "references": [{"name": names[k], "share": float(share[k])} for k in top if share[k] > 0]})
    return {"materials": len(names), "channels": out}


def _pull_toward_prior(problems: list[_Channel], prior, references, nh: int, nd: int) -> tuple[tuple[float, ...], str | None, dict]:
    """Point each channel's regulariser at its prior's node values; the ``lam_rel`` grid, the prior's name for
    the report and the report's ``references`` entry (no prior: the plain grid from :data:`LAMBDA_MIN`)."""
    if references is not None:
        columns, labels = references.columns()
        fits = [_reference_prior(ch, columns) for ch in problems]
        for ch, (x0, _, _) in zip(problems, fits):
            ch.pull_toward(x0)
        report = _references_report(labels, [f[1] for f in fits], [f[2] for f in fits])
        return (REFERENCE_LAMBDA,), "measured references", {"references": report}
    if prior is not None:
        x0 = np.moveaxis(project_to_nodes(prior, nh, nd), 0, 1).reshape(len(problems), -1)
        for ch, x in zip(problems, x0):
            ch.pull_toward(x)
        return PRIOR_LAMBDA_GRID, str(getattr(prior, "model", type(prior).__name__)), {}
    return tuple(lam for lam in LAMBDA_GRID if lam >= LAMBDA_MIN), None, {}


def _resample_references(problems: list[_Channel], lams: list[float], references, count: int) -> np.ndarray:
    """Tables (count, C, 2K) re-solved, at the chosen ``lam_rel``, with the reference prior refitted to a bootstrap
    resample of the reference materials (materials drawn with replacement, all of a material's columns together).

    Their spread is what the choice of references leaves undetermined (:func:`tables_spread`).
    """
    columns, labels = references.columns()
    names = sorted({n for n, _ in labels})
    owner = np.array([names.index(n) for n, _ in labels])
    rng = np.random.default_rng(RESAMPLE_SEED)
    saved = [ch.reg_prior for ch in problems]
    out = np.empty((count, len(problems), len(problems[0].g)))
    for b in range(count):
        pick = np.concatenate([np.flatnonzero(owner == k) for k in rng.integers(0, len(names), len(names))])
        for c, (ch, lam) in enumerate(zip(problems, lams)):
            ch.pull_toward(_reference_prior(ch, columns[:, pick])[0])
            out[b, c] = np.maximum(ch.constrained(lam, None), 0.0)
    for ch, r in zip(problems, saved):
        ch.reg_prior = r
    return out


def tables_spread(parts, env: Environment, normals, weights) -> float:
    """Relative RMS spread about their mean (:func:`brdfrig.fit.metrics.relative_spread`) of B radiances under
    ``env``, the b-th of which is ``sum_p w_p x radiance(tables_p[b])`` (:func:`predict_tables`, one pass).

    ``parts``: ``(w_p, tables_p)`` pairs, ``tables_p`` (B, C, 2, nh_p, nd_p) node values (a fit report's
    ``resampled_tables`` with weight 1, or each blend part's ``fold_tables`` with its blend weight); ``normals``
    (N, 3) unit sphere normals (view ``v = (0, 0, 1)``) and ``weights`` (N,) pixel weights.
    """
    parts = [(float(w), np.asarray(t, dtype=np.float64)) for w, t in parts]
    count = {len(t) for _, t in parts}
    if len(count) != 1:
        raise ValueError(f"every part needs the same number of tables, got {sorted(count)}")
    b = count.pop()
    radiance = predict_tables([BivariateBRDF(x[:, 0], x[:, 1]) for _, t in parts for x in t], env, normals)
    return relative_spread(sum(w * np.stack(radiance[i * b:(i + 1) * b]) for i, (w, _) in enumerate(parts)), weights)


def _solve_tables(problems: list[_Channel], grid: tuple[float, ...], monotone: bool | None, transform: np.ndarray, norm: float):
    """Per-channel ``lam_rel``, the check errors of each, the chosen node values (C, 2K), monotone or not, and
    the check pixels' relative RMS error of the non-negative and the monotone tables."""
    lams, lam_errors, tables = [], [], {"non_negative": [], "monotone": []}
    for ch in problems:
        lam, errs = _choose_lambda(ch, grid)
        lams.append(lam)
        lam_errors.append(errs)
        if monotone is not True:
            tables["non_negative"].append(ch.constrained(lam, None))
        if monotone is not False:
            tables["monotone"].append(ch.constrained(lam, transform))
    check_err = {k: math.sqrt(sum(ch.check_error(x) for ch, x in zip(problems, v)) / norm) for k, v in tables.items() if v}
    if monotone is None:
        use_monotone = not problems[0].check_y.size or check_err["non_negative"] >= (1.0 - MONOTONE_MAX_LOSS) * check_err["monotone"]
    else:
        use_monotone = monotone
    x = np.maximum(np.stack(tables["monotone" if use_monotone else "non_negative"]), 0.0)  # NNLS's -0.0 -> 0
    return lams, lam_errors, x, bool(use_monotone), check_err


def _identifiability(problems: list[_Channel], lams: list[float], reg: np.ndarray, nh: int, nd: int, prior: bool) -> dict:
    """Report entries: per node, data weight ``diag(R^T R)`` against the regulariser's ``lam diag(reg)``, both
    summed over the node's in-plane and cross values.

    With a prior the unobserved nodes follow it, so the table counts as determined.
    """
    k = nh * nd
    data_w = np.stack([np.diag(ch.g_mat)[:k] + np.diag(ch.g_mat)[k:] for ch in problems])  # (C, K)
    reg_w = np.stack([lam * ch.scale * (np.diag(reg)[:k] + np.diag(reg)[k:]) for lam, ch in zip(lams, problems)])
    observed = np.all(data_w > reg_w, axis=0).reshape(nh, nd)
    return {
        "observation": (data_w / np.maximum(data_w.max(axis=1, keepdims=True), 1e-300)).reshape(len(problems), nh, nd).tolist(),
        "observed": observed.tolist(),
        "filled_by_regulariser": (~observed).tolist(),
        "observed_fraction": float(observed.mean()),
        "determined": bool(prior or observed.mean() >= DETERMINED_MIN_OBSERVED),
    }


def fit_bivariate(
    scenes: list[Scene],
    *,
    lmax: int | None = None, bands: tuple[int, ...] | None = None,
    nh: int | None = None, nd: int | None = None,
    max_pixels: int = DEFAULT_MAX_PIXELS, monotone: bool | None = None,
    prior=None, references=None, resamples: int = 0,
    cone_deg: float = FIT_CONE_DEG, subdiv: int = FIT_SUBDIV,
    seed: int = 0, progress: bool = True,
) -> tuple[BivariateBRDF, dict]:
    """Fit the bivariate table to one or more scenes (one table from all of them).

    Parameters
    ----------
    scenes : list of Scene
        Lighting and observed sphere pixels (channel counts must agree).
    lmax, bands
        Ignored (common fit signature): the lighting enters through its quadrature samples.
    nh, nd : int, optional
        Nodes in ``theta_h`` (sqrt-spaced) and ``theta_d`` (uniform), >= 3; default 24 x 8, or the references' grid.
    max_pixels : int
        Fit pixels of the subsample (plus a quarter as many check pixels).
    monotone : bool or None
        Force or forbid monotone decrease in ``theta_h``; None: the check pixels choose (with ``references``: False).
    prior : FittedBRDF, optional
        A fit the table deviates from smoothly: smoothness of ``x - x0``, ``x0`` its node values (:func:`project_to_nodes`),
        ``lam_rel`` from :data:`PRIOR_LAMBDA_GRID`: unobserved nodes follow the prior, not a linear continuation.
    references : brdfrig.fit.references.ReferenceTables, optional
        Instead of ``prior`` (``bivariate+measured``): ``x0`` per channel the non-negative combination of these
        measured tables that best reproduces the pixels (:func:`_reference_prior`), ``lam_rel`` :data:`REFERENCE_LAMBDA`.
    resamples : int
        With ``references``: also re-solve the table this many times, each with the prior refitted to a bootstrap
        resample of the reference materials (report ``resampled_tables``; :func:`tables_spread`).
    cone_deg, subdiv, seed, progress : float, int, int, bool
        Sharp-lobe quadrature of the design (:func:`brdfrig.fit.quadrature.lobe_quadrature`); seed of the pixel
        subsample; a tqdm bar (stderr) over streamed pixels.

    Returns
    -------
    brdf : BivariateBRDF
    report : dict
        JSON-able: ``theta_h_nodes_deg``, ``theta_d_nodes_deg``, ``lambda_rel`` per channel, ``monotone``,
        ``prior`` (a model name, ``"measured references"`` or None), ``references`` (per channel the ridge and
        the materials carrying most of the prior's image), ``check_relative_rms``, ``observation`` (C, nh, nd:
        data weight ``diag(R^T R)`` relative to the channel's largest), ``observed`` ((nh, nd): data weight above
        the regulariser's in every channel), ``filled_by_regulariser``, ``observed_fraction``, ``determined``
        (>= :data:`DETERMINED_MIN_OBSERVED` observed, or a prior), ``relative_rms_residual``, ``pixels_used``,
        ``check_pixels``, ``resampled_tables`` ((resamples, C, 2, nh, nd), with ``references`` and ``resamples``),
        ``seconds``.
    """
    t0 = time.perf_counter()
    channels = _check_scenes(scenes)
    nh, nd = _grid(nh, nd, max_pixels, prior, references)
    fit_picks, check_picks = _subsample(scenes, max_pixels, np.random.default_rng(seed))
    bar = tqdm(desc="bivariate fit", unit="px", total=sum(len(p) for p in fit_picks), disable=not progress, leave=False)
    quad = {"cone_deg": cone_deg, "subdiv": subdiv}
    qr, yy = _stream(scenes, fit_picks, nh, nd, channels, quad, bar)
    bar.close()
    check_rows, check_y = _check_system(scenes, check_picks, nh, nd, quad)
    reg, problems = _problems(qr, yy, check_rows, check_y, nh, nd)
    grid, prior_name, extra = _pull_toward_prior(problems, prior, references, nh, nd)
    monotone = False if references is not None and monotone is None else monotone
    norm = max(float(np.sum(check_y**2)), 1e-300)
    lams, lam_errors, x, use_monotone, check_err = _solve_tables(problems, grid, monotone, cumulative_operator(nh, nd), norm)
    tables = x.reshape(channels, 2, nh, nd)
    brdf = BivariateBRDF(tables[:, 0], tables[:, 1])
    report = {
        "model": "bivariate", "nh": nh, "nd": nd,
        "theta_h_nodes_deg": np.degrees(theta_h_nodes(nh)).tolist(), "theta_d_nodes_deg": np.degrees(theta_d_nodes(nd)).tolist(),
        "lambda_rel": lams, "lambda_check_errors": lam_errors, "monotone": use_monotone,
        "prior": prior_name, **extra, "check_relative_rms": check_err,
        **_identifiability(problems, lams, reg, nh, nd, prior_name is not None),
        "relative_rms_residual": math.sqrt(sum(ch.residual(xc) for ch, xc in zip(problems, x)) / max(float(yy.sum()), 1e-300)),
        "pixels_used": int(sum(len(p) for p in fit_picks)), "check_pixels": int(len(check_y)),
    }
    if references is not None and resamples > 0:
        report["resampled_tables"] = _resample_references(problems, lams, references, resamples).reshape(resamples, *tables.shape)
    return brdf, report | {"seconds": time.perf_counter() - t0}
