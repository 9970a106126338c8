"""Allowed ranges of numeric options and config keys: one checker for the CLI (argparse) and the TOML schema.

A :class:`Range` states the bounds (and whether the value is an integer); it
turns a value into a clear error naming the option or key, what is allowed
and what was given.  NaN, inf and booleans are never numbers here.

>>> Range(0, 1e7, open_lo=True).check(20000.0, "--full-well")
20000.0
>>> Range(0, 1e7, open_lo=True).check(0.0, "--full-well")
Traceback (most recent call last):
...
brdfrig.errors.InputError: --full-well must be a number in (0, 1e+07], got 0.0
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass

from brdfrig.errors import InputError

__all__ = ["Range", "COLOUR_SPACES", "BANDS", "EXPOSURE_S", "PIXELS", "ALBEDO", "FULL_WELL_E", "READ_NOISE_E", "BAUD",
           "STEPS_PER_DEGREE", "BACKLASH_DEG"]


@dataclass(frozen=True)
class Range:
    """Closed (or half-open) interval ``[lo, hi]`` of allowed values; ``None`` = unbounded on that side."""

    lo: float | None = None
    hi: float | None = None
    open_lo: bool = False
    open_hi: bool = False
    integer: bool = False

    def text(self) -> str:
        """The range in words, e.g. ``" in (0, 1]"``, ``" >= 1"`` (empty when unbounded)."""
        lo, hi = (None if b is None else f"{b:g}" for b in (self.lo, self.hi))
        if lo is not None and hi is not None:
            return f" in {'(' if self.open_lo else '['}{lo}, {hi}{')' if self.open_hi else ']'}"
        if lo is not None:
            return f" {'>' if self.open_lo else '>='} {lo}"
        if hi is not None:
            return f" {'<' if self.open_hi else '<='} {hi}"
        return ""

    def contains(self, v: float) -> bool:
        """Whether the (finite) number ``v`` is allowed."""
        if self.lo is not None and (v < self.lo or (self.open_lo and v == self.lo)):
            return False
        return not (self.hi is not None and (v > self.hi or (self.open_hi and v == self.hi)))

    def _error(self, where: str, got, error: type[Exception]) -> Exception:
        kind = "an integer" if self.integer else "a number"
        return error(f"{where} must be {kind}{self.text()}, got {got!r}".lstrip())

    def check(self, v, where: str, error: type[Exception] = InputError):
        """``v`` as ``int``/``float`` if it is an allowed number, else ``error`` naming ``where``."""
        is_number = isinstance(v, int if self.integer else (int, float)) and not isinstance(v, bool)
        if not is_number or not math.isfinite(v) or not self.contains(v):
            raise self._error(where, v, error)
        return int(v) if self.integer else float(v)

    def parse(self, text: str, where: str, error: type[Exception] = InputError):
        """A command-line string checked against the range (``error`` naming ``where`` and quoting ``text``)."""
        try:
            return self.check(int(text) if self.integer else float(text), where, error)
        except (ValueError, error):
            raise self._error(where, text, error) from None

    def arg(self, what: str = ""):
        """An argparse ``type=``: parses and checks one string (argparse names the option in its message)."""
        def parse(text: str):
            return self.parse(text, what, argparse.ArgumentTypeError)

        parse.__name__ = "integer" if self.integer else "number"
        return parse

    def args(self, what: str = "each value", n: tuple[int, ...] | None = None):
        """An argparse ``type=`` for comma-separated values, each checked (``n``: the allowed counts)."""
        def parse(text: str) -> list:
            values = [self.parse(t.strip(), what, argparse.ArgumentTypeError) for t in text.split(",")]
            if n is not None and len(values) not in n:
                raise argparse.ArgumentTypeError(
                    f"needs {' or '.join(map(str, n))} comma-separated values, got {text!r}")
            return values

        parse.__name__ = "list"
        return parse


# Quantities that both the command line and the TOML configs take: one range each.
BANDS = Range(0, 30, integer=True)  #: SH band limits lmax, pmax
EXPOSURE_S = Range(0, 3600, open_lo=True)  #: exposure times, seconds
PIXELS = Range(-1e5, 1e5)  #: circle centres and radii, pixel boxes
ALBEDO = Range(0, 1, open_lo=True)  #: reflectances
FULL_WELL_E = Range(1, 1e7)  #: sensor full-well capacity, electrons
READ_NOISE_E = Range(0, 1e4)  #: read noise, electrons
BAUD = Range(300, 4_000_000, integer=True)  #: serial baud rates
STEPS_PER_DEGREE = Range(0, 1e5, open_lo=True)  #: motor steps per table degree
BACKLASH_DEG = Range(0, 45)  #: gear play, degrees
#: Colour spaces of merged images and fitted BRDFs: camera RGB as recorded, linear Rec.709, ACEScg (brdfrig.hdr.colour)
COLOUR_SPACES = ("camera", "rec709", "acescg")
