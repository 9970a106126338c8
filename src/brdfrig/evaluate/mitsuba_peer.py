"""Mitsuba 3 as brdfrig's peer: sphere renders in brdfrig's conventions and a ``principled`` fit by inverse rendering.

Optional (``pip install brdfrig[bench]``): :mod:`mitsuba` is imported lazily by
the functions that need it; importing this module does not need it.

Scene (``../shared/docs/MATH.md`` conventions).  A unit sphere at the origin is
seen orthographically from +z looking toward -z with ``up = +y``, on a square
film whose columns grow with world +x and rows with world -y; the film spans
the sphere's diameter, so an ``N`` px image has the sphere centred with radius
``N / 2`` px.  Every pixel is the box-filtered average over its area (an
anti-aliased camera image); the background (the map seen directly) is black.
The integrator is ``path`` (``prb`` for gradients) with ``max_depth = 2``:
direct lighting only, which is exact for a convex object under distant light.

Lighting.  Mitsuba's ``envmap`` uses the same axes as MATH.md's lat-long map
(longitude ``u = atan2(x, -z) / 2 pi``, ``t = acos(y) / pi``; the map centre
looks at +z, the top row at +y; a value is radiance arriving FROM that
direction), but it interpolates bilinearly between texels placed at column
centres ``(c + 0.5) / W`` and at rows from pole to pole, ``t = r / (H - 1)``.
:func:`mitsuba_envmap` therefore resamples the map to ``k H x k W`` texels,
columns by repetition (texel columns tile the cells), rows by the
solid-angle-weighted mean over each texel's band (:func:`mitsuba_envmap`), so
every cell keeps its power and bilinear blending is confined to about one fine
texel at each cell edge (``k = 4`` by default; MATH.md measured a ~3% change of
a diffuse render of a real probe without resampling).

The peer (:func:`fit_principled`, :func:`render_principled`): Mitsuba's ``principled``
BSDF (base colour, roughness, metallic, specular, specular tint, sheen, clearcoat)
fitted to one sphere image under known lighting, as a user of a differentiable
renderer would: gradient descent through Mitsuba (``llvm_ad_rgb``, which needs
libLLVM >= 19: :func:`ad_variant`), or a derivative-free search over ``scalar_rgb``
renders where no AD variant runs.
"""

from __future__ import annotations

import functools
import time

import numpy as np

from brdfrig.errors import InputError

__all__ = [
    "DEFAULT_UPSAMPLE",
    "require_mitsuba",
    "mitsuba_envmap",
    "sphere_scene",
    "render_sphere",
    "PIXEL_MODES",
    "PRINCIPLED_SCALARS",
    "PRINCIPLED_START",
    "ad_variant",
    "principled_bsdf",
    "render_principled",
    "fit_principled",
]

DEFAULT_UPSAMPLE = 4
"""Texels per lat-long cell along each axis in :func:`mitsuba_envmap`.  Diffuse sphere under grace
(64x32, Mitsuba vs brdfrig's ground truth): 0.25% at 4, 0.6% at 1; nearest-row resampling instead
gave 2.4% at 4 and 10% at 1."""


def require_mitsuba(variant: str):
    """Import :mod:`mitsuba`, select ``variant`` and return the module.

    Raises
    ------
    ImportError
        If Mitsuba 3 is not installed (the message says how to install it).
    ValueError
        If this Mitsuba build or machine cannot run ``variant``.
    """
    try:
        import mitsuba as mi
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError("Mitsuba 3 is not installed: pip install 'brdfrig[bench]' (or mitsuba>=3.6)") from exc
    if variant not in mi.variants():
        raise ValueError(f"Mitsuba variant {variant!r} is not available (have {mi.variants()})")
    mi.set_variant(variant)
    return mi


def _check_latlong(latlong, name: str) -> np.ndarray:
    img = np.asarray(latlong, dtype=np.float64)
    if img.ndim == 2:
        img = img[:, :, None]
    if img.ndim != 3 or img.shape[0] < 2 or img.shape[1] < 2 or img.shape[2] not in (1, 3):
        raise InputError(f"{name}: expected an (H, W), (H, W, 1) or (H, W, 3) lat-long map, got shape {np.shape(latlong)}")
    if not np.all(np.isfinite(img)) or np.any(img < 0):
        raise InputError(f"{name}: lat-long radiance must be finite and non-negative")
    return np.repeat(img, 3, axis=2) if img.shape[2] == 1 else img


