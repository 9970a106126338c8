"""Environment-image geometry: per-pixel directions and exact solid angles, and inverse maps.

Conventions (public contract, ``docs/MATH.md``): world frame
right-handed, camera far along +z; image column grows with +x, row grows with
-y; pixel ``(i, j)`` has its centre at continuous image coordinates
``(x, y) = (j + 0.5, i + 0.5)``.  Directions are unit vectors the light
arrives FROM.  Three parametrisations:

- lat-long (OpenEXR ``LatLongMap``): ``u = x / W``, ``t = y / H``,
  longitude ``lam = -2 pi (u - 1/2)``, latitude ``phi = -pi (t - 1/2)``,
  ``dir = (sin lam cos phi, sin phi, cos lam cos phi)``; the image centre looks
  at +z, the top row at +y.
- mirror ball seen orthographically, circle ``(cx, cy, r)`` in image
  coordinates: the normal at image offset ``(dx, dy) = (x - cx, cy - y) / r`` is
  ``n = (dx, dy, sqrt(1 - dx^2 - dy^2))`` and the reflected direction is
  ``w = 2 (n.v) n - v`` with ``v = (0, 0, 1)``; every unit of disc area subtends
  ``4 / r^2`` sr.
- angular map (Debevec's light-probe format), square of side ``S``, disc radius
  ``R = S / 2`` centred in the image: ``theta = pi * rho`` with ``rho`` the
  distance from the centre over ``R``, measured from +z (the centre looks at +z,
  like the mirror ball; the rim is -z), azimuth as in the image.

Solid angles are EXACT integrals of the parametrisation's Jacobian over each
pixel's square (lat-long: closed form per row; mirror ball: closed-form area of
pixel-square intersect disc; angular map: tensor Gauss-Legendre per pixel,
finer at the rim), so that each map sums to ``4 pi`` to rounding, which the
per-pixel-centre formulas of MATH.md do only to O(1/H^2).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

__all__ = [
    "angular_directions",
    "latlong_directions",
    "latlong_pixels",
    "mirrorball_directions",
    "mirrorball_pixels",
    "sample_latlong",
]

#: Largest accepted deviation of ``|dir|`` from 1 for direction inputs.
UNIT_TOLERANCE = 1e-6


# ----------------------------------------------------------------------------- validation


def _check_size(value, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")
    return int(value)


def _check_dirs(dirs, name: str = "dirs") -> np.ndarray:
    d = np.asarray(dirs, dtype=np.float64)
    if d.ndim < 1 or d.shape[-1] != 3:
        raise ValueError(f"{name} must have shape (..., 3), got {d.shape}")
    if not np.all(np.isfinite(d)):
        raise ValueError(f"{name} contains non-finite values")
    if d.size and np.abs(np.einsum("...i,...i->...", d, d) - 1.0).max() > 2 * UNIT_TOLERANCE:
        raise ValueError(f"{name} must be unit vectors")
    return d


def _check_circle(circle) -> tuple[float, float, float]:
    c = np.asarray(circle, dtype=np.float64)
    if c.shape != (3,) or not np.all(np.isfinite(c)) or c[2] <= 0:
        raise ValueError(f"circle must be finite (cx, cy, r) with r > 0, got {circle!r}")
    return float(c[0]), float(c[1]), float(c[2])


# ----------------------------------------------------------------------------- lat-long


def latlong_directions(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Directions and solid angles of the pixels of a lat-long map.

    Parameters
    ----------
    height, width : int
        Map size in pixels (``H`` rows, ``W`` columns), both >= 1.

    Returns
    -------
    dirs : (H, W, 3) float64
        Unit direction of each pixel centre (OpenEXR ``LatLongMap``).
    solid_angle : (H, W) float64
        Exact solid angle of each pixel in sr: ``(2 pi / W) (sin phi_top - sin phi_bottom)``
        (the integral of ``cos phi`` over the row); the map sums to ``4 pi``.
    """
    h = _check_size(height, "height")
    w = _check_size(width, "width")
    lam = -2 * np.pi * ((np.arange(w) + 0.5) / w - 0.5)
    phi = -np.pi * ((np.arange(h) + 0.5) / h - 0.5)
    edges = np.sin(-np.pi * (np.arange(h + 1) / h - 0.5))
    cp = np.cos(phi)[:, None]
    dirs = np.stack(
        np.broadcast_arrays(np.sin(lam)[None, :] * cp, np.sin(phi)[:, None], np.cos(lam)[None, :] * cp),
        axis=-1,
    )
    solid = np.broadcast_to(((2 * np.pi / w) * (edges[:-1] - edges[1:]))[:, None], (h, w)).copy()
    return dirs, solid


