"""Checks every command makes on the file it writes, before doing any work.

An output must not be one of the command's inputs (the same file, however
named: hard links, symlinks, ``./a`` vs ``a``), must have a suffix the command
really writes, must live in an existing directory and, with ``--no-clobber``,
must not exist yet (the atomic writer then also refuses to replace a file that
appears meanwhile).

``--json`` (:func:`add_json_argument`, :func:`print_json`): a command prints one
JSON document holding every number of its text output, and nothing else on
stdout (warnings and progress stay on stderr).
"""

from __future__ import annotations

import os
from pathlib import Path

from brdfrig.errors import InputError

__all__ = ["add_output_arguments", "check_output", "add_json_argument", "print_json", "Printer"]


def add_output_arguments(parser, metavar: str, help: str) -> None:
    """Add ``-o/--output`` (required) and ``--no-clobber`` to a command's parser."""
    parser.add_argument("-o", "--output", type=Path, required=True, metavar=metavar, help=help)
    parser.add_argument("--no-clobber", action="store_true",
                        help="refuse to replace an existing output file (default: replace it atomically)")


def add_json_argument(parser) -> None:
    """Add ``--json`` to a command's parser."""
    parser.add_argument("--json", action="store_true",
                        help="print one JSON document of every number the command prints, nothing else on stdout")


def print_json(doc) -> None:
    """Print ``doc`` as one JSON document (numpy values, paths and fit reports converted; non-finite as text)."""
    import json

    from brdfrig.fit.brdffile import jsonable

    print(json.dumps(jsonable(doc), indent=1, allow_nan=False))


class Printer:
    """``print`` for a command's text output, silent under ``--json`` (the JSON document replaces it)."""

    def __init__(self, json_mode: bool):
        self.json_mode = bool(json_mode)

    def __call__(self, *text) -> None:
        if not self.json_mode:
            print(*text)


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:  # one of them does not exist (yet): compare where they would be
        return a.resolve() == b.resolve()


def check_output(output, inputs, *, suffixes: tuple[str, ...], writes: str, no_clobber: bool = False,
                 option: str = "-o") -> Path:
    """Validate the output path of a command; returns it as a ``Path``.

    Parameters
    ----------
    output : path-like
        The file the command will write.
    inputs : iterable of path-like
        Every file the command reads.
    suffixes : tuple of str
        Allowed lower-case suffixes, e.g. ``(".exr",)``.
    writes : str
        What the command writes, for the message (e.g. ``"an OpenEXR image"``).
    no_clobber : bool
        Refuse an output that exists.

    Raises
    ------
    InputError
        The output is an input, has another suffix, exists under ``--no-clobber``
        or its directory does not exist.
    """
    out = Path(output)
    for source in inputs:
        if _same_file(out, Path(source)):
            raise InputError(f"{option} {out} is the input {source}: brdfrig never overwrites its inputs; "
                             "choose another output name")
    if out.suffix.lower() not in suffixes:
        raise InputError(f"{option} {out}: this command writes {writes}; name the output "
                         f"{' or '.join('*' + s for s in suffixes)}")
    if not out.parent.is_dir():
        raise InputError(f"{option} {out}: directory {out.parent} does not exist")
    if out.is_dir():
        raise InputError(f"{option} {out} is a directory")
    if no_clobber and (out.exists() or out.is_symlink()):
        raise InputError(f"{option} {out} exists and --no-clobber is given: nothing written")
    return out