def _row_weights(h: int, rows: int) -> np.ndarray:
    """``(rows, h)`` solid-angle overlap of Mitsuba texel rows (at ``t = r / (rows - 1)``) with MATH.md rows.

    Texel ``r`` stands for the band ``t in [(r - 1/2), (r + 1/2)] / (rows - 1)`` (clipped to
    ``[0, 1]``); its weight on cell row ``i`` is the solid angle of that band inside
    ``[i / h, (i + 1) / h]`` (``int sin(pi t) dt``), normalised to sum 1.
    """
    half = 0.5 / (rows - 1)
    centre = np.arange(rows) / (rows - 1)
    lo = np.clip(centre - half, 0.0, 1.0)[:, None]
    hi = np.clip(centre + half, 0.0, 1.0)[:, None]
    edges = np.arange(h + 1) / h
    a = np.maximum(lo, edges[None, :-1])
    b = np.minimum(hi, edges[None, 1:])
    w = np.where(b > a, np.cos(np.pi * a) - np.cos(np.pi * b), 0.0)
    return w / w.sum(axis=1, keepdims=True)


def mitsuba_envmap(latlong, upsample: int = DEFAULT_UPSAMPLE, *, name: str = "lighting") -> np.ndarray:
    """Texels of Mitsuba's ``envmap`` reproducing a MATH.md lat-long map (cell-constant radiance).

    Parameters
    ----------
    latlong : (H, W) or (H, W, C) array_like, C in {1, 3}
        Radiance per cell, MATH.md convention (cell ``(i, j)`` spans
        ``t in [i/H, (i+1)/H]``, ``u in [j/W, (j+1)/W]``); one channel is repeated to RGB.
    upsample : int
        ``k``: the result has ``k H x k W`` texels.
    name : str
        What to call the map in error messages.

    Returns
    -------
    (k H, k W, 3) float32
        Texel ``(r, c)``, which Mitsuba places at ``t = r / (k H - 1)``, ``u = (c + 0.5) / (k W)``:
        column ``c`` takes cell column ``c // k`` (texel bands tile the cells exactly); row ``r``
        the solid-angle-weighted mean of the cell rows its band ``t +- 1 / (2 (k H - 1))``
        overlaps (:func:`_row_weights`).  Nearest rows instead give some cells ``k - 1`` texels
        and others ``k``: a small bright source then loses or gains up to ``1 / k`` of its power.
    """
    img = _check_latlong(latlong, name)
    if int(upsample) < 1:
        raise InputError(f"upsample must be >= 1, got {upsample}")
    k = int(upsample)
    h, w = img.shape[:2]
    rows = np.einsum("rh,hwc->rwc", _row_weights(h, k * h), img)
    return np.ascontiguousarray(np.repeat(rows, k, axis=1), dtype=np.float32)


PIXEL_MODES = ("area", "centre")
"""How a pixel samples the image plane: ``area`` box-filters its square (an anti-aliased camera:
Mitsuba's ``orthographic`` sensor); ``centre`` takes every sample at the pixel centre, as brdfrig's
renderers do (MATH.md: the normal of a pixel is the one at its centre).  They differ where the image
changes within a pixel: the limb, and highlights narrower than a pixel (GGX alpha 0.05 under grace,
48 px: 12% RMS apart with equal total power; alpha 0.3: 0.1%)."""
_CENTRE_SENSOR = "brdfrig_centre_ortho"


def _register_centre_sensor(mi) -> None:
    """Register the ``centre`` pixel mode's sensor for the selected variant (a Python plugin, once each)."""
    done = _register_centre_sensor.__dict__.setdefault("variants", set())
    if mi.variant() in done:
        return
    import drjit as dr

    class CentreOrthographic(mi.Sensor):
        """Orthographic view along -z of the square [-1, 1]^2 from z = 3, each sample at its pixel centre."""

        def _ray(self, time, sample2):
            n = mi.Float(self.film().size().x)
            p = (dr.floor(sample2 * n) + 0.5) / n
            origin = mi.Point3f(2.0 * p.x - 1.0, 1.0 - 2.0 * p.y, 3.0)
            return mi.Ray3f(origin, mi.Vector3f(0.0, 0.0, -1.0), time, mi.Color0f())

        def sample_ray(self, time, sample1, sample2, sample3, active=True):
            return self._ray(time, sample2), mi.Spectrum(1.0)

        def sample_ray_differential(self, time, sample1, sample2, sample3, active=True):
            return mi.RayDifferential3f(self._ray(time, sample2)), mi.Spectrum(1.0)

        def bbox(self):
            return mi.ScalarBoundingBox3f()

        def to_string(self):
            return "CentreOrthographic[]"

    mi.register_sensor(_CENTRE_SENSOR, lambda props: CentreOrthographic(props))
    done.add(mi.variant())


