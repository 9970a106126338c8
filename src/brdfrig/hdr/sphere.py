"""Pixels of a sphere seen orthographically: which pixels, their normals and their weights.

Convention (``docs/MATH.md``): the sphere's outline is the circle
``(cx, cy, r)`` in image coordinates (pixel ``(i, j)`` has its centre at
``(j + 0.5, i + 0.5)``, y down); the normal of the pixel at offset
``(dx, dy) = (x - cx, cy - y) / r`` is ``n = (dx, dy, sqrt(1 - dx^2 - dy^2))``
(camera along +z).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["DEFAULT_LIMB_MARGIN_PX", "SpherePixels", "sphere_pixels"]

#: Width (pixels) of the ring inside the limb that gets weight 0.  Near the limb the
#: normal changes fastest per pixel (d theta / d rho -> infinity), so a sub-pixel
#: error in the detected circle or the pixel's area average turns into large normal
#: errors, and the view is grazing; two pixels keep that ring out of the fit.
DEFAULT_LIMB_MARGIN_PX = 2.0


@dataclass(frozen=True)
class SpherePixels:
    """Pixels whose centre lies inside a sphere's outline.

    Attributes
    ----------
    rows, cols : (N,) int64
        Pixel indices in the image.
    normals : (N, 3) float64
        Unit normal at each pixel centre (world frame, camera along +z).
    weights : (N,) float64
        1 for usable pixels; 0 for pixels partly outside the disc and within
        ``margin_px`` of the limb.
    """

    rows: np.ndarray
    cols: np.ndarray
    normals: np.ndarray
    weights: np.ndarray


def sphere_pixels(shape, circle, margin_px: float = DEFAULT_LIMB_MARGIN_PX) -> SpherePixels:
    """Pixels of the sphere with outline ``circle`` in an image of size ``shape``.

    Parameters
    ----------
    shape : (H, W) or (H, W, C)
        Image size.
    circle : (cx, cy, r)
        Outline in image coordinates (pixels), ``r > 0``.
    margin_px : float
        Pixels whose centre is closer than this to the limb get weight 0 (>= 0).

    Returns
    -------
    SpherePixels
        Every in-image pixel whose centre is strictly inside the circle, row-major.
    """
    if len(shape) < 2 or any(not isinstance(s, (int, np.integer)) or s < 1 for s in shape[:2]):
        raise ValueError(f"shape must start with two positive integers (H, W), got {shape!r}")
    c = np.asarray(circle, dtype=np.float64)
    if c.shape != (3,) or not np.all(np.isfinite(c)) or c[2] <= 0:
        raise ValueError(f"circle must be finite (cx, cy, r) with r > 0, got {circle!r}")
    if not np.isfinite(margin_px) or margin_px < 0:
        raise ValueError(f"margin_px must be a finite number >= 0, got {margin_px!r}")
    cx, cy, r = c
    h, w = int(shape[0]), int(shape[1])
    rows, cols = np.mgrid[0:h, 0:w]
    dx = (cols + 0.5 - cx) / r
    dy = (cy - rows - 0.5) / r
    rho2 = dx * dx + dy * dy
    sel = rho2 < 1.0
    rows, cols, dx, dy = rows[sel], cols[sel], dx[sel], dy[sel]
    normals = np.stack([dx, dy, np.sqrt(1.0 - dx * dx - dy * dy)], axis=-1)
    # farthest corner of the pixel square from the centre, in pixels
    half = 0.5 / r
    far = r * np.hypot(np.abs(dx) + half, np.abs(dy) + half)
    dist_to_limb = r * (1.0 - np.hypot(dx, dy))
    weights = ((far <= r) & (dist_to_limb >= margin_px)).astype(np.float64)
    return SpherePixels(rows=rows.astype(np.int64), cols=cols.astype(np.int64), normals=normals, weights=weights)
