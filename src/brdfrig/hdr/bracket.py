"""Merge a bracket of camera files: the one path ``brdfrig merge`` and the session pipeline share.

:func:`merge_files` reads the frames (:func:`brdfrig.hdr.raw.read_frame`) and
their exposure metadata, computes the effective exposure times, decides the
response (linear, or recovered from the bracket: :mod:`brdfrig.hdr.response`)
and the clip radius, and merges with :func:`brdfrig.hdr.merge.merge_bracket`.
Every choice it makes from the data is returned with a sentence saying why
(:class:`BracketMerge`), for the command to print and store.

Response (``policy.response="auto"``): raw and floating-point frames are
linear; for integer TIFF/JPEG/PNG frames a response is recovered from the
bracket and tested against a straight line relative to its own uncertainty
(:func:`brdfrig.hdr.response.linearity`): linear within it, the frames are
merged as they are (a recovered curve would only add its noise), else they
are linearised by the curve.

Clip radius (``policy.clip_radius=None``): 1 for raw files (brdfrig decodes
them with bilinear demosaicing, a 3x3 support); for TIFF/JPEG/PNG the
demosaicing support measured from the correlation of the bracket's noise
between neighbouring pixels (:func:`brdfrig.hdr.demosaic.demosaic_radius`: 0
for pixels measured independently), or 1 when it cannot be measured.

Effective exposure: ``t * (ISO / ISO_0) * (N_0 / N)^2`` relative to the
first frame, when ISO or f-number vary within the bracket (NaN when a file
does not record them: then that factor is 1).

Colour: the merge is in camera RGB; with ``MergePolicy.colour_space`` =
``"rec709"`` or ``"acescg"`` the merged radiance is converted by the first raw
file's colour matrix and as-shot neutral (:mod:`brdfrig.hdr.colour`), the
variance by the squared matrix (channels independent), and a pixel flagged in
any channel is flagged in all; negative values (noise or out-of-gamut colours)
are set to 0 with a warning.
"""

from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from brdfrig.errors import InputError
from brdfrig.hdr.colour import convert_merged, raw_file_matrix
from brdfrig.hdr.merge import DEFAULT_FULL_WELL, DEFAULT_READ_NOISE, MergeResult, merge_bracket
from brdfrig.hdr.raw import Exposure, is_raw, read_exposure

__all__ = ["MergePolicy", "BracketMerge", "merge_files", "effective_times", "check_distinct", "RAW_CLIP_RADIUS"]

#: Clip radius of frames decoded by brdfrig from raw files: the 3x3 support of the bilinear demosaicing of
#: :func:`brdfrig.hdr.raw.decode_raw`.
RAW_CLIP_RADIUS = 1
#: Smoothness of the response curve used to linearise 16-bit frames (1024 bins), around the power law of a first
#: recovery: on 7-frame 16-bit brackets the merge's median error is then within a few % of the noise-optimal one.
_SMOOTHNESS_16BIT = 160.0


@dataclass(frozen=True)
class MergePolicy:
    """How a bracket of files is merged.

    Attributes
    ----------
    full_well, read_noise : float
        Sensor noise model in electrons (full-scale signal, read-noise sigma).
    weighting : {"optimal", "debevec"}
        Merge weights (:func:`brdfrig.hdr.merge.merge_bracket`).
    response : {"auto", "linear", "recover"}
        Linearisation of integer TIFF/JPEG/PNG frames: ``"auto"`` decides
        from the data (raw and float frames are always linear).
    clip_radius : int or None
        Pixels weighted out around a clipped pixel; None = by what the frames
        are (see :func:`merge_files`).
    clip_threshold : float
        Fraction of full scale at and above which a sample is saturated.
    reestimate_times : bool
        Re-estimate exposure ratios from well-exposed overlap.
    align : bool
        Align the frames by translation first.
    colour_space : {"camera", "rec709", "acescg"}
        Colour space of the result (``"camera"``: camera RGB, no conversion).
    """

    full_well: float = DEFAULT_FULL_WELL
    read_noise: float = DEFAULT_READ_NOISE
    weighting: str = "optimal"
    response: str = "auto"
    clip_radius: int | None = None
    clip_threshold: float = 0.95
    reestimate_times: bool = True
    align: bool = False
    colour_space: str = "camera"


