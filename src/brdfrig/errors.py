"""The errors brdfrig raises for what the user can fix: bad files and values, configs, sessions, devices.

Every error the user can act on derives from :class:`BrdfrigError`; the
``brdfrig`` command prints its message as one line and exits 2.  Any other
exception escaping a command is a bug in brdfrig: the command prints the
traceback and asks for a report (exit 1).

:class:`InputError`, :class:`ConfigError` and :class:`StoreError` are also
``ValueError`` (callers and tests that catch ``ValueError`` keep working);
:class:`DiskFullError` is also ``OSError`` with ``errno.ENOSPC``.  This module
imports nothing from brdfrig, so every layer (``rig`` included) may use it.
"""

from __future__ import annotations

import contextlib
import errno

__all__ = [
    "BrdfrigError",
    "InputError",
    "ConfigError",
    "StoreError",
    "DiskFullError",
    "DeviceError",
    "on_disk_full",
]


class BrdfrigError(Exception):
    """Something the user did or can fix; its message names the file, option or key and what is allowed."""


class InputError(BrdfrigError, ValueError):
    """A bad input file or value (corrupt image, NaN option, output that is one of the inputs, ...)."""


class ConfigError(BrdfrigError, ValueError):
    """A configuration file is missing, unreadable or invalid; the message names file, table and key."""


class StoreError(BrdfrigError, ValueError):
    """A session directory is not usable (wrong kind, newer format, damaged metadata, in use)."""


class DiskFullError(BrdfrigError, OSError):
    """The disk filled up while writing; files already written completely are intact.

    Built as ``DiskFullError(errno.ENOSPC, message)``; ``str()`` is the message alone.
    """

    def __str__(self) -> str:
        return self.strerror if self.strerror else super().__str__()


class DeviceError(BrdfrigError):
    """A device (turntable, camera) failed, refused or is not there."""


@contextlib.contextmanager
def on_disk_full(hint: str):
    """Re-raise a full disk (``DiskFullError`` or ``OSError(ENOSPC)``) in the block as ``DiskFullError`` + ``hint``.

    >>> with on_disk_full("free some space, then run `brdfrig refit S`"):  # doctest: +SKIP
    ...     run_pipeline("S")
    """
    try:
        yield
    except OSError as exc:
        if exc.errno != errno.ENOSPC:
            raise
        what = str(exc) if isinstance(exc, DiskFullError) else "disk full" + (
            f" while writing {exc.filename}" if exc.filename else "")
        raise DiskFullError(errno.ENOSPC, f"{what}: {hint}") from exc
