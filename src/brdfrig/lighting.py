"""The one bridge between images (:mod:`brdfrig.hdr`) and numbers (:mod:`brdfrig.fit`).

``hdr`` and ``fit`` never import each other; every conversion of an image into
the fitter's plain-array inputs happens here: a lat-long map into an
:class:`~brdfrig.fit.scene.Environment`, a sphere image into a
:class:`~brdfrig.fit.scene.Scene`.  Conventions are MATH.md's (lat-long maps in
OpenEXR's ``LatLongMap`` orientation, radiance arriving FROM each direction).
"""

from __future__ import annotations

import numpy as np

from brdfrig.errors import InputError
from brdfrig.fit.scene import Environment, LatLongMap, Scene
from brdfrig.hdr.envmap import latlong_directions
from brdfrig.hdr.sphere import sphere_pixels

__all__ = ["environment_from_latlong", "read_latlong", "environment_from_probe", "scene_from_image",
           "standard_lightings"]

STANDARD_HEIGHT = 32
"""Rows of the standard lat-long lightings (64 x 32 cells of 5.6 degrees; sharp lobes are integrated over cells)."""


def environment_from_latlong(image, rotation=None, *, name: str = "lighting") -> Environment:
    """Environment of a lat-long radiance map, keeping the map for cell-integrating quadrature.

    Parameters
    ----------
    image : (H, W) or (H, W, C) array_like
        Linear radiance per cell (MATH.md lat-long convention).
    rotation : (3, 3) array_like or None
        World direction of a map direction ``d`` is ``rotation @ d`` (None: identity).
    name : str
        What to call the map in error messages (e.g. its file name).

    Returns
    -------
    Environment
        One sample per cell (row-major), exact per-cell solid angles, ``latlong`` set.

    Raises
    ------
    ValueError
        If the map is empty, not 2-D/3-D, or holds non-finite or negative radiance.
    """
    img = np.asarray(image, dtype=np.float64)
    if img.ndim == 2:
        img = img[:, :, None]
    if img.ndim != 3 or min(img.shape) < 1:
        raise InputError(f"{name}: expected an (H, W) or (H, W, C) lat-long map, got shape {np.shape(image)}")
    if not np.all(np.isfinite(img)):
        raise InputError(f"{name}: {int(np.sum(~np.isfinite(img)))} non-finite radiance value(s)")
    if np.any(img < 0):
        raise InputError(f"{name}: {int(np.sum(img < 0))} negative radiance value(s)")
    rot = np.eye(3) if rotation is None else np.asarray(rotation, dtype=np.float64)
    if rot.shape != (3, 3) or not np.allclose(rot @ rot.T, np.eye(3), atol=1e-9):
        raise InputError(f"{name}: rotation must be a 3x3 orthogonal matrix")
    h, w, c = img.shape
    dirs, omega = latlong_directions(h, w)
    img = np.ascontiguousarray(img)
    return Environment(dirs.reshape(-1, 3) @ rot.T, img.reshape(h * w, c), omega.reshape(-1), LatLongMap(img, rot))


def read_latlong(path, lmax: int | None = None) -> Environment:
    """Environment of a lat-long map file (EXR or Radiance .hdr).

    A map of H rows samples latitude every 180/H degrees and resolves bands up to
    ``H/2 - 1``; ValueError (naming the file) when ``lmax`` asks for more.
    """
    from brdfrig.hdr.exr import read_image

    img = read_image(path)
    h, w = img.shape[:2]
    if lmax is not None and lmax > h // 2 - 1:
        raise InputError(f"{path}: a {w}x{h} lat-long map supports bands up to {h // 2 - 1}, --lmax is {lmax}")
    return environment_from_latlong(img, name=str(path))


