"""Merge an exposure bracket of linear frames into radiance plus a per-pixel variance.

Model (MATH.md pitfall 7).  Frame ``k`` records, per pixel and channel,
``z_k = X t_k + noise`` in frame units (1.0 = ``saturation``), with
``Var(z_k) = z/full_well + (read_noise/full_well)^2`` (shot + read noise, both
expressed in units of the full-well capacity).  Each frame gives the estimate
``X_k = z_k / t_k`` of the radiance ``X`` (frame units per second); the merge
is the weighted mean ``X = sum w_k X_k / sum w_k``:

- ``weighting="optimal"`` (default, Granados et al. 2010, "Optimal HDR
  reconstruction with linear digital cameras"): ``w_k = t_k^2 / Var(z_k)``
  with the variance evaluated at the current estimate ``X t_k`` (not at the
  noisy ``z_k``, which would favour samples with negative noise), iterated;
  the variance of the result is ``1 / sum w_k``.
- ``weighting="debevec"`` (baseline, Debevec & Malik 1997): the hat
  ``w(z) = min(z - lo, hi - z)``; variance ``sum w_k^2 Var(X_k) / (sum w_k)^2``.

Samples at or above ``hi`` (saturated, default 0.95 of full scale) or at or
below ``lo`` (black, default 0: clipped at the black level, i.e. censored)
get zero weight, per channel.  So do all channels of a pixel within
``clip_radius`` pixels (default 1) of a pixel saturated in any channel of
the same frame (:func:`clipped_neighbourhood`): demosaicing interpolates a
clipped sample into its neighbours, which then read low while staying below
``hi``.  Near-black samples above ``lo`` get vanishing weight
smoothly: the hat goes to 0 at ``lo``, and the optimal weight of a frame
whose signal is buried in read noise is ``t^2 / read_var``, negligible beside
a longer exposure's.  (A higher ``lo`` drops the negative-noise half of the
faintest samples and biases them up: 2e-4 gave +16% instead of +10% at 11
electrons in the tests' sensor model.)  A pixel with no usable sample falls
back to the longest unsaturated frame (dark pixel,
flag ``FLAG_DARK``) or, when it is saturated in every frame, to the shortest
frame's value, a lower bound (``FLAG_SATURATED``, variance = value^2, and a
:class:`SaturationWarning`; a sample weighted out as a neighbour of a clipped
one counts as saturated here, and its value is a lower bound too:
demosaicing mixed a clipped, too low, value into it).

Exposure times: nominal times are rounded by cameras (1/125 s is not
1/128 s), so the ratio between consecutive exposures is re-estimated from
pixels well exposed in both (ratio of sums, selected on the pair's summed
signal, away from demosaiced neighbours of clipped samples, outliers
trimmed; a ratio with a standard error above 0.2% is not used, one more
than 10% from the nominal one is rejected with an
:class:`ExposureTimeWarning`) and, when it differs from the nominal ratio
by more than ``ratio_tolerance``, the re-estimated times are used, anchored
so that the median of ``t_estimated / t_nominal`` is 1 (one wrong nominal
time does not shift the others).  Optional alignment (OpenCV's
median threshold bitmaps) runs before the re-estimation.

Streaming: frames are frame sources (:mod:`brdfrig.hdr.frames`; arrays are
wrapped) read in bands of ``tile_rows`` rows (plus ``clip_radius`` rows of
halo for the clipped neighbourhoods), so the merge holds one band of every
frame, never whole frames; the exposure ratios are measured on evenly spaced
bands of rows (at most 2e6 pixel-channels per frame).  The outputs are stored
plane by plane (channel-major), so writing them to EXR copies nothing.  The
per-pixel loop is one fused numba kernel, parallel over blocks of pixels:
each block of every frame is gathered once (frames read in their own dtype),
then merged per pixel and channel.  Alignment (``align=True``) holds two
grey planes while it measures the shifts, then the merge reads the shifted
frames band by band (:func:`brdfrig.hdr.align.align_sources`).
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass
from typing import Sequence

import numba as nb
import numpy as np

from brdfrig.errors import InputError
from brdfrig.hdr.align import align_frames, align_sources
from brdfrig.hdr.exposure_times import RATIO_MAX_SAMPLES, ExposureTimeWarning, estimate_times
from brdfrig.hdr.frames import ArrayFrame, as_frame

__all__ = [
    "MergeResult",
    "SaturationWarning",
    "ExposureTimeWarning",
    "merge_bracket",
    "estimate_times",
    "align_frames",
    "clipped_neighbourhood",
    "FLAG_DARK",
    "FLAG_SATURATED",
    "DEFAULT_FULL_WELL",
    "DEFAULT_READ_NOISE",
]

log = logging.getLogger(__name__)

FLAG_DARK = 1
FLAG_SATURATED = 2
#: Default sensor noise model, in electrons (a typical APS-C/full-frame sensor at base ISO).
DEFAULT_FULL_WELL = 20000.0
DEFAULT_READ_NOISE = 5.0


class SaturationWarning(UserWarning):
    """Some pixels are saturated in every frame of a bracket: their radiance is only a lower bound."""


@dataclass(frozen=True)
class MergeResult:
    """Merged HDR image.

    Attributes
    ----------
    radiance : (H, W, C) float32
        Linear radiance in frame units per second of exposure (``z / t``).
    variance : (H, W, C) float32
        Variance of ``radiance`` under the noise model (same units squared).
    flags : (H, W, C) uint8
        0 = merged from usable samples, ``FLAG_DARK`` = below the black
        threshold in every frame, ``FLAG_SATURATED`` = saturated, or within
        ``clip_radius`` of a saturated pixel, in every frame.
    times : (K,) float64
        Exposure times used (re-estimated or nominal), in input order.
    nominal_times : (K,) float64
        Exposure times given.
    shifts : (K, 2) int or None
        (dx, dy) shift applied to each frame by alignment, or None.
    weighting : str
        ``"optimal"`` or ``"debevec"``.
    """

    radiance: np.ndarray
    variance: np.ndarray
    flags: np.ndarray
    times: np.ndarray
    nominal_times: np.ndarray
    shifts: np.ndarray | None
    weighting: str

    @property
    def saturated_fraction(self) -> float:
        """Fraction of pixel-channels saturated in every frame."""
        return float(np.mean(self.flags == FLAG_SATURATED))


_BLOCK = 512  # pixels per block of the merge kernel (the gathered block stays in L1/L2 cache)


@nb.njit(parallel=True, cache=True)  # no fastmath: NaN (no data after alignment) must compare false
def _merge_kernel(frames, near, times, inv_sat, lo, hi, optimal, inv_well, read_var, iterations,
                  out_rad, out_var, out_flag):  # pragma: no cover - compiled
    npix, nch = out_rad.shape
    nfr = len(frames)
    use_near = near[0].size > 0  # per frame, (npix,) bool: near a clipped pixel, weighted out like saturation
    mid = 0.5 * (lo + hi)
    inv_t = 1.0 / times
    nblocks = (npix + _BLOCK - 1) // _BLOCK
    for b in nb.prange(nblocks):
        p0 = b * _BLOCK
        p1 = min(p0 + _BLOCK, npix)
        # Gather the block of every frame once, normalised (contiguous reads, one tuple dispatch per frame).
        # A sample near a clipped pixel is gathered as +inf: weighted out like a saturated one.
        zb = np.empty((nfr, p1 - p0, nch), np.float32)
        for k in range(nfr):
            fk = frames[k]
            for p in range(p0, p1):
                for c in range(nch):
                    zb[k, p - p0, c] = fk[p, c] * inv_sat
            if use_near:
                nk = near[k]
                for p in range(p0, p1):
                    if nk[p]:
                        zb[k, p - p0, :] = np.inf
        for q in range(p1 - p0):
            p = p0 + q
            for c in range(nch):
                # Debevec hat estimate (the result for "debevec", the starting point for "optimal").
                num = 0.0
                den = 0.0
                for k in range(nfr):
                    z = zb[k, q, c]
                    if z > lo and z < hi:
                        w = z - lo if z <= mid else hi - z
                        num += w * z * inv_t[k]
                        den += w
                if den <= 0.0:
                    # No usable sample: longest unsaturated frame (dark), else shortest (saturated).
                    best = -1
                    for k in range(nfr):
                        z = zb[k, q, c]
                        if z == z and z < hi and (best < 0 or times[k] > times[best]):
                            best = k
                    if best >= 0:
                        x = max(zb[best, q, c], 0.0) * inv_t[best]
                        out_rad[p, c] = x
                        out_var[p, c] = (x * times[best] * inv_well + read_var) * inv_t[best] * inv_t[best]
                        out_flag[p, c] = 1
                    else:
                        for k in range(nfr):
                            if best < 0 or times[k] < times[best]:
                                best = k
                        x = np.float32(frames[best][p, c] * inv_sat) * inv_t[best]  # the value, not the +inf mark
                        out_rad[p, c] = x
                        out_var[p, c] = x * x
                        out_flag[p, c] = 2
                    continue
                x = num / den
                if optimal:
                    for _ in range(iterations):
                        num = 0.0
                        den = 0.0
                        xs = max(x, 0.0) * inv_well
                        for k in range(nfr):
                            z = zb[k, q, c]
                            if z > lo and z < hi:
                                # u = t / Var(z_k) = w_k / t_k, Var(z_k) = x t / well + read_var, w_k = t^2 / Var
                                u = 1.0 / (xs + read_var * inv_t[k])
                                num += u * z  # sum w_k (z_k / t_k)
                                den += u * times[k]  # sum w_k
                        x = num / den
                    var = 1.0 / den  # at the weights of the last iteration
                else:
                    xs = max(x, 0.0)
                    acc = 0.0
                    for k in range(nfr):
                        z = zb[k, q, c]
                        if z > lo and z < hi:
                            w = z - lo if z <= mid else hi - z
                            acc += w * w * (xs * times[k] * inv_well + read_var) * inv_t[k] * inv_t[k]
                    var = acc / (den * den)
                out_rad[p, c] = x
                out_var[p, c] = var
                out_flag[p, c] = 0


def _validate(frames, times, names, saturation) -> tuple[list, np.ndarray, list[str]]:
    """Frame sources (arrays checked and wrapped), times and names of a bracket; InputError naming the frame."""
    if len(frames) == 0:
        raise InputError("merge: the bracket has no frames")
    names = list(names) if names is not None else [f"frame {k}" for k in range(len(frames))]
    if len(names) != len(frames):
        raise InputError(f"merge: {len(names)} names for {len(frames)} frames")
    if times is None:
        raise InputError("merge: exposure times are missing")
    times = np.asarray(times, dtype=float).ravel()
    if times.size != len(frames):
        raise InputError(f"merge: {times.size} exposure times for {len(frames)} frames")
    for name, t in zip(names, times):
        if not (np.isfinite(t) and t > 0):
            raise InputError(f"merge: {name}: exposure time must be a positive number, got {t}")
    sources = [_checked_source(f, name, saturation) for name, f in zip(names, frames)]
    for name, src in zip(names, sources):
        if src.shape != sources[0].shape:
            raise InputError(f"merge: {name} has size {src.shape}, {names[0]} has {sources[0].shape}: "
                             "a bracket must have one image size")
    return sources, times, names


def _checked_source(frame, name: str, saturation: float | None):
    if hasattr(frame, "rows"):
        return frame
    f = np.asarray(frame)
    if f.ndim == 2:
        f = f[:, :, None]
    if f.ndim != 3:
        raise InputError(f"merge: {name}: expected an (H, W, C) image, got shape {f.shape}")
    if not (np.issubdtype(f.dtype, np.integer) or np.issubdtype(f.dtype, np.floating)):
        raise InputError(f"merge: {name}: unsupported pixel type {f.dtype}")
    if np.issubdtype(f.dtype, np.floating) and not np.all(np.isfinite(f)):
        raise InputError(f"merge: {name}: contains NaN/inf pixel values")
    return ArrayFrame(f, name, saturation)


def _check_settings(weighting, black_threshold, clip_threshold, clip_radius, sources) -> None:
    if weighting not in ("optimal", "debevec"):
        raise InputError(f"merge: weighting must be 'optimal' or 'debevec', got {weighting!r}")
    if not 0 <= black_threshold < clip_threshold <= 1:
        raise InputError(f"merge: need 0 <= black_threshold < clip_threshold <= 1, got "
                         f"{black_threshold}, {clip_threshold}")
    for src in sources:
        if not src.saturation > 0:
            raise InputError(f"merge: saturation must be positive, got {src.saturation}")
    if isinstance(clip_radius, bool) or not isinstance(clip_radius, (int, np.integer)) or clip_radius < 0:
        raise InputError(f"merge: clip_radius must be a non-negative integer (pixels), got {clip_radius!r}")


@nb.njit(parallel=True, cache=True)
def _clipped_pixels(frame, clip, out):  # pragma: no cover - compiled
    # Hand-written: numpy's (frame >= clip).any(axis=-1) takes ~0.7 s on a 12 MP RGB frame, this ~0.03 s.
    h, w, nch = frame.shape
    for i in nb.prange(h):
        for j in range(w):
            hit = False
            for c in range(nch):
                hit |= frame[i, j, c] >= clip  # NaN (no data) compares false
            out[i, j] = hit


def clipped_neighbourhood(frame: np.ndarray, clip: float, radius: int) -> np.ndarray:
    """Pixels within ``radius`` of a pixel that reaches ``clip`` in any channel.

    A demosaiced value interpolates the samples within the demosaicing support
    (bilinear, :func:`brdfrig.hdr.raw.decode_raw`: the 3x3 neighbourhood, ``radius``
    1), so next to a clipped sample it reads low while staying below the clip
    level.  Any channel, not only the same one.  With ``decode_raw``
    (bilinear, camera colour, no white balance) the damage stays in the
    clipped channel (four clipped lights in a 32x32 DNG: all 62 unclipped
    samples more than 1% off the demosaiced truth lie within radius 1 of a
    clipped sample of their own channel; the lights of the tests' bracket
    merge within 0.8% under either rule).  But frames colour-converted after
    demosaicing (camera TIFF/JPEG: a camera-to-sRGB matrix) carry a clipped
    camera channel into every output channel of the neighbours: a saturated
    red light (16, 3, 1 x full scale) merged within 0.7% with this any-channel
    rule, up to 226% off (13 pixel-channels beyond 2%) with a same-channel
    rule (``tests/test_merge.py``).  The price is small: 231 instead of 107
    samples weighted out around the four lights of the 32x32 DNG, which the
    merge takes from the next shorter exposure.

    Parameters
    ----------
    frame : (H, W, C) or (H, W) array
        Linear frame (any real dtype); NaN (no data) is never clipped.
    clip : float
        Clip level, in frame units (``clip_threshold * saturation``).
    radius : int
        Neighbourhood radius in pixels (a ``(2 radius + 1)^2`` square; 0 = the
        clipped pixels themselves).  Beyond the image edge nothing is clipped.

    Returns
    -------
    (H, W) bool
    """
    frame = np.asarray(frame)
    if frame.ndim == 2:
        frame = frame[:, :, None]
    hit = np.empty(frame.shape[:2], np.uint8)
    _clipped_pixels(frame, clip, hit)
    if radius > 0 and hit.any():
        import cv2

        hit = cv2.dilate(hit, np.ones((2 * radius + 1, 2 * radius + 1), np.uint8))
    return hit.view(bool)


def _band(src, y0: int, y1: int, clip: float, radius: int, mask: bool):
    """Rows y0:y1 of a source (own dtype) and, if ``mask``, their clipped neighbourhood (read with a halo)."""
    h = src.shape[0]
    a0, a1 = max(0, y0 - radius), min(h, y1 + radius)
    rows = src.rows(a0, a1)
    near = clipped_neighbourhood(rows, clip * src.saturation, radius)[y0 - a0:y1 - a0] if mask else None
    return rows[y0 - a0:y1 - a0], near


def sample_bands(shape, max_samples: int = RATIO_MAX_SAMPLES, bands: int = 8) -> list[tuple[int, int]]:
    """Row ranges (y0, y1): ``bands`` evenly spaced bands of rows holding at most ``max_samples`` pixel-channels."""
    h, w, c = shape
    total = max(1, min(h, max_samples // (w * c)))
    if total >= h:
        return [(0, h)]
    n = min(bands, total)
    per = total // n
    starts = np.linspace(0, h - per, n).astype(int)
    return [(int(y), int(y) + per) for y in starts]


def _sample(sources, clip: float, radius: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Evenly spaced bands of rows of every frame (fractions of full scale) and their clipped neighbourhoods."""
    frames, masks = [], []
    for src in sources:
        parts = [_band(src, y0, y1, clip, radius, True) for y0, y1 in sample_bands(src.shape)]
        frames.append(np.concatenate([np.asarray(r, np.float64) / src.saturation for r, _ in parts]))
        masks.append(np.concatenate([m for _, m in parts]))
    return frames, masks


