"""`brdfrig probe`: chrome-ball probe image(s) to a calibrated lat-long environment EXR.

Each image is a linear HDR (EXR or Radiance .hdr) of the chrome ball seen
(nearly) orthographically.  The ball's circle is detected in every image
unless `--circle` gives it (then used for all).  Several images taken at
different turntable rotations of the ball are registered on their circles
and combined by a robust per-pixel statistic, which removes the ball's
blemishes.  The ball's albedo is given (`--albedo`) or measured by the
ratio method (`--albedo-patches`: a diffuse patch seen directly and in the
ball, as pixel boxes of the first image), optionally with a Fresnel model for
chrome (`--fresnel`).

The output is a lat-long map in OpenEXR's LatLongMap convention (MATH.md);
directions the ball does not show (the cone behind the ball, the camera's
reflection if masked) have zero radiance and `mask = 0`.  The colour space the
input EXRs declare (`brdfrig merge --colour-space`) is kept: `brdfrig:colour_space`
and the standard `chromaticities` (inputs in different spaces are refused).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from brdfrig.cli._command import add_command
from brdfrig.cli._output import add_json_argument, add_output_arguments, check_output, print_json
from brdfrig.ranges import ALBEDO, PIXELS, Range

RIM = Range(0, 1, open_lo=True)
CAMERA_MASK = Range(0, 90)  # degrees
WIDTH = Range(8, 16384, integer=True)  # lat-long pixels


def _patches(text: str) -> tuple[list[float], list[float]]:
    parts = text.split(":")
    if len(parts) != 2:
        raise argparse.ArgumentTypeError(f"--albedo-patches must be DIRECT:REFLECTED pixel boxes "
                                         f"x0,y0,x1,y1:x0,y0,x1,y1, got {text!r}")
    box = PIXELS.args("each box coordinate", (4,))
    return box(parts[0]), box(parts[1])


def register(subparsers) -> None:
    p = add_command(subparsers, "probe",
                    "chrome-ball image(s) to a calibrated lat-long environment EXR (unseen directions masked)",
                    __doc__)
    p.add_argument("images", nargs="+", type=Path, metavar="PROBE",
                   help="probe image(s) (.exr/.hdr); several = captures at different ball rotations")
    add_output_arguments(p, "ENV.exr", "output lat-long EXR")
    p.add_argument("--circle", type=PIXELS.args("each of cx, cy, r", (3,)), metavar="CX,CY,R",
                   help="ball circle in pixels (MATH.md image coordinates); default: detected per image")
    group = p.add_mutually_exclusive_group()
    group.add_argument("--albedo", type=ALBEDO.args("each albedo", (1, 3)), metavar="A[,G,B]",
                       help="ball reflectance, one value or one per channel (default: 1, uncalibrated)")
    group.add_argument("--albedo-patches", type=_patches, metavar="X0,Y0,X1,Y1:X0,Y0,X1,Y1",
                       help="pixel boxes of a diffuse patch seen directly and reflected in the ball (ratio method)")
    p.add_argument("--fresnel", action="store_true", help="angle-dependent chrome reflectance (conductor Fresnel)")
    p.add_argument("--rim", type=RIM.arg(), default=None, metavar="F", help="drop ball pixels beyond F of the radius, "
                   f"F{RIM.text()} (default 0.97)")
    p.add_argument("--camera-mask", type=CAMERA_MASK.arg(), default=0.0, metavar="DEG",
                   help=f"drop the cone of DEG degrees around the view direction (camera reflection), "
                        f"DEG{CAMERA_MASK.text()} (default 0)")
    p.add_argument("--width", type=WIDTH.arg(), default=512, metavar="W",
                   help=f"lat-long width, even, W{WIDTH.text()} (height W/2; default 512)")
    p.add_argument("--statistic", choices=("median", "trimmed"), default="median",
                   help="per-pixel statistic over rotations (default: %(default)s)")
    add_json_argument(p)
    p.set_defaults(func=run)


def run(args) -> int:
    import numpy as np

    from brdfrig.errors import InputError
    from brdfrig.hdr.colour import chromaticities, declared_colour_space
    from brdfrig.hdr.exr import read_image, write_exr
    from brdfrig.hdr.probe import CHROME_IOR, DEFAULT_RIM, combine_probe, probe_to_latlong, unseen_cone_deg

    check_output(args.output, args.images, suffixes=(".exr",), writes="an OpenEXR lat-long map",
                 no_clobber=args.no_clobber)
    rim = DEFAULT_RIM if args.rim is None else args.rim
    if args.width % 2:
        raise InputError(f"--width must be an even integer{WIDTH.text()}, got {args.width}")
    if args.circle is not None and not args.circle[2] > 0:
        raise InputError(f"--circle radius must be > 0, got {args.circle[2]:g}")
    colour_space = declared_colour_space(args.images)  # the merged captures' space, kept by the lat-long map
    probe = combine_probe([read_image(path) for path in args.images],
                          None if args.circle is None else [tuple(args.circle)], names=[str(p) for p in args.images],
                          statistic=args.statistic, albedo=args.albedo, albedo_patches=args.albedo_patches)
    fresnel = CHROME_IOR if args.fresnel else None
    latlong, seen = probe_to_latlong(probe.image, probe.circle, args.width, rim=rim, camera_mask_deg=args.camera_mask,
                                     fresnel=fresnel, **probe.calibration())
    cone = unseen_cone_deg(rim)
    several = len(args.images) > 1
    attributes = {
        "kind": "latlong_environment",
        "source_files": [str(Path(p).resolve()) for p in args.images],
        "circles_px": [list(c) for c in probe.circles],
        "circle_px": list(probe.circle),
        "rim": rim,
        "unseen_cone_deg": cone,
        "camera_mask_deg": args.camera_mask,
        "albedo": None if probe.albedo is None else [float(a) for a in probe.albedo],
        "albedo_angle_deg": probe.albedo_angle_deg,
        "fresnel_ior": None if fresnel is None else list(fresnel),
        "rotation_statistic": args.statistic if several else None,
        "colour_space": colour_space,
    }
    space_xy = chromaticities(colour_space)
    write_exr(args.output, latlong, {"mask": seen.astype(np.float32)}, attributes, latlong=True,
              standard={} if space_xy is None else {"chromaticities": space_xy}, overwrite=not args.no_clobber)
    unseen = 1 - float(np.mean(seen))
    albedo_text = "1 (uncalibrated)" if probe.albedo is None else ", ".join(f"{a:.4g}" for a in probe.albedo)
    c = probe.circle
    if args.json:
        print_json({"output": str(Path(args.output).resolve()), "circle_px": list(c), "rotations": len(args.images),
                    "rotation_statistic": attributes["rotation_statistic"], "albedo": attributes["albedo"],
                    "width": args.width, "height": args.width // 2, "unseen_cone_deg": cone,
                    "camera_mask_deg": args.camera_mask, "unseen_fraction": unseen})
        return 0
    print(f"probe: circle ({c[0]:.2f}, {c[1]:.2f}, {c[2]:.2f}) px"
          + (f", {len(args.images)} rotations combined ({args.statistic})" if several else "") + f", albedo {albedo_text}")
    print(f"wrote {args.output} ({args.width}x{args.width // 2} lat-long); unseen: cone of {cone:.1f} deg around "
          f"-z (behind the ball)" + (f" and {args.camera_mask:g} deg around +z (camera)" if args.camera_mask else "")
          + f", {100 * unseen:.1f}% of the map's pixels, zero radiance and mask = 0")
    return 0
