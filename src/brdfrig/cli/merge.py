"""``brdfrig merge``: merge an exposure bracket into one linear HDR EXR (radiance + variance).

Frames are camera raw files (DNG, CR2, NEF, ... decoded linearly by LibRaw)
or TIFF/JPEG.  Exposure times come from the files' metadata (EXIF) unless
``--times`` gives them; when ISO or aperture also vary, the effective exposure
``t * ISO / N^2`` (relative to the first frame) is used.  Integer TIFF/JPEG
frames are taken as non-linear and linearised by a response curve recovered
from the bracket itself (Debevec & Malik), unless ``--response linear``.

The output EXR holds the radiance as R,G,B (frame units per second), its
variance as ``variance.R/G/B``, the per-pixel merge flags as ``flags``
(0 ok, 1 black in every frame, 2 saturated, or within ``--clip-radius`` of a
clipped pixel, in every frame, or with no data after ``--align``: radiance and
variance 0 there) and the exposure provenance as ``brdfrig:`` attributes.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from brdfrig.cli._output import add_output_arguments, check_output
from brdfrig.ranges import EXPOSURE_S as EXPOSURE_TIME
from brdfrig.ranges import FULL_WELL_E as FULL_WELL
from brdfrig.ranges import READ_NOISE_E as READ_NOISE
from brdfrig.ranges import Range

CLIP_RADIUS = Range(0, 16, integer=True)  # pixels


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "merge",
        help="merge an exposure bracket (raw/TIFF/JPEG) into a linear HDR EXR with a variance image",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("files", nargs="+", type=Path, metavar="FILE", help="the frames of one bracket")
    add_output_arguments(p, "OUT.exr", "output EXR")
    p.add_argument("--times", type=EXPOSURE_TIME.args("each exposure time (s)"), metavar="T1,T2,...",
                   help="exposure times in seconds, one per file (default: from the files' metadata)")
    p.add_argument("--weighting", choices=("optimal", "debevec"), default="optimal",
                   help="noise-optimal t^2/variance weights or Debevec's hat (default: %(default)s)")
    p.add_argument("--response", choices=("auto", "linear", "recover"), default="auto",
                   help="linearisation of integer TIFF/JPEG frames: recover the response from the bracket "
                        "(auto for integer TIFF/JPEG), or take them as linear (default: %(default)s)")
    p.add_argument("--align", action="store_true", help="align frames by translation (median threshold bitmaps)")
    p.add_argument("--clip-radius", type=CLIP_RADIUS.arg(), default=1, metavar="PX",
                   help="weight out every pixel within PX pixels of a pixel clipped in any channel: demosaicing "
                        "spreads clipped values into neighbours that then read low (1 = bilinear demosaicing, as "
                        "for raw files; 0 = frames not demosaiced; in-camera TIFF/JPEG may need 2) "
                        "(default: %(default)s)")
    p.add_argument("--no-reestimate", action="store_true",
                   help="trust the nominal exposure times (no re-estimation from well-exposed overlap)")
    p.add_argument("--full-well", type=FULL_WELL.arg(), default=None, metavar="E",
                   help=f"sensor full-well capacity in electrons for the noise model, {FULL_WELL.text()[1:]} "
                        "(default: 20000)")
    p.add_argument("--read-noise", type=READ_NOISE.arg(), default=None, metavar="E",
                   help=f"read noise in electrons for the noise model, {READ_NOISE.text()[1:]} (default: 5)")
    p.set_defaults(func=run)


def _effective_times(exposures) -> list[float]:
    """Exposure times scaled by ISO and aperture when these vary within the bracket."""
    import math

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


def _check_distinct(files) -> None:
    """InputError if one file is given twice (also under another name): a bracket needs distinct frames."""
    import os

    from brdfrig.errors import InputError

    for i, a in enumerate(files):
        for b in files[:i]:
            if a.exists() and b.exists() and os.path.samefile(a, b):
                raise InputError(f"{a} is given twice (also as {b}): a bracket needs distinct frames")


def run(args) -> int:
    import sys
    import warnings

    import numpy as np

    from brdfrig.errors import InputError
    from brdfrig.hdr.exr import write_exr
    from brdfrig.hdr.merge import DEFAULT_FULL_WELL, DEFAULT_READ_NOISE, merge_bracket
    from brdfrig.hdr.raw import read_exposure, read_frame
    from brdfrig.hdr.response import linearize, recover_response

    files = list(args.files)
    check_output(args.output, files, suffixes=(".exr",), writes="an OpenEXR image", no_clobber=args.no_clobber)
    _check_distinct(files)
    if args.times is not None:
        if len(args.times) != len(files):
            raise InputError(f"--times has {len(args.times)} values for {len(files)} files")
        times = args.times
        provenance = "--times"
        exposures = None
    else:
        exposures = [read_exposure(f) for f in files]
        times = _effective_times(exposures)
        provenance = "metadata"

    frames, linear = [], []
    for f in files:
        image, is_linear = read_frame(f)
        if frames and image.shape != frames[0].shape:
            raise InputError(f"{f} has size {image.shape[1]}x{image.shape[0]}, {files[0]} has "
                             f"{frames[0].shape[1]}x{frames[0].shape[0]}: a bracket must have one image size")
        for g, other in zip(files, frames):
            if np.array_equal(image, other):
                raise InputError(f"{f} and {g} hold identical pixels: the same frame given twice")
        frames.append(image)
        linear.append(is_linear)
    response = args.response
    if response == "auto":
        response = "linear" if all(linear) else "recover"
    if response == "recover":
        if len(files) < 2:
            raise InputError("response recovery needs at least 2 frames; use --response linear for one frame")
        curve = recover_response(frames, times, levels=256 if all(f.suffix.lower() in (".jpg", ".jpeg")
                                                                 for f in files) else 1024)
        frames = [linearize(f, curve) for f in frames]

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = merge_bracket(
            frames, times, weighting=args.weighting, saturation=1.0, clip_radius=args.clip_radius,
            align=args.align, reestimate_times=not args.no_reestimate, names=[str(f) for f in files],
            full_well=DEFAULT_FULL_WELL if args.full_well is None else args.full_well,
            read_noise=DEFAULT_READ_NOISE if args.read_noise is None else args.read_noise,
        )
    for w in caught:
        print(f"brdfrig merge: warning: {w.message}", file=sys.stderr)
    no_data = ~np.isfinite(res.radiance)  # pixels shifted in from outside every aligned frame (flag 2)
    if no_data.any():
        res.radiance[no_data] = 0.0
        res.variance[no_data] = 0.0
        print(f"brdfrig merge: note: {int(no_data.sum())} pixel-channel(s) at the frame borders have no data after "
              "alignment: written as 0 with flags = 2", file=sys.stderr)
    attributes = {
        "kind": "merged_bracket",
        "source_files": [f.name for f in files],
        "times_source": provenance,
        "nominal_times_s": res.nominal_times.tolist(),
        "times_s": res.times.tolist(),
        "weighting": res.weighting,
        "clip_radius_px": args.clip_radius,
        "response": response,
        "units": "frame full scale per second",
    }
    if exposures is not None:
        attributes["exposures"] = [{"time_s": e.time_s, "f_number": e.f_number if np.isfinite(e.f_number) else None,
                                    "iso": e.iso if np.isfinite(e.iso) else None} for e in exposures]
    if res.shifts is not None:
        attributes["shifts_px"] = res.shifts.tolist()
    write_exr(args.output, res.radiance, {"variance": res.variance, "flags": res.flags.max(axis=2)}, attributes,
              overwrite=not args.no_clobber)
    ok = res.radiance[res.flags == 0]
    pos = ok[ok > 0]
    rng = f"{pos.max() / pos.min():.3g}:1" if pos.size else "n/a"
    changed = "" if np.array_equal(res.times, res.nominal_times) else \
        " (times re-estimated from overlap: " + ", ".join(f"{t:.6g}" for t in res.times) + " s)"
    print(f"merged {len(files)} frames -> {args.output} ({frames[0].shape[1]}x{frames[0].shape[0]}, "
          f"dynamic range {rng}, {100 * res.saturated_fraction:.3g}% saturated in every frame){changed}")
    return 0
