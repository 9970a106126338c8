"""Find the circle of a sphere (chrome probe or sample) in an HDR image to sub-pixel accuracy.

Two stages:

1. Coarse: OpenCV ``HoughCircles`` (``HOUGH_GRADIENT_ALT``) on a log-compressed,
   8-bit, downscaled copy of the luminance.  Log compression makes a bright
   ball on a dark background and a dark ball on a bright one look alike and
   keeps clipped highlights from dominating.  Hough alone is good to 0.5-1 px.
2. Ray stage (hand-written, as OpenCV has no sub-pixel circle refinement),
   on a 3x3 median of the image so that isolated bright pixels or speckles
   outside the ball are not taken for its edge: along ``n_rays`` rays from
   the coarse centre the luminance profile is sampled across the expected
   rim; each ray's rim is its outermost edge of at least 10% contrast
   (reflections squeezed inside a chrome ball's rim and clipped highlights
   make stronger edges further in), located where the linear profile crosses
   halfway between the levels just inside and just outside; rays without
   such an edge (a stand under the ball, a background matching the rim) are
   dropped.  A robust geometric circle fit (soft-L1 loss plus outlier
   rejection) of the edge points, repeated around the new circle, gives the
   circle to a few tenths of a pixel.  The halfway rule is biased wherever
   the ball's radiance changes across the last pixel (a chrome ball's rim
   compresses tens of degrees of the room into it).
3. Model stage: every pixel within ``_RIM_HALF_WIDTH`` of the circle is
   fitted with the known anti-aliased disc profile -- the pixel-area integral
   of the ball's radiance ``a + b sqrt(depth) + c depth`` inside the outline
   (the limb behaviour of both a mirror ball's reflected direction and a
   diffuse sphere's shading) plus a linear background outside it -- with the
   radiance coefficients solved per rim sector by linear least squares and
   the circle by ``scipy.optimize.least_squares`` (variable projection);
   sectors without an edge or that the model cannot explain, and outlying
   pixels, are dropped.  The answer must agree with the ray stage to 1.5 px
   and with the coarse circle to ``max(5, 0.1 r)`` px, or the candidate is
   rejected.

A sphere touching the frame edges (e.g. what ``brdfrig render`` writes: radius
N/2, centred) leaves no background outside its rim where it touches them, so
Hough sees no full circle.  When nothing is found, the search is repeated on
the image padded by a margin of the background level (the median of the four
corner patches); a circle found there is accepted if it lies within the frame
(to 0.5 px; its radius is then clipped to the frame).

Coordinates follow MATH.md: x = column, y = row (down), pixel (i, j) has its
centre at (j + 0.5, i + 0.5).
"""

from __future__ import annotations

import numpy as np

from brdfrig.errors import InputError

__all__ = ["detect_sphere", "refine_circle", "SphereNotFoundError"]

_HOUGH_MAX_DIM = 480  # coarse search image size (pixels)
_HOUGH_MIN_RADIUS = 12  # smallest radius worth searching after downscaling (pixels)
_MIN_CONTRAST = 0.1  # smallest relative step from ball to background that counts as the rim (10%)
_RIM_HALF_WIDTH = 2.0  # half width (px) of the annulus the final rim model is fitted over
_SECTOR_ARC = 8.0  # arc length (px) of one rim sector with its own radiance model
_MAX_SECTORS = 256  # sectors used at most (evenly spread), bounding the cost at large radii
_SS = 4  # sub-samples per pixel side for the rim model's coverage integrals


class SphereNotFoundError(InputError):
    """No sphere could be found in the image."""


def _luminance(image: np.ndarray, name: str = "detect_sphere") -> np.ndarray:
    image = np.asarray(image, dtype=np.float32)
    if image.ndim == 3:
        image = image.mean(axis=2) if image.shape[2] != 1 else image[:, :, 0]
    if image.ndim != 2:
        raise InputError(f"{name}: expected an (H, W) or (H, W, C) image, got shape {image.shape}")
    if not np.all(np.isfinite(image)):
        raise InputError(f"{name}: the image contains NaN/inf pixels")
    return image


