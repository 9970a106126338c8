"""Design matrices of the linear BRDF models, evaluated per block of sphere pixels.

Every linear model writes the radiance a camera at ``v = (0, 0, 1)`` sees at a
sphere point with unit normal ``n`` as ``B(n) = A(n) @ x`` per colour channel,
where the design row ``A(n)`` depends only on the lighting's SH coefficients
``L_lm`` (per channel) and ``n``; ``x`` are the BRDF unknowns.  Models
(``docs/MATH.md``, "Reflected radiance of a sphere, in real SH"):

``diffuse``  ``B = sum_l a_l sum_m L_lm Y_lm(n)``: radially symmetric about the
             normal (Funk-Hecke); a Lambertian BRDF of albedo ``a`` has
             ``a_l = (a / pi) A_l`` (``A_0 = pi``), so ``a_0`` is the hemispherical albedo.
``lobe``     ``diffuse`` plus ``sum_{l>=1} s_l sum_m L_lm Y_lm(r)``, a lobe radially
             symmetric about the mirror direction ``r = 2 (n.v) n - v`` (its band 0
             is a constant, already in ``a_0``).
``full``     ``B = sum_{l,p,k} tau[l,p,k] L'_{l,k}(n) Y_{p,k}(w_o')``, ``0 <= k <= min(l, p)``,
             ``L'`` the lighting rotated into the frame ``R_n = Rz(phi_N) Ry(theta_N)``
             and ``w_o' = (-sin theta_N, 0, cos theta_N)`` (the sine-order terms vanish there).

Bands the lighting cannot excite are left out by passing the ``bands`` to keep
(:mod:`brdfrig.fit.identifiability` decides which).  The rotated lighting is computed
once per block for all channels (``brdfrig.fit.rotation.local_lighting``); :func:`design_rows`
assembles the rows of pixels of several scenes with the direction SH evaluated once.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numba
import numpy as np

from brdfrig.fit.sh import sh_eval, sh_index
from brdfrig.fit.rotation import local_lighting

__all__ = ["LINEAR_MODELS", "ModelSpec", "design_block", "design_rows", "outgoing_directions", "mirror_directions"]

LINEAR_MODELS = ("diffuse", "lobe", "full")


@dataclass(frozen=True)
class ModelSpec:
    """Which unknowns a linear model has.

    Attributes
    ----------
    kind : str
        ``"diffuse"``, ``"lobe"`` or ``"full"``.
    lmax : int
        Lighting band limit L (bands 0..L).
    pmax : int
        Outgoing band limit P of the ``full`` model (ignored otherwise).
    bands : tuple of int
        The lighting bands kept (observable ones); default all of 0..L.
    """

    kind: str
    lmax: int
    pmax: int = 0
    bands: tuple[int, ...] | None = None
    _cols: dict = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.kind not in LINEAR_MODELS:
            raise ValueError(f"unknown linear model {self.kind!r}; expected one of {LINEAR_MODELS}")
        if self.lmax < 0 or self.pmax < 0:
            raise ValueError(f"band limits must be >= 0, got lmax={self.lmax}, pmax={self.pmax}")
        bands = tuple(range(self.lmax + 1)) if self.bands is None else tuple(sorted(set(int(b) for b in self.bands)))
        if any(b < 0 or b > self.lmax for b in bands):
            raise ValueError(f"bands {bands} outside 0..{self.lmax}")
        object.__setattr__(self, "bands", bands)
        object.__setattr__(self, "_cols", _columns(self.kind, bands, self.pmax))

    @property
    def n_unknowns(self) -> int:
        return len(self._cols["band"])

    @property
    def column_band(self) -> np.ndarray:
        """(n,) lighting band l of every unknown."""
        return self._cols["band"]

    @property
    def column_labels(self) -> list[str]:
        """Human-readable name of every unknown (``a_l``, ``s_l``, ``tau[l,p,k]``)."""
        return self._cols["labels"]

    @property
    def full_index(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For ``full``: (l, p, k) arrays of every unknown."""
        return self._cols["l"], self._cols["p"], self._cols["k"]


def _columns(kind: str, bands: tuple[int, ...], pmax: int) -> dict:
    if kind == "full":
        lpk = [(l, p, k) for l in bands for p in range(pmax + 1) for k in range(min(l, p) + 1)]
        l, p, k = (np.array(v, dtype=np.int64).reshape(-1) for v in zip(*lpk)) if lpk else (np.zeros(0, int),) * 3
        return {
            "band": l,
            "l": l,
            "p": p,
            "k": k,
            "labels": [f"tau[{a},{b},{c}]" for a, b, c in lpk],
        }
    # The lobe's band 0 is the constant the diffuse a_0 already carries (Y_00(r) = Y_00(n)).
    cols = [("a", b) for b in bands] + ([("s", b) for b in bands if b > 0] if kind == "lobe" else [])
    return {
        "band": np.array([b for _, b in cols], dtype=np.int64),
        "labels": [f"{nm}_{b}" for nm, b in cols],
    }


def mirror_directions(normals: np.ndarray) -> np.ndarray:
    """Mirror directions ``r = 2 (n.v) n - v`` for ``v = (0, 0, 1)``; (N, 3) -> (N, 3)."""
    r = 2.0 * normals[:, 2:3] * normals
    r[:, 2] -= 1.0
    return r


def outgoing_directions(normals: np.ndarray) -> np.ndarray:
    """Local outgoing directions ``w_o' = (-sin theta_N, 0, cos theta_N)``; (N, 3) -> (N, 3)."""
    cos_t = np.clip(normals[:, 2], -1.0, 1.0)
    sin_t = np.sqrt(np.maximum(1.0 - cos_t * cos_t, 0.0))
    return np.stack([-sin_t, np.zeros_like(cos_t), cos_t], axis=1)