def environment_from_probe(probe, *, mask=None, name: str = "probe", **unwrap) -> Environment:
    """Environment of a calibrated probe (:func:`brdfrig.hdr.probe.combine_probe`): the ball's valid, finite
    pixels as samples (``4/R^2`` sr each).

    Parameters
    ----------
    probe : brdfrig.hdr.probe.ProbeCapture
        The (rotation-averaged) ball image, its circle and albedo.
    mask : (H, W) bool or None
        Pixels to drop (True = drop), e.g. clipped ones.
    name : str
        What to call the probe in error messages.
    **unwrap
        ``rim``, ``camera_mask_deg``, ``fresnel`` of :func:`brdfrig.hdr.probe.unwrap_probe`.
    """
    from brdfrig.hdr.probe import unwrap_probe

    s = unwrap_probe(probe.image, probe.circle, mask=mask, **probe.calibration(), **unwrap)
    valid = s.valid & np.all(np.isfinite(s.radiance), axis=1) & (s.solid_angle > 0)
    if not np.any(valid):
        raise ValueError(f"{name}: no usable mirror-ball pixel inside circle {tuple(probe.circle)}")
    return Environment(np.asarray(s.dirs[valid], np.float64), np.asarray(s.radiance[valid], np.float64),
                       np.asarray(s.solid_angle[valid], np.float64))


def scene_from_image(env: Environment, image, circle, *, margin_px: float = 2.0, name: str = "image") -> Scene:
    """Scene of a sphere image under ``env``: the pixels inside ``circle`` with their normals and weights.

    Parameters
    ----------
    env : Environment
        The lighting the image was taken under.
    image : (H, W, C) array_like
        Linear radiance of the sphere image.
    circle : (cx, cy, r)
        Sphere circle in pixels (centre in image coordinates, MATH.md).
    margin_px : float
        Pixels within this distance of the limb get zero weight (:func:`brdfrig.hdr.sphere.sphere_pixels`).
    name : str
        What to call the image in error messages.
    """
    img = np.asarray(image, dtype=np.float64)
    if img.ndim == 2:
        img = img[:, :, None]
    if img.shape[2] != env.channels:
        raise InputError(f"{name}: image has {img.shape[2]} channel(s), the lighting {env.channels}")
    px = sphere_pixels(img.shape[:2], tuple(float(v) for v in circle), margin_px=margin_px)
    radiance = img[px.rows, px.cols]
    weights = np.where(np.all(np.isfinite(radiance), axis=1), px.weights, 0.0)
    return Scene(env, px.normals, np.nan_to_num(radiance), weights)


def _blob(dirs: np.ndarray, centre, width_deg: float) -> np.ndarray:
    """A smooth light of angular radius ~``width_deg`` around the unit direction ``centre``."""
    c = np.asarray(centre, dtype=np.float64)
    c = c / np.linalg.norm(c)
    cos_w = np.cos(np.radians(width_deg))
    return np.exp((dirs @ c - 1.0) / (1.0 - cos_w))


def standard_lightings(height: int = STANDARD_HEIGHT) -> dict[str, Environment]:
    """Three fixed RGB lightings shipped with brdfrig, for reports and export checks (radiance, 1 = white sky).

    - ``overcast``: a bright sky dome over a dark ground, brightest at the zenith (+y);
    - ``studio``: a large soft key light up-left-front, a smaller fill right, a dim grey surround;
    - ``sunset``: a small warm sun 10 degrees above the horizon behind-left, a blue sky, a brown ground.

    They are analytic (no file needed) and lat-long (cell-integrating quadrature applies).
    """
    dirs, _ = latlong_directions(height, 2 * height)
    y = dirs[..., 1]
    sky = np.clip(y, 0.0, 1.0)
    overcast = (0.15 + 1.6 * sky**0.6)[..., None] * np.array([1.0, 1.0, 1.0]) * np.where(y > 0, 1.0, 0.25)[..., None]
    studio = (0.05 + 8.0 * _blob(dirs, (-0.5, 0.6, 0.6), 12.0) + 2.5 * _blob(dirs, (0.8, 0.1, 0.5), 6.0))[..., None] \
        * np.array([1.0, 0.98, 0.95])
    sun = 600.0 * _blob(dirs, (-0.6, np.sin(np.radians(10.0)), -0.75), 1.5)[..., None] * np.array([1.0, 0.6, 0.3])
    blue = (0.3 + 0.7 * sky)[..., None] * np.array([0.35, 0.5, 0.9]) * (y > 0)[..., None]
    ground = np.array([0.12, 0.08, 0.05]) * (y <= 0)[..., None]
    return {name: environment_from_latlong(img, name=name)
            for name, img in (("overcast", overcast), ("studio", studio), ("sunset", sun + blue + ground))}

