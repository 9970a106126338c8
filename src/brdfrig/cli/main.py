"""The ``brdfrig`` command line.

Each sub-command lives in its own module ``capture/cmd_<name>.py`` exposing
``register(subparsers)``, which adds its parser and sets ``func`` to a callable
``run(args) -> int``.  Heavy imports (OpenCV, numba, OpenImageIO) belong inside
``run`` so that ``brdfrig --help`` stays instant.

User errors (bad files, bad arguments, device failures) are raised as
``ValueError``/``OSError``/``rig.errors.RigError`` subclasses anywhere below
and turned here into one clear line on stderr and a non-zero exit.  Set
``BRDFRIG_DEBUG=1`` to see the traceback instead.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

COMMAND_MODULES: tuple[str, ...] = (
    # at the bench
    "capture.cmd_demo",
    "capture.cmd_rig",
    "capture.cmd_capture",
    "capture.cmd_refit",
    # offline, one step at a time
    "capture.cmd_merge",
    "capture.cmd_probe",
    "capture.cmd_envsh",
    "capture.cmd_fit",
    "capture.cmd_render",
    "capture.cmd_bench",
)

EXIT_USER_ERROR = 2
EXIT_INTERRUPTED = 130


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="brdfrig",
        description="Measure isotropic BRDFs under natural light with a chrome probe and sample spheres.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from rig.errors import RigError

    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("brdfrig: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except (ValueError, OSError, RigError) as exc:
        if os.environ.get("BRDFRIG_DEBUG"):
            raise
        print(f"brdfrig {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_USER_ERROR


if __name__ == "__main__":
    sys.exit(main())