def _coarse_circles(lum: np.ndarray, min_radius: float, max_radius: float) -> np.ndarray:
    """Hough candidates (cx, cy, r) in full-resolution pixel coordinates (pixel centres at +0.5), best first."""
    import cv2

    h, w = lum.shape
    scale = min(1.0, max(_HOUGH_MAX_DIM / max(h, w), _HOUGH_MIN_RADIUS / max(min_radius, 1.0)))
    positive = lum[lum > 0]
    ref = float(np.median(positive)) if positive.size else 1.0
    comp = np.log1p(np.maximum(lum, 0) / (0.05 * ref))
    lo, hi = np.percentile(comp, [0.5, 99.5])
    grey = np.clip((comp - lo) / max(hi - lo, 1e-12) * 255, 0, 255).astype(np.uint8)
    if scale < 1:
        grey = cv2.resize(grey, (max(1, round(w * scale)), max(1, round(h * scale))), interpolation=cv2.INTER_AREA)
    grey = cv2.GaussianBlur(grey, (5, 5), 1.2)
    sx, sy = grey.shape[1] / w, grey.shape[0] / h
    circles = None
    for perfectness in (0.9, 0.8, 0.65, 0.5):
        circles = cv2.HoughCircles(grey, cv2.HOUGH_GRADIENT_ALT, dp=1.5, minDist=max(4.0, min_radius * scale),
                                   param1=60, param2=perfectness,
                                   minRadius=max(3, int(min_radius * scale * 0.9)),
                                   maxRadius=int(np.ceil(max_radius * scale * 1.1)) + 1)
        if circles is not None and len(circles[0]):
            break
    if circles is None or not len(circles[0]):
        return np.zeros((0, 3))
    c = circles[0][:, :3].astype(float)
    # OpenCV's pixel centres are at integers: convert to MATH.md's (+0.5) and undo the downscale.
    return np.stack([(c[:, 0] + 0.5) / sx, (c[:, 1] + 0.5) / sy, c[:, 2] / (0.5 * (sx + sy))], axis=1)


def _edge_points(lum: np.ndarray, circle, n_rays: int, band: float):
    """Sub-pixel rim points along rays across ``circle`` and their log contrasts.

    On each ray the rim is the OUTERMOST step of at least ``_MIN_CONTRAST`` in
    log luminance: the silhouette is the last edge before the background,
    whereas the reflections squeezed inside a chrome ball's rim or a clipped
    highlight make stronger edges further in.  Its sub-pixel position is where
    the linear profile crosses halfway between the levels 2.5 px either side
    (the 50% coverage point of an anti-aliased edge).
    """
    from scipy.ndimage import map_coordinates

    cx, cy, r = circle
    phi = np.linspace(0, 2 * np.pi, n_rays, endpoint=False)
    step = 0.25
    s = np.arange(-band - 3.5, band + 3.5 + step / 2, step)  # radial offsets from the rim (+ level margins)
    rad = r + s
    xs = cx + np.cos(phi)[:, None] * rad[None, :]
    ys = cy + np.sin(phi)[:, None] * rad[None, :]
    prof = map_coordinates(lum, [ys - 0.5, xs - 0.5], order=1, mode="nearest")  # pixel centres at integers
    eps = 0.01 * max(float(np.median(np.abs(prof))), 1e-30)
    q = np.log(np.abs(prof) + eps)
    one, lev = int(round(0.5 / step)), int(round(1.0 / step))
    contrast = np.zeros_like(q)
    contrast[:, one:-one] = q[:, 2 * one:] - q[:, :-2 * one]  # log step across +-0.5 px
    mag = np.abs(contrast)
    peak = np.zeros_like(mag, dtype=bool)
    peak[:, 1:-1] = (mag[:, 1:-1] >= mag[:, :-2]) & (mag[:, 1:-1] > mag[:, 2:]) & (mag[:, 1:-1] > _MIN_CONTRAST)
    lo_k, hi_k = lev, len(s) - lev - 1  # room for the level samples
    peak[:, :lo_k] = False
    peak[:, hi_k:] = False
    pts, strength = [], []
    for i in np.nonzero(peak.any(axis=1))[0]:
        k = int(np.nonzero(peak[i])[0][-1])  # outermost
        p = prof[i]
        inside, outside = p[k - lev], p[k + lev]
        half = 0.5 * (inside + outside)
        seg = p[k - lev:k + lev + 1] - half
        cross = np.nonzero(np.sign(seg[:-1]) != np.sign(seg[1:]))[0]
        if not cross.size:
            continue
        j = int(cross[np.argmin(np.abs(cross - lev))])
        t = seg[j] / (seg[j] - seg[j + 1])
        rr = rad[k - lev + j] + t * step
        pts.append((cx + np.cos(phi[i]) * rr, cy + np.sin(phi[i]) * rr))
        strength.append(mag[i, k])
    return np.asarray(pts).reshape(-1, 2), np.asarray(strength)


