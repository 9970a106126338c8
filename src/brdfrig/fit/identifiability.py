"""What the lighting of a capture can determine, computed before any image is read.

``docs/MATH.md`` pitfall 1: on a ring of constant ``theta_N`` the image
of a sphere is a Fourier series in ``phi_N`` of orders ``|j| <= L``, and the
order-``j`` part is ``sum_{l >= j} (L_{l,j} cos(j phi) + L_{l,-j} sin(j phi)) g_{l,j}(theta)``
with ``g_{l,j}(theta) = sum_k d^l_{jk}(theta) f_{l,k}(theta)`` (``d^l`` the real
Wigner d-matrix of ``Ry(theta)``, invertible on ``k >= 0``).  So, per order
``j``, the lighting of S scenes enters through the *lighting matrix*
``M_j`` with one row per scene (two for ``j > 0``: cosine and sine) and one
column per band ``l >= j``; the full model's band-``l`` content at order ``j``
is determined (for any BRDF, not only band-limited ones) iff ``e_l`` lies in
the row space of ``M_j``.  Order 0 gives one row per scene, so separating
``n_b`` observable bands needs at least ``n_b`` (``= L + 1``) scenes whose
lighting differs.  Pitfall 2: a band with no lighting energy multiplies
nothing; it is reported unobservable and left out of every model.

Independently, the numerical rank of each linear model's design matrix
(:mod:`brdfrig.fit.system`) is computed from the lighting alone on a synthetic grid of
sphere normals (rings in ``theta_N`` x equispaced ``phi_N``, dense enough for
the trigonometric degree of every column), per colour channel, with the same
column equilibration and threshold as :mod:`brdfrig.fit.solvers`.  The rank equals that
of the system assembled from an image's pixels (tested).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from brdfrig.fit.sh import sh_index
from brdfrig.fit.solvers import numerical_rank
from brdfrig.fit.system import LINEAR_MODELS, ModelSpec, design_block

__all__ = ["ENERGY_RTOL", "THETA_MAX_DEG", "Identifiability", "analyse_lighting", "scenes_needed"]

ENERGY_RTOL = 2e-3
"""A band whose RMS lighting coefficient is below this fraction of the strongest band's (in every
scene and channel) is unobservable.  Projecting a band-1 lighting sampled on a 64x32 lat-long map
leaks 4e-4 into higher bands (measured); real probes carry 1e-2 to 1 in bands <= 12."""

THETA_MAX_DEG = 80.0
"""Largest normal polar angle of the synthetic rank grid (sphere pixels beyond the limb margin)."""


def scenes_needed(lmax: int) -> int:
    """Differing scenes the full model needs at band limit ``lmax`` (order 0: one equation per scene per band)."""
    return lmax + 1


@dataclass
class Identifiability:
    """Identifiability of the models under the lighting of a set of scenes.

    Attributes
    ----------
    lmax, pmax : int
        Requested band limits.
    n_scenes : int
    band_energy : (lmax+1,) float
        Per band, the largest RMS lighting coefficient over scenes and channels,
        relative to the strongest band.
    observable_bands, unobservable_bands : list of int
    order_rank : (lmax+1,) int
        Rank of the lighting matrix ``M_j`` (worst channel) per Fourier order j.
    order_unknowns : (lmax+1,) int
        Observable bands ``l >= j`` (columns of ``M_j``).
    band_determined : (lmax+1, lmax+1) bool
        ``[l, j]``: band l's order-j content is determined (``j <= l``; False where l unobservable).
    full_lmax_determined : int
        Largest band limit ``L' <= lmax`` at which the full model is determined (-1 if none).
    models : dict
        Per linear model: ``unknowns``, ``rank`` (worst channel), ``determined`` and ``reason``.
    """

    lmax: int
    pmax: int
    n_scenes: int
    band_energy: np.ndarray
    observable_bands: list[int]
    unobservable_bands: list[int]
    order_rank: np.ndarray
    order_unknowns: np.ndarray
    band_determined: np.ndarray
    full_lmax_determined: int
    models: dict = field(default_factory=dict)

    @property
    def scenes_needed(self) -> int:
        """Differing scenes the full model needs at this ``lmax`` (observable bands)."""
        return len(self.observable_bands)

    def determined(self, model: str) -> bool:
        return bool(self.models.get(model, {}).get("determined", False))

    def to_dict(self) -> dict:
        return {
            "lmax": self.lmax,
            "pmax": self.pmax,
            "n_scenes": self.n_scenes,
            "band_energy": [float(e) for e in self.band_energy],
            "observable_bands": list(self.observable_bands),
            "unobservable_bands": list(self.unobservable_bands),
            "order_rank": [int(r) for r in self.order_rank],
            "order_unknowns": [int(u) for u in self.order_unknowns],
            "band_determined": self.band_determined.astype(int).tolist(),
            "scenes_needed": self.scenes_needed,
            "full_lmax_determined": self.full_lmax_determined,
            "models": self.models,
        }

    def summary(self) -> str:
        """Human-readable report (printed by ``brdfrig fit``)."""
        lines = [f"identifiability: {self.n_scenes} scene(s), lmax={self.lmax}, pmax={self.pmax}"]
        if self.unobservable_bands:
            lines.append(f"  bands with no lighting energy (skipped, not measured): {self.unobservable_bands}")
        lines.append("  Fourier order j : " + " ".join(f"{j:3d}" for j in range(self.lmax + 1)))
        lines.append("  lighting rank   : " + " ".join(f"{r:3d}" for r in self.order_rank))
        lines.append("  bands to separate: " + " ".join(f"{u:3d}" for u in self.order_unknowns))
        need = self.scenes_needed
        lines.append(
            f"  full model at lmax={self.lmax} needs >= {need} scenes with differing lighting; "
            f"determined up to lmax={self.full_lmax_determined}"
        )
        for name, m in self.models.items():
            state = "determined" if m["determined"] else "UNDETERMINED"
            lines.append(f"  {name:8s}: rank {m['rank']}/{m['unknowns']} -> {state} ({m['reason']})")
        return "\n".join(lines)


def _band_energy(coeffs: list[np.ndarray], lmax: int) -> np.ndarray:
    e = np.zeros(lmax + 1)
    for c in coeffs:
        for l in range(lmax + 1):
            band = c[l * l : (l + 1) * (l + 1)]
            e[l] = max(e[l], float(np.sqrt(np.mean(band * band, axis=0)).max()))
    top = e.max()
    return e / top if top > 0 else e


def _lighting_matrix(coeffs: list[np.ndarray], bands: list[int], j: int, channel: int) -> np.ndarray:
    """``M_j`` (rows: scenes x {cos, sin}; columns: observable bands >= j), columns equilibrated."""
    cols = [l for l in bands if l >= j]
    rows = []
    for c in coeffs:
        rows.append([c[sh_index(l, j), channel] for l in cols])
        if j > 0:
            rows.append([c[sh_index(l, -j), channel] for l in cols])
    m = np.array(rows, dtype=np.float64).reshape(len(rows), len(cols))
    norms = np.linalg.norm(m, axis=0)
    return m / np.where(norms > 0, norms, 1.0)


def _separated(coeffs: list[np.ndarray], bands: list[int], j: int) -> bool:
    """Whether every band of ``bands`` (>= j) is separated at order j: ``M_j`` has full column rank."""
    cols = [l for l in bands if l >= j]
    if not cols:
        return True
    return all(
        numerical_rank(np.linalg.svd(_lighting_matrix(coeffs, bands, j, ch), compute_uv=False)) == len(cols)
        for ch in range(coeffs[0].shape[1])
    )


def _ring_normals(lmax: int, pmax: int, theta_max: float) -> np.ndarray:
    """Synthetic normals (R*Q, 3): Gauss-Legendre rings in theta x Q equispaced phi.

    The design columns are Fourier series of order <= lmax in phi (Q = 2 lmax + 2
    samples separate them) and, per order, trigonometric polynomials in theta of
    degree <= lmax + max(pmax, lmax) (the mirror direction is at 2 theta), which
    R = lmax + max(pmax, lmax) + 4 rings resolve (checked against pixel grids in the tests).
    """
    n_rings = lmax + max(pmax, lmax) + 4
    n_phi = 2 * lmax + 2
    x, _ = np.polynomial.legendre.leggauss(n_rings)
    theta = 0.5 * theta_max * (x + 1.0)
    phi = 2.0 * np.pi * np.arange(n_phi) / n_phi
    t, p = np.meshgrid(theta, phi, indexing="ij")
    normals = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1).reshape(-1, 3)
    return normals


def _equilibrated_rank(a: np.ndarray) -> int:
    norms = np.linalg.norm(a, axis=0)
    a = a / np.where(norms > 0, norms, 1.0)
    return numerical_rank(np.linalg.svd(a, compute_uv=False))


def _model_rank(spec: ModelSpec, coeffs: list[np.ndarray], theta_max: float) -> int:
    """Worst-channel numerical rank of the model's design on the synthetic ring grid of every scene."""
    normals = _ring_normals(spec.lmax, spec.pmax, theta_max)
    design = np.concatenate([design_block(spec, c, normals) for c in coeffs], axis=0)  # (S*R*Q, n, C)
    return min(_equilibrated_rank(design[:, :, ch]) for ch in range(design.shape[2]))