def sphere_scene(bsdf: dict, latlong, size: int, *, spp: int, sampler: str = "multijitter",
                 upsample: int = DEFAULT_UPSAMPLE, integrator: str = "path", pixel: str = "area") -> dict:
    """Mitsuba scene dictionary of the sphere (module docstring) with ``bsdf`` under ``latlong``.

    Parameters
    ----------
    bsdf : dict
        A Mitsuba BSDF dictionary, e.g. ``{"type": "diffuse", "reflectance": {"type": "rgb", "value": [.5] * 3}}``.
    latlong : array_like
        Lighting, MATH.md lat-long convention (see :func:`mitsuba_envmap`).
    size : int
        Image side ``N`` in pixels (sphere radius ``N / 2``).
    spp : int
        Samples per pixel.
    sampler, integrator : str
        Mitsuba sampler and integrator plugin names (``path``, or ``prb`` for differentiation).
    pixel : {"area", "centre"}
        :data:`PIXEL_MODES`.  ``centre`` is a Python sensor plugin: fast in the ``llvm`` variants,
        about 30x slower than ``area`` in ``scalar_rgb`` (one Python call per ray).

    Requires the Mitsuba variant to be set (:func:`require_mitsuba`).
    """
    import mitsuba as mi

    if int(size) < 1 or int(spp) < 1:
        raise InputError(f"size and spp must be >= 1 (size={size}, spp={spp})")
    if pixel not in PIXEL_MODES:
        raise InputError(f"pixel must be one of {PIXEL_MODES}, got {pixel!r}")
    film = {"type": "hdrfilm", "width": int(size), "height": int(size), "rfilter": {"type": "box"}, "pixel_format": "rgb"}
    sensor = {"film": film, "sampler": {"type": sampler, "sample_count": int(spp)}}
    if pixel == "area":
        sensor["type"] = "orthographic"
        sensor["to_world"] = mi.ScalarTransform4f().look_at(origin=[0, 0, 3], target=[0, 0, 0], up=[0, 1, 0])
    else:
        _register_centre_sensor(mi)
        sensor["type"] = _CENTRE_SENSOR
    return {
        "type": "scene",
        "integrator": {"type": integrator, "max_depth": 2, "hide_emitters": True},
        "sensor": sensor,
        "sphere": {"type": "sphere", "center": [0, 0, 0], "radius": 1.0, "bsdf": bsdf},
        "light": {"type": "envmap", "bitmap": mi.Bitmap(mitsuba_envmap(latlong, upsample))},
    }


def render_sphere(bsdf: dict, latlong, size: int, *, spp: int = 1024, seed: int = 0,
                  variant: str = "scalar_rgb", upsample: int = DEFAULT_UPSAMPLE, pixel: str = "area") -> np.ndarray:
    """Render the sphere of :func:`sphere_scene` with Mitsuba: ``(size, size, 3)`` float64 linear radiance.

    ``seed`` fixes the sample sequence (same seed, same image).  Relative per-pixel noise with
    the default ``multijitter`` sampler, measured on 48-64 px spheres under real probes at 64x32
    (``area`` pixels): 0.5-0.7% at 1024 spp, 0.34% at 2048 under grace, about 1/sqrt(spp) around
    that; ``centre`` pixels are quieter (GGX alpha 0.05 under grace: 0.44% vs 1.6%).
    """
    mi = require_mitsuba(variant)
    scene = mi.load_dict(sphere_scene(bsdf, latlong, size, spp=spp, upsample=upsample, pixel=pixel))
    return np.array(mi.render(scene, seed=int(seed)), dtype=np.float64)


