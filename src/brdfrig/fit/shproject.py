"""Projection of radiance samples onto real SH, reconstruction, and band windows.

Conventions: ``brdfrig.fit.sh`` (real orthonormal SH, column ``l*l + l + m``).  A
coefficient array has shape ``(ncoef, C)`` with ``ncoef = (lmax + 1)**2`` and one
column per colour channel.

Two projection paths:

- ``project`` (any samples): quadrature ``L_lm = sum_k Y_lm(d_k) L(d_k) dOmega_k``
  over the given directions and solid angles (``dOmega = 0`` marks unseen
  samples, whose radiance is ignored and may be NaN), evaluated in chunks so
  memory stays bounded.  It is exact only as far as the solid angles are a good
  quadrature rule.
- ``project_latlong`` / ``reconstruct_latlong`` (lat-long maps in the OpenEXR
  convention of ``docs/MATH.md``, restated here because ``fit`` never
  imports ``hdr``; a test checks they agree with ``brdfrig.hdr.envmap``): separable.  In
  the frame whose pole is the map's +y axis, map rows are circles of constant
  colatitude ``theta_i = (i + 1/2) pi / H`` and columns equally spaced
  longitudes, so the longitude sums are one real FFT per row and the latitude
  sums use Fejer's first quadrature rule, whose nodes are exactly those row
  centres; the coefficients are then rotated to the world frame (one Wigner-D
  rotation).  Treating pixels as point samples at their centres, this is EXACT
  for maps band-limited to ``lmax`` when ``2 lmax <= H - 1`` and ``2 lmax < W``,
  and costs O(H W log W + H lmax^2) instead of the O(H W lmax^2) of the dense
  product.  Measured by ``python -m benchmarks.bench_sh`` (one run, busy 2-core
  machine): a 1024x512 RGB map to l = 30 in 41 ms, against 91 ms for pyshtools'
  ``SHExpandDH`` (3 calls) and 7.3 s for the dense sphericart product.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from brdfrig.fit.rotation import wigner_d_real
from brdfrig.fit.scene import Environment
from brdfrig.fit.sh import check_lmax, check_unit_dirs, sh_degree, sh_eval, sh_index

__all__ = [
    "WINDOWS",
    "project",
    "project_environment",
    "project_latlong",
    "reconstruct",
    "reconstruct_latlong",
    "sh_window",
]

#: Names accepted by ``sh_window`` (``None`` means "none").
WINDOWS = ("none", "hann", "lanczos")

#: Elements of the SH matrix evaluated at once (bounds memory to ~64 MB).
_CHUNK_ELEMENTS = 1 << 23

#: World -> polar frame of a lat-long map: ``d' = Q d = (d_z, d_x, d_y)``, so the map's
#: +y axis is the pole, colatitude ``theta' = pi/2 - latitude`` and azimuth ``phi' = longitude``.
_LATLONG_TO_POLAR = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def sh_window(lmax: int, kind: str | None = None) -> np.ndarray:
    """Per-band factors that taper SH coefficients against ringing.

    Parameters
    ----------
    lmax : int
        Band limit.
    kind : {None, "none", "hann", "lanczos"}
        ``None``/``"none"``: all ones.  ``"hann"``: ``(1 + cos(pi l / (lmax + 1))) / 2``.
        ``"lanczos"``: ``sinc(l / (lmax + 1))`` (Lanczos sigma factors).  Both are 1 at
        l = 0 and reach 0 at l = lmax + 1; Hann blurs more and rings less.

    Returns
    -------
    (lmax + 1,) float64
        Factor of band l (multiply every ``m`` of band l).
    """
    lmax = check_lmax(lmax)
    t = np.arange(lmax + 1) / (lmax + 1)
    if kind is None or kind == "none":
        return np.ones(lmax + 1)
    if kind == "hann":
        return 0.5 * (1.0 + np.cos(np.pi * t))
    if kind == "lanczos":
        return np.sinc(t)
    raise ValueError(f"window must be one of {WINDOWS} or None, got {kind!r}")


def _apply_window(coeffs: np.ndarray, lmax: int, window: str | None) -> np.ndarray:
    factors = sh_window(lmax, window)
    return coeffs * np.repeat(factors, 2 * np.arange(lmax + 1) + 1)[:, None]


def project(dirs, radiance, solid_angle, lmax: int, window: str | None = None) -> np.ndarray:
    """SH coefficients of radiance samples by quadrature.

    Parameters
    ----------
    dirs : (M, 3) array_like
        Unit directions (world frame), M >= 1.
    radiance : (M, C) or (M,) array_like
        Radiance from each direction; must be finite wherever ``solid_angle > 0``.
    solid_angle : (M,) array_like
        Quadrature weight (sr) of each sample, >= 0; 0 = unseen.
    lmax : int
        Band limit (0..200).
    window : {None, "none", "hann", "lanczos"}
        Optional taper (``sh_window``) applied to the result.

    Returns
    -------
    (ncoef, C) float64, or (ncoef,) for 1-D ``radiance``
        ``sum_k Y(d_k) radiance_k solid_angle_k``, windowed.
    """
    lmax = check_lmax(lmax)
    d = check_unit_dirs(dirs)
    if d.ndim != 2 or d.shape[0] == 0:
        raise ValueError(f"dirs must have shape (M, 3) with M >= 1, got {d.shape}")
    rad = np.asarray(radiance, dtype=np.float64)
    vector = rad.ndim == 1
    rad2 = rad[:, None] if vector else rad
    if rad2.ndim != 2 or rad2.shape[0] != d.shape[0] or rad2.shape[1] == 0:
        raise ValueError(f"radiance must have shape ({d.shape[0]}, C), got {rad.shape}")
    sa = np.asarray(solid_angle, dtype=np.float64)
    if sa.shape != (d.shape[0],):
        raise ValueError(f"solid_angle must have shape ({d.shape[0]},), got {sa.shape}")
    if not np.all(np.isfinite(sa)) or sa.min() < 0:
        raise ValueError("solid_angle must be finite and >= 0")
    seen = sa > 0
    if not np.all(np.isfinite(rad2[seen])):
        raise ValueError("radiance contains non-finite values where solid_angle > 0")
    d, weighted = d[seen], rad2[seen] * sa[seen, None]
    ncoef = (lmax + 1) ** 2
    out = np.zeros((ncoef, rad2.shape[1]))
    chunk = max(1, _CHUNK_ELEMENTS // ncoef)
    for s in range(0, d.shape[0], chunk):
        out += sh_eval(d[s : s + chunk], lmax).T @ weighted[s : s + chunk]
    out = _apply_window(out, lmax, window)
    return out[:, 0] if vector else out


def project_environment(env: Environment, lmax: int, window: str | None = None) -> np.ndarray:
    """``project(env.dirs, env.radiance, env.solid_angle, lmax, window)``: (ncoef, C) coefficients."""
    return project(env.dirs, env.radiance, env.solid_angle, lmax, window)


def _check_coeffs(coeffs) -> tuple[np.ndarray, int, bool]:
    c = np.asarray(coeffs, dtype=np.float64)
    vector = c.ndim == 1
    c2 = c[:, None] if vector else c
    if c2.ndim != 2:
        raise ValueError(f"coeffs must have shape (ncoef, C) or (ncoef,), got {c.shape}")
    if not np.all(np.isfinite(c2)):
        raise ValueError("coeffs contains non-finite values")
    return c2, sh_degree(c2.shape[0]), vector


def reconstruct(coeffs, dirs) -> np.ndarray:
    """Evaluate an SH expansion in given directions.

    Parameters
    ----------
    coeffs : (ncoef, C) or (ncoef,) array_like
        Coefficients, ``ncoef = (lmax + 1)**2``.
    dirs : (N, 3) array_like
        Unit directions.

    Returns
    -------
    (N, C) float64, or (N,) for 1-D ``coeffs``
        ``sum_lm coeffs_lm Y_lm(dir)``.
    """
    c, lmax, vector = _check_coeffs(coeffs)
    d = check_unit_dirs(dirs)
    if d.ndim != 2:
        raise ValueError(f"dirs must have shape (N, 3), got {d.shape}")
    out = np.empty((d.shape[0], c.shape[1]))
    chunk = max(1, _CHUNK_ELEMENTS // c.shape[0])
    for s in range(0, d.shape[0], chunk):
        out[s : s + chunk] = sh_eval(d[s : s + chunk], lmax) @ c
    return out[:, 0] if vector else out


# ----------------------------------------------------------------------------- lat-long (separable)


def _fejer_weights(n: int) -> np.ndarray:
    """Fejer's first rule on nodes ``x_k = cos((k + 1/2) pi / n)``: weights for integrals over [-1, 1].

    Exact for polynomials of degree <= n - 1 (hand-written: scipy has no Fejer rule;
    it is the closed form ``w_k = 2/n (1 - 2 sum_j cos(2 j t_k) / (4 j^2 - 1))``).
    """
    t = (np.arange(n) + 0.5) * np.pi / n
    j = np.arange(1, n // 2 + 1)
    return 2.0 / n * (1.0 - 2.0 * (np.cos(2.0 * np.outer(t, j)) / (4.0 * j * j - 1.0)).sum(axis=1))


@lru_cache(maxsize=8)
def _latlong_tables(height: int, lmax: int) -> tuple[np.ndarray, np.ndarray]:
    """``A[i, k] = A_l|m|(theta_i)`` (``Y_lm = A cos/sin(|m| phi)``) per row, and Fejer weights."""
    theta = (np.arange(height) + 0.5) * np.pi / height
    y = sh_eval(np.stack([np.sin(theta), np.zeros(height), np.cos(theta)], axis=-1), lmax)
    l = np.repeat(np.arange(lmax + 1), 2 * np.arange(lmax + 1) + 1)
    m = np.arange((lmax + 1) ** 2) - l * l - l
    table = y[:, sh_index(l, np.abs(m))]  # at phi = 0 the cos columns hold A, sin columns are 0
    weights = _fejer_weights(height)
    table.setflags(write=False)
    weights.setflags(write=False)
    return table, weights


@lru_cache(maxsize=8)
def _polar_frame_d(lmax: int) -> tuple[np.ndarray, ...]:
    """``D_l(Q^T)`` for l = 0..lmax (``Q = _LATLONG_TO_POLAR``): polar-frame -> world coefficients."""
    mats = tuple(wigner_d_real(_LATLONG_TO_POLAR.T[None], lmax))
    for a in mats:
        a.setflags(write=False)
    return mats


def _polar_to_world(coeffs: np.ndarray, lmax: int, inverse: bool = False) -> np.ndarray:
    """Coefficients of ``w -> g(Q w)`` from those of ``g`` (``inverse``: the other way round)."""
    out = np.empty_like(coeffs)
    for l, d in enumerate(_polar_frame_d(lmax)):
        s = slice(l * l, (l + 1) ** 2)
        out[s] = (d[0].T if inverse else d[0]) @ coeffs[s]
    return out


def _check_latlong_size(width: int, lmax: int) -> None:
    if width <= 2 * lmax:
        raise ValueError(f"a lat-long map {width} pixels wide resolves bands up to {(width - 1) // 2}, not lmax={lmax}")


def _longitude_phase(width: int, lmax: int) -> np.ndarray:
    """``exp(i m (pi - pi / W))``: links ``rfft`` bins to ``e^{i m phi_j}``, ``phi_j = pi - 2 pi (j + 1/2) / W``."""
    return np.exp(1j * np.arange(lmax + 1) * (np.pi - np.pi / width))


def project_latlong(image, lmax: int, window: str | None = None) -> np.ndarray:
    """SH coefficients of a lat-long map (OpenEXR convention) by the separable exact rule.

    Parameters
    ----------
    image : (H, W, C) or (H, W) array_like
        Finite radiance; pixels are point samples at their centres.
    lmax : int
        Band limit; needs ``W > 2 lmax`` (exact when also ``H > 2 lmax``).
    window : {None, "none", "hann", "lanczos"}
        Optional taper (``sh_window``).

    Returns
    -------
    (ncoef, C) float64, or (ncoef,) for a 2-D image
        World-frame coefficients.
    """
    lmax = check_lmax(lmax)
    img = np.asarray(image, dtype=np.float64)
    vector = img.ndim == 2
    img3 = img[..., None] if vector else img
    if img3.ndim != 3 or 0 in img3.shape:
        raise ValueError(f"image must be a non-empty (H, W, C) array, got shape {img.shape}")
    if not np.all(np.isfinite(img3)):
        raise ValueError("image contains non-finite values")
    h, w, nc = img3.shape
    _check_latlong_size(w, lmax)
    table, fejer = _latlong_tables(h, lmax)
    # channel-first so that each FFT runs over contiguous memory
    spec = np.fft.rfft(np.ascontiguousarray(img3.transpose(2, 0, 1)), axis=-1)[..., : lmax + 1]
    spec *= _longitude_phase(w, lmax) * ((2 * np.pi / w) * fejer[:, None])  # (C, H, m): weighted sums of f e^{i m phi_j}
    polar = np.empty(((lmax + 1) ** 2, nc))
    for m in range(lmax + 1):
        idx = sh_index(np.arange(m, lmax + 1), m)
        polar[idx] = table[:, idx].T @ spec[:, :, m].real.T
        if m:
            polar[idx - 2 * m] = table[:, idx].T @ spec[:, :, m].imag.T
    out = _apply_window(_polar_to_world(polar, lmax), lmax, window)
    return out[:, 0] if vector else out


def reconstruct_latlong(coeffs, height: int, width: int) -> np.ndarray:
    """Evaluate an SH expansion at the pixel centres of a lat-long map (separable).

    Parameters
    ----------
    coeffs : (ncoef, C) or (ncoef,) array_like
        World-frame coefficients.
    height, width : int
        Map size; needs ``width > 2 lmax``.

    Returns
    -------
    (H, W, C) float64, or (H, W) for 1-D ``coeffs``
    """
    c, lmax, vector = _check_coeffs(coeffs)
    for name, v in (("height", height), ("width", width)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
            raise ValueError(f"{name} must be a positive integer, got {v!r}")
    _check_latlong_size(width, lmax)
    polar = _polar_to_world(c, lmax, inverse=True)
    table, _ = _latlong_tables(height, lmax)
    spec = np.zeros((height, width // 2 + 1, c.shape[1]), dtype=complex)
    for m in range(lmax + 1):
        idx = sh_index(np.arange(m, lmax + 1), m)
        a = table[:, idx] @ polar[idx]
        b = table[:, idx] @ polar[idx - 2 * m] if m else 0.0
        spec[:, m] = (a - 1j * b) * _longitude_phase(width, lmax)[m]
    spec = np.conj(spec) * (width / 2.0)
    spec[:, 0] *= 2.0
    out = np.fft.irfft(spec, n=width, axis=1)
    return out[..., 0] if vector else out
