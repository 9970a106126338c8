"""Every command's --help is plain words: no reST roles, no double backquotes, no internal module names."""

from __future__ import annotations

import re

import pytest

from brdfrig.cli.main import build_parser

PARSER = build_parser()
COMMANDS = sorted(PARSER._subparsers._group_actions[0].choices)  # argparse keeps the sub-commands here
FORBIDDEN = [r"``", r":(func|mod|class|meth|data|attr):", r"\bbrdfrig\.(fit|hdr|rig|session|sim|cli|evaluate|report|export)\b",
             r"\b(fit|hdr|rig|session|sim|cli)/\w+\.py\b"]


def _help(command: str) -> str:
    sub = PARSER._subparsers._group_actions[0].choices[command]
    text = sub.format_help()
    for action in sub._actions:  # nested sub-commands (library add/list/show)
        if hasattr(action, "choices") and isinstance(action.choices, dict):
            text += "".join(p.format_help() for p in action.choices.values())
    return text


def test_there_are_commands():
    assert {"demo", "fit", "render", "merge", "probe", "export", "plot", "library", "refit", "bench"} <= set(COMMANDS)


@pytest.mark.parametrize("command", COMMANDS)
def test_help_is_plain_words(command):
    text = _help(command)
    bad = [m.group(0) for pattern in FORBIDDEN for m in re.finditer(pattern, text)]
    assert not bad, f"brdfrig {command} --help contains {sorted(set(bad))}"
