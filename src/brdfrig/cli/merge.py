"""`brdfrig merge`: merge an exposure bracket into one linear HDR EXR (radiance + variance).

Frames are camera raw files (DNG, CR2, NEF, ... decoded linearly by LibRaw)
or TIFF/JPEG.  Exposure times come from the files' metadata (EXIF) unless
`--times` gives them; when ISO or aperture also vary, the effective exposure
`t * ISO / N^2` (relative to the first frame) is used.  Integer TIFF/JPEG
frames may be non-linear: with `--response auto` a response curve is recovered
from the bracket itself (Debevec & Malik) and tested: a curve that is a
straight line within its uncertainty means linear frames, merged as they are.
The response and the clip radius chosen, and why, are printed and stored.

The output EXR holds the radiance as R,G,B (frame units per second), its
variance as `variance.R/G/B`, the per-pixel merge flags as `flags`
(0 ok, 1 black in every frame, 2 saturated, or within `--clip-radius` of a
clipped pixel, in every frame, or with no data after `--align`: radiance and
variance 0 there) and the exposure provenance as `brdfrig:` attributes (source
files by absolute path).  Standard attributes: `expTime` = 1 s (the radiance
is full scale per second, i.e. the equivalent of a 1 s exposure) and, where the
first frame records them, its `aperture` and `isoSpeed` (the reference of
the effective exposure times).

`--colour-space rec709` or `acescg` converts camera RGB by the first raw
file's colour matrix and as-shot neutral (white
balanced: a grey card reads R = G = B); the space is stored as
`brdfrig:colour_space` with the matrix, and the standard `chromaticities`
are set.  The default `camera` keeps camera RGB (no `chromaticities`).
"""

from __future__ import annotations

from pathlib import Path

from brdfrig.cli._command import add_command
from brdfrig.cli._output import add_json_argument, add_output_arguments, check_output, print_json
from brdfrig.hdr.colour import COLOUR_SPACES
from brdfrig.ranges import EXPOSURE_S as EXPOSURE_TIME
from brdfrig.ranges import FULL_WELL_E as FULL_WELL
from brdfrig.ranges import READ_NOISE_E as READ_NOISE
from brdfrig.ranges import Range

CLIP_RADIUS = Range(0, 16, integer=True)  # pixels


def register(subparsers) -> None:
    p = add_command(subparsers, "merge",
                    "merge an exposure bracket (raw/TIFF/JPEG) into a linear HDR EXR with a variance image",
                    __doc__)
    p.add_argument("files", nargs="+", type=Path, metavar="FILE", help="the frames of one bracket")
    add_output_arguments(p, "OUT.exr", "output EXR")
    p.add_argument("--times", type=EXPOSURE_TIME.args("each exposure time (s)"), metavar="T1,T2,...",
                   help="exposure times in seconds, one per file (default: from the files' metadata)")
    p.add_argument("--weighting", choices=("optimal", "debevec"), default="optimal",
                   help="noise-optimal t^2/variance weights or Debevec's hat (default: %(default)s)")
    p.add_argument("--response", choices=("auto", "linear", "recover"), default="auto",
                   help="linearisation of integer TIFF/JPEG frames: auto = recover a response curve from the "
                        "bracket and use it only if it is not a straight line within its uncertainty; linear = "
                        "take the frames as linear; recover = always use the recovered curve. Raw and float "
                        "frames are always linear (default: %(default)s)")
    p.add_argument("--colour-space", choices=COLOUR_SPACES, default="camera",
                   help="colour space of the output: camera RGB as recorded, or linear Rec.709 / ACEScg from the "
                        "raw files' colour matrix and white balance (default: %(default)s)")
    p.add_argument("--align", action="store_true", help="align frames by translation (median threshold bitmaps)")
    p.add_argument("--clip-radius", type=CLIP_RADIUS.arg(), default=None, metavar="PX",
                   help="weight out every pixel within PX pixels of a pixel clipped in any channel: demosaicing "
                        "spreads clipped values into neighbours that then read low (default: 1 for raw files, "
                        "which brdfrig demosaics bilinearly; for TIFF/JPEG the demosaicing support measured "
                        "from how the noise of neighbouring pixels correlates, 0 for frames never demosaiced)")
    p.add_argument("--no-reestimate", action="store_true",
                   help="trust the nominal exposure times (no re-estimation from well-exposed overlap)")
    p.add_argument("--full-well", type=FULL_WELL.arg(), default=None, metavar="E",
                   help=f"sensor full-well capacity in electrons for the noise model, {FULL_WELL.text()[1:]} "
                        "(default: 20000)")
    p.add_argument("--read-noise", type=READ_NOISE.arg(), default=None, metavar="E",
                   help=f"read noise in electrons for the noise model, {READ_NOISE.text()[1:]} (default: 5)")
    add_json_argument(p)
    p.set_defaults(func=run)