def _order_ranks(coeffs: list[np.ndarray], observable: list[int], lmax: int):
    """Per Fourier order j: worst-channel rank of the bands l >= j, their count, and which bands are determined."""
    order_rank = np.zeros(lmax + 1, dtype=np.int64)
    order_unknowns = np.zeros(lmax + 1, dtype=np.int64)
    band_det = np.zeros((lmax + 1, lmax + 1), dtype=bool)
    for j in range(lmax + 1):
        cols = [l for l in observable if l >= j]
        order_unknowns[j] = len(cols)
        if not cols:
            continue
        ranks, det = [], np.ones(len(cols), dtype=bool)
        for ch in range(coeffs[0].shape[1]):
            _, s, vt = np.linalg.svd(_lighting_matrix(coeffs, observable, j, ch), full_matrices=False)
            k = numerical_rank(s)
            ranks.append(k)
            # e_l is in the row space iff its projection onto the leading right singular vectors has norm 1.
            det &= np.sum(vt[:k] ** 2, axis=0) > 1.0 - 1e-6
        order_rank[j] = min(ranks)
        band_det[cols, j] = det
    return order_rank, order_unknowns, band_det


def _full_lmax_determined(coeffs: list[np.ndarray], observable: list[int], lmax: int) -> int:
    """Largest band limit whose bands every Fourier order separates (-1: none)."""
    full_lmax = -1
    for lp in range(lmax + 1):
        sub = [l for l in observable if l <= lp]
        if not sub or not all(_separated(coeffs, sub, j) for j in range(lp + 1)):
            break
        full_lmax = lp
    return full_lmax


