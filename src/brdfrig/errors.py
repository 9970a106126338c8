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

import errno

__all__ = [
    "BrdfrigError",
    "InputError",
    "ConfigError",
    "StoreError",
    "DiskFullError",
    "DeviceError",
    "disk_full",
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


def disk_full(exc: BaseException, what, hint: str = "free some space and run the command again") -> BaseException:
    """``exc`` as a :class:`DiskFullError` naming ``what`` if it is ``ENOSPC``; otherwise ``exc`` itself."""
    if isinstance(exc, DiskFullError) or not (isinstance(exc, OSError) and exc.errno == errno.ENOSPC):
        return exc
    return DiskFullError(errno.ENOSPC, f"disk full while writing {what}: {hint}")
