"""``brdfrig render``: render a sphere with a fitted BRDF under a lat-long lighting map (relighting).

The sphere is centred in an N x N image with radius N/2 pixels, seen
orthographically from ``v = (0, 0, 1)`` (MATH.md); pixels outside it are 0.
Written as a linear float32 EXR (``brdfrig.hdr.exr.write_exr``, atomic).
"""

from __future__ import annotations

import argparse


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "render",
        help="render a sphere with a BRDF file under a lat-long lighting map",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("brdf", help="BRDF file written by 'brdfrig fit'")
    p.add_argument("--lighting", required=True, help="lat-long environment map (EXR or .hdr)")
    p.add_argument("--size", type=int, required=True, help="image size N in pixels (sphere radius N/2)")
    p.add_argument("-o", "--output", required=True, help="output EXR")
    p.set_defaults(func=run)


def run(args) -> int:
    from pathlib import Path

    import numpy as np

    from brdfrig.fit.brdffile import load_brdf
    from brdfrig.hdr.exr import write_exr
    from brdfrig.hdr.sphere import sphere_pixels
    from brdfrig.lighting import read_latlong

    if args.size < 1:
        raise ValueError(f"--size must be >= 1, got {args.size}")
    out = Path(args.output)
    if not out.parent.is_dir():
        raise OSError(f"-o {out}: directory {out.parent} does not exist")
    brdf, _ = load_brdf(args.brdf)
    env = read_latlong(args.lighting, getattr(brdf, "lmax", 0))
    if env.channels != brdf.channels and brdf.channels != 1:
        raise ValueError(f"{args.lighting}: lighting has {env.channels} channel(s), the BRDF {brdf.channels}")
    n = args.size
    px = sphere_pixels((n, n), (n / 2, n / 2, n / 2), margin_px=0.0)
    image = np.zeros((n, n, env.channels), dtype=np.float32)
    image[px.rows, px.cols] = brdf.predict(env, px.normals)
    write_exr(out, image, attributes={"brdfrig_brdf": str(args.brdf), "brdfrig_lighting": str(args.lighting)})
    print(f"wrote {out}")
    return 0
