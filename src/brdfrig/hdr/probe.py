"""Chrome-ball light probe: unwrap to environment samples, calibrate, average rotations, resample to lat-long.

Geometry is A's :mod:`brdfrig.hdr.envmap` (MATH.md): orthographic view along
``v = (0, 0, 1)``, a ball pixel at normalised offset ``(dx, dy)`` from the
centre has normal ``n = (dx, dy, sqrt(1 - dx^2 - dy^2))`` and shows the
radiance arriving from ``w = 2 (n.v) n - v``; every pixel subtends ``4 / r^2``
sr.  Masks (MATH.md pitfall 8):

- rim: pixels with ``rho = |(dx, dy)| > rim`` (default 0.97) are dropped:
  the directions behind the ball are squeezed into a thin ring there.  The
  unseen cone around ``-v`` has half-angle ``180 deg - 2 asin(rim)``
  (28.1 deg at 0.97), reported as ``unseen_cone_deg``;
- camera: the camera and rig are reflected at the centre of the ball: the
  cone of half-angle ``camera_mask_deg`` around ``+v`` is dropped;
- an optional user mask (stand, operator) in image pixels.

Calibration (seed 3.3.1): a chrome ball reflects only a fraction of the
light.  Its albedo is given, or measured by the ratio method
(:func:`albedo_from_patches`: a diffuse patch seen directly and in the ball),
and the radiance divided by it.  Optionally the albedo varies with the angle
of incidence on the ball like a conductor's Fresnel reflectance
(:func:`conductor_fresnel`, chrome by default), normalised at the angle at
which the albedo was measured.

Several captures at different turntable rotations (ball turned, rig fixed)
see the same ideal reflection but with the ball's blemishes moved:
:func:`average_rotations` registers each capture's circle onto a reference
circle and takes a robust per-pixel statistic (median by default).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from brdfrig.errors import InputError
from brdfrig.hdr import envmap

__all__ = [
    "DEFAULT_RIM",
    "CHROME_IOR",
    "ProbeSamples",
    "unwrap_probe",
    "calibrate_probe",
    "albedo_from_patches",
    "conductor_fresnel",
    "average_rotations",
    "probe_to_latlong",
    "check_circle_in_frame",
    "unseen_cone_deg",
]

#: Default rim mask: pixels beyond 0.97 of the radius are dropped (unseen cone 28.1 deg around -v).
DEFAULT_RIM = 0.97
#: Complex index of refraction (n, k) of chromium at ~550 nm (Johnson & Christy 1974).
CHROME_IOR = (3.18, 3.33)


@dataclass(frozen=True)
class ProbeSamples:
    """Environment samples from one probe image.

    Attributes
    ----------
    dirs : (M, 3) float64
        Unit directions the light arrives FROM, one per ball pixel (world frame, MATH.md).
    radiance : (M, C) float64
        Calibrated radiance arriving from ``dirs``.
    solid_angle : (M,) float64
        Solid angle of each sample in sr (``4 / r^2`` times the pixel's
        coverage by the disc); 0 where ``valid`` is False.
    valid : (M,) bool
        False for masked samples (rim, camera, user mask, non-finite).
    rows, cols : (M,) int
        Image pixel of each sample.
    circle : (cx, cy, r)
        The ball's circle in image pixels.
    unseen_cone_deg : float
        Half-angle of the cone around ``-v = (0, 0, -1)`` that the rim mask leaves unseen.
    camera_cone_deg : float
        Half-angle of the masked cone around ``+v`` (camera reflection).
    """

    dirs: np.ndarray
    radiance: np.ndarray
    solid_angle: np.ndarray
    valid: np.ndarray
    rows: np.ndarray
    cols: np.ndarray
    circle: tuple[float, float, float]
    unseen_cone_deg: float
    camera_cone_deg: float


def unseen_cone_deg(rim: float) -> float:
    """Half-angle (degrees) of the cone around ``-v`` not seen when ball pixels beyond ``rim`` (r/R) are dropped."""
    return float(180.0 - 2.0 * np.degrees(np.arcsin(rim)))


def check_circle_in_frame(shape, circle, what: str = "probe circle") -> tuple[float, float, float]:
    """Validate a circle (cx, cy, r) against an image shape; ValueError if it is not fully inside the frame."""
    c = np.asarray(circle, dtype=float)
    if c.shape != (3,) or not np.all(np.isfinite(c)) or c[2] <= 0:
        raise InputError(f"{what} must be three finite numbers cx,cy,r with r > 0, got {circle!r}")
    cx, cy, r = (float(v) for v in c)
    h, w = shape[:2]
    if cx - r < 0 or cy - r < 0 or cx + r > w or cy + r > h:
        raise InputError(f"{what} ({cx:.2f}, {cy:.2f}, {r:.2f}) extends outside the {w}x{h} image")
    return cx, cy, r


def conductor_fresnel(cos_theta: np.ndarray, ior: tuple[float, float] = CHROME_IOR) -> np.ndarray:
    """Unpolarised Fresnel reflectance of a conductor with complex index ``n + i k`` (from air).

    Parameters
    ----------
    cos_theta : array
        Cosine of the angle of incidence, in [0, 1].
    ior : (n, k)
        Real and imaginary parts of the index of refraction.

    Returns
    -------
    array
        Reflectance in [0, 1], same shape as ``cos_theta``.
    """
    n, k = ior
    c = np.clip(np.asarray(cos_theta, dtype=float), 0.0, 1.0)
    s2 = 1.0 - c * c
    eta2 = complex(n, k) ** 2
    root = np.sqrt(eta2 - s2)  # complex cos of the refracted angle times eta
    rs = (c - root) / (c + root)
    rp = (eta2 * c - root) / (eta2 * c + root)
    return 0.5 * (np.abs(rs) ** 2 + np.abs(rp) ** 2)


def _box_mean(image: np.ndarray, box, name: str) -> np.ndarray:
    b = np.asarray(box, dtype=float)
    h, w = image.shape[:2]
    if b.shape != (4,) or not np.all(np.isfinite(b)):
        raise InputError(f"{name} must be a pixel box x0,y0,x1,y1, got {box!r}")
    x0, y0, x1, y1 = (int(round(v)) for v in b)
    if not (0 <= x0 < x1 <= w and 0 <= y0 < y1 <= h):
        raise InputError(f"{name} ({x0},{y0},{x1},{y1}) is empty or outside the {w}x{h} image")
    return image[y0:y1, x0:x1].reshape(-1, image.shape[2]).mean(axis=0)


def albedo_from_patches(image: np.ndarray, direct_box, reflected_box) -> np.ndarray:
    """Probe albedo by the seed's ratio method (3.3.1).

    A diffuse patch is seen directly and reflected in the ball; the ratio of
    the reflected to the direct radiance is the ball's albedo.

    Parameters
    ----------
    image : (H, W, C) array
        Linear image showing both the patch and its reflection in the ball.
    direct_box, reflected_box : (x0, y0, x1, y1)
        Pixel boxes (columns x0..x1-1, rows y0..y1-1) over the patch seen
        directly and over its reflection in the ball.

    Returns
    -------
    (C,) float64
        Albedo per channel.
    """
    image = np.asarray(image, dtype=np.float64)
    if image.ndim == 2:
        image = image[:, :, None]
    direct = _box_mean(image, direct_box, "direct patch box")
    reflected = _box_mean(image, reflected_box, "reflected patch box")
    if np.any(direct <= 0) or not np.all(np.isfinite(direct)):
        raise InputError(f"direct patch box {tuple(direct_box)} has no positive radiance: {direct}")
    albedo = reflected / direct
    if np.any(albedo <= 0) or np.any(albedo > 1.5):
        raise InputError(f"albedo from patches {albedo} is implausible (expected in (0, 1]): check the boxes")
    return albedo


def _ball_offsets(shape, circle) -> tuple[np.ndarray, np.ndarray]:
    """Normalised offsets (dx, dy) of every pixel centre from the ball centre (MATH.md: dy up)."""
    cx, cy, r = circle
    h, w = shape[:2]
    dx = ((np.arange(w) + 0.5 - cx) / r)[None, :]
    dy = ((cy - np.arange(h) - 0.5) / r)[:, None]
    return np.broadcast_arrays(dx, dy)


def calibrate_probe(
    image: np.ndarray,
    circle,
    *,
    albedo: float | Sequence[float] | None = None,
    fresnel: tuple[float, float] | None = None,
    albedo_angle_deg: float = 0.0,
) -> np.ndarray:
    """Divide a probe image by the ball's reflectance.

    Parameters
    ----------
    image : (H, W, C) array
        Linear probe image.
    circle : (cx, cy, r)
        Ball circle in pixels.
    albedo : float or (C,) floats, optional
        Ball reflectance (per channel); None = 1 (uncalibrated).
    fresnel : (n, k), optional
        Make the reflectance vary with the angle of incidence on the ball like
        a conductor of complex index ``n + i k`` (e.g. :data:`CHROME_IOR`):
        ``albedo * F(theta) / F(albedo_angle)``.
    albedo_angle_deg : float
        Angle of incidence at which ``albedo`` holds (for the ratio method:
        the angle at the reflected patch, ``asin(rho)``; 0 = at the centre).

    Returns
    -------
    (H, W, C) float64
        Calibrated radiance (pixels outside the ball unchanged).
    """
    image = np.asarray(image, dtype=np.float64)
    a = np.ones(image.shape[2]) if albedo is None else np.broadcast_to(np.asarray(albedo, float), (image.shape[2],))
    if np.any(~np.isfinite(a)) or np.any(a <= 0):
        raise InputError(f"probe albedo must be positive, got {albedo}")
    gain = np.broadcast_to(a, image.shape).copy()
    if fresnel is not None:
        dx, dy = _ball_offsets(image.shape, circle)
        cos_t = np.sqrt(np.clip(1.0 - dx * dx - dy * dy, 0.0, 1.0))  # n.v = cos of the incidence angle
        ref = conductor_fresnel(np.cos(np.radians(albedo_angle_deg)), fresnel)
        gain *= (conductor_fresnel(cos_t, fresnel) / ref)[:, :, None]
    return image / gain


def unwrap_probe(
    image: np.ndarray,
    circle,
    *,
    rim: float = DEFAULT_RIM,
    camera_mask_deg: float = 0.0,
    mask: np.ndarray | None = None,
    albedo: float | Sequence[float] | None = None,
    fresnel: tuple[float, float] | None = None,
    albedo_angle_deg: float = 0.0,
) -> ProbeSamples:
    """Mirror-ball image to environment samples (directions, radiance, solid angle, validity).

    Parameters
    ----------
    image : (H, W, C) or (H, W) array
        Linear HDR image of the chrome ball, orthographic view.
    circle : (cx, cy, r)
        Ball circle in pixels (MATH.md image coordinates); must lie inside the frame.
    rim : float
        Drop pixels with ``r/R > rim`` (see :func:`unseen_cone_deg`).
    camera_mask_deg : float
        Drop the cone of this half-angle around ``+v`` (the camera's reflection).
    mask : (H, W) bool, optional
        Extra pixels to drop (True = drop), e.g. the stand.
    albedo, fresnel, albedo_angle_deg
        Reflectance calibration, see :func:`calibrate_probe`.

    Returns
    -------
    ProbeSamples
        One sample per pixel covered by the ball.
    """
    image = np.asarray(image, dtype=np.float64)
    if image.ndim == 2:
        image = image[:, :, None]
    if image.ndim != 3:
        raise ValueError(f"probe image must be (H, W) or (H, W, C), got shape {image.shape}")
    circle = check_circle_in_frame(image.shape, circle)
    if not 0 < rim <= 1:
        raise InputError(f"rim must be in (0, 1], got {rim}")
    if not 0 <= camera_mask_deg < 180:
        raise InputError(f"camera mask angle must be in [0, 180) degrees, got {camera_mask_deg}")
    dirs, solid, inside = envmap.mirrorball_directions(image.shape[:2], circle)
    radiance = calibrate_probe(image, circle, albedo=albedo, fresnel=fresnel, albedo_angle_deg=albedo_angle_deg)
    dx, dy = _ball_offsets(image.shape, circle)
    valid = inside & (np.hypot(dx, dy) <= rim) if rim < 1 else inside.copy()
    if camera_mask_deg > 0:
        valid &= dirs[..., 2] < np.cos(np.radians(camera_mask_deg))
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != image.shape[:2]:
            raise ValueError(f"probe mask has shape {mask.shape}, image is {image.shape[:2]}")
        valid &= ~mask
    valid &= np.all(np.isfinite(radiance), axis=2)
    rows, cols = np.nonzero(inside)
    v = valid[rows, cols]
    return ProbeSamples(
        dirs=dirs[rows, cols],
        radiance=np.where(v[:, None], radiance[rows, cols], 0.0),
        solid_angle=np.where(v, solid[rows, cols], 0.0),
        valid=v,
        rows=rows,
        cols=cols,
        circle=circle,
        unseen_cone_deg=unseen_cone_deg(rim),
        camera_cone_deg=float(camera_mask_deg),
    )


def _resample_to_circle(image: np.ndarray, circle, ref_circle) -> np.ndarray:
    """Resample a probe image so its ball lands on ``ref_circle`` (same normalised ball coordinates)."""
    from scipy.ndimage import map_coordinates

    dx, dy = _ball_offsets(image.shape, ref_circle)
    cx, cy, r = circle
    x = cx + r * dx
    y = cy - r * dy
    coords = np.stack([y.ravel() - 0.5, x.ravel() - 0.5])  # map_coordinates: pixel centres at integers
    out = np.stack([map_coordinates(image[:, :, c], coords, order=1, mode="nearest").reshape(dx.shape)
                    for c in range(image.shape[2])], axis=-1)
    return out


def average_rotations(
    images: Sequence[np.ndarray],
    circles: Sequence | None = None,
    *,
    statistic: str = "median",
    ref_circle=None,
) -> tuple[np.ndarray, tuple[float, float, float]]:
    """Robust per-pixel average of probe captures taken at different turntable rotations.

    Each capture's ball is resampled (bilinear) onto a common reference circle,
    so that the ideal reflection coincides pixel by pixel, then the captures
    are combined per pixel and channel by a robust statistic that rejects the
    blemishes, which move with the ball.

    Parameters
    ----------
    images : sequence of K (H, W, C) arrays
        Linear probe images, same shape.
    circles : sequence of K (cx, cy, r), optional
        Each capture's ball circle; detected (:func:`brdfrig.hdr.detect.detect_sphere`) when None.
    statistic : {"median", "trimmed"}
        Per-pixel median, or the mean of the middle half of the values
        (interquartile mean: more efficient against noise, still robust to
        blemishes covering < 1/4 of the captures at a pixel).
    ref_circle : (cx, cy, r), optional
        Reference circle (default: the mean of ``circles``).

    Returns
    -------
    image : (H, W, C) float64
        The combined probe image.
    circle : (cx, cy, r)
        Its ball circle.
    """
    if len(images) == 0:
        raise ValueError("average_rotations: no probe images")
    images = [np.asarray(im, dtype=np.float64) for im in images]
    images = [im[:, :, None] if im.ndim == 2 else im for im in images]
    if any(im.shape != images[0].shape for im in images):
        raise InputError("average_rotations: the probe images have different sizes: "
                         + ", ".join(str(im.shape) for im in images))
    if statistic not in ("median", "trimmed"):
        raise ValueError(f"average_rotations: statistic must be 'median' or 'trimmed', got {statistic!r}")
    if circles is None:
        from brdfrig.hdr.detect import detect_sphere

        circles = [detect_sphere(im) for im in images]
    if len(circles) != len(images):
        raise ValueError(f"average_rotations: {len(circles)} circles for {len(images)} images")
    circles = [check_circle_in_frame(images[0].shape, c, f"probe circle of capture {k}") for k, c in
               enumerate(circles)]
    ref = tuple(float(v) for v in (np.mean(circles, axis=0) if ref_circle is None else ref_circle))
    stack = np.stack([_resample_to_circle(im, c, ref) for im, c in zip(images, circles)])
    if statistic == "median":
        combined = np.median(stack, axis=0)
    else:
        k = len(images)
        lo, hi = k // 4, k - k // 4
        combined = np.sort(stack, axis=0)[lo:hi].mean(axis=0)
    return combined, ref


def probe_to_latlong(
    image: np.ndarray,
    circle,
    width: int,
    *,
    rim: float = DEFAULT_RIM,
    camera_mask_deg: float = 0.0,
    albedo: float | Sequence[float] | None = None,
    fresnel: tuple[float, float] | None = None,
    albedo_angle_deg: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Resample a probe image to a lat-long map (OpenEXR ``LatLongMap``, MATH.md), unseen directions marked.

    Parameters
    ----------
    image : (H, W, C) array
        Linear probe image.
    circle : (cx, cy, r)
        Ball circle in pixels.
    width : int
        Map width ``W`` (height ``W / 2``); even, >= 8.
    rim, camera_mask_deg, albedo, fresnel, albedo_angle_deg
        As in :func:`unwrap_probe`.

    Returns
    -------
    latlong : (W/2, W, C) float32
        Calibrated radiance arriving from each direction; 0 where unseen.
    seen : (W/2, W) bool
        True where the direction was seen on the ball (outside the rim and
        camera masks).
    """
    image = np.asarray(image, dtype=np.float64)
    if image.ndim == 2:
        image = image[:, :, None]
    circle = check_circle_in_frame(image.shape, circle)
    if isinstance(width, bool) or not isinstance(width, (int, np.integer)) or width < 8 or width % 2:
        raise InputError(f"lat-long width must be an even integer >= 8, got {width!r}")
    from scipy.ndimage import map_coordinates

    radiance = calibrate_probe(image, circle, albedo=albedo, fresnel=fresnel, albedo_angle_deg=albedo_angle_deg)
    dirs, _ = envmap.latlong_directions(width // 2, width)
    x, y = envmap.mirrorball_pixels(dirs, circle)
    cx, cy, r = circle
    rho = np.hypot(x - cx, y - cy) / r
    seen = rho <= rim
    if camera_mask_deg > 0:
        seen &= dirs[..., 2] < np.cos(np.radians(camera_mask_deg))
    coords = np.stack([y.ravel() - 0.5, x.ravel() - 0.5])
    out = np.stack([map_coordinates(radiance[:, :, c], coords, order=1, mode="nearest").reshape(x.shape)
                    for c in range(radiance.shape[2])], axis=-1)
    out[~seen] = 0.0
    return out.astype(np.float32), seen


@dataclass(frozen=True)
class ProbeCapture:
    """One scene's probe, ready to unwrap: the (rotation-averaged) ball image and its calibration.

    Attributes
    ----------
    image : (H, W, C) float64
        Linear probe image (the robust average of the rotations when there were several).
    circle : (cx, cy, r)
        The ball's circle in ``image``.
    circles : list of (cx, cy, r)
        Each capture's circle (given or detected).
    albedo : (C,) float64 or None
        The ball's albedo (given, or by the ratio method), None when uncalibrated.
    albedo_angle_deg : float
        Angle from the view at which ``albedo`` was measured (0 when given).
    """

    image: np.ndarray
    circle: tuple[float, float, float]
    circles: list
    albedo: np.ndarray | None
    albedo_angle_deg: float = 0.0

    def calibration(self) -> dict:
        """Keyword arguments of :func:`unwrap_probe` / :func:`probe_to_latlong` for this capture's albedo."""
        return {"albedo": self.albedo, "albedo_angle_deg": self.albedo_angle_deg}


def combine_probe(images: Sequence[np.ndarray], circles: Sequence | None = None, *, names: Sequence[str] | None = None,
                  statistic: str = "median", albedo=None, albedo_patches=None) -> ProbeCapture:
    """The one path from probe captures to a calibrated probe: circles, rotation average, albedo.

    Parameters
    ----------
    images : sequence of (H, W, C) arrays
        Linear captures of the ball at one or more turntable rotations (same size).
    circles : sequence of (cx, cy, r), optional
        Each capture's circle (one circle for all is repeated); detected when None.
    names : sequence of str, optional
        The captures' file names, for messages.
    statistic : {"median", "trimmed"}
        Per-pixel statistic over rotations (:func:`average_rotations`).
    albedo : float or (C,), optional
        The ball's albedo, given.
    albedo_patches : ((x0, y0, x1, y1), (x0, y0, x1, y1)), optional
        Boxes over a diffuse patch seen directly and reflected in the ball (ratio method,
        :func:`albedo_from_patches`), measured on the combined image.

    Raises
    ------
    InputError
        Captures of different sizes, a circle outside the frame, a reflected box off the ball.
    """
    from brdfrig.errors import InputError

    names = list(names) if names is not None else [f"probe capture {k + 1}" for k in range(len(images))]
    images = [np.asarray(im, dtype=np.float64) for im in images]
    for name, im in zip(names, images):
        if im.shape != images[0].shape:
            raise InputError(f"{name} is {im.shape[1]}x{im.shape[0]}, {names[0]} is "
                             f"{images[0].shape[1]}x{images[0].shape[0]}: probe captures must have one size")
    if circles is None:
        from brdfrig.hdr.detect import detect_sphere

        circles = [detect_sphere(im, name=name) for name, im in zip(names, images)]
    elif len(circles) == 1 and len(images) > 1:
        circles = list(circles) * len(images)
    circles = [check_circle_in_frame(im.shape, c, f"{name}: probe circle") for name, im, c in zip(names, images, circles)]
    if len(images) > 1:
        image, circle = average_rotations(images, circles, statistic=statistic)
    else:
        image, circle = images[0], circles[0]
    angle = 0.0
    if albedo is not None:
        albedo = np.broadcast_to(np.asarray(albedo, float), (image.shape[2],)).copy()
    elif albedo_patches is not None:
        direct, reflected = albedo_patches
        albedo = albedo_from_patches(image, direct, reflected)
        rx, ry = 0.5 * (reflected[0] + reflected[2]), 0.5 * (reflected[1] + reflected[3])
        rho = np.hypot(rx - circle[0], ry - circle[1]) / circle[2]
        if rho >= 1:
            raise InputError(f"--albedo-patches: the reflected box centre ({rx:.1f}, {ry:.1f}) is not on the ball "
                             f"{tuple(round(c, 2) for c in circle)}")
        angle = float(np.degrees(np.arcsin(rho)))
    return ProbeCapture(image, tuple(float(v) for v in circle), circles, albedo, angle)

