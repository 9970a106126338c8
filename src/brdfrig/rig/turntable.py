"""Turntable interface and its GRBL 1.1 driver.

The driver speaks the dialect documented in :mod:`brdfrig.rig.grbl_protocol` over a
:class:`brdfrig.rig.serial_link.SerialLink`.  Its contract:

* a position is reported (returned, or exposed by :attr:`position_deg`) only
  after two consecutive status reports say ``Idle`` at that position: while
  moving, after an error, or before homing, :attr:`position_deg` is ``None``;
* every exchange has an overall deadline; lost replies and garbage on the line
  trigger a resynchronisation (drain until quiet, fresh status report) and a
  bounded number of re-sends, which is safe because every command it sends is
  idempotent (absolute moves, homing, settings writes);
* no confirmation rests on timing: a reply taken for lost that was merely late
  costs a resend and a re-approach, never a wrong angle.  Waits for motion and
  homing are counted in status polls; a device that can say when it has
  answered everything (``settled``, the simulator) makes every reply deadline
  mean "the device stopped answering", so the exchange is the same however
  loaded the computer is;
* backlash is compensated by approaching every target from the same (+) side:
  a move that would end going - first goes ``backlash_deg`` (plus a margin)
  below the target.  The side is known only after a *clean* final move: its
  line sent once, its ``ok`` received, nothing garbled, no resynchronisation,
  starting from a confirmed position below the target.  A resent or
  resynchronised move may have run as another move first (line noise can turn
  ``X-67.15`` into ``X967.15`` and lose its ``ok``), so its last segment may
  have run downward: the driver then approaches again from below;
* homing is confirmed only by positive evidence: a status report in the
  ``Home`` state (which only a running homing cycle produces; the driver polls
  while it waits for the cycle's ``ok``) followed by two reports ``Idle`` at 0.
  A garbled ``$H`` (e.g. ``$X``, which unlocks a freshly powered board at
  whatever angle it stands) produces no ``Home`` report and is homed again;
  the absence of a line (``[MSG:Caution: Unlocked]``) is never evidence;
* every retry, resynchronisation and re-approach is reported to ``journal``
  (the session runner writes them to the session journal);
* the port is opened exclusively: a second process gets
  :class:`brdfrig.rig.errors.DeviceBusy`;
* any failure during a move (timeout, stall, alarm, disconnect, Ctrl-C) stops
  the table (feed hold ``!``, then soft reset ``0x18``, which keeps the
  position when the hold completed) before the typed error propagates.

Assumption about the machine: GRBL homing finishes with the table driven in
the + direction (the pull-off of a switch sought in the - direction, ``$23``),
so the gear play is taken up on the + side right after homing.
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
from typing import Callable, Protocol, runtime_checkable

from brdfrig.rig import grbl_protocol as gp
from brdfrig.rig.errors import DeviceDisconnected, DeviceNotFound, DeviceRefused, DeviceTimeout, RigError
from brdfrig.rig.serial_link import SerialLink

__all__ = ["Turntable", "GrblTurntable"]

# Parse-class error codes: on a command we know to be valid they mean line noise, so re-sending is right.
_RETRYABLE_ERRORS = frozenset({1, 2, 3, 11, 20})


@runtime_checkable
class Turntable(Protocol):
    """A rotation stage with an absolute, confirmed angle in degrees.

    ``position_deg`` is the last position confirmed by the device, or ``None``
    when it is unknown (not homed, moving, after an error).
    """

    @property
    def position_deg(self) -> float | None: ...

    def connect(self) -> None: ...

    def home(self) -> float: ...

    def move_to(self, angle_deg: float) -> float: ...

    def stop(self) -> None: ...

    def close(self) -> None: ...

    def __enter__(self) -> Turntable: ...

    def __exit__(self, *exc) -> None: ...


def _positive(name: str, value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        raise ValueError(f"{name} must be a positive finite number, got {value!r}")
    return float(value)


class GrblTurntable:
    """A turntable driven by a GRBL 1.1 controller whose X axis is the table angle in degrees.

    Parameters
    ----------
    port : str
        Serial device path.
    baud : int
        Baud rate (GRBL 1.1 default 115200).
    steps_per_degree : float
        Motor (micro)steps per table degree, > 0; written to the controller's
        ``$100`` on connect if it differs.
    backlash_deg : float
        Gear play in degrees, >= 0; 0 disables the same-side approach.
    reply_timeout_s : float
        Deadline for one command's ``ok`` or one status report.
    connect_timeout_s : float
        Deadline for the greeting after a soft reset.
    homing_timeout_s : float
        Deadline for the ``ok`` of a homing cycle.
    move_margin_s : float
        Added to twice the move's nominal duration (distance / ``$110``) to give its deadline.
    stall_timeout_s : float
        A move whose reported position does not change for this long has stalled.  This and
        the move deadline are counted in polls when ``poll_interval_s`` > 0 (each poll pauses
        that long, so at least this much time has passed), so that the exchange does not
        depend on how loaded the computer is.
    poll_interval_s : float
        Pause between status reports while waiting for a move.
    retries : int
        Re-sends per command (and per move) before giving up, >= 0.
    reconnect_attempts : int
        Port-open attempts in :meth:`connect` (a USB device may take a moment to reappear).
    reconnect_delay_s : float
        Pause between those attempts.
    resync_quiet_s : float
        Quiet time that ends a resynchronisation drain.
    journal : callable, optional
        ``journal(event, **fields)`` is called for every retry, resynchronisation
        and re-approach (events ``turntable_resync``, ``turntable_status_retry``,
        ``turntable_reapproach``, ``turntable_home_retry``,
        ``turntable_reconnect``), e.g. ``SessionStore.append``.
    settled : callable, optional
        ``settled()`` is True once the device has answered every byte sent
        (:meth:`brdfrig.sim.grbl.GrblSimulator.settled`); see
        :class:`brdfrig.rig.serial_link.SerialLink`.  None for real hardware,
        where ``reply_timeout_s`` alone tells a lost reply.
    """

    def __init__(
        self,
        port: str,
        baud: int = 115200,
        steps_per_degree: float = 80.0,
        backlash_deg: float = 0.0,
        *,
        reply_timeout_s: float = 1.0,
        connect_timeout_s: float = 3.0,
        homing_timeout_s: float = 60.0,
        move_margin_s: float = 2.0,
        stall_timeout_s: float = 2.0,
        poll_interval_s: float = 0.05,
        retries: int = 3,
        reconnect_attempts: int = 3,
        reconnect_delay_s: float = 0.5,
        resync_quiet_s: float = 0.05,
        journal: Callable[..., object] | None = None,
        settled: Callable[[], bool] | None = None,
    ) -> None:
        self.steps_per_degree = _positive("steps_per_degree", steps_per_degree)
        if isinstance(backlash_deg, bool) or not isinstance(backlash_deg, (int, float)) or not (
            math.isfinite(backlash_deg) and backlash_deg >= 0
        ):
            raise ValueError(f"backlash_deg must be a finite number >= 0, got {backlash_deg!r}")
        self.backlash_deg = float(backlash_deg)
        self.reply_timeout_s = _positive("reply_timeout_s", reply_timeout_s)
        self.connect_timeout_s = _positive("connect_timeout_s", connect_timeout_s)
        self.homing_timeout_s = _positive("homing_timeout_s", homing_timeout_s)
        self.move_margin_s = _positive("move_margin_s", move_margin_s)
        self.stall_timeout_s = _positive("stall_timeout_s", stall_timeout_s)
        self.reconnect_delay_s = _positive("reconnect_delay_s", reconnect_delay_s)
        self.resync_quiet_s = _positive("resync_quiet_s", resync_quiet_s)
        if not (isinstance(poll_interval_s, (int, float)) and 0 <= poll_interval_s < math.inf):
            raise ValueError(f"poll_interval_s must be a finite number >= 0, got {poll_interval_s!r}")
        self.poll_interval_s = float(poll_interval_s)
        for name, value in (("retries", retries), ("reconnect_attempts", reconnect_attempts)):
            if isinstance(value, bool) or not isinstance(value, int) or value < (0 if name == "retries" else 1):
                raise ValueError(f"{name} must be an integer >= {0 if name == 'retries' else 1}, got {value!r}")
        self.retries = retries
        self.reconnect_attempts = reconnect_attempts
        self.link = SerialLink(port, baud, settled=settled)
        self.journal = journal
        self.firmware = ""  # the controller's greeting, e.g. "Grbl 1.1h ['$' for help]"
        self.settings: dict[int, float] = {}  # the controller's $$ settings as last read (number -> value)
        self.rate_deg_s = 1.0
        self._lock = threading.RLock()
        self._homed = False
        self._position: float | None = None
        self._loaded_positive = False
        self._last_alarm: int | None = None

    # -- state ----------------------------------------------------------------------------------
    @property
    def position_deg(self) -> float | None:
        """Last confirmed angle in degrees, or ``None`` when unknown."""
        return self._position

    @property
    def homed(self) -> bool:
        return self._homed

    @property
    def _tolerance(self) -> float:
        # half a step, but never below the 3-decimal resolution of GRBL's MPos
        return max(0.5 / self.steps_per_degree, 0.0005) + 1e-9

    def _quantise(self, angle_deg: float) -> float:
        return round(angle_deg * self.steps_per_degree) / self.steps_per_degree

    def _note(self, event: str, **fields) -> None:
        if self.journal is not None:
            self.journal(event, **fields)

    def _forget(self) -> None:
        self._homed = False
        self._position = None
        self._loaded_positive = False

    # -- lifetime -------------------------------------------------------------------------------
    def connect(self) -> None:
        """Open the port, reset the controller, check it is GRBL 1.1, read (and fix) its settings.

        Raises
        ------
        DeviceNotFound
            Port missing, or no GRBL 1.1 greeting (wrong baud rate, another device).
        DeviceTimeout
            Silence on the port.
        """
        with self._lock:
            self._forget()
            for attempt in range(self.reconnect_attempts):
                try:
                    self.link.open()
                    break
                except DeviceNotFound as exc:
                    if attempt + 1 == self.reconnect_attempts:
                        raise
                    self._note("turntable_reconnect", attempt=attempt + 1, reason=str(exc))
                    time.sleep(self.reconnect_delay_s)
            try:
                self._soft_reset()
                self._configure()
            except BaseException:
                self.link.close()
                raise

    def close(self) -> None:
        """Close the port (the controller keeps its state); never raises."""
        with self._lock:
            self.link.close()
            self._position = None

    def __enter__(self) -> GrblTurntable:
        self.connect()
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:
            self._halt_quietly()
        self.close()

    # -- public actions -------------------------------------------------------------------------
    def home(self) -> float:
        """Run the homing cycle (reconnecting first if the link was lost); return the confirmed angle 0.0."""
        with self._lock:
            if not self.link.is_open:
                self.connect()
            try:
                if self._status().state == "Alarm":
                    self._soft_reset()  # a hard alarm ignores everything until reset
                self._forget()
                for attempt in range(self.retries + 1):
                    why = self._homing_cycle()
                    if why is None and self._confirm_idle_at(0.0) and self._confirm_idle_at(0.0):
                        break
                    why = why or "no two status reports Idle at 0 after the cycle"
                    self._note("turntable_home_retry", attempt=attempt + 1, reason=why)
                else:
                    raise DeviceRefused(
                        f"no evidence that the controller homed after {self.retries + 1} attempts ({why}): "
                        "check the serial line and the homing switch"
                    )
            except BaseException:
                self._halt_quietly()
                raise
            self._homed = True
            self._position = 0.0
            self._loaded_positive = True
            return 0.0

    def move_to(self, angle_deg: float) -> float:
        """Rotate to an absolute angle (degrees), wait, verify, and return the confirmed angle.

        The target is rounded to whole motor steps.  Raises a
        :class:`brdfrig.rig.errors.RigError` subclass (the table is then stopped and
        :attr:`position_deg` tells what is still known) or ``ValueError`` for a
        non-finite angle.
        """
        if isinstance(angle_deg, bool) or not isinstance(angle_deg, (int, float)) or not math.isfinite(angle_deg):
            raise ValueError(f"turntable angle must be a finite number of degrees, got {angle_deg!r}")
        with self._lock:
            if not self.link.is_open:
                raise DeviceDisconnected(f"turntable on {self.link.port!r} is not connected: connect and home it")
            if not self._homed:
                raise DeviceRefused("turntable is not homed (position unknown): home it before moving")
            target = self._quantise(float(angle_deg))
            start = self._position
            loaded = self._loaded_positive  # is the gear play taken up on the + side at ``start``?
            self._position = None
            self._loaded_positive = False
            try:
                for attempt in range(self.retries + 1):
                    if self.backlash_deg > 0 and (start is None or target < start - self._tolerance or not loaded):
                        margin = max(2.0 / self.steps_per_degree, 0.1 * self.backlash_deg)
                        below = self._quantise(target - self.backlash_deg - margin)
                        reached, start, _ = self._move_verified(start, below)
                        if not reached:  # idle somewhere else (a corrupted command), play side unknown
                            loaded = False
                            why = f"idle at {start:.4f} deg instead of {below:.4f} deg"
                            self._note("turntable_reapproach", target_deg=target, attempt=attempt + 1, reason=why)
                            continue
                    reached, start, clean = self._move_verified(start, target)
                    if reached and (clean or self.backlash_deg == 0):
                        break
                    loaded = False  # arrived from either side: approach again from below
                    why = ("the final move was resent or resynchronised: approach side unknown" if reached
                           else f"idle at {start:.4f} deg instead of {target:.4f} deg")
                    self._note("turntable_reapproach", target_deg=target, attempt=attempt + 1, reason=why)
                else:
                    raise DeviceRefused(
                        f"no clean approach to {target:.4f} deg in {self.retries + 1} attempts (last: {why}): "
                        "check the serial line"
                    )
            except BaseException:
                self._halt_quietly()
                raise
            self._loaded_positive = True  # the final segment went + (or the play is zero)
            self._position = target
            return target

    def stop(self) -> None:
        """Stop now (feed hold, then soft reset) and confirm the controller is stopped.

        Raises a :class:`brdfrig.rig.errors.RigError` when the controller cannot be reached.
        """
        with self._lock:
            self._halt()

    # -- protocol -------------------------------------------------------------------------------
    def _soft_reset(self) -> None:
        """Send 0x18 and wait for the GRBL 1.1 greeting; explain what came instead if it never does."""
        heard: list[str] = []
        noise = bytearray()  # bytes that never formed a line (a wrong baud rate gives such noise)
        for _ in range(self.retries + 1):
            noise += self.link.drain(self.resync_quiet_s, self.reply_timeout_s)
            self.link.write(gp.RESET)
            deadline = time.monotonic() + self.connect_timeout_s
            try:
                while True:
                    line = self.link.readline(deadline)
                    m = gp.GREETING_RE.match(line.strip())
                    if m:
                        major, minor = int(m.group(1)), int(m.group(2))
                        if (major, minor) < (1, 1):
                            raise DeviceRefused(
                                f"controller on {self.link.port!r} runs {line.strip()!r}; GRBL 1.1 or later is needed"
                            )
                        self.firmware = line.strip()
                        self.link.drain(self.resync_quiet_s, self.reply_timeout_s)
                        return
                    heard.append(line)
            except DeviceTimeout:
                continue
        noise += self.link.drain(self.resync_quiet_s, self.reply_timeout_s)
        port, baud = self.link.port, self.link.baud
        readable = [h for h in heard if h.isprintable() and "\ufffd" not in h]
        if readable:
            raise DeviceNotFound(
                f"the device on port {port!r} is not a GRBL 1.1 controller: it answered {readable[0]!r} "
                "(check the 'port' setting)"
            )
        if heard or noise:
            raise DeviceNotFound(
                f"only unreadable bytes came back from port {port!r} at {baud} baud: check the 'baud' setting "
                "(GRBL 1.1 uses 115200)"
            )
        raise DeviceTimeout(
            f"no answer from port {port!r} within {self.connect_timeout_s:g} s: check the 'port' setting and "
            "that the controller is powered"
        )

    def _configure(self) -> None:
        """Read ``$$``; write ``$100`` when it disagrees with ``steps_per_degree``; learn the rate ``$110``."""
        settings = self._settings()
        if abs(settings.get(100, -1.0) - self.steps_per_degree) > 1e-6 * self.steps_per_degree + 5e-4:
            self._command(f"$100={self.steps_per_degree:.3f}")
            settings = self._settings()
            if abs(settings.get(100, -1.0) - self.steps_per_degree) > 1e-6 * self.steps_per_degree + 5e-4:
                raise DeviceRefused(
                    f"controller kept $100={settings.get(100)} after writing steps_per_degree="
                    f"{self.steps_per_degree:g}"
                )
        rate_deg_min = settings.get(110, 0.0)
        if rate_deg_min <= 0:
            raise DeviceRefused(f"controller reports max rate $110={rate_deg_min}: set a positive rate")
        self.rate_deg_s = rate_deg_min / 60.0
        self.settings = dict(settings)
        self._homed = False

    def _homing_cycle(self) -> str | None:
        """Send ``$H`` once and watch it: return None when a homing cycle demonstrably ran, else why not.

        A status report is requested every ``poll_interval_s`` while waiting (GRBL
        answers one queued during the cycle with state ``Home`` just before the
        ``ok``).  The cycle counts only if a ``Home`` report was seen and the
        cycle then ended: its ``ok``, or a report ``Idle`` after the ``Home``
        one (the ``ok`` was lost).  Two reports in a row in another state
        before any ``Home`` one mean no cycle started (GRBL defers reports
        during a cycle; the first may predate the line).  Raises
        ``DeviceRefused`` on a homing alarm or a refusal, ``DeviceTimeout``
        when a seen cycle outlasts ``homing_timeout_s`` (counted in polls, as
        :meth:`_waited`).  A status report counts as lost only when the link's
        reply deadline says so.
        """
        self.link.write_line("$H")
        t0 = next_poll = time.monotonic()
        asked, polls = None, 0
        saw_home = unlocked = ended = False
        why, other_reports = None, 0
        while not ended and why is None:
            now = time.monotonic()
            if asked is None and self._waited(polls, now - t0, self.homing_timeout_s):
                if saw_home:
                    raise DeviceTimeout(f"homing did not finish within {self.homing_timeout_s:g} s (setting 'timeout_s')")
                why = f"no reply to $H within {self.homing_timeout_s:g} s"
                break
            if asked is None and now >= next_poll:  # one status request outstanding at a time
                self.link.write(gp.STATUS_QUERY)
                asked, next_poll, polls = now, now + self.poll_interval_s, polls + 1
            try:
                reply = gp.parse_reply(self.link.readline(asked + self.reply_timeout_s if asked is not None
                                                          else next_poll))
            except DeviceTimeout:
                if asked is not None:
                    asked = None  # that report was lost: ask again
                    self._note("turntable_status_retry", reason="no status report during homing")
                continue
            if reply.kind == "status":
                asked = None
                saw_home = saw_home or reply.status.state == "Home"
                ended = saw_home and reply.status.state == "Idle"
                other_reports = 0 if saw_home else other_reports + 1
                if other_reports >= 2:
                    why = f"no homing cycle started (status {reply.status.state} twice after $H)"
            elif reply.kind == "ok":
                ended = True
            elif reply.kind == "error" and reply.code in _RETRYABLE_ERRORS:
                why = f"$H answered error:{reply.code} ({gp.describe_error(reply.code)})"
            elif reply.kind == "error":
                raise DeviceRefused(f"controller refused $H: error:{reply.code} ({gp.describe_error(reply.code)})")
            elif reply.kind == "alarm":
                self._forget()
                raise DeviceRefused(f"homing failed: ALARM:{reply.code} ({gp.describe_alarm(reply.code)})")
            elif reply.kind == "greeting":
                why = "the controller reset during homing"
            elif reply.kind == "message" and "Unlocked" in reply.text:
                unlocked = True
        self.link.drain(self.resync_quiet_s, self.reply_timeout_s)  # status reports still on the way
        if why is None and not saw_home:
            why = "it unlocked instead of homing" if unlocked else "no status report showed a homing cycle"
        return why

    def _settings(self) -> dict[int, float]:
        replies, _ = self._command("$$")
        return {r.setting[0]: r.setting[1] for r in replies if r.kind == "setting"}

    def _command(self, line: str, timeout: float | None = None) -> tuple[list[gp.Reply], bool]:
        """Send one line; return the lines before its ``ok`` and whether the exchange was clean.

        Clean means sent once, answered ``ok`` with nothing garbled, no
        resynchronisation and no status report or greeting in between (which
        would mean the reply stream was out of step).  A lost or garbled reply, or a parse-class error,
        is journalled, resynchronised and re-sent (at most ``retries`` times).
        """
        timeout = self.reply_timeout_s if timeout is None else timeout
        for attempt in range(self.retries + 1):
            self.link.write_line(line)
            deadline = time.monotonic() + timeout
            info: list[gp.Reply] = []
            try:
                while True:
                    reply = gp.parse_reply(self.link.readline(deadline))
                    if reply.kind == "ok":
                        return info, attempt == 0 and not any(r.kind in ("status", "greeting") for r in info)
                    if reply.kind == "error":
                        if reply.code in _RETRYABLE_ERRORS and attempt < self.retries:
                            why = f"error:{reply.code}"
                            break
                        raise DeviceRefused(
                            f"controller refused {line!r}: error:{reply.code} ({gp.describe_error(reply.code)})"
                        )
                    if reply.kind == "alarm":
                        self._forget()
                        raise DeviceRefused(
                            f"controller raised ALARM:{reply.code} ({gp.describe_alarm(reply.code)}) on {line!r}"
                        )
                    if reply.kind == "garbage":
                        why = f"garbled reply {reply.text!r}"
                        break
                    info.append(reply)
            except DeviceTimeout:
                why = "no reply"
            self._note("turntable_resync", command=line, attempt=attempt + 1, reason=why)
            self._resync()
        raise DeviceTimeout(
            f"controller on {self.link.port!r} did not acknowledge {line!r} after {self.retries + 1} attempts"
        )

    def _resync(self) -> gp.Status:
        """Drop whatever is in flight and re-establish the reply stream with a fresh status report."""
        self.link.drain(self.resync_quiet_s, self.reply_timeout_s)
        return self._status()

    def _status(self) -> gp.Status:
        """One status report (``?``), tolerating lost and garbled lines; ALARM lines are remembered."""
        for _ in range(self.retries + 1):
            self.link.write(gp.STATUS_QUERY)
            deadline = time.monotonic() + self.reply_timeout_s
            try:
                while True:
                    reply = gp.parse_reply(self.link.readline(deadline))
                    if reply.kind == "status":
                        return reply.status
                    if reply.kind == "alarm":
                        self._last_alarm = reply.code
                    elif reply.kind == "greeting":
                        self._forget()  # the controller reset by itself: nothing we knew holds
            except DeviceTimeout:
                self._note("turntable_status_retry", reason="no status report")
                self.link.drain(self.resync_quiet_s, self.reply_timeout_s)
        raise DeviceTimeout(f"no status report from the controller on {self.link.port!r}")

    def _alarm_error(self, doing: str) -> DeviceRefused:
        self._forget()
        code = self._last_alarm
        self._last_alarm = None
        what = f"ALARM:{code} ({gp.describe_alarm(code)})" if code is not None else "alarm state"
        return DeviceRefused(f"turntable controller is in {what} while {doing}; home it again")

    def _move_verified(self, start: float | None, target: float) -> tuple[bool, float, bool]:
        """Command an absolute move to ``target`` and wait until the controller is idle.

        Returns ``(True, target, clean)`` once two status reports confirm it idle
        at the target, or ``(False, where, clean)`` when it went idle elsewhere
        (a command corrupted on the line: the caller re-approaches); ``clean``
        tells whether the command's exchange was clean (see :meth:`_command`).
        Raises on timeout, stall or alarm.
        """
        command = f"G90 G0 X{target:.6f}"
        distance = abs(target - start) if start is not None else 360.0
        allowed = 2.0 * distance / self.rate_deg_s + self.move_margin_s
        t0 = time.monotonic()
        self._last_alarm = None
        _, clean = self._command(command)
        last_pos, last_change, still, polls = None, time.monotonic(), 0, 0
        while True:
            now = time.monotonic()
            if self._waited(polls, now - t0, allowed):
                raise DeviceTimeout(
                    f"turntable did not reach {target:.4f} deg within {allowed:.2f} s (last reported at {last_pos} deg)"
                )
            status = self._status()
            polls += 1
            if status.state == "Alarm":
                raise self._alarm_error(f"moving to {target:.4f} deg")
            if status.state == "Idle":
                if abs(status.mpos - target) > self._tolerance:
                    return False, status.mpos, clean
                if self._confirm_idle_at(target):
                    return True, target, clean
                continue
            if status.state in ("Run", "Jog", "Home"):
                if status.mpos != last_pos:
                    last_pos, last_change, still = status.mpos, now, 0
                elif self._waited(still := still + 1, now - last_change, self.stall_timeout_s):
                    raise DeviceTimeout(
                        f"turntable stalled at {status.mpos:.4f} deg while moving to {target:.4f} deg "
                        f"(no progress for {self.stall_timeout_s:g} s)"
                    )
            else:
                raise DeviceRefused(f"controller entered state {status.state!r} while moving to {target:.4f} deg")
            if self.poll_interval_s:
                time.sleep(self.poll_interval_s)

    def _waited(self, polls: int, seconds: float, limit_s: float) -> bool:
        """Has a wait of ``limit_s`` run out?  Counted in polls of ``poll_interval_s`` when that is > 0.

        Each poll pauses ``poll_interval_s``, so ``polls * poll_interval_s`` never
        exceeds the wall time waited; counting polls makes the exchange the same
        however loaded the computer is.  Without a pause, wall time decides.
        """
        if self.poll_interval_s > 0:
            return polls * self.poll_interval_s >= limit_s
        return seconds > limit_s

    def _confirm_idle_at(self, target: float) -> bool:
        """A second status report must also say Idle at ``target``: one report can be a garbled fluke."""
        status = self._status()
        if status.state == "Alarm":
            raise self._alarm_error(f"confirming the position {target:.4f} deg")
        return status.state == "Idle" and abs(status.mpos - target) <= self._tolerance

    def _halt(self) -> None:
        """Feed hold, wait for the hold to complete, soft reset.

        The position is kept only when confirmed idle and the gear has no play
        (stopped mid-move, the table may sit anywhere within the play).
        """
        self._position = None
        self._loaded_positive = False
        self.link.write(gp.FEED_HOLD)
        previous, polls, t0 = None, 0, time.monotonic()
        while not self._waited(polls, time.monotonic() - t0, self.stall_timeout_s):  # a hung controller stays in Run
            try:
                status = self._status()
            except DeviceTimeout:  # replies lost: the reset below stops the table anyway
                break
            if status.state != "Run" or status.mpos == previous:
                break
            previous, polls = status.mpos, polls + 1
            if self.poll_interval_s:
                time.sleep(self.poll_interval_s)
        self._soft_reset()
        status = self._status()
        if status.state == "Alarm":
            self._forget()
        elif status.state != "Idle":
            raise DeviceRefused(f"controller is in state {status.state!r} after a stop")
        elif self._homed and self.backlash_deg == 0:  # with play, the table is only known within the play
            if self._confirm_idle_at(status.mpos):
                self._position = status.mpos

    def _halt_quietly(self) -> None:
        """Best-effort stop on an error path: never raises; an unreachable controller is closed and forgotten."""
        try:
            if self.link.is_open:
                self._halt()
        except (RigError, OSError):
            self._forget()
            with contextlib.suppress(RigError, OSError):  # a last reset byte, in case only the replies are lost
                self.link.write(gp.RESET)
            self.link.close()