def _fit_circle(pts: np.ndarray, start) -> np.ndarray:
    """Robust geometric circle fit (soft-L1 loss) of (N, 2) points."""
    from scipy.optimize import least_squares

    def resid(q):
        return np.hypot(pts[:, 0] - q[0], pts[:, 1] - q[1]) - q[2]

    return least_squares(resid, np.asarray(start, float), loss="soft_l1", f_scale=0.3).x


def _ray_refine(lum: np.ndarray, circle, n_rays: int, iterations: int) -> tuple[float, float, float]:
    """Ray-profile refinement of a rough circle (within a few px) to a few tenths of a pixel."""
    cx, cy, r = (float(v) for v in circle)
    band = max(4.0, 0.04 * r)
    for _ in range(iterations):
        pts, contrast = _edge_points(lum, (cx, cy, r), n_rays, band)
        if len(pts) < 0.3 * n_rays:
            raise SphereNotFoundError(f"no sphere rim found near circle ({cx:.1f}, {cy:.1f}, {r:.1f}): "
                                      f"only {len(pts)} of {n_rays} rays cross an edge")
        keep = contrast >= 0.25 * np.median(contrast)
        pts = pts[keep]
        q = _fit_circle(pts, (cx, cy, r))
        for _ in range(2):  # drop outliers (stand, highlights) and refit
            res = np.abs(np.hypot(pts[:, 0] - q[0], pts[:, 1] - q[1]) - q[2])
            mad = 1.4826 * np.median(res) + 0.02
            pts = pts[res < max(3 * mad, 0.3)]
            q = _fit_circle(pts, q)
        if len(pts) < 0.3 * n_rays:
            raise SphereNotFoundError(f"no consistent sphere rim near circle ({cx:.1f}, {cy:.1f}, {r:.1f})")
        cx, cy, r = (float(v) for v in q)
        band = 3.0
    return cx, cy, r


def _rim_pixels(shape, circle):
    """Pixels within ``_RIM_HALF_WIDTH`` of ``circle``, grouped by rim sector.

    Returns rows, cols (N,) int sorted by sector, the sector start offsets (S,),
    and each pixel's position within its sector (-0.5 .. 0.5).  At large radii
    only ``_MAX_SECTORS`` evenly spread sectors are kept (plenty for 3 parameters).
    """
    h, w = shape
    cx, cy, r = circle
    n_all = max(16, int(2 * np.pi * r / _SECTOR_ARC))
    reach = r + _RIM_HALF_WIDTH + 1
    x0, x1 = max(0, int(cx - reach)), min(w, int(np.ceil(cx + reach)))
    y0, y1 = max(0, int(cy - reach)), min(h, int(np.ceil(cy + reach)))
    yy, xx = np.mgrid[y0:y1, x0:x1]
    sel = np.abs(np.hypot(xx + 0.5 - cx, yy + 0.5 - cy) - r) < _RIM_HALF_WIDTH
    rows, cols = yy[sel], xx[sel]
    u = (np.arctan2(rows + 0.5 - cy, cols + 0.5 - cx) % (2 * np.pi)) / (2 * np.pi) * n_all
    sec = np.minimum(u.astype(int), n_all - 1)
    kept = np.zeros(n_all, bool)
    kept[np.linspace(0, n_all, min(n_all, _MAX_SECTORS), endpoint=False).astype(int)] = True
    m = kept[sec]
    order = np.argsort(sec[m], kind="stable")
    rows, cols, sec, pos = rows[m][order], cols[m][order], sec[m][order], (u - sec - 0.5)[m][order]
    starts = np.nonzero(np.r_[True, sec[1:] != sec[:-1]])[0]
    return rows, cols, starts, pos