@dataclass(frozen=True)
class BracketMerge:
    """A merged bracket of files and the choices made on the way.

    Attributes
    ----------
    merge : MergeResult
        Radiance, variance, flags and times; pixels without data after
        alignment hold radiance and variance 0 (flags 2).
    files : list of Path
    exposures : list of Exposure or None
        Metadata of each file (None when the times were given).
    times_source : {"metadata", "given"}
    response : {"linear", "recover"}
        Linearisation applied to the frames.
    response_reason : str
        Why (one sentence).
    clip_radius : int
        Clip radius used, in pixels.
    clip_reason : str
        Why (one sentence).
    no_data : int
        Pixel-channels without data after alignment.
    colour_space : str
        Colour space of the radiance (see :class:`MergePolicy`).
    colour_matrix : (3, 3) array or None
        Camera RGB -> ``colour_space`` matrix applied (None for ``"camera"``).
    """

    merge: MergeResult
    files: list[Path]
    exposures: list[Exposure] | None
    times_source: str
    response: str
    response_reason: str
    clip_radius: int
    clip_reason: str
    no_data: int = 0
    colour_space: str = "camera"
    colour_matrix: np.ndarray | None = None


def effective_times(exposures: Sequence[Exposure]) -> list[float]:
    """Exposure times scaled by ISO and aperture where these vary within the bracket (relative to frame 0), s."""
    ref = exposures[0]
    out = []
    for e in exposures:
        t = e.time_s
        if not math.isnan(e.iso) and not math.isnan(ref.iso) and e.iso != ref.iso:
            t *= e.iso / ref.iso
        if not math.isnan(e.f_number) and not math.isnan(ref.f_number) and e.f_number != ref.f_number:
            t *= (ref.f_number / e.f_number) ** 2
        out.append(t)
    return out


def check_distinct(files: Sequence[Path]) -> None:
    """InputError if one file is given twice (also under another name): a bracket needs distinct frames."""
    for i, a in enumerate(files):
        for b in files[:i]:
            if a.exists() and b.exists() and os.path.samefile(a, b):
                raise InputError(f"{a} is given twice (also as {b}): a bracket needs distinct frames")


def _open_frames(files: Sequence[Path]) -> tuple[list, list[bool]]:
    """Frame sources of a bracket (one size, no two identical) and whether each is linear by its format.

    Raw files are decoded one at a time into a temporary file read back by rows
    (:class:`brdfrig.hdr.frames.RawFrame`); other images are read by rows.
    """
    from brdfrig.hdr.frames import ImageFileFrame, RawFrame

    sources, linear = [], []
    for f in files:
        src = RawFrame(f) if is_raw(f) else ImageFileFrame(f)
        if sources and src.shape != sources[0].shape:
            raise InputError(f"{f} has size {src.shape[1]}x{src.shape[0]}, {files[0]} has "
                             f"{sources[0].shape[1]}x{sources[0].shape[0]}: a bracket must have one image size")
        for g, other in zip(files, sources):
            if _same_pixels(src, other):
                raise InputError(f"{f} and {g} hold identical pixels: the same frame given twice")
        sources.append(src)
        linear.append(is_raw(f) or src.is_float)
    return sources, linear


def _same_pixels(a, b, rows: int = 256) -> bool:
    """Whether two sources of one shape hold the same pixels (sample bands first, then band by band)."""
    from brdfrig.hdr.merge import sample_bands

    h = a.shape[0]
    if not all(np.array_equal(a.rows(y0, y1), b.rows(y0, y1)) for y0, y1 in sample_bands(a.shape, 20_000, 2)):
        return False
    return all(np.array_equal(a.rows(y, min(h, y + rows)), b.rows(y, min(h, y + rows))) for y in range(0, h, rows))


def _samples(sources) -> list[np.ndarray]:
    """Evenly spaced bands of rows of every frame, as fractions of full scale (float64)."""
    from brdfrig.hdr.merge import sample_bands

    return [np.concatenate([np.asarray(s.rows(y0, y1), np.float64) / s.saturation
                            for y0, y1 in sample_bands(s.shape)]) for s in sources]


