"""Plots of BRDFs: incidence-plane slices, rho against theta_h, directional albedo; several BRDFs overlaid.

Every BRDF is anything with ``evaluate(theta_i, theta_o, delta_phi) -> (..., C)`` in
1/sr (:class:`brdfrig.fit.brdf.FittedBRDF`): fitted models, analytic ones and
measured tables alike.  Angles are in the local frame of the normal
(``delta_phi = phi_o - phi_i``; ``delta_phi = pi`` is the specular side of the
incidence plane).  Colour channels are drawn in their own colours (one channel:
black); BRDFs are told apart by line style.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

__all__ = ["incidence_slices", "theta_h_slices", "directional_albedo", "brdf_figure", "plot_brdfs"]

INCIDENCE_DEG = (0.0, 30.0, 60.0, 75.0)
"""Incidence angles of the in-plane slices (degrees)."""
THETA_D_DEG = (5.0, 30.0, 60.0)
"""Difference angles of the theta_h slices (degrees)."""
ALBEDO_NODES = 48
"""Gauss-Legendre nodes in cos(theta_o) for the directional albedo (times 2x that in phi)."""
_STYLES = ("-", "--", ":", "-.")
_CHANNEL_COLOURS = ("tab:red", "tab:green", "tab:blue")


def incidence_slices(brdf, theta_i_deg=INCIDENCE_DEG, n: int = 181):
    """rho in the incidence plane: ``theta_o`` signed in (-90, 90) degrees, positive on the specular side.

    Returns
    -------
    theta_o_deg : (n,) ; rho : (len(theta_i_deg), n, C) in 1/sr.
    """
    t = np.linspace(-89.5, 89.5, n)
    ti = np.radians(np.asarray(theta_i_deg, dtype=float))[:, None]
    to = np.radians(np.abs(t))[None, :]
    dphi = np.where(t >= 0, math.pi, 0.0)[None, :]
    return t, np.asarray(brdf.evaluate(ti, to, dphi), dtype=float)


def theta_h_slices(brdf, theta_d_deg=THETA_D_DEG, n: int = 120):
    """rho against the half-vector angle ``theta_h`` at fixed difference angles (``phi_d = pi/2``).

    Pairs whose incident or outgoing direction falls below the horizon are NaN (none at
    ``phi_d = pi/2`` for ``theta_h < 90`` deg; the guard keeps other choices honest).

    Returns
    -------
    theta_h_deg : (n,) ; rho : (len(theta_d_deg), n, C) in 1/sr.
    """
    from brdfrig.fit.measured import rusinkiewicz_directions

    th = np.linspace(0.0, 89.0, n)
    td = np.asarray(theta_d_deg, dtype=float)[:, None]
    wi, wo = rusinkiewicz_directions(np.radians(th)[None, :], np.radians(td), math.pi / 2)
    ok = (wi[..., 2] > 1e-6) & (wo[..., 2] > 1e-6)
    ti = np.arccos(np.clip(wi[..., 2], -1, 1))
    to = np.arccos(np.clip(wo[..., 2], -1, 1))
    dphi = np.arctan2(wo[..., 1], wo[..., 0]) - np.arctan2(wi[..., 1], wi[..., 0])
    rho = np.asarray(brdf.evaluate(np.where(ok, ti, 0.0), np.where(ok, to, 0.0), dphi), dtype=float)
    rho[~ok] = np.nan
    return th, rho


def directional_albedo(brdf, n_theta: int = 46, nodes: int = ALBEDO_NODES):
    """``a(theta_i) = integral rho(theta_i, w_o) cos(theta_o) dw_o`` over the outgoing hemisphere.

    The quadrature is centred on the mirror direction ``r`` of ``w_i``, where glossy lobes
    peak: the angle ``psi`` from ``r`` is ``pi u^2`` with ``u`` at Gauss-Legendre nodes
    (dense near the peak), the azimuth about ``r`` uniform (``2 * nodes`` points);
    directions below the horizon count zero.  A Lambertian of albedo ``a`` gives ``a``
    within 0.2% (the horizon cuts through nodes); a lobe a fraction of a degree wide still gets tens of nodes.

    Returns
    -------
    theta_i_deg : (n_theta,) ; albedo : (n_theta, C).
    """
    x, w = np.polynomial.legendre.leggauss(nodes)
    u, wu = 0.5 * (x + 1.0), 0.5 * w
    psi, dpsi = math.pi * u**2, 2.0 * math.pi * u * wu  # angle from the mirror direction and its weight
    chi = (np.arange(2 * nodes) + 0.5) * (math.pi / nodes)
    theta_i = np.linspace(0.0, 89.0, n_theta)
    ti = np.radians(theta_i)[:, None, None]
    # w_o = cos(psi) r + sin(psi) (cos(chi) e1 + sin(chi) e2), r = (-sin ti, 0, cos ti), e1 = (cos ti, 0, sin ti), e2 = y
    sp, cp = np.sin(psi)[None, :, None], np.cos(psi)[None, :, None]
    ox = -cp * np.sin(ti) + sp * np.cos(chi) * np.cos(ti)
    oy = sp * np.sin(chi) * np.ones_like(ti)
    oz = cp * np.cos(ti) + sp * np.cos(chi) * np.sin(ti)
    above = oz > 0
    to = np.arccos(np.clip(oz, 0.0, 1.0))
    dphi = np.arctan2(oy, ox)  # phi_i = 0
    rho = np.asarray(brdf.evaluate(np.broadcast_to(ti, to.shape), to, dphi), dtype=float)
    weights = np.where(above, oz, 0.0) * (sp * dpsi[None, :, None]) * (math.pi / nodes)
    return theta_i, np.sum(rho * weights[..., None], axis=(1, 2))


def _draw(ax, x, y, style, label):
    c = y.shape[-1]
    for k in range(c):
        colour = "black" if c == 1 else _CHANNEL_COLOURS[k % 3]
        ax.plot(x, y[..., k], style, color=colour, lw=1.2, label=label if k == 0 else None)


def plot_brdfs(brdfs: dict, path, *, title: str = "") -> Path:
    """Write :func:`brdf_figure` of ``brdfs`` as a PNG, atomically."""
    from brdfrig.report.figures import save_png

    return save_png(brdf_figure(brdfs, title=title), path)


def brdf_figure(brdfs: dict, *, title: str = ""):
    """A matplotlib figure comparing ``brdfs`` (name -> BRDF): incidence-plane slices, theta_h slices and
    directional albedo.  Values are drawn on a log scale where they span more than two decades (glossy
    lobes), linear otherwise."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not brdfs:
        raise ValueError("plot_brdfs needs at least one BRDF")
    n_inc = len(INCIDENCE_DEG)
    fig, axes = plt.subplots(2, max(n_inc, 3), figsize=(3.2 * max(n_inc, 3), 6.4), squeeze=False)
    for (name, brdf), style in zip(brdfs.items(), _STYLES * 8):
        t, rho = incidence_slices(brdf)
        for k, ti in enumerate(INCIDENCE_DEG):
            _draw(axes[0, k], t, rho[k], style, name)
            axes[0, k].set_title(f"incidence plane, theta_i = {ti:g} deg", fontsize=8)
        th, rh = theta_h_slices(brdf)
        for k, td in enumerate(THETA_D_DEG[:2]):
            _draw(axes[1, k], th, rh[k], style, name)
            axes[1, k].set_title(f"rho vs theta_h, theta_d = {td:g} deg", fontsize=8)
        ta, alb = directional_albedo(brdf)
        _draw(axes[1, 2], ta, alb, style, name)
        axes[1, 2].set_title("directional albedo", fontsize=8)
    for ax in axes.ravel():
        ax.tick_params(labelsize=7)
        lines = [l.get_ydata() for l in ax.get_lines()]
        vals = np.concatenate([np.ravel(v) for v in lines]) if lines else np.array([])
        vals = vals[np.isfinite(vals) & (vals > 0)]
        if ax is not axes[1, 2] and vals.size and vals.max() > 100 * np.percentile(vals, 5):
            ax.set_yscale("log")
    for k in range(n_inc):
        axes[0, k].set_xlabel("theta_o (deg), + = specular side", fontsize=7)
    for k in range(2):
        axes[1, k].set_xlabel("theta_h (deg)", fontsize=7)
    axes[1, 2].set_xlabel("theta_i (deg)", fontsize=7)
    axes[0, 0].set_ylabel("rho (1/sr)", fontsize=8)
    axes[1, 0].set_ylabel("rho (1/sr)", fontsize=8)
    axes[1, 2].set_ylim(bottom=0)
    for ax in axes[1, 3:]:
        ax.axis("off")
    axes[0, 0].legend(fontsize=7)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig
