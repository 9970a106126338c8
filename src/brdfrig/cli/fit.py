"""`brdfrig fit`: fit a BRDF to HDR images of a sample sphere under measured lighting.

Each `--scene ENV IMAGE` pairs a lat-long environment map (MATH.md
convention, EXR or Radiance .hdr, any resolution) with an HDR image of the
sample sphere taken under it; `--probe-scene PROBE IMAGE` takes the lighting
from a mirror-ball image instead (circle auto-detected, `--probe-circle`
overrides detection).  The sample sphere's circle is auto-detected in every IMAGE
unless `--circle cx,cy,r` is given.  Pixels within 2 px of the
limb get weight 0, and the fitter ignores normals beyond 80 degrees from
the view.  Prints the identifiability report and the fit
statistics; writes the versioned BRDF file atomically,
with the colour space the input EXRs declare (`brdfrig merge --colour-space`;
`camera` when none does; inputs declaring different spaces are refused).
"""

from __future__ import annotations

import sys

from brdfrig.cli._command import add_command, add_progress_argument
from brdfrig.cli._output import Printer, add_json_argument, add_output_arguments, check_output, print_json
from brdfrig.fit.registry import MODELS, SOLVERS
from brdfrig.ranges import BANDS


def register(subparsers) -> None:
    p = add_command(subparsers, "fit", "fit a BRDF to sphere images under lat-long or mirror-ball lighting", __doc__)
    p.add_argument("--scene", nargs=2, action="append", default=[], metavar=("ENV", "IMAGE"),
                   help="lat-long lighting map and the sphere image taken under it (repeatable)")
    p.add_argument("--probe-scene", nargs=2, action="append", default=[], metavar=("PROBE", "IMAGE"),
                   help="mirror-ball image of the lighting and the sphere image taken under it (repeatable)")
    p.add_argument("--model", choices=MODELS, default="auto", help="BRDF model (default: %(default)s)")
    p.add_argument("--lmax", type=BANDS.arg(), default=8, help=f"lighting band limit{BANDS.text()} (default: %(default)s)")
    p.add_argument("--pmax", type=BANDS.arg(), default=8,
                   help=f"outgoing band limit of the full model{BANDS.text()} (default: %(default)s)")
    p.add_argument("--solver", choices=SOLVERS, default="joint", help="least-squares solver (default: %(default)s)")
    p.add_argument("--circle", default=None, help="sample sphere circle 'cx,cy,r' in pixels (default: detect in each image)")
    p.add_argument("--probe-circle", default=None, help="mirror-ball circle 'cx,cy,r' in every PROBE (default: detect)")
    p.add_argument("--references", default=None, metavar="TABLES.npz",
                   help="measured materials the bivariate+measured model combines (default: the 51 RGL-EPFL materials "
                        "shipped with brdfrig; the README says how to build your own from MERL or neural files)")
    p.add_argument("--no-estimate", action="store_true",
                   help="skip the relighting estimate of the requested --model and the reference fits it takes "
                        "(faster; 'auto' always estimates, it chooses by it)")
    add_progress_argument(p)
    p.add_argument("--figure", default=None, help="also write a PNG: each scene's image, the fit's rendering and the residual")
    p.add_argument("--report", default=None, metavar="REPORT.html",
                   help="also write a self-contained HTML report: spheres, relighting, BRDF plots, statistics")
    add_output_arguments(p, "BRDF.json", "output BRDF file (JSON)")
    add_json_argument(p)
    p.set_defaults(func=run)


def parse_circle(text: str, option: str = "--circle") -> tuple[float, float, float]:
    """``'cx,cy,r'`` -> floats; InputError naming ``option`` otherwise."""
    from brdfrig.errors import InputError
    from brdfrig.ranges import PIXELS

    parts = text.split(",")
    if len(parts) != 3:
        raise InputError(f"{option} must be 'cx,cy,r' (three numbers), got {text!r}")
    cx, cy, r = (PIXELS.parse(v, f"each of {option} cx,cy,r") for v in parts)
    if not r > 0:
        raise InputError(f"{option} radius must be > 0, got {r}")
    return cx, cy, r


def _probe_environment(path, lmax: int, circle=None):
    from brdfrig.hdr.exr import read_image
    from brdfrig.hdr.probe import combine_probe
    from brdfrig.lighting import environment_from_probe

    probe = combine_probe([read_image(path)], None if circle is None else [circle], names=[str(path)])
    # The ball spans 360 degrees over its diameter 2r: r/2 pixels per band-limit half-period budget.
    if lmax > probe.circle[2] / 4:
        raise ValueError(f"{path}: a mirror ball of radius {probe.circle[2]:.0f} px supports bands up to "
                         f"{int(probe.circle[2] / 4)}, --lmax is {lmax}")
    return environment_from_probe(probe, name=str(path))