# --------------------------------------------------------------------------------------------
# The peer: Mitsuba's ``principled`` BSDF fitted to one sphere image by inverse rendering.

PRINCIPLED_SCALARS = ("roughness", "metallic", "specular", "spec_tint", "sheen", "clearcoat", "clearcoat_gloss")
"""Scalar ``principled`` parameters the peer optimises, each in [0, 1], besides the RGB ``base_color``."""
PRINCIPLED_START = {"base_color": [0.5, 0.5, 0.5], "roughness": 0.5, "metallic": 0.0, "specular": 0.5,
                    "spec_tint": 0.0, "sheen": 0.1, "clearcoat": 0.05, "clearcoat_gloss": 0.5}
"""Starting point of :func:`fit_principled`: Mitsuba's defaults, mid roughness, and sheen and clearcoat
slightly above 0 (a ``principled`` BSDF created with either at 0 leaves that lobe out, so it would get
no gradient).  Also the values :func:`principled_bsdf` fills in for missing keys."""
_ROUGHNESS_MIN = 0.02
MIN_LLVM = (19, 0, 0)
"""Oldest libLLVM drjit is allowed to use here: with Debian 12's LLVM 15, drjit 1.5 aborts the process
compiling Mitsuba's kernels ("Cannot select fminimum"); LLVM 19 (Debian's ``libllvm19``) works."""


@functools.cache
def ad_variant() -> str | None:
    """``"llvm_ad_rgb"`` when Mitsuba's differentiable CPU variant can run here (drjit found libLLVM
    >= :data:`MIN_LLVM`), else None.  Leaves ``scalar_rgb`` selected."""
    try:
        mi = require_mitsuba("llvm_ad_rgb")
    except (ImportError, ValueError, RuntimeError):
        return None
    import drjit as dr

    try:
        ok = tuple(dr.detail.llvm_version()) >= MIN_LLVM
    except (AttributeError, RuntimeError):
        ok = False
    mi.set_variant("scalar_rgb")
    return "llvm_ad_rgb" if ok else None


def principled_bsdf(params: dict) -> dict:
    """Mitsuba ``principled`` BSDF dictionary of ``params`` (keys of :data:`PRINCIPLED_START`; missing: start values).

    Raises
    ------
    InputError
        On an unknown key or a value outside [0, 1] (``base_color`` three values).
    """
    unknown = set(params) - set(PRINCIPLED_START)
    if unknown:
        raise InputError(f"unknown principled parameter(s) {sorted(unknown)}; expected {sorted(PRINCIPLED_START)}")
    values = {**PRINCIPLED_START, **params}
    colour = np.asarray(values["base_color"], dtype=float).reshape(-1)
    if colour.size != 3 or not np.all((colour >= 0) & (colour <= 1)):
        raise InputError(f"principled base_color must be three values in [0, 1], got {values['base_color']}")
    bsdf = {"type": "principled", "base_color": {"type": "rgb", "value": colour.tolist()}}
    for key in PRINCIPLED_SCALARS:
        v = float(values[key])
        if not 0.0 <= v <= 1.0:
            raise InputError(f"principled {key} must be in [0, 1], got {values[key]}")
        bsdf[key] = v
    return bsdf


def render_principled(params: dict, latlong, size: int, *, spp: int = 1024, seed: int = 0,
                      variant: str | None = None, pixel: str | None = None) -> np.ndarray:
    """Mitsuba render ``(size, size, 3)`` of the ``principled`` sphere with ``params`` under ``latlong``.

    ``variant`` None: the AD variant where it runs, else ``scalar_rgb``; ``pixel`` None: ``centre``
    (brdfrig's convention, :data:`PIXEL_MODES`) in an ``llvm`` variant, else ``area``.
    """
    variant = variant or ad_variant() or "scalar_rgb"
    pixel = pixel or ("centre" if variant.startswith("llvm") else "area")
    return render_sphere(principled_bsdf(params), latlong, size, spp=spp, seed=seed, variant=variant, pixel=pixel)