def _model_entry(kind: str, result: "Identifiability", coeffs: list[np.ndarray], theta_max: float) -> dict:
    """Unknowns, design rank on the ring grid, whether determined and why, for one linear model."""
    observable = result.observable_bands
    spec = ModelSpec(kind, result.lmax, result.pmax, bands=tuple(observable))
    if spec.n_unknowns == 0:
        return {"unknowns": 0, "rank": 0, "determined": False, "reason": "no observable band"}
    rank = _model_rank(spec, coeffs, theta_max)
    entry = {"unknowns": spec.n_unknowns, "rank": int(rank)}
    full_rank = rank == spec.n_unknowns
    if kind != "full":
        entry["determined"] = bool(full_rank)
        entry["reason"] = "full column rank" if full_rank else "design rank-deficient"
        return entry
    separable = result.full_lmax_determined >= max(observable)
    entry["determined"] = bool(full_rank and separable)
    if not separable:
        entry["reason"] = (
            f"order 0 separates {result.order_rank[0]} of {result.order_unknowns[0]} bands; "
            f"needs >= {len(observable)} scenes with differing lighting (has {len(coeffs)})"
        )
    elif not full_rank:
        entry["reason"] = "design rank-deficient along the outgoing bands"
    else:
        entry["reason"] = "every band separated at every Fourier order"
    return entry


def analyse_lighting(
    coeffs: list[np.ndarray],
    lmax: int,
    pmax: int,
    models: tuple[str, ...] = LINEAR_MODELS,
    theta_max_deg: float = THETA_MAX_DEG,
) -> Identifiability:
    """Identifiability of ``models`` from the lighting SH coefficients of every scene.

    Parameters
    ----------
    coeffs : list of (ncoef, C) float64
        One lighting per scene (``ncoef >= (lmax+1)**2``).
    lmax, pmax : int
        Band limits of the models.
    models : tuple of str
        Linear models whose design rank to check.
    theta_max_deg : float
        Largest normal polar angle observed (degrees).
    """
    if not coeffs:
        raise ValueError("identifiability needs at least one scene's lighting")
    coeffs = [np.asarray(c, dtype=np.float64) for c in coeffs]
    energy = _band_energy(coeffs, lmax)
    observable = [l for l in range(lmax + 1) if energy[l] > ENERGY_RTOL]
    order_rank, order_unknowns, band_det = _order_ranks(coeffs, observable, lmax)
    result = Identifiability(
        lmax=lmax,
        pmax=pmax,
        n_scenes=len(coeffs),
        band_energy=energy,
        observable_bands=observable,
        unobservable_bands=[l for l in range(lmax + 1) if l not in observable],
        order_rank=order_rank,
        order_unknowns=order_unknowns,
        band_determined=band_det,
        full_lmax_determined=_full_lmax_determined(coeffs, observable, lmax),
    )
    for kind in models:
        result.models[kind] = _model_entry(kind, result, coeffs, np.radians(theta_max_deg))
    return result