def _attributes(merged) -> dict:
    """The EXR's ``brdfrig:`` provenance attributes of a merged bracket."""
    import numpy as np

    res = merged.merge
    attributes = {
        "kind": "merged_bracket",
        "source_files": [str(f.resolve()) for f in merged.files],
        "times_source": "--times" if merged.times_source == "given" else merged.times_source,
        "nominal_times_s": res.nominal_times.tolist(),
        "times_s": res.times.tolist(),
        "weighting": res.weighting,
        "clip_radius_px": merged.clip_radius,
        "clip_radius_reason": merged.clip_reason,
        "response": merged.response,
        "response_reason": merged.response_reason,
        "units": "frame full scale per second",
        "colour_space": merged.colour_space,
    }
    if merged.colour_matrix is not None:
        attributes["colour_matrix"] = np.asarray(merged.colour_matrix).tolist()
    if merged.exposures is not None:
        attributes["exposures"] = [{"time_s": e.time_s, "f_number": e.f_number if np.isfinite(e.f_number) else None,
                                    "iso": e.iso if np.isfinite(e.iso) else None} for e in merged.exposures]
    if res.shifts is not None:
        attributes["shifts_px"] = res.shifts.tolist()
    return attributes


def _standard_attributes(merged) -> dict:
    """``expTime`` (1 s: radiance per second), the reference frame's ``aperture`` / ``isoSpeed`` where known and
    the ``chromaticities`` of a declared colour space."""
    import math

    from brdfrig.hdr.colour import chromaticities

    standard = {"expTime": 1.0}
    if merged.colour_space != "camera":
        standard["chromaticities"] = chromaticities(merged.colour_space)
    if merged.exposures:
        ref = merged.exposures[0]
        for key, value in (("aperture", ref.f_number), ("isoSpeed", ref.iso)):
            if math.isfinite(value) and value > 0:
                standard[key] = float(value)
    return standard


def _numbers(merged, output) -> dict:
    """Every number the summary prints (for ``--json``): size, dynamic range, saturation, times, choices."""
    import numpy as np

    res = merged.merge
    ok = res.radiance[res.flags == 0]
    pos = ok[ok > 0]
    h, w = res.radiance.shape[:2]
    return {"output": str(Path(output).resolve()), "frames": len(merged.files), "width": w, "height": h,
            "dynamic_range": float(pos.max() / pos.min()) if pos.size else None,
            "saturated_fraction": float(res.saturated_fraction), "nominal_times_s": res.nominal_times.tolist(),
            "times_s": res.times.tolist(), "times_reestimated": not np.array_equal(res.times, res.nominal_times),
            "response": merged.response, "response_reason": merged.response_reason,
            "clip_radius_px": merged.clip_radius, "clip_radius_reason": merged.clip_reason,
            "colour_space": merged.colour_space, "no_data": merged.no_data}


def _summary(merged, output) -> str:
    import numpy as np

    res = merged.merge
    ok = (res.flags == 0) & (res.radiance > 0)  # masked reductions: no copy of the radiance
    hi = np.max(res.radiance, where=ok, initial=0.0)
    rng = f"{hi / np.min(res.radiance, where=ok, initial=np.inf):.3g}:1" if hi > 0 else "n/a"
    changed = "" if np.array_equal(res.times, res.nominal_times) else \
        " (times re-estimated from overlap: " + ", ".join(f"{t:.6g}" for t in res.times) + " s)"
    h, w = res.radiance.shape[:2]
    return (f"merged {len(merged.files)} frames -> {output} ({w}x{h}, dynamic range {rng}, "
            f"{100 * res.saturated_fraction:.3g}% saturated in every frame){changed}\n"
            f"response: {merged.response} ({merged.response_reason}); clip radius {merged.clip_radius} px "
            f"({merged.clip_reason}); colour space {merged.colour_space}")


def run(args) -> int:
    import sys
    import warnings

    from brdfrig.hdr.bracket import MergePolicy, check_distinct, merge_files
    from brdfrig.hdr.exr import write_exr

    files = list(args.files)
    check_output(args.output, files, suffixes=(".exr",), writes="an OpenEXR image", no_clobber=args.no_clobber)
    check_distinct(files)
    policy = MergePolicy(
        weighting=args.weighting, response=args.response, clip_radius=args.clip_radius, align=args.align,
        reestimate_times=not args.no_reestimate, colour_space=args.colour_space,
        **({} if args.full_well is None else {"full_well": args.full_well}),
        **({} if args.read_noise is None else {"read_noise": args.read_noise}),
    )
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        merged = merge_files(files, policy, times=args.times)
    for w in caught:
        print(f"brdfrig merge: warning: {w.message}", file=sys.stderr)
    if merged.no_data:
        print(f"brdfrig merge: note: {merged.no_data} pixel-channel(s) at the frame borders have no data after "
              "alignment: written as 0 with flags = 2", file=sys.stderr)
    res = merged.merge
    write_exr(args.output, res.radiance, {"variance": res.variance, "flags": res.flags.max(axis=2)},
              _attributes(merged), standard=_standard_attributes(merged), overwrite=not args.no_clobber)
    if args.json:
        print_json(_numbers(merged, args.output))
    else:
        print(_summary(merged, args.output))
    return 0
