"""What the sub-commands' parsers share: how one is made and the options several commands take alike.

A command's ``--help`` is its module docstring, shown with its line breaks
(:class:`argparse.RawDescriptionHelpFormatter`); the one-line ``help`` is its
entry in ``brdfrig --help``.  Output options live in :mod:`brdfrig.cli._output`.
"""

from __future__ import annotations

import argparse

__all__ = ["add_command", "add_progress_argument"]


def add_command(subparsers, name: str, help: str, description: str | None) -> argparse.ArgumentParser:
    """Add the parser of sub-command ``name``: ``help`` in the command list, ``description`` as its --help text."""
    return subparsers.add_parser(name, help=help, description=description,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)


def add_progress_argument(parser) -> None:
    """Add ``--no-progress`` (the command's tqdm bars on stderr are on by default)."""
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")