def _zonal_columns(sh: np.ndarray, coeffs: np.ndarray, bands: tuple[int, ...]) -> np.ndarray:
    """``sum_m L_lm Y_lm(w)`` per band: sh (N, ncoef), coeffs (ncoef, C) -> (N, len(bands), C)."""
    out = np.empty((sh.shape[0], len(bands), coeffs.shape[1]))
    for i, l in enumerate(bands):
        sl = slice(l * l, (l + 1) * (l + 1))
        out[:, i, :] = sh[:, sl] @ coeffs[sl, :]
    return out


@numba.njit(cache=True, nogil=True)
def _full_rows(local, y_out, light_col, out_col, out):  # pragma: no cover - compiled
    """``out[i, j, c] = local[i, light_col[j], c] * y_out[i, out_col[j]]``, looping in ``out``'s memory order
    (channel, column, pixel: the layout :func:`design_block` allocates)."""
    n_px, n_cols, n_ch = out.shape
    for c in range(n_ch):
        for j in range(n_cols):
            a, b = light_col[j], out_col[j]
            for i in range(n_px):
                out[i, j, c] = local[i, a, c] * y_out[i, b]


def design_block(spec: ModelSpec, coeffs: np.ndarray, normals: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """Design rows of ``spec`` for one lighting and a block of sphere points.

    Parameters
    ----------
    spec : ModelSpec
    coeffs : (ncoef, C) float64
        Lighting SH coefficients (real orthonormal, ``ncoef >= (lmax+1)**2``).
    normals : (N, 3) float64
        Unit normals of the sphere points.
    out : (N, n_unknowns, C) float64, optional
        Array (any strides) to write the rows into.

    Returns
    -------
    (N, n_unknowns, C) float64
        ``B[:, c] = A[:, :, c] @ x[:, c]``, laid out as :func:`design_rows` lays it out.
    """
    normals = np.asarray(normals, dtype=np.float64)
    return design_rows(spec, [coeffs], np.zeros(normals.shape[0], dtype=np.int64), normals, out)


def design_rows(spec: ModelSpec, coeffs: list[np.ndarray], scene: np.ndarray, normals: np.ndarray,
                out: np.ndarray | None = None) -> np.ndarray:
    """Design rows of ``spec`` for sphere points seen under several lightings.

    The SH of the directions (outgoing for ``full``, normal and mirror for ``diffuse``/``lobe``) are
    evaluated once for all points, the lighting-dependent part per run of equal ``scene``: one SH call
    per block instead of one per scene matters, because every sphericart call wakes its OpenMP
    threads (measured ~10 ms per call of 170 directions on the busy 2-core machine, 0.2 ms with one
    thread), and limiting those threads from the fitter corrupted memory once numba's own OpenMP
    runtime ran in the same process.

    Parameters
    ----------
    spec : ModelSpec
    coeffs : list of (ncoef, C) float64
        Lighting SH coefficients of each scene (``ncoef >= (lmax+1)**2``).
    scene : (N,) int
        Index into ``coeffs`` of each point (points of one scene are best contiguous: one run each).
    normals : (N, 3) float64
        Unit normals of the sphere points.
    out : (N, n_unknowns, C) float64, optional
        Array (any strides) to write the rows into.

    Returns
    -------
    (N, n_unknowns, C) float64
        ``B[:, c] = A[:, :, c] @ x[:, c]``.  When ``out`` is not given the memory is laid out channel by
        channel and column by column (a transposed view of a C-ordered (C, n, N) array), so that
        ``A[:, :, c]`` is one Fortran-ordered matrix, as LAPACK reads it.
    """
    L = spec.lmax
    coeffs = [np.asarray(c, dtype=np.float64)[: (L + 1) ** 2] for c in coeffs]
    normals = np.asarray(normals, dtype=np.float64)
    scene = np.asarray(scene)
    if out is None:
        out = np.empty((coeffs[0].shape[1], spec.n_unknowns, normals.shape[0])).transpose(2, 1, 0)
    if normals.shape[0] == 0:
        return out
    edges = [0, *(np.flatnonzero(np.diff(scene)) + 1).tolist(), len(scene)]
    runs = [(a, b, coeffs[scene[a]]) for a, b in zip(edges[:-1], edges[1:])]
    if spec.kind == "full":
        lc, pc, kc = spec.full_index
        light_col, out_col = sh_index(lc, kc), sh_index(pc, kc)
        # Pixel-major transposes make the kernel's inner loop (pixels) contiguous.  Numba because
        # numpy's fancy-indexed product (``local[:, lk, :] * y[:, pk, None]``) measured 40 ms per
        # 2048 x 285 x 3 block, the kernel 1.8 ms.
        y_out = np.ascontiguousarray(sh_eval(outgoing_directions(normals), spec.pmax).T).T
        for a, b, c in runs:  # rotated lighting once for every channel
            local = np.ascontiguousarray(local_lighting(c, normals[a:b]).transpose(2, 1, 0)).transpose(2, 1, 0)
            _full_rows(local, y_out[a:b], light_col, out_col, out[a:b])
        return out
    nb = len(spec.bands)
    sh_n = sh_eval(normals, L)
    lobe_bands = tuple(b for b in spec.bands if b > 0)
    sh_r = sh_eval(mirror_directions(normals), L) if spec.kind == "lobe" else None
    for a, b, c in runs:
        out[a:b, :nb] = _zonal_columns(sh_n[a:b], c, spec.bands)
        if sh_r is not None:
            out[a:b, nb:] = _zonal_columns(sh_r[a:b], c, lobe_bands)
    return out
