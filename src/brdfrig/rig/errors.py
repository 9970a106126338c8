"""Typed device errors shared by every rig driver."""

from __future__ import annotations

from brdfrig.errors import DeviceError


class RigError(DeviceError):
    """Base class of every device error; the CLI prints its message and exits 2."""


class DeviceTimeout(RigError):
    """The device did not answer or finish within the allowed time."""


class DeviceDisconnected(RigError):
    """The link to the device is gone (port closed, USB unplugged)."""


class DeviceBusy(RigError):
    """The device is busy (another process, or still settling) and retries ran out."""


class DeviceRefused(RigError):
    """The device answered with a refusal (alarm, error code, unsupported setting)."""


class DeviceNotFound(RigError):
    """No device answered where the configuration says it is."""