def _rim_design(rows, cols, pos, circle) -> np.ndarray:
    """(N, 10) design matrix of the anti-aliased rim model of each pixel for ``circle``.

    A pixel's value is the pixel-area integral of the ball radiance inside the
    disc plus the background outside it.  Near the limb both a mirror ball's
    reflected direction and a diffuse sphere's shading vary as ``sqrt(depth)``
    (the normal's z component), so the ball side is ``a + b sqrt(s) + c s`` at
    depth s (px) inside the outline and the background ``d + e t`` at distance
    t outside; each coefficient varies linearly along the sector (``pos``).
    The integrals are taken over ``_SS x _SS`` sub-samples of each pixel.
    """
    cx, cy, r = circle
    off = (np.arange(_SS) + 0.5) / _SS
    x = cols[:, None, None] + off[None, None, :]
    y = rows[:, None, None] + off[None, :, None]
    s = (r - np.hypot(x - cx, y - cy)).reshape(len(rows), -1)  # signed depth, > 0 inside
    # each sub-sample's covered fraction ramps linearly across its width and its covered part's mean depth
    # goes smoothly to 0 with it: the model (and so the fit's objective) is then smooth in the circle, where
    # a 0/1 test per sub-sample would make it a staircase and sqrt(depth) would put a cusp at each crossing
    cov = np.clip(s * _SS + 0.5, 0.0, 1.0)
    si = np.where(cov < 1, cov / (2 * _SS), s)  # mean depth of the covered part
    so = np.where(cov > 0, (1 - cov) / (2 * _SS), -s)  # mean distance of the uncovered part
    base = np.stack([cov, cov * np.sqrt(si), cov * si, 1.0 - cov, (1.0 - cov) * so], axis=1).mean(axis=2)
    return np.concatenate([base, base * pos[:, None]], axis=1)


def _sector_solve(a: np.ndarray, v: np.ndarray, wt: np.ndarray, starts: np.ndarray):
    """Weighted per-sector linear least squares.

    Returns the model values (N,) of each sector's best coefficients and those coefficients (S, K).
    """
    aw = a * wt[:, None]
    gram = np.add.reduceat(aw[:, :, None] * aw[:, None, :], starts, axis=0)
    rhs = np.add.reduceat(aw * (v * wt)[:, None], starts, axis=0)
    ridge = 1e-9 * np.trace(gram, axis1=1, axis2=2)[:, None, None] * np.eye(a.shape[1]) + 1e-300
    coef = np.linalg.solve(gram + ridge, rhs[:, :, None])[:, :, 0]
    counts = np.diff(np.r_[starts, len(v)])
    return np.einsum("nk,nk->n", a, np.repeat(coef, counts, axis=0)), coef


def _model_refine(lum: np.ndarray, circle) -> tuple[float, float, float]:
    """Fit the circle to the anti-aliased rim model of every pixel near the outline (variable projection).

    The pixel set, sectors and weights are fixed at the starting circle (so the
    objective is smooth in the circle); each sector's residuals are relative to
    its own brightness, so a dim stretch of rim counts as much as one next to a
    lamp.  Sectors whose fitted step from ball to background is under
    ``_MIN_CONTRAST`` (a background matching the rim: no edge to locate),
    sectors the model cannot explain (a stand, a reflection crossing the rim)
    and single outlying pixels (speckles) are dropped and the fit repeated.
    """
    from scipy.optimize import least_squares

    q = np.asarray(circle, float)
    rows, cols, starts, pos = _rim_pixels(lum.shape, q)
    v = lum[rows, cols].astype(float)
    counts = np.diff(np.r_[starts, len(v)])
    level = np.maximum(np.maximum.reduceat(np.abs(v), starts), 1e-30)
    wt = np.repeat(1.0 / level, counts)

    def resid(p):
        return (v - _sector_solve(_rim_design(rows, cols, pos, p), v, wt, starts)[0]) * wt

    for _ in range(4):
        if np.count_nonzero(wt) < 0.3 * len(v):
            raise SphereNotFoundError(f"no consistent sphere rim near circle ({q[0]:.1f}, {q[1]:.1f}, {q[2]:.1f})")
        q = least_squares(resid, q, x_scale=0.1, diff_step=1e-4, xtol=1e-5, ftol=1e-6).x
        model, coef = _sector_solve(_rim_design(rows, cols, pos, q), v, wt, starts)
        res = np.abs(v - model) * wt
        used = np.add.reduceat(wt > 0, starts)
        sector_rms = np.sqrt(np.add.reduceat(res ** 2, starts) / np.maximum(used, 1))
        no_edge = np.abs(coef[:, 0] - coef[:, 3]) < _MIN_CONTRAST * level  # ball and background levels at the rim
        misfit = sector_rms > 3 * np.median(sector_rms[used > 0])
        drop = np.repeat(no_edge | misfit, counts) | (res > 6 * 1.4826 * np.median(res[wt > 0]) + 1e-9)
        if not np.any(drop & (wt > 0)):
            break
        wt = np.where(drop, 0.0, wt)
    return float(q[0]), float(q[1]), float(q[2])


