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
from typing import Callable

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
    settled : callable, optional
        ``settled()`` is True when the device has read and answered every byte
        sent to it (a simulator can tell; real hardware cannot: None).  When
        given, a deadline that passes while the device is still busy does not
        count: the read goes on until the device has settled, so a reply that is
        merely late (a loaded computer) is never taken for a lost one, up to
        ``silence_s`` past the deadline (the device stopped answering).
    silence_s : float
        With ``settled``: how long past a deadline a busy device may take, in seconds.

    Notes
    -----
    Every read takes an absolute ``deadline`` (``time.monotonic()`` seconds).
    The port is opened exclusively (``flock``): while one link holds it,
    another process (or link) gets :class:`DeviceBusy`.
    Errors: :class:`DeviceNotFound` (port absent or not a serial device),
    :class:`DeviceDisconnected` (the port went away while open),
    :class:`DeviceTimeout` (no complete line before the deadline).
    """

    def __init__(self, port: str, baud: int, *, eol: bytes = b"\n", settled: Callable[[], bool] | None = None,
                 silence_s: float = 30.0) -> None:
        if not isinstance(port, str) or not port:
            raise ValueError(f"port must be a serial device path, got {port!r}")
        if not isinstance(baud, int) or isinstance(baud, bool) or baud <= 0:
            raise ValueError(f"baud must be a positive integer, got {baud!r}")
        self.port = port
        self.baud = baud
        self.eol = eol
        self.settled = settled
        self.silence_s = silence_s
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
                    if self._nothing_more(deadline):
                        raise DeviceTimeout(f"no reply on {self.port!r} in time")
                    remaining = 0.005  # the device is still busy: its reply is late, not lost
                self._buffer += self._read(port, remaining, "reading")

    def _read(self, port: serial.Serial, timeout: float, doing: str) -> bytes:
        """What arrives within ``timeout`` seconds (at least one byte unless it runs out)."""
        try:
            port.timeout = timeout
            return port.read(max(1, port.in_waiting))
        except (serial.SerialException, OSError) as exc:
            self.close()
            raise DeviceDisconnected(f"lost serial port {self.port!r} while {doing}: {exc}") from exc

    def _nothing_more(self, deadline: float) -> bool:
        """At or past ``deadline`` with nothing buffered: may the wait end?

        Without ``settled``, yes.  With it, only once the device has settled and
        nothing arrived meanwhile (a last non-blocking look), or ``silence_s``
        after the deadline.
        """
        if self.settled is None or time.monotonic() > deadline + self.silence_s:
            return True
        if not self.settled():
            return False
        late = self._read(self._port(), 0, "reading")
        self._buffer += late
        return not late

    def drain(self, quiet_s: float, max_s: float) -> bytes:
        """Discard input until the line has been quiet for ``quiet_s`` (at most ``max_s``); return what was dropped.

        Used to resynchronise after garbage or a lost reply: whatever the device
        was still sending belongs to the exchange being abandoned.  With
        ``settled``, quiet means the device has settled with nothing in flight
        (however long that takes on a loaded computer, up to ``max_s + silence_s``).
        """
        with self.lock:
            port = self._port()
            dropped = bytearray(self._buffer)
            self._buffer.clear()
            end = time.monotonic() + max_s
            while time.monotonic() < end or (self.settled is not None and time.monotonic() < end + self.silence_s):
                chunk = self._read(port, quiet_s if self.settled is None else 0.005, "resynchronising")
                if chunk:
                    dropped += chunk
                elif self.settled is None or self.settled():
                    chunk = self._read(port, 0, "resynchronising")
                    if not chunk:
                        break
                    dropped += chunk
            return bytes(dropped)
