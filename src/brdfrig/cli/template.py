"""brdfrig template: write a copy of a shipped configuration file to edit.

Templates: sim-bench (the simulated bench session the demo runs), rig-bench (a real
bench: GRBL turntable and a gphoto2 camera), plan-bench (a session plan for a real
bench), fit-full and fit-quick (fit presets for `brdfrig refit --preset`).
"""

from __future__ import annotations

from pathlib import Path

from brdfrig.cli._command import add_command
from brdfrig.cli._output import check_output

CONFIG_DIR = Path(__file__).resolve().parents[1] / "config"


def names() -> list[str]:
    return sorted(p.stem for p in CONFIG_DIR.glob("*.toml"))


def register(subparsers) -> None:
    p = add_command(subparsers, "template", "write a copy of a shipped configuration file to edit", __doc__)
    p.add_argument("name", choices=names(), help="which template")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="FILE.toml", help="where to write it")
    p.set_defaults(func=run)


def run(args) -> int:
    from brdfrig._atomic import write_bytes

    out = check_output(args.output, [], suffixes=(".toml",), writes="a TOML configuration", no_clobber=True)
    write_bytes(out, (CONFIG_DIR / f"{args.name}.toml").read_bytes(), overwrite=False)
    print(f"wrote {out}")
    return 0