def latlong_pixels(dirs, height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Continuous image coordinates where directions fall in a lat-long map (inverse of ``latlong_directions``).

    Parameters
    ----------
    dirs : (..., 3) array_like
        Unit directions.
    height, width : int
        Map size.

    Returns
    -------
    x, y : (...) float64
        Image coordinates, ``x`` in ``[0, W)`` (longitude wraps), ``y`` in ``[0, H]``;
        pixel ``(i, j)``'s centre is ``(j + 0.5, i + 0.5)``.
    """
    h = _check_size(height, "height")
    w = _check_size(width, "width")
    d = _check_dirs(dirs)
    lam = np.arctan2(d[..., 0], d[..., 2])
    phi = np.arctan2(d[..., 1], np.hypot(d[..., 0], d[..., 2]))
    x = np.mod((0.5 - lam / (2 * np.pi)) * w, w)
    y = (0.5 - phi / np.pi) * h
    return x, y


def sample_latlong(image, dirs) -> np.ndarray:
    """Bilinear lookup of a lat-long map in given directions.

    Parameters
    ----------
    image : (H, W, C) array_like
        Lat-long map (``(H, W)`` is taken as one channel).
    dirs : (..., 3) array_like
        Unit directions.

    Returns
    -------
    (..., C) float64
        Values interpolated between the four nearest pixel centres; longitude wraps
        around, latitude clamps at the first/last row's centre.

    Notes
    -----
    Uses ``scipy.ndimage.map_coordinates`` (order 1) on the map padded by one
    wrapped column each side, since its boundary modes apply to all axes at once.
    """
    from scipy.ndimage import map_coordinates

    img = np.asarray(image, dtype=np.float64)
    if img.ndim == 2:
        img = img[..., None]
    if img.ndim != 3 or img.shape[0] == 0 or img.shape[1] == 0 or img.shape[2] == 0:
        raise ValueError(f"image must be a non-empty (H, W, C) array, got shape {np.shape(image)}")
    h, w, nc = img.shape
    x, y = latlong_pixels(dirs, h, w)
    padded = np.concatenate([img[:, -1:], img, img[:, :1]], axis=1)
    coords = np.stack([y.ravel() - 0.5, x.ravel() + 0.5])
    out = np.stack([map_coordinates(padded[..., c], coords, order=1, mode="nearest") for c in range(nc)], axis=-1)
    return out.reshape(x.shape + (nc,))


# ----------------------------------------------------------------------------- mirror ball


def _disc_quadrant_area(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Signed area of ``{(s, t): s^2 + t^2 < 1}`` within ``[0, x] x [0, y]`` (odd in x and y).

    Closed form (a rectangle part plus the integral of the arc), written here
    because neither OpenCV nor scikit-image give exact pixel/disc overlap areas
    (only rasterised or anti-aliased discs).
    """
    sx, sy = np.sign(x), np.sign(y)
    x, y = np.minimum(np.abs(x), 1.0), np.minimum(np.abs(y), 1.0)
    xs = np.sqrt(np.maximum(1.0 - y * y, 0.0))  # where the arc crosses t = y

    def arc(s):  # integral_0^s sqrt(1 - u^2) du
        return 0.5 * (s * np.sqrt(np.maximum(1.0 - s * s, 0.0)) + np.arcsin(s))

    area = np.where(x <= xs, x * y, y * xs + arc(x) - arc(xs))
    return sx * sy * area


def _disc_coverage(shape: tuple[int, int], cx: float, cy: float, r: float) -> np.ndarray:
    """Exact fraction of each pixel square covered by the disc (cx, cy, r)."""
    h, w = shape
    xe = (np.arange(w + 1) - cx) / r
    ye = (np.arange(h + 1) - cy) / r
    f = _disc_quadrant_area(xe[None, :], ye[:, None])  # (H+1, W+1) corner function
    area = np.clip((f[1:, 1:] - f[1:, :-1] - f[:-1, 1:] + f[:-1, :-1]) * r * r, 0.0, 1.0)
    # The corner-function differences leave ~1e-13 of roundoff on pixels the disc
    # does not touch at all: decide those exactly from the nearest point of each square.
    near_x = np.maximum(np.maximum(xe[:-1], -xe[1:]), 0.0)
    near_y = np.maximum(np.maximum(ye[:-1], -ye[1:]), 0.0)
    area[near_x[None, :] ** 2 + near_y[:, None] ** 2 >= 1.0] = 0.0
    return area


def mirrorball_directions(shape, circle) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Reflected directions and solid angles of the pixels of an orthographic mirror-ball image.

    Parameters
    ----------
    shape : (H, W)
        Image size (extra trailing entries, e.g. channels, are ignored).
    circle : (cx, cy, r)
        Ball outline in image coordinates (pixels; y down).

    Returns
    -------
    dirs : (H, W, 3) float64
        Direction seen at each pixel centre, ``2 (n.v) n - v``.  Pixels whose centre
        lies on or outside the outline use the nearest point just inside it
        (directions there converge to ``-v``); outside pixels get ``-v``.
    solid_angle : (H, W) float64
        ``4 / r^2`` sr times the exact fraction of the pixel square inside the disc;
        sums to ``4 pi``.
    inside : (H, W) bool
        Pixels at least partly covered by the ball (``solid_angle > 0``).
    """
    if len(shape) < 2:
        raise ValueError(f"shape must be (H, W), got {shape!r}")
    h, w = _check_size(shape[0], "shape[0]"), _check_size(shape[1], "shape[1]")
    cx, cy, r = _check_circle(circle)
    coverage = _disc_coverage((h, w), cx, cy, r)
    dx = ((np.arange(w) + 0.5 - cx) / r)[None, :]
    dy = ((cy - np.arange(h) - 0.5) / r)[:, None]
    dx, dy = np.broadcast_arrays(dx, dy)
    rho = np.hypot(dx, dy)
    shrink = np.where(rho >= 1.0, (1.0 - 1e-12) / np.maximum(rho, 1e-300), 1.0)
    dx, dy = dx * shrink, dy * shrink
    nz = np.sqrt(np.maximum(1.0 - dx * dx - dy * dy, 0.0))
    dirs = np.stack([2 * nz * dx, 2 * nz * dy, 2 * nz * nz - 1.0], axis=-1)
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
    inside = coverage > 0
    return dirs, 4.0 / (r * r) * coverage, inside


def mirrorball_pixels(dirs, circle) -> tuple[np.ndarray, np.ndarray]:
    """Where on an orthographic mirror-ball image each direction is seen (inverse map).

    Parameters
    ----------
    dirs : (..., 3) array_like
        Unit directions.
    circle : (cx, cy, r)
        Ball outline in image coordinates.

    Returns
    -------
    x, y : (...) float64
        Image coordinates of the ball point whose normal is the half vector
        ``(w + v) / |w + v|``.  The exact back direction ``-v`` (seen all round the
        rim) maps to the rim point at +x.
    """
    cx, cy, r = _check_circle(circle)
    d = _check_dirs(dirs)
    half = d + np.array([0.0, 0.0, 1.0])
    norm = np.linalg.norm(half, axis=-1)
    back = norm < 1e-12
    nx = np.where(back, 1.0, half[..., 0] / np.where(back, 1.0, norm))
    ny = np.where(back, 0.0, half[..., 1] / np.where(back, 1.0, norm))
    return cx + r * nx, cy - r * ny


# ----------------------------------------------------------------------------- angular map

#: Gauss-Legendre points per axis and pixel: interior pixels, and pixels crossed by the rim.
_ANGULAR_NODES = 4
_ANGULAR_RIM_NODES = 64


@lru_cache(maxsize=4)
def _angular_maps(size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    radius = size / 2.0

    def direction(dx, dy):
        rho = np.hypot(dx, dy)
        theta = np.pi * np.minimum(rho, 1.0)
        s = np.where(rho > 0, np.sin(theta) / np.where(rho > 0, rho, 1.0), np.pi)
        return np.stack([s * dx, s * dy, np.cos(theta)], axis=-1), rho

    def density(rho):  # dOmega / dA in units of the normalised disc (radius 1): pi^2 sin(theta)/theta
        return np.where(rho < 1.0, np.pi * np.pi * np.sinc(rho), 0.0)

    def pixel_integral(rows, cols, nodes):
        g, wt = np.polynomial.legendre.leggauss(nodes)
        off = 0.5 * g  # sub-pixel offsets in [-0.5, 0.5]
        x = cols[:, None, None] + 0.5 + off[None, :, None]
        y = rows[:, None, None] + 0.5 + off[None, None, :]
        rho = np.hypot((x - radius) / radius, (radius - y) / radius)
        return (density(rho) * (0.25 * wt[None, :, None] * wt[None, None, :])).sum(axis=(1, 2)) / radius**2

    rows, cols = np.mgrid[0:size, 0:size]
    rows, cols = rows.ravel(), cols.ravel()
    dx = (cols + 0.5 - radius) / radius
    dy = (radius - rows - 0.5) / radius
    dirs, rho = direction(dx, dy)
    # pixel squares crossed by the rim (farthest corner outside, nearest point inside)
    half = 0.5 / radius
    far = np.hypot(np.abs(dx) + half, np.abs(dy) + half)
    near = np.hypot(np.maximum(np.abs(dx) - half, 0.0), np.maximum(np.abs(dy) - half, 0.0))
    rim = (far > 1.0) & (near < 1.0)
    solid = np.zeros(size * size)
    interior = near < 1.0
    solid[interior & ~rim] = pixel_integral(rows[interior & ~rim], cols[interior & ~rim], _ANGULAR_NODES)
    solid[rim] = pixel_integral(rows[rim], cols[rim], _ANGULAR_RIM_NODES)
    inside = solid > 0
    out = dirs.reshape(size, size, 3), solid.reshape(size, size), inside.reshape(size, size)
    for a in out:
        a.setflags(write=False)
    return out


def angular_directions(size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Directions and solid angles of the pixels of an angular map (Debevec's light-probe format).

    Parameters
    ----------
    size : int
        Side ``S`` of the square image; the disc has radius ``S / 2`` and is centred.

    Returns
    -------
    dirs : (S, S, 3) float64
        Direction at each pixel centre: ``theta = pi * rho`` from +z (centre) to -z (rim);
        centres outside the disc get ``-z``.
    solid_angle : (S, S) float64
        Integral of ``(pi / R)^2 sin(theta) / theta`` over the part of each pixel inside
        the disc (4x4 Gauss-Legendre points per pixel, 64x64 on pixels crossed by the
        rim, where the density has a kink); sums to ``4 pi`` within ~1e-8 for S >= 64.
    inside : (S, S) bool
        Pixels with a non-zero solid angle.
    """
    s = _check_size(size, "size")
    dirs, solid, inside = _angular_maps(s)
    return dirs.copy(), solid.copy(), inside.copy()
