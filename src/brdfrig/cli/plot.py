"""brdfrig plot: BRDF plots as a PNG, several BRDFs overlaid for comparison.

Each BRDF is a file written by `brdfrig fit` or a measured material (a neural fit .h5
with its .json, or a MERL .binary table). The figure shows rho in the incidence plane
for several incidence angles, rho against the half-vector angle at fixed difference
angles, and the directional albedo against the incidence angle; colour channels in
their colours, BRDFs by line style (e.g. a fit against a measured reference).
"""

from __future__ import annotations

from pathlib import Path

from brdfrig.cli._command import add_command
from brdfrig.cli._output import add_output_arguments, check_output


def register(subparsers) -> None:
    p = add_command(subparsers, "plot", "plot one or more BRDFs (slices and albedo) into a PNG", __doc__)
    p.add_argument("brdfs", nargs="+", type=Path, metavar="BRDF", help="BRDF file or measured material")
    add_output_arguments(p, "FIG.png", "output PNG")
    p.add_argument("--title", default="", help="figure title")
    p.set_defaults(func=run)


def run(args) -> int:
    from brdfrig.fit.brdffile import open_brdf
    from brdfrig.report.plots import plot_brdfs

    out = check_output(args.output, args.brdfs, suffixes=(".png",), writes="a PNG figure", no_clobber=args.no_clobber)
    names = [p.stem.removesuffix(".brdf") for p in args.brdfs]
    names = [n if names.count(n) == 1 else str(p) for n, p in zip(names, args.brdfs)]
    plot_brdfs({n: open_brdf(p) for n, p in zip(names, args.brdfs)}, out, title=args.title)
    print(f"wrote {out}")
    return 0