def _target(image, name: str) -> tuple[np.ndarray, np.ndarray]:
    """The image as (N, N, 3) float32 and the weight mask of its interior sphere pixels (MATH.md disc)."""
    from brdfrig.hdr.sphere import DEFAULT_LIMB_MARGIN_PX, sphere_pixels

    img = np.asarray(image, dtype=np.float64)
    if img.ndim == 2:
        img = img[:, :, None]
    if img.ndim != 3 or img.shape[0] != img.shape[1] or img.shape[2] not in (1, 3) or img.shape[0] < 8:
        raise InputError(f"{name}: expected a square (N, N, 1 or 3) sphere image with N >= 8, got shape {np.shape(image)}")
    img = np.repeat(img, 3, axis=2) if img.shape[2] == 1 else img
    n = img.shape[0]
    px = sphere_pixels((n, n), (n / 2, n / 2, n / 2), margin_px=DEFAULT_LIMB_MARGIN_PX)
    mask = np.zeros((n, n, 3))
    good = (px.weights > 0) & np.all(np.isfinite(img[px.rows, px.cols]), axis=1)
    mask[px.rows[good], px.cols[good]] = 1.0
    if np.any(img[mask > 0] < 0):
        raise InputError(f"{name}: negative radiance inside the sphere")
    if not np.any(img[mask > 0] > 0):
        raise InputError(f"{name}: the sphere is black")
    return np.nan_to_num(img).astype(np.float32), mask.astype(np.float32)


def _clamped(values: dict) -> dict:
    out = {k: np.clip(np.asarray(v, float), 0.0, 1.0) for k, v in values.items()}
    out["roughness"] = np.clip(out["roughness"], _ROUGHNESS_MIN, 1.0)
    return {k: (v.tolist() if v.ndim else float(v)) for k, v in out.items()}


_KEYS = {"base_color": "sphere.bsdf.base_color.value", "specular": "sphere.bsdf.specular",
         **{k: f"sphere.bsdf.{k}.value" for k in PRINCIPLED_SCALARS if k != "specular"}}
"""Where each optimised ``principled`` parameter sits in Mitsuba's scene parameters (``mi.traverse``)."""


def _fit_ad(target, mask, latlong, start: dict, spp: int, iterations: int, seed: int, lr: float,
            loss_kind: str) -> dict:
    """Adam on an image loss over ``mask``, differentiated by Mitsuba (``prb``, ``llvm_ad_rgb``).

    ``loss_kind``: ``"l2"`` relative squared error; ``"log"`` squared error of ``log(1 + I / s)``
    with ``s`` the target's mean over the mask (highlights do not swamp the rest of the sphere).
    """
    mi = require_mitsuba("llvm_ad_rgb")
    import drjit as dr

    n = target.shape[0]
    scene = mi.load_dict(sphere_scene(principled_bsdf(start), latlong, n, spp=spp, sampler="independent",
                                      integrator="prb", pixel="centre"))
    params = mi.traverse(scene)
    opt = mi.ad.Adam(lr=lr)
    for key in _KEYS.values():
        opt[key] = params[key]
    params.update(opt)
    scale = float(np.sum(mask * target) / np.sum(mask))
    ref, weight = mi.TensorXf(target), mi.TensorXf(mask)
    ref_log = dr.log(1.0 + ref / scale)
    norm = float(np.sum(mask * target.astype(np.float64) ** 2))
    for it in range(int(iterations)):
        image = mi.render(scene, params, spp=spp, seed=seed + 2 * it, seed_grad=seed + 2 * it + 1)
        if loss_kind == "log":
            loss = dr.sum(weight * dr.square(dr.log(1.0 + image / scale) - ref_log), axis=None) / float(np.sum(mask))
        else:
            loss = dr.sum(weight * dr.square(image - ref), axis=None) / norm
        dr.backward(loss)
        opt.step()
        for name, key in _KEYS.items():
            opt[key] = dr.clip(opt[key], _ROUGHNESS_MIN if name == "roughness" else 0.0, 1.0)
        params.update(opt)
    out = {name: np.array(params[key], dtype=np.float64).reshape(-1) for name, key in _KEYS.items()}
    return _clamped({k: (v if k == "base_color" else v[0]) for k, v in out.items()})


