"""A line-oriented serial link with overall deadlines, resynchronisation and typed errors.

The link is an object a device driver *has* (python-microscope's lesson: not
a mixin it *is*).  It owns the pyserial port, a lock serialising exchanges,
and line assembly with an overall deadline: pyserial's ``readline`` restarts
its timeout on every byte, so a device that trickles garbage would block it
forever.
"""

from __future__ import annotations

import errno
import threading
import time

import serial

from brdfrig.rig.errors import DeviceBusy, DeviceDisconnected, DeviceNotFound, DeviceTimeout

__all__ = ["SerialLink"]


class SerialLink:
    """A serial port spoken to in ASCII lines.

    Parameters
    ----------
    port : str
        Device path (``/dev/ttyUSB0``, ``/dev/serial/by-id/...``, a pty).
    baud : int
        Baud rate, positive.
    eol : bytes
        Line terminator appended by :meth:`write_line`.

    Notes
    -----
    Every read takes an absolute ``deadline`` (``time.monotonic()`` seconds).
    The port is opened exclusively (``flock``): while one link holds it,
    another process (or link) gets :class:`DeviceBusy`.
    Errors: :class:`DeviceNotFound` (port absent or not a serial device),
    :class:`DeviceDisconnected` (the port went away while open),
    :class:`DeviceTimeout` (no complete line before the deadline).
    """

    def __init__(self, port: str, baud: int, *, eol: bytes = b"\n") -> None:
        if not isinstance(port, str) or not port:
            raise ValueError(f"port must be a serial device path, got {port!r}")
        if not isinstance(baud, int) or isinstance(baud, bool) or baud <= 0:
            raise ValueError(f"baud must be a positive integer, got {baud!r}")
        self.port = port
        self.baud = baud
        self.eol = eol
        self.lock = threading.RLock()
        self._serial: serial.Serial | None = None
        self._buffer = bytearray()

    # -- lifetime -------------------------------------------------------------------------
    @property
    def is_open(self) -> bool:
        return self._serial is not None

    def open(self) -> None:
        """Open the port exclusively (8N1, no flow control).

        A missing or unusable port raises :class:`DeviceNotFound`; a port held
        by another process raises :class:`DeviceBusy`.
        """
        with self.lock:
            self.close()
            try:
                self._serial = serial.Serial(self.port, self.baud, timeout=0, write_timeout=1.0, exclusive=True)
            except serial.SerialException as exc:
                err = getattr(exc, "errno", None)
                if err in (errno.EBUSY, errno.EAGAIN, errno.EWOULDBLOCK):
                    raise DeviceBusy(f"port {self.port!r} is in use by another process (setting 'port')") from exc
                raise DeviceNotFound(f"cannot open serial port {self.port!r} (setting 'port'): {exc}") from exc
            except (OSError, ValueError) as exc:
                raise DeviceNotFound(f"cannot open serial port {self.port!r} (setting 'port'): {exc}") from exc
            self._buffer.clear()

    def close(self) -> None:
        """Close the port; never raises."""
        with self.lock:
            if self._serial is not None:
                try:
                    self._serial.close()
                except (serial.SerialException, OSError):
                    pass
            self._serial = None
            self._buffer.clear()

    def __enter__(self) -> SerialLink:
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- I/O ----------------------------------------------------------------------------------
    def _port(self) -> serial.Serial:
        if self._serial is None:
            raise DeviceDisconnected(f"serial port {self.port!r} is not open")
        return self._serial

    def write(self, data: bytes) -> None:
        """Write raw bytes (realtime commands, or a full line)."""
        with self.lock:
            try:
                self._port().write(data)
            except (serial.SerialException, OSError) as exc:
                self.close()
                raise DeviceDisconnected(f"lost serial port {self.port!r} while writing: {exc}") from exc

    def write_line(self, text: str) -> None:
        """Write ``text`` followed by the line terminator."""
        self.write(text.encode("ascii") + self.eol)

    def readline(self, deadline: float) -> str:
        """Return the next line (without terminator, undecodable bytes replaced) before ``deadline``.

        Carriage returns are dropped and blank lines skipped.
        """
        with self.lock:
            port = self._port()
            while True:
                nl = self._buffer.find(b"\n")
                while nl >= 0:
                    raw = bytes(self._buffer[:nl]).replace(b"\r", b"")
                    del self._buffer[: nl + 1]
                    if raw.strip():
                        return raw.decode("ascii", errors="replace")
                    nl = self._buffer.find(b"\n")
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise DeviceTimeout(f"no reply on {self.port!r} in time")
                try:
                    port.timeout = remaining
                    chunk = port.read(max(1, port.in_waiting))
                except (serial.SerialException, OSError) as exc:
                    self.close()
                    raise DeviceDisconnected(f"lost serial port {self.port!r} while reading: {exc}") from exc
                self._buffer += chunk

    def drain(self, quiet_s: float, max_s: float) -> bytes:
        """Discard input until the line has been quiet for ``quiet_s`` (at most ``max_s``); return what was dropped.

        Used to resynchronise after garbage or a lost reply: whatever the device
        was still sending belongs to the exchange being abandoned.
        """
        with self.lock:
            port = self._port()
            dropped = bytearray(self._buffer)
            self._buffer.clear()
            end = time.monotonic() + max_s
            try:
                while time.monotonic() < end:
                    port.timeout = quiet_s
                    chunk = port.read(max(1, port.in_waiting))
                    if not chunk:
                        break
                    dropped += chunk
            except (serial.SerialException, OSError) as exc:
                self.close()
                raise DeviceDisconnected(f"lost serial port {self.port!r} while resynchronising: {exc}") from exc
            return bytes(dropped)