def refine_circle(image: np.ndarray, circle, *, n_rays: int | None = None, iterations: int = 3
                  ) -> tuple[float, float, float]:
    """Refine an approximate sphere circle (within a few px) to sub-pixel accuracy.

    Parameters
    ----------
    image : (H, W) or (H, W, C) array
        Linear image (any units).
    circle : (cx, cy, r)
        Approximate circle, pixel coordinates (MATH.md).
    n_rays : int, optional
        Rays across the rim in the first stage (default: about one per pixel
        of circumference, between 180 and 2048).
    iterations : int
        Ray-stage passes.

    Returns
    -------
    (cx, cy, r) : floats

    Raises
    ------
    SphereNotFoundError
        When no rim is found, or the answer strays from ``circle`` by more
        than ``max(5, 0.1 r)`` px or from the ray stage's circle by 1.5 px.
    """
    from scipy.ndimage import median_filter

    lum = _luminance(image)
    cx, cy, r = (float(v) for v in circle)
    n_rays = n_rays or int(np.clip(2 * np.pi * r, 180, 2048))
    # the ray stage runs on a 3x3 median of the image: isolated hot pixels or speckles outside the ball
    # would otherwise be taken for its outermost edge (the final model fit rejects them itself)
    h, w = lum.shape
    reach = r + max(4.0, 0.04 * r) + 8
    x0, y0 = max(0, int(cx - reach)), max(0, int(cy - reach))
    x1, y1 = min(w, int(np.ceil(cx + reach))), min(h, int(np.ceil(cy + reach)))
    crop = median_filter(lum[y0:y1, x0:x1], size=3, mode="nearest")
    rx, ry, rr = _ray_refine(crop, (cx - x0, cy - y0, r), n_rays, iterations)
    fx, fy, fr = _model_refine(lum, (rx + x0, ry + y0, rr))
    tol = max(5.0, 0.1 * r)  # how far a rough (Hough) circle may be off
    if max(abs(fx - cx), abs(fy - cy), abs(fr - r)) > tol or max(abs(fx - rx - x0), abs(fy - ry - y0),
                                                                 abs(fr - rr)) > 1.5:
        raise SphereNotFoundError(f"no consistent sphere rim near circle ({cx:.1f}, {cy:.1f}, {r:.1f}): "
                                  f"refinement moved to ({fx:.1f}, {fy:.1f}, {fr:.1f})")
    return fx, fy, fr


def _search(lum: np.ndarray, min_r: float, max_r: float) -> tuple[float, float, float]:
    """Refine the best of the first three Hough candidates that confirms; SphereNotFoundError otherwise."""
    errors = []
    for cand in _coarse_circles(lum, min_r, max_r)[:3]:
        try:
            return refine_circle(lum, cand)
        except SphereNotFoundError as exc:
            errors.append(str(exc))
    raise SphereNotFoundError(errors[0] if errors else "no circle candidate")


