"""The ``brdfrig`` command line.

Each sub-command lives in its own module ``brdfrig/cli/<name>.py`` exposing
``register(subparsers)``, which adds its parser and sets ``func`` to a callable
``run(args) -> int``.  Heavy imports (OpenCV, numba, OpenImageIO) belong inside
``run`` so that ``brdfrig --help`` stays instant.

What the user can fix is a :class:`brdfrig.errors.BrdfrigError` (bad input,
config, session store, device) or an ``OSError`` about a file (missing,
unwritable, disk full): one line ``brdfrig CMD: error: ...`` on stderr, exit 2.
Any other exception is a bug in brdfrig: its traceback, then a line asking for
a report with the version, exit 1.  ``BRDFRIG_DEBUG=1`` shows the traceback of
user errors too.
"""

from __future__ import annotations

import argparse
import errno
import importlib
import os
import sys
import traceback

from brdfrig.errors import BrdfrigError

COMMAND_MODULES: tuple[str, ...] = (
    # at the bench
    "brdfrig.cli.demo",
    "brdfrig.cli.rig",
    "brdfrig.cli.locate",
    "brdfrig.cli.template",
    "brdfrig.cli.capture",
    "brdfrig.cli.refit",
    "brdfrig.cli.library",
    # offline, one step at a time
    "brdfrig.cli.merge",
    "brdfrig.cli.probe",
    "brdfrig.cli.envsh",
    "brdfrig.cli.fit",
    "brdfrig.cli.render",
    "brdfrig.cli.plot",
    "brdfrig.cli.export",
    "brdfrig.cli.bench",
)

EXIT_BUG = 1
EXIT_USER_ERROR = 2
EXIT_INTERRUPTED = 130


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="brdfrig",
        description="Measure isotropic BRDFs under natural light with a chrome probe and sample spheres.",
    )
    from brdfrig import __version__

    parser.add_argument("--version", action="version", version=f"brdfrig {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exc:  # bad arguments (argparse printed its one line: exit 2), --help, --version
        return int(exc.code or 0) if not isinstance(exc.code, str) else EXIT_USER_ERROR
    _announce_compilation(args.command)
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("brdfrig: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except (BrdfrigError, OSError, MemoryError) as exc:
        if os.environ.get("BRDFRIG_DEBUG"):
            raise
        print(f"brdfrig {args.command}: error: {user_message(exc)}", file=sys.stderr)
        return EXIT_USER_ERROR
    except Exception:
        from brdfrig import __version__

        traceback.print_exc()
        print(f"brdfrig {args.command}: internal error: this is a bug in brdfrig {__version__}, not in your input; "
              "please report it to the brdfrig issue tracker with the command line and the traceback above",
              file=sys.stderr)
        return EXIT_BUG


#: Commands that run numba kernels (the others only read files or print).
COMPUTING = frozenset({"demo", "capture", "refit", "merge", "probe", "envsh", "fit", "render", "bench", "export", "plot"})


def _announce_compilation(command: str) -> None:
    """Say so on stderr when numba has no compiled kernels cached for brdfrig yet (the first run after install)."""
    if command not in COMPUTING:
        return
    from pathlib import Path

    package = Path(__file__).resolve().parents[1]
    cache = Path(os.environ["NUMBA_CACHE_DIR"]) if os.environ.get("NUMBA_CACHE_DIR") else package
    if not any(cache.rglob("*.nbi")):
        print("brdfrig: first run after installation: compiling numerical kernels (numba) once; "
              "later runs start faster", file=sys.stderr, flush=True)


def user_message(exc: BaseException) -> str:
    """The one line shown for a user error: the message, with the file name and a hint for OS errors."""
    if isinstance(exc, MemoryError):
        return "out of memory: the images or sizes asked for are too large for this machine"
    if isinstance(exc, OSError) and not isinstance(exc, BrdfrigError):
        if exc.errno == errno.ENOSPC:
            where = f" while writing {exc.filename}" if exc.filename else ""
            return f"disk full{where}: free some space and run the command again"
        if exc.strerror:
            return f"{exc.filename}: {exc.strerror}" if exc.filename else exc.strerror
    return str(exc)


if __name__ == "__main__":
    sys.exit(main())