def _times_used(sources, nominal, clip, radius, ratio_tolerance) -> np.ndarray:
    """Exposure times re-estimated from the frames' overlap where they differ from the nominal ratios."""
    frames, near = _sample(sources, clip, radius)
    est = estimate_times(frames, nominal, saturation=1.0, clip=clip, clip_radius=radius, near_clip=near)
    ratio_err = np.abs(est / nominal / np.median(est / nominal) - 1)
    if np.any(ratio_err > ratio_tolerance):
        log.info("merge: exposure times re-estimated from overlap: %s -> %s", nominal.tolist(), est.tolist())
        return est
    return nominal


def _merge_tiles(sources, used, settings: dict, tile_rows: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Radiance, variance and flags as (C, H, W) planes, merged band by band."""
    h, w, c = sources[0].shape
    rad = np.empty((c, h, w), np.float32)
    var = np.empty((c, h, w), np.float32)
    flags = np.empty((c, h, w), np.uint8)
    radius = settings["clip_radius"]
    same = len({(np.dtype(s.dtype), s.saturation) for s in sources}) == 1
    inv_sat = 1.0 / sources[0].saturation if same else 1.0
    for y0 in range(0, h, tile_rows):
        y1 = min(h, y0 + tile_rows)
        bands = [_band(s, y0, y1, settings["clip"], radius, radius > 0) for s in sources]
        rows = [r if same else np.asarray(r, np.float32) / np.float32(s.saturation) for (r, _), s in zip(bands, sources)]
        flat = tuple(np.ascontiguousarray(r).reshape(-1, c) for r in rows)
        near = tuple(m.reshape(-1) for _, m in bands) if radius > 0 else (np.empty(0, bool),)
        _merge_kernel(flat, near, used, inv_sat, settings["lo"], settings["clip"], settings["optimal"],
                      settings["inv_well"], settings["read_var"], settings["iterations"],
                      rad[:, y0:y1].reshape(c, -1).T, var[:, y0:y1].reshape(c, -1).T,
                      flags[:, y0:y1].reshape(c, -1).T)
    return rad, var, flags


def merge_bracket(
    frames: Sequence,
    times: Sequence[float],
    *,
    weighting: str = "optimal",
    saturation: float | None = None,
    clip_threshold: float = 0.95,
    clip_radius: int = 1,
    black_threshold: float = 0.0,
    full_well: float = DEFAULT_FULL_WELL,
    read_noise: float = DEFAULT_READ_NOISE,
    reestimate_times: bool = True,
    ratio_tolerance: float = 0.005,
    align: bool = False,
    iterations: int = 2,
    names: Sequence[str] | None = None,
    tile_rows: int = 256,
) -> MergeResult:
    """Merge a bracket of linear frames into radiance and variance (model: the module docstring).

    Parameters
    ----------
    frames : sequence of K (H, W, C) or (H, W) arrays or frame sources
        Linear frames of one scene (float or integer arrays, or
        :mod:`brdfrig.hdr.frames` sources read by rows), all the same shape.
    times : (K,) float
        Nominal exposure times in seconds (any order).
    weighting : {"optimal", "debevec"}
        Noise-optimal ``t^2 / variance`` weights (default) or Debevec's hat.
    saturation : float, optional
        Frame value of full scale of array frames: 1.0 for float arrays, the
        dtype's maximum for integer arrays by default (sources carry their own).
    clip_threshold, black_threshold : float
        Samples ``>= clip_threshold`` or ``<= black_threshold`` (fractions of
        full scale) get zero weight, per channel.
    clip_radius : int
        Every channel of a pixel within ``clip_radius`` pixels of a pixel
        ``>= clip_threshold`` in any channel of a frame gets zero weight in it
        (:func:`clipped_neighbourhood`): 1 covers bilinear demosaicing
        (small lights clipped at 16x full scale merged up to 84% low at their
        demosaiced rim with 0, within 0.8% with 1), 0 frames never demosaiced.
    full_well, read_noise : float
        Noise model in electrons: full-scale signal and read-noise sigma.
    reestimate_times : bool
        Use exposure ratios re-estimated from well-exposed overlap
        (:func:`estimate_times`) where they differ from the nominal ones by
        more than ``ratio_tolerance`` (relative).
    align : bool
        Translate frames onto the median-exposure frame first (:func:`brdfrig.hdr.align.align_sources`).
    iterations : int
        Re-weighting iterations of the optimal merge.
    names : sequence of str, optional
        Frame names (file names) used in error messages.
    tile_rows : int
        Rows merged at a time.

    Returns
    -------
    MergeResult
        Arrays (H, W, C), views of channel-major planes.
    """
    sources, nominal, names = _validate(frames, times, names, saturation)
    _check_settings(weighting, black_threshold, clip_threshold, clip_radius, sources)
    shifts = None
    if align and len(sources) > 1:
        sources, shifts = align_sources(sources, nominal)
    used = _times_used(sources, nominal, clip_threshold, clip_radius, ratio_tolerance) \
        if reestimate_times and len(sources) > 1 else nominal.copy()
    settings = {"clip_radius": int(clip_radius), "clip": clip_threshold, "lo": black_threshold,
                "optimal": weighting == "optimal", "inv_well": 1.0 / full_well,
                "read_var": (read_noise / full_well) ** 2, "iterations": int(iterations)}
    rad, var, flags = _merge_tiles(sources, used, settings, max(1, int(tile_rows)))
    _warn_saturated(flags, clip_radius, used)
    return MergeResult(radiance=rad.transpose(1, 2, 0), variance=var.transpose(1, 2, 0),
                       flags=flags.transpose(1, 2, 0), times=used, nominal_times=nominal, shifts=shifts,
                       weighting=weighting)


def _warn_saturated(flags: np.ndarray, clip_radius: int, used: np.ndarray) -> None:
    nsat = int(np.count_nonzero(flags == FLAG_SATURATED))
    if nsat:
        warnings.warn(
            f"merge: {nsat} pixel-channels ({100 * nsat / flags.size:.3g}%) are saturated in every "
            f"frame (or within clip_radius={clip_radius} px of a saturated pixel), shortest exposure "
            f"{used.min():.6g} s: their radiance is only a lower bound (add a shorter exposure)",
            SaturationWarning,
            stacklevel=3,
        )
