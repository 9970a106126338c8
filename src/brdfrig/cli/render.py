"""`brdfrig render`: render a sphere with a fitted or measured BRDF under a lat-long lighting map (relighting).

The BRDF is a file written by `brdfrig fit`, or a measured material: a neural
fit (`NAME.h5` with `NAME.json` beside it) or a MERL table (`.binary`).
Measured materials are rendered by brute-force quadrature of their MERL-grid table,
with the map's cells near each pixel's mirror direction subdivided (sharp lobes).
The sphere is centred in an N x N image with radius N/2 pixels, seen
orthographically from `v = (0, 0, 1)` (MATH.md); pixels outside it are 0.
Written as a linear float32 EXR, atomically.

For a fitted BRDF file the fit's relighting error is estimated for this lighting
(one-image fits: from how much the fit's tables, re-solved on resampled reference
materials, disagree under it; fits of several scenes: from how much its refits on
the leave-one-scene-out folds disagree under it) and printed with how it was obtained.
"""

from __future__ import annotations


from brdfrig.cli._command import add_command
from brdfrig.cli._output import add_json_argument, add_output_arguments, check_output, print_json
from brdfrig.ranges import Range

SIZE = Range(1, 4096, integer=True)  # image side, pixels


def register(subparsers) -> None:
    p = add_command(subparsers, "render", "render a sphere with a BRDF file under a lat-long lighting map", __doc__)
    p.add_argument("brdf", help="BRDF file written by 'brdfrig fit', or a measured material (.h5 neural fit, MERL .binary)")
    p.add_argument("--lighting", required=True, help="lat-long environment map (EXR or .hdr)")
    p.add_argument("--size", type=SIZE.arg(), required=True,
                   help=f"image size N in pixels, N{SIZE.text()} (sphere radius N/2)")
    add_output_arguments(p, "OUT.exr", "output EXR (linear float32)")
    add_json_argument(p)
    p.set_defaults(func=run)


def _radiance(pred, brdf_path):
    """Predicted radiance as float32, negatives (SH ringing) clamped to 0 with a warning; InputError if not finite."""
    import sys

    import numpy as np

    from brdfrig.errors import InputError

    pred = np.asarray(pred, np.float64)
    bad = ~np.isfinite(pred) | (np.abs(pred) > np.finfo(np.float32).max)
    if bad.any():
        raise InputError(f"{brdf_path}: rendering gives {int(bad.sum())} non-finite value(s): the BRDF's "
                         "coefficients are out of range (a damaged file?); nothing written")
    neg = pred < 0
    if neg.any():
        peak = float(np.abs(pred).max())
        print(f"brdfrig render: warning: {int(neg.sum())} pixel-channel(s) ({100 * neg.mean():.2g}%) rendered "
              f"negative (down to {100 * float(pred.min()) / peak:.2g}% of the peak): clamped to 0", file=sys.stderr)
    return np.maximum(pred, 0.0).astype(np.float32)


def run(args) -> int:
    from dataclasses import asdict
    from pathlib import Path

    import numpy as np

    from brdfrig.errors import InputError
    from brdfrig.fit.brdffile import load_brdf
    from brdfrig.fit.measured import load_measured
    from brdfrig.fit.relight import lighting_estimate
    from brdfrig.hdr.exr import write_exr
    from brdfrig.hdr.sphere import sphere_pixels
    from brdfrig.lighting import read_latlong

    out = check_output(args.output, [args.brdf, args.lighting], suffixes=(".exr",), writes="a linear OpenEXR image",
                       no_clobber=args.no_clobber)
    report = None
    if Path(args.brdf).suffix in (".h5", ".binary"):
        brdf = load_measured(args.brdf)
    else:
        brdf, report = load_brdf(args.brdf)
    env = read_latlong(args.lighting, getattr(brdf, "lmax", 0))
    if env.channels != brdf.channels and brdf.channels != 1:
        raise InputError(f"{args.lighting}: lighting has {env.channels} channel(s), the BRDF {brdf.channels}")
    n = args.size
    px = sphere_pixels((n, n), (n / 2, n / 2, n / 2), margin_px=0.0)
    image = np.zeros((n, n, env.channels), dtype=np.float32)
    image[px.rows, px.cols] = _radiance(brdf.predict(env, px.normals), args.brdf)
    provenance = {"brdf": str(Path(args.brdf).resolve()), "lighting": str(Path(args.lighting).resolve())}
    try:
        estimate = None if report is None else lighting_estimate(report, env, px.normals, px.weights)
    except (ValueError, TypeError, KeyError) as exc:
        raise InputError(f"{args.brdf}: damaged fit report, no relighting estimate: {exc}; nothing written") from exc
    write_exr(out, image, attributes=provenance, overwrite=not args.no_clobber)
    if args.json:
        print_json({"output": str(Path(out).resolve()), **provenance, "size": n, "channels": env.channels,
                    "relight_estimate": None if estimate is None else asdict(estimate)})
    else:
        print(f"wrote {out}")
        if estimate is not None and estimate.value is not None:
            print(f"estimated relighting error under this lighting: {100 * estimate.value:.2g}% ({estimate.how})")
    return 0