def _fit_search(target, mask, latlong, start: dict, spp: int, iterations: int, seed: int) -> dict:
    """Nelder-Mead over ``scalar_rgb`` renders with one fixed seed (a deterministic objective).

    Pixels are ``area`` samples (``centre`` costs a Python call per ray in ``scalar_rgb``).
    """
    from scipy.optimize import minimize

    x0 = np.concatenate([start["base_color"], [start[k] for k in PRINCIPLED_SCALARS]])
    norm = float(np.sum(mask * target.astype(np.float64) ** 2))

    def unpack(x):
        return _clamped({"base_color": x[:3], **{k: x[3 + i] for i, k in enumerate(PRINCIPLED_SCALARS)}})

    def loss(x):
        image = render_sphere(principled_bsdf(unpack(x)), latlong, target.shape[0], spp=spp, seed=seed)
        return float(np.sum(mask * (image - target) ** 2)) / norm

    res = minimize(loss, x0, method="Nelder-Mead", options={"maxfev": int(iterations), "xatol": 1e-3, "fatol": 1e-5})
    return unpack(res.x)


def fit_principled(image, latlong_fit, *, spp: int = 16, iterations: int = 120, seed: int = 0,
                   lr: float = 0.03, method: str = "auto", loss: str = "log") -> tuple[dict, float]:
    """Fit Mitsuba's ``principled`` BSDF to one sphere image under known lighting (the peer of ``fit_brdf``).

    Parameters
    ----------
    image : (N, N, C) array_like, C in {1, 3}
        Linear radiance of the sphere (MATH.md: centred, radius N / 2, orthographic view from +z);
        pixels at least 2 px inside the limb are fitted, non-finite ones ignored.
    latlong_fit : (H, W, C) array_like
        The lighting of ``image`` (MATH.md lat-long convention).
    spp : int
        Samples per pixel of each rendered iterate.
    iterations : int
        Gradient steps (``method="ad"``) or objective evaluations (``"search"``).
    seed : int
        Seed of Mitsuba's samples (iteration ``i`` uses ``seed + 2 i`` and ``seed + 2 i + 1``).
    lr : float
        Adam's learning rate (parameters are in [0, 1]).
    method : {"auto", "ad", "search"}
        ``ad``: differentiable rendering (``llvm_ad_rgb``, ``prb``, pixel-centre samples, Adam,
        parameters clipped to their ranges after each step); ``search``: Nelder-Mead over
        ``scalar_rgb`` renders (pixel-area samples); ``auto``: ``ad`` where :func:`ad_variant`
        finds it runnable, else ``search``.
    loss : {"log", "l2"}
        ``ad`` only.  ``log``: squared error of ``log(1 + I / mean)``, which a highlight holding most
        of the image's energy does not swamp; ``l2``: relative squared error (what Mitsuba's
        inverse-rendering tutorials minimise).  Measured (96 px, grace -> ennis at 128x64, 120
        iterations x 16 spp; felt, paper, metallic paint, colour-changing paint from rgl/): log
        19.9%, 13.8%, 13.4%, 27.2%; l2 11.1%, 10.4%, 40.9%, 146% (the metallic paint's top 1% of
        pixels hold 92% of its image's squared sum).  The log of a noisy render is biased: a
        principled sphere (tests/test_mitsuba_peer.py) relights at 3.6% with ``log``, 1.9% with ``l2``.

    Returns
    -------
    params : dict
        ``base_color`` (three values) and :data:`PRINCIPLED_SCALARS`, each in [0, 1]; input of
        :func:`render_principled`.
    seconds : float
        Wall-clock time of the fit (Mitsuba's kernel compilation included).
    """
    if method not in ("auto", "ad", "search"):
        raise InputError(f"method must be 'auto', 'ad' or 'search', got {method!r}")
    if loss not in ("l2", "log"):
        raise InputError(f"loss must be 'l2' or 'log', got {loss!r}")
    if int(spp) < 1 or int(iterations) < 1 or not lr > 0:
        raise InputError(f"spp and iterations must be >= 1 and lr > 0 (spp={spp}, iterations={iterations}, lr={lr})")
    target, mask = _target(image, "image")
    _check_latlong(latlong_fit, "latlong_fit")
    t0 = time.perf_counter()
    if method == "auto":
        method = "ad" if ad_variant() else "search"
    start = dict(PRINCIPLED_START)
    if method == "ad":
        params = _fit_ad(target, mask, latlong_fit, start, int(spp), int(iterations), int(seed), float(lr), loss)
    else:
        params = _fit_search(target, mask, latlong_fit, start, int(spp), int(iterations), int(seed))
    return params, time.perf_counter() - t0