def _padded(lum: np.ndarray) -> tuple[np.ndarray, int]:
    """``lum`` inside a margin of its background level (median of the corner patches), and the margin (px)."""
    h, w = lum.shape
    k = max(1, min(h, w) // 16)
    corners = np.concatenate([lum[:k, :k], lum[:k, -k:], lum[-k:, :k], lum[-k:, -k:]], axis=None)
    pad = 12 + int(0.06 * min(h, w))
    return np.pad(lum, pad, mode="constant", constant_values=float(np.median(corners))), pad


def detect_sphere(image: np.ndarray, *, radius_range: tuple[float, float] | None = None,
                  name: str = "the image") -> tuple[float, float, float]:
    """Find the circle of the most prominent sphere in an image, to sub-pixel accuracy.

    Parameters
    ----------
    image : (H, W) or (H, W, C) array
        Linear (HDR) image of a chrome probe or a sample sphere.
    radius_range : (min_r, max_r), optional
        Radius bounds in pixels (default: 20 to half the smaller image side).
    name : str
        The image's file name, for messages.

    Returns
    -------
    (cx, cy, r) : floats
        Centre (x = column, y = row, MATH.md pixel coordinates) and radius, in pixels.

    Raises
    ------
    SphereNotFoundError (an InputError, a ValueError)
        When no circle is found or its rim cannot be confirmed; the message
        names ``name`` and suggests giving the circle.
    """
    lum = _luminance(image, name)
    h, w = lum.shape
    min_r, max_r = radius_range if radius_range is not None else (20.0, min(h, w) / 2.0)
    hint = "give the sphere's circle with --circle cx,cy,r (pixels)"
    if min(h, w) < 16 or max_r < min_r:
        raise SphereNotFoundError(f"{name}: image {w}x{h} too small for a sphere of radius {min_r}-{max_r} px; {hint}")
    try:
        return _search(lum, min_r, max_r)
    except SphereNotFoundError as exc:
        first = str(exc)
    padded, pad = _padded(lum)
    try:
        cx, cy, r = _search(padded, min_r, max_r)
    except SphereNotFoundError:
        cx = cy = r = np.nan
    cx, cy = cx - pad, cy - pad
    slack = 0.5  # px: a rim on the frame edge is found to within a fraction of a pixel
    if r > 0 and cx - r >= -slack and cy - r >= -slack and cx + r <= w + slack and cy + r <= h + slack:
        return float(cx), float(cy), float(min(r, cx, cy, w - cx, h - cy))  # the rim is inside the frame
    raise SphereNotFoundError(f"{name}: no sphere found in the image ({first}); {hint}")


def detect_spheres(image: np.ndarray, *, max_count: int = 8, radius_range: tuple[float, float] | None = None,
                   name: str = "the image") -> list[tuple[float, float, float]]:
    """Every sphere in an image (chrome probe and samples), each refined to sub-pixel accuracy, left to right.

    Hough candidates are refined one by one (:func:`refine_circle`); a candidate that does
    not confirm, or overlaps a sphere already found, is skipped.

    Raises
    ------
    SphereNotFoundError
        When no sphere is found.
    """
    lum = _luminance(image, name)
    h, w = lum.shape
    min_r, max_r = radius_range if radius_range is not None else (20.0, min(h, w) / 2.0)
    found: list[tuple[float, float, float]] = []
    for cand in _coarse_circles(lum, min_r, max_r)[: 4 * max_count]:
        if any(np.hypot(cand[0] - c[0], cand[1] - c[1]) < 0.9 * (cand[2] + c[2]) for c in found):
            continue
        try:
            circle = refine_circle(lum, cand)
        except SphereNotFoundError:
            continue
        if not any(np.hypot(circle[0] - c[0], circle[1] - c[1]) < 0.9 * (circle[2] + c[2]) for c in found):
            found.append(circle)
        if len(found) == max_count:
            break
    if not found:
        raise SphereNotFoundError(f"{name}: no sphere found in the image; give the circles in the plan by hand")
    return sorted(found)


def mirror_score(image: np.ndarray, circle) -> float:
    """How much a sphere looks like a mirror ball: the 99.5th over the 50th percentile of its luminance.

    A chrome ball reflects the light sources themselves (ratios of 100 or more under room
    light); a diffuse or glossy sample shades them smoothly (ratios of a few).
    """
    from brdfrig.hdr.sphere import sphere_pixels

    lum = _luminance(image)
    px = sphere_pixels(lum.shape, circle, margin_px=2.0)
    values = lum[px.rows[px.weights > 0], px.cols[px.weights > 0]]
    lo, hi = np.percentile(values, [50.0, 99.5]) if values.size else (0.0, 0.0)
    return float(hi / max(lo, 1e-12 * max(hi, 1e-300)))

