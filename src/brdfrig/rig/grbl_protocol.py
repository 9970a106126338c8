"""The subset of the GRBL 1.1 serial dialect that brdfrig relies on, shared by driver and simulator.

GRBL 1.1 (https://github.com/gnea/grbl/wiki, "Grbl v1.1 Interface") is the
firmware of most DIY stepper turntables (an Arduino + stepper driver).  The
turntable's rotation is GRBL's X axis, configured so that one "mm" is one
table degree (``$100`` = steps per degree, ``$110`` = max rate in degrees per
minute).

Commands the driver sends (each terminated by ``\\n``; all idempotent, so a
command whose reply was lost can be sent again):

==================  =========================================================
``0x18``            soft reset (realtime byte); answered by the greeting
``?``               status report request (realtime byte, no ``ok``)
``!``               feed hold (realtime byte): decelerate and stop
``$$``              dump settings (``$100=80.000`` lines, then ``ok``)
``$100=<v>``        write steps per unit (degree) to EEPROM
``$H``              homing cycle; ``ok`` once it completes (a ``?`` sent during
                    the cycle is answered ``<Home|...>`` before that ``ok``)
``G90 G0 X<deg>``   absolute rapid move of the table to ``<deg>`` degrees
==================  =========================================================

The simulator also implements ``~`` (cycle start), ``$X`` (kill alarm lock:
``[MSG:Caution: Unlocked]``, ``ok``; the driver never sends it, but line
noise can turn ``$H`` into ``$X``, and that message can be lost too, so the
driver accepts a homing only on seeing a ``Home`` status report), ``G91``,
``G1 F<rate>`` and empty lines (answered ``ok``, like GRBL).

Replies it understands:

==============================  ==============================================
``Grbl 1.1h ['$' for help]``    greeting after reset / power-up
``ok``                          command accepted
``error:N``                     command refused, N from :data:`ERROR_CODES`
``ALARM:N``                     alarm raised, N from :data:`ALARM_CODES`;
                                G-code is locked out until reset + ``$H``/``$X``
``<State|MPos:x,y,z|...>``      status; State in Idle, Run, Hold:N, Jog, Alarm,
                                Door:N, Check, Home, Sleep; MPos in degrees
``[MSG:...]``, ``$N=v``         informational lines
==============================  ==============================================

Anything else is garbage (line noise, wrong baud rate, another device).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

__all__ = [
    "ALARM_CODES",
    "ERROR_CODES",
    "GREETING_RE",
    "RESET",
    "STATUS_QUERY",
    "FEED_HOLD",
    "CYCLE_START",
    "Reply",
    "Status",
    "parse_reply",
    "format_status",
    "describe_error",
    "describe_alarm",
]

RESET = b"\x18"
STATUS_QUERY = b"?"
FEED_HOLD = b"!"
CYCLE_START = b"~"

GREETING_RE = re.compile(r"^Grbl (\d+)\.(\d+)([a-z]?) \[.*\]$")
_STATUS_RE = re.compile(r"^<([A-Za-z]+)(?::(\d))?\|MPos:(-?\d+\.\d+),(-?\d+\.\d+),(-?\d+\.\d+)(\|[^<>]*)?>$")
_SETTING_RE = re.compile(r"^\$(\d+)=(-?\d+(?:\.\d+)?)$")
_STATES = {"Idle", "Run", "Hold", "Jog", "Alarm", "Door", "Check", "Home", "Sleep"}

ERROR_CODES = {
    1: "expected command letter",
    2: "bad number format",
    3: "invalid '$' statement",
    4: "negative value",
    5: "setting disabled (homing is not enabled: set $22=1)",
    8: "'$' command only valid when idle",
    9: "G-code locked out during alarm or jog state",
    11: "line too long",
    15: "travel exceeded",
    20: "unsupported or invalid G-code command",
    22: "feed rate not set",
}

ALARM_CODES = {
    1: "hard limit triggered; position lost, home again",
    2: "soft limit: target exceeds machine travel",
    3: "reset while in motion; position lost, home again",
    6: "homing failed: reset during homing",
    8: "homing failed: pull-off did not clear the limit switch",
    9: "homing failed: limit switch not found",
}


def describe_error(code: int) -> str:
    """Human-readable meaning of a GRBL ``error:N`` code."""
    return ERROR_CODES.get(code, "unknown error code")


def describe_alarm(code: int) -> str:
    """Human-readable meaning of a GRBL ``ALARM:N`` code."""
    return ALARM_CODES.get(code, "unknown alarm code")


@dataclass(frozen=True)
class Status:
    """A parsed status report.

    Attributes
    ----------
    state : str
        Machine state without its sub-state ("Idle", "Run", "Hold", "Alarm", ...).
    substate : int or None
        The ``N`` of ``Hold:N`` / ``Door:N``.
    mpos : float
        Machine position of the X axis (table degrees when ``$100`` is steps per degree).
    """

    state: str
    substate: int | None
    mpos: float


@dataclass(frozen=True)
class Reply:
    """One classified line from the controller.

    ``kind`` is one of "ok", "error", "alarm", "status", "greeting", "message",
    "setting", "garbage"; ``code`` holds N for error/alarm, ``status`` the parsed
    report, ``setting`` the ``(number, value)`` pair, ``text`` the raw line.
    """

    kind: str
    text: str
    code: int | None = None
    status: Status | None = None
    setting: tuple[int, float] | None = None


def parse_reply(line: str) -> Reply:
    """Classify one line received from a GRBL controller (line ending already stripped)."""
    text = line.strip()
    if text == "ok":
        return Reply("ok", text)
    for prefix, kind in (("error:", "error"), ("ALARM:", "alarm")):
        if text.startswith(prefix) and text[len(prefix):].isdigit():
            return Reply(kind, text, code=int(text[len(prefix):]))
    m = _STATUS_RE.match(text)
    if m and m.group(1) in _STATES:
        sub = int(m.group(2)) if m.group(2) else None
        return Reply("status", text, status=Status(m.group(1), sub, float(m.group(3))))
    if GREETING_RE.match(text):
        return Reply("greeting", text)
    if text.startswith("[") and text.endswith("]") and text.isprintable():
        return Reply("message", text)
    m = _SETTING_RE.match(text)
    if m:
        return Reply("setting", text, setting=(int(m.group(1)), float(m.group(2))))
    return Reply("garbage", text)


def format_status(state: str, mpos: float, substate: int | None = None) -> str:
    """The status report GRBL 1.1 prints for a one-axis machine at ``mpos`` (3 decimals, like GRBL)."""
    name = state if substate is None else f"{state}:{substate}"
    return f"<{name}|MPos:{mpos:.3f},0.000,0.000|FS:0,0>"