def _centre(source, size: int = 1024) -> np.ndarray:
    """The central ``size x size`` window of a source, as fractions of full scale."""
    h, w = source.shape[:2]
    y0, x0 = max(0, (h - size) // 2), max(0, (w - size) // 2)
    return np.asarray(source.rows(y0, min(h, y0 + size))[:, x0:x0 + size], np.float64) / source.saturation


def _times(files: Sequence[Path], times: Sequence[float] | None) -> tuple[list[float], list[Exposure] | None, str]:
    if times is not None:
        if len(times) != len(files):
            raise InputError(f"--times has {len(times)} values for {len(files)} files")
        return [float(t) for t in times], None, "given"
    exposures = [read_exposure(f) for f in files]
    return effective_times(exposures), exposures, "metadata"


def _response(sources, times, linear, files, policy: MergePolicy) -> tuple[list, str, str]:
    """Linearised frame sources, the response applied (``"linear"`` or ``"recover"``) and why.

    The curve is recovered from evenly spaced bands of rows (:func:`brdfrig.hdr.merge.sample_bands`).
    """
    from brdfrig.hdr.frames import MappedFrame
    from brdfrig.hdr.response import linearity, linearize, power_slope, recover_response

    if all(linear):
        return sources, "linear", "raw or floating-point frames are linear"
    if policy.response == "linear":
        return sources, "linear", "linear response requested"
    frames = _samples(sources)
    if len(frames) < 2:
        raise InputError("response recovery needs at least 2 frames; give --response linear for one frame")
    levels = 256 if all(f.suffix.lower() in (".jpg", ".jpeg") for f in files) else 1024
    curve = recover_response(frames, times, levels=levels)
    if policy.response == "auto":
        test = linearity(curve)
        if test.linear:
            return sources, "linear", test.describe()
        reason = test.describe() + ": linearised by it"
    else:
        reason = "response recovery requested"
    if levels > 256:  # 4x fewer samples per bin than 8-bit data: smooth harder, around the curve's power law
        curve = recover_response(frames, times, levels=levels, smoothness=_SMOOTHNESS_16BIT, slope=power_slope(curve))
    return [MappedFrame(s, lambda rows: linearize(rows, curve)) for s in sources], "recover", reason


def _clip_radius(files, sources, times, policy: MergePolicy) -> tuple[int, str]:
    """Clip radius (pixels) by what the frames are, and why."""
    from brdfrig.hdr.demosaic import demosaic_radius

    if policy.clip_radius is not None:
        return int(policy.clip_radius), "given"
    if all(is_raw(f) for f in files):
        return RAW_CLIP_RADIUS, "raw files, decoded with bilinear demosaicing (3x3 support)"
    support = demosaic_radius([_centre(s) for s in sources], times) if len(sources) > 1 else None
    if support is None:
        return RAW_CLIP_RADIUS, ("too few well-exposed neighbours to measure the noise correlation: "
                                 f"{RAW_CLIP_RADIUS}, as for demosaiced frames")
    return support.radius, support.describe()


def merge_files(paths: Sequence[str | os.PathLike], policy: MergePolicy = MergePolicy(), *,
                times: Sequence[float] | None = None) -> BracketMerge:
    """Read, linearise and merge one bracket of camera files (raw, TIFF, JPEG, PNG, EXR), streaming the rows.

    Parameters
    ----------
    paths : sequence of path-like
        The frames of one bracket (distinct files, one image size).
    policy : MergePolicy
        Noise model and merge settings.
    times : sequence of float, optional
        Exposure times in seconds, one per file; default: from the files'
        metadata (effective times, see the module docstring).

    Returns
    -------
    BracketMerge
    """
    files = [Path(p) for p in paths]
    check_distinct(files)
    used_times, exposures, source = _times(files, times)
    matrix = raw_file_matrix(files[0], policy.colour_space)
    sources, linear = _open_frames(files)
    sources, response, response_reason = _response(sources, used_times, linear, files, policy)
    radius, clip_reason = _clip_radius(files, sources, used_times, policy)
    res = merge_bracket(sources, used_times, weighting=policy.weighting,
                        clip_threshold=policy.clip_threshold, clip_radius=radius, align=policy.align,
                        reestimate_times=policy.reestimate_times, full_well=policy.full_well,
                        read_noise=policy.read_noise, names=[str(f) for f in files])
    no_data = ~np.isfinite(res.radiance)  # pixels shifted in from outside every aligned frame (flag 2)
    if no_data.any():
        res.radiance[no_data] = 0.0
        res.variance[no_data] = 0.0
    if matrix is not None and (clipped := convert_merged(res.radiance, res.variance, res.flags, matrix)):
        warnings.warn(f"{clipped} pixel-channel(s) negative after conversion to {policy.colour_space} "
                      "(noise or colours outside its gamut): set to 0", stacklevel=2)
    return BracketMerge(res, files, exposures, source, response, response_reason, radius, clip_reason,
                        int(no_data.sum()), policy.colour_space, matrix)
