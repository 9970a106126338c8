"""brdfrig export: write a BRDF in a format other tools read, with the error the conversion introduces.

Formats: merl (MERL .binary table, read by BRDF Explorer, pbrt and every MERL reader),
table (rho on a theta_i, theta_o, delta_phi grid as .csv or .npz), mitsuba (a Mitsuba 3
XML <bsdf>, or with --scene ENV a whole scene: the sphere under that lighting), openpbr
(an OpenPBR Surface material in a MaterialX .mtlx document), gltf (a glTF 2.0 material
with the KHR extensions that apply).

The renderer formats hold the closest physically based material (dielectric, conductor
or sheen, with OpenPBR's parameter names); mitsuba holds the Mitsuba BSDF (diffuse,
roughplastic or principled) fitted as Mitsuba evaluates it. Every export is rendered back under brdfrig's
three standard lightings against the BRDF it came from; that error is printed and written
beside the export as OUT.error.json.
"""

from __future__ import annotations

from pathlib import Path

from brdfrig.cli._command import add_command, add_progress_argument
from brdfrig.cli._output import add_output_arguments, check_output
from brdfrig.cli.library import add_library_argument
from brdfrig.ranges import Range

STEP = Range(0.25, 15.0)  # degrees


def register(subparsers) -> None:
    from brdfrig.export.formats import FORMATS

    p = add_command(subparsers, "export", "write a BRDF as MERL, a grid table, Mitsuba, OpenPBR or glTF", __doc__)
    p.add_argument("brdf", type=Path, help="BRDF file from 'brdfrig fit', or a measured material (.h5, .binary)")
    p.add_argument("--format", required=True, choices=FORMATS, help="what to write")
    add_output_arguments(p, "OUT", "output file (.binary, .csv/.npz, .xml, .mtlx or .gltf by format)")
    p.add_argument("--scene", metavar="ENV", help="mitsuba: write a whole scene lit by this lat-long map")
    p.add_argument("--step", type=STEP.arg(), default=2.0, metavar="DEG",
                   help=f"table: grid step in degrees{STEP.text()} (default: %(default)s)")
    p.add_argument("--json", action="store_true", help="print the error record as JSON")
    add_progress_argument(p)
    add_library_argument(p)
    p.set_defaults(func=run)


def run(args) -> int:
    import json

    from brdfrig import __version__
    from brdfrig.cli.library import open_library
    from brdfrig.errors import InputError
    from brdfrig.export.formats import SUFFIXES
    from brdfrig.export.run import export_brdf
    from brdfrig.fit.brdffile import brdf_colour_space, jsonable, open_brdf

    if args.scene is not None and args.format != "mitsuba":
        raise InputError("--scene applies to --format mitsuba only")
    inputs = [args.brdf] + ([Path(args.scene)] if args.scene else [])
    out = check_output(args.output, inputs, suffixes=SUFFIXES[args.format], writes=f"a {args.format} export",
                       no_clobber=args.no_clobber)
    options = {"step_deg": args.step} if args.format == "table" else {}
    if args.scene:
        options["scene_env"] = str(Path(args.scene).resolve())
    result = export_brdf(open_brdf(args.brdf), args.format, out, source=str(Path(args.brdf).resolve()),
                         colour_space=brdf_colour_space(args.brdf), progress=not args.no_progress, **options)
    with open_library(args) as library:
        library.record_export(args.brdf, args.format, out, result.relative_rms, __version__)
    if args.json:
        print(json.dumps(jsonable(result.to_dict()), indent=1))
        return 0
    per = ", ".join(f"{k} {100 * v:.2f}%" for k, v in result.per_lighting.items())
    print(f"wrote {out} ({args.format}); error against the BRDF in rendered radiance: "
          f"{100 * result.relative_rms:.2f}% ({per}); record {result.record_path}")
    return 0