def _sample_scene(env, image_path, circle):
    """(Scene, circle used, image shape, (rows, cols) of the sphere pixels)."""
    import numpy as np

    from brdfrig.errors import InputError
    from brdfrig.fit.scene import Scene
    from brdfrig.hdr.detect import detect_sphere
    from brdfrig.hdr.exr import read_image
    from brdfrig.hdr.probe import check_circle_in_frame
    from brdfrig.hdr.sphere import sphere_pixels

    img = read_image(image_path)
    if img.shape[2] != env.channels:
        raise InputError(f"{image_path}: image has {img.shape[2]} channel(s) but its lighting has {env.channels}")
    circle = detect_sphere(img, name=str(image_path)) if circle is None else circle
    circle = check_circle_in_frame(img.shape, circle, what=f"{image_path}: sphere circle")
    px = sphere_pixels(img.shape, circle)
    radiance = np.asarray(img, np.float64)[px.rows, px.cols]
    return Scene(env, px.normals, radiance, px.weights), circle, img.shape, (px.rows, px.cols)


def run(args) -> int:
    from pathlib import Path

    from brdfrig.errors import InputError
    from brdfrig.fit.brdffile import jsonable, save_brdf
    from brdfrig.fit.fitter import fit_brdf
    from brdfrig.fit.references import ReferenceTables
    from brdfrig.hdr.colour import declared_colour_space
    from brdfrig.fit.report import format_report
    from brdfrig.lighting import read_latlong
    from brdfrig.orientation import check_orientation
    from brdfrig.report.html import SampleReport, write_report
    from brdfrig.report.figures import fit_figure, fit_figure_of, png_bytes

    if not args.scene and not args.probe_scene:
        raise InputError("give at least one --scene ENV IMAGE or --probe-scene PROBE IMAGE")
    sources = [p for pair in args.scene + args.probe_scene for p in pair]
    out = check_output(args.output, sources, suffixes=(".json",), writes="a BRDF file (JSON)",
                       no_clobber=args.no_clobber)
    if args.figure:
        check_output(args.figure, sources + [out], suffixes=(".png",), writes="a PNG figure",
                     no_clobber=args.no_clobber, option="--figure")
    if args.report:
        report_path = check_output(args.report, sources + [out], suffixes=(".html",), writes="an HTML report",
                                   no_clobber=args.no_clobber, option="--report")
    colour_space = declared_colour_space(sources)  # before any fitting: mixed spaces are refused
    references = None if args.references is None else ReferenceTables.load(args.references)
    circle = None if args.circle is None else parse_circle(args.circle)
    probe_circle = None if args.probe_circle is None else parse_circle(args.probe_circle, "--probe-circle")
    scenes, inputs, shapes, pixels = [], [], [], []
    for kind, pairs in (("latlong", args.scene), ("probe", args.probe_scene)):
        for env_path, image_path in pairs:
            if kind == "latlong":
                env = read_latlong(env_path, args.lmax)
            else:
                env = _probe_environment(env_path, args.lmax, probe_circle)
            scene, used, shape, px = _sample_scene(env, image_path, circle)
            check = check_orientation(scene)  # a mirrored or turned map fits, silently worse: say so
            if check is not None and check.warning(env_path):
                print(f"brdfrig fit: warning: {check.warning(env_path)}", file=sys.stderr)
            scenes.append(scene)
            shapes.append(shape)
            pixels.append(px)
            inputs.append({"lighting": str(env_path), "lighting_kind": kind, "image": str(image_path), "circle": list(used)})

    result = fit_brdf(scenes, model=args.model, lmax=args.lmax, pmax=args.pmax, solver=args.solver, progress=not args.no_progress,
                      estimate=not args.no_estimate, reference_tables=references)
    rep = result.report
    say = Printer(args.json)
    say(rep.identifiability_summary)
    say("\n".join(format_report(rep)))
    for w in rep.warnings:
        print(f"warning: {w}", file=sys.stderr)
    save_brdf(out, result.brdf, rep, provenance={"command": "brdfrig fit", "inputs": inputs, "argv": sys.argv[1:]},
              colour_space=colour_space, overwrite=not args.no_clobber)
    say(f"wrote {out}")
    title = f"{Path(inputs[0]['image']).stem}: {result.brdf.model} fit, lmax {args.lmax}, {len(scenes)} scene(s)"
    if args.figure:
        fit_figure(args.figure, scenes, pixels, result.brdf, title=title)
        say(f"wrote {args.figure}")
    if args.report:
        fig = png_bytes(fit_figure_of(scenes, pixels, result.brdf, title=title), dpi=90)
        sample = SampleReport(Path(inputs[0]["image"]).stem, result.brdf, jsonable(rep.to_dict()), fit_png=fig)
        write_report(report_path, f"brdfrig fit: {out.name}", [sample], notes=" ".join(sys.argv[1:]))
        say(f"wrote {report_path}")
    if args.json:
        print_json({"brdf": str(out.resolve()), "model": result.brdf.model, "colour_space": colour_space,
                    "inputs": inputs, "report": rep.to_dict(),
                    "figure": str(Path(args.figure).resolve()) if args.figure else None,
                    "html_report": str(report_path.resolve()) if args.report else None})
    return 0
