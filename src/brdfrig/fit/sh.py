"""Real orthonormal spherical harmonics, evaluated for many directions at once.

Convention (public contract, ``docs/MATH.md``), the one of sphericart:

- column ``sh_index(l, m) = l*l + l + m`` for ``0 <= l <= lmax``, ``-l <= m <= l``;
- orthonormal on the unit sphere: ``integral Y_lm Y_l'm' dOmega = delta_ll' delta_mm'``;
- polar axis +z, azimuth ``phi = atan2(y, x)``, NO Condon-Shortley phase:
  ``Y_l0 = K_l0 P_l(cos theta)``, and for ``m > 0``
  ``Y_lm = A_lm(theta) cos(m phi)``, ``Y_l,-m = A_lm(theta) sin(m phi)`` with the
  same factor ``A_lm(theta) = Y_lm(theta, phi=0)``; equivalently
  ``Y_l,+-m = sqrt(2) (-1)^m Re/Im sph_harm_y(l, m, theta, phi)`` (scipy, which
  includes the Condon-Shortley phase).  Band 1 is ``sqrt(3/4pi) (y, z, x)``.

Evaluation: sphericart (a well-kept, fast C++ library) up to
``SPHERICART_MAX_LMAX``.  Measured with sphericart 2.0.4: it matches
``scipy.special.sph_harm_y`` to ~6e-14 up to l = 86, but from l = 87 on it
returns wrong values (zeros instead of ~1.3) for the highest orders |m| near
the equator.  Above ``SPHERICART_MAX_LMAX`` the values therefore come from
scipy's normalised associated-Legendre recursion
(``scipy.special.assoc_legendre_p_all(norm=True)``, stable to l = 200 and
beyond, about 10x slower) times ``cos/sin(m phi)``.  Measured: the Gram matrix
of ``sh_eval`` under Gauss-Legendre x uniform-phi quadrature equals the
identity to 1.2e-13 at l = 60.  Both paths are checked
against ``sph_harm_y`` in ``tests/test_sh.py``.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

__all__ = [
    "LMAX_LIMIT",
    "SPHERICART_MAX_LMAX",
    "UNIT_TOLERANCE",
    "check_lmax",
    "check_unit_dirs",
    "num_coeffs",
    "sh_degree",
    "sh_eval",
    "sh_index",
]

#: Largest band limit accepted anywhere in ``fit`` (beyond this, a request is a mistake).
LMAX_LIMIT = 200
#: Band limits up to this use sphericart; above it, scipy's normalised Legendre recursion.
SPHERICART_MAX_LMAX = 80
#: Largest accepted deviation of ``|dir|`` from 1 for "unit" direction inputs.
UNIT_TOLERANCE = 1e-6


def check_lmax(lmax, name: str = "lmax") -> int:
    """Return ``lmax`` as an int after checking ``0 <= lmax <= LMAX_LIMIT``.

    Raises
    ------
    ValueError
        Naming ``name`` when ``lmax`` is not an integer in range.
    """
    if isinstance(lmax, bool) or not isinstance(lmax, (int, np.integer)):
        raise ValueError(f"{name} must be an integer, got {lmax!r}")
    if not 0 <= lmax <= LMAX_LIMIT:
        raise ValueError(f"{name} must be in [0, {LMAX_LIMIT}], got {lmax}")
    return int(lmax)


def check_unit_dirs(dirs, name: str = "dirs") -> np.ndarray:
    """Return ``dirs`` as a float64 array of shape ``(..., 3)`` of unit vectors.

    Raises
    ------
    ValueError
        Naming ``name`` when the shape is not ``(..., 3)``, a value is not finite,
        or a vector's norm differs from 1 by more than ``UNIT_TOLERANCE``.
    """
    d = np.asarray(dirs, dtype=np.float64)
    if d.ndim < 1 or d.shape[-1] != 3:
        raise ValueError(f"{name} must have shape (..., 3), got {d.shape}")
    if not np.all(np.isfinite(d)):
        raise ValueError(f"{name} contains non-finite values")
    if d.size:
        err = np.abs(np.einsum("...i,...i->...", d, d) - 1.0).max()
        if err > 2 * UNIT_TOLERANCE:
            raise ValueError(f"{name} must be unit vectors (largest | |d|^2 - 1 | = {err:.3g})")
    return d


def num_coeffs(lmax: int) -> int:
    """Number of real SH coefficients up to and including band ``lmax``: ``(lmax + 1)**2``."""
    return (check_lmax(lmax) + 1) ** 2


def sh_index(l, m):
    """Column of ``Y_lm``: ``l*l + l + m`` (works on ints and integer arrays)."""
    return l * l + l + m


def sh_degree(ncoef: int, name: str = "coeffs") -> int:
    """Band limit ``lmax`` of a coefficient vector of length ``ncoef = (lmax + 1)**2``.

    Raises
    ------
    ValueError
        Naming ``name`` when ``ncoef`` is not a perfect square in range.
    """
    lmax = int(round(np.sqrt(ncoef))) - 1
    if lmax < 0 or (lmax + 1) ** 2 != ncoef:
        raise ValueError(f"{name} must have (lmax+1)**2 rows, got {ncoef}")
    return check_lmax(lmax, f"band limit of {name}")


@lru_cache(maxsize=8)
def _calculator(lmax: int):
    import sphericart

    return sphericart.SphericalHarmonics(lmax)


def _sh_eval_legendre(flat: np.ndarray, lmax: int) -> np.ndarray:
    """Real SH of unit vectors ``(N, 3)`` from scipy's normalised ``P_l^m`` (all l, m).

    ``assoc_legendre_p_all(norm=True)`` is normalised to unit L2 norm on [-1, 1]
    and includes the Condon-Shortley phase, hence the factor ``(-1)^m / sqrt(pi)``
    (``1 / sqrt(2 pi)`` for m = 0) in this module's convention.
    """
    from scipy.special import assoc_legendre_p_all

    ncoef = (lmax + 1) ** 2
    out = np.empty((flat.shape[0], ncoef))
    m = np.arange(1, lmax + 1)
    scale = (-1.0) ** m / np.sqrt(np.pi)
    chunk = max(1, (1 << 23) // ((lmax + 1) * (2 * lmax + 1)))
    for s in range(0, flat.shape[0], chunk):
        d = flat[s : s + chunk]
        p = assoc_legendre_p_all(lmax, lmax, np.clip(d[:, 2], -1.0, 1.0), norm=True)[0]  # (l, m, N)
        phi = np.arctan2(d[:, 1], d[:, 0])
        cos = np.cos(m[:, None] * phi) * scale[:, None]
        sin = np.sin(m[:, None] * phi) * scale[:, None]
        o = out[s : s + chunk]
        for l in range(lmax + 1):
            c = l * l + l
            o[:, c] = p[l, 0] / np.sqrt(2 * np.pi)
            o[:, c + 1 : c + l + 1] = (p[l, 1 : l + 1] * cos[:l]).T
            o[:, c - l : c] = (p[l, 1 : l + 1] * sin[:l])[::-1].T
    return out


def sh_eval(dirs, lmax: int) -> np.ndarray:
    """Evaluate all real SH up to band ``lmax`` at unit directions.

    Parameters
    ----------
    dirs : (..., 3) array_like
        Unit direction vectors (world frame); checked to ``UNIT_TOLERANCE``.
    lmax : int
        Band limit, ``0 <= lmax <= LMAX_LIMIT``.

    Returns
    -------
    (..., (lmax + 1)**2) float64
        ``Y[..., sh_index(l, m)] = Y_lm(dir)`` in the module's convention.
    """
    lmax = check_lmax(lmax)
    d = check_unit_dirs(dirs)
    flat = np.ascontiguousarray(d.reshape(-1, 3))
    if flat.shape[0] == 0:
        return np.zeros(d.shape[:-1] + ((lmax + 1) ** 2,))
    if lmax <= SPHERICART_MAX_LMAX:
        out = _calculator(lmax).compute(flat)
    else:
        out = _sh_eval_legendre(flat, lmax)
    return out.reshape(d.shape[:-1] + (-1,))
