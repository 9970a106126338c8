"""A GRBL 1.1 turntable firmware simulator served on a pseudo-terminal, with mechanics and fault injection.

The simulator models the device, not the driver's expectations: motion takes
time and advances in integer motor steps, the gear has backlash (the table
lags the motor by up to the play), the firmware speaks the dialect documented
in :mod:`brdfrig.rig.grbl_protocol`, and faults happen the way they do on a bench:
lost or garbled reply lines, a stalled motor, slow motion, a USB disconnect
(the board resets and comes back, possibly under a new ``/dev/pts/N``), and
alarms that lock the controller until it is reset and homed.

Clients open :attr:`GrblSimulator.port` with real pyserial.  That path is a
symlink that always points at the current pty slave, like the stable
``/dev/serial/by-id/...`` names udev gives a USB serial adapter.

Mechanics (integer steps): ``motor`` is the motor shaft position, ``table``
the table position, both in motor steps from the home switch.  The gear play
keeps ``motor <= table <= motor + play``: moving +, the motor pushes the table
(``table = max(table, motor)``); moving -, it pulls it from the other side
(``table = min(table, motor + play)``).  Homing ends with a + approach, so
afterwards ``table == motor == 0``.  The firmware's MPos is
``(motor - counter_zero) / $100``: the firmware never knows about the play.

Fault schedule (reproducible, independent of timing): every random decision
is drawn from ``random.Random`` seeded by ``(seed, stream, index)``, where the
index counts protocol events, not time.  Reply lines are indexed by
``(epoch, n)``: ``epoch`` counts the command lines and reset bytes received,
``n`` the lines sent since; received command lines by their count; moves by
their count.  The same bytes from the client therefore meet the same faults.
With ``tick_s`` set, motion and homing also run on a virtual clock that
advances ``tick_s`` per status report (``?``), so how far a move has got when
the client looks depends on how often it looked, never on the machine's load.
Scripted faults (:meth:`GrblSimulator.rewrite_command`,
:meth:`GrblSimulator.drop_reply`) reproduce a given failure exactly.
"""

from __future__ import annotations

import math
import os
import random
import re
import select
import tempfile
import termios
import threading
import time
import tty
from collections import Counter, deque
from dataclasses import dataclass
from pathlib import Path

from brdfrig.rig import grbl_protocol as gp

__all__ = ["FaultRates", "MOTION_FAULTS", "LINE_FAULTS", "GrblSimulator"]

MOTION_FAULTS = ("stall", "slow", "disconnect", "alarm")
LINE_FAULTS = ("drop", "garble")
_WORD_RE = re.compile(r"([A-Z])([-+]?(?:\d+\.?\d*|\.\d+))")


@dataclass(frozen=True)
class FaultRates:
    """Probabilities of injected faults (each in [0, 1]).

    Attributes
    ----------
    drop, garble : float
        Per reply line sent: the line is lost / some of its bytes are corrupted.
        ``garble`` also applies to each received command line (noise toward the device).
    stall, slow, disconnect, alarm : float
        Per planned move (at most one of them per move, tried in this order):
        the motor stops partway while the firmware still reports Run; the move
        runs ``slow_factor`` times slower; the USB link drops partway (the board
        resets, reconnecting after ``reconnect_delay_s``); a hard-limit alarm
        (``ALARM:1``) stops the move partway and locks the controller.
    """

    drop: float = 0.0
    garble: float = 0.0
    stall: float = 0.0
    slow: float = 0.0
    disconnect: float = 0.0
    alarm: float = 0.0

    def __post_init__(self) -> None:
        for name in LINE_FAULTS + MOTION_FAULTS:
            p = getattr(self, name)
            if not 0.0 <= p <= 1.0:
                raise ValueError(f"fault rate {name!r} must be in [0, 1], got {p!r}")


@dataclass
class _Segment:
    start: int  # motor steps at t0
    target: int  # motor steps at the end
    t0: float  # monotonic start time
    steps_per_s: float
    stall_after: int | None = None  # motor stops after this many steps and never finishes

    @property
    def total(self) -> int:
        return abs(self.target - self.start)

    @property
    def direction(self) -> int:
        return 1 if self.target >= self.start else -1

    def steps_done(self, now: float) -> int:
        n = min(self.total, int(math.floor(max(0.0, now - self.t0) * self.steps_per_s)))
        return n if self.stall_after is None else min(n, self.stall_after)

    def end_time(self) -> float | None:
        return None if self.stall_after is not None else self.t0 + self.total / self.steps_per_s


def _check_mechanics(steps_per_degree, backlash_deg, max_rate_deg_s, tick_s) -> None:
    """ValueError naming the first impossible mechanical setting of a simulated table."""
    if not steps_per_degree > 0:
        raise ValueError(f"steps_per_degree must be > 0, got {steps_per_degree!r}")
    if not backlash_deg >= 0:
        raise ValueError(f"backlash_deg must be >= 0, got {backlash_deg!r}")
    if not max_rate_deg_s > 0:
        raise ValueError(f"max_rate_deg_s must be > 0, got {max_rate_deg_s!r}")
    if tick_s is not None and not tick_s > 0:
        raise ValueError(f"tick_s must be > 0 or None, got {tick_s!r}")


class GrblSimulator:
    """GRBL 1.1 turntable controller on a pseudo-terminal, served by a background thread.

    Parameters
    ----------
    steps_per_degree : float
        True mechanics: motor steps per table degree (>0).
    backlash_deg : float
        Gear play in table degrees (>= 0), rounded to whole steps.
    max_rate_deg_s : float
        Rapid (G0) speed in degrees per second (GRBL ``$110`` is this x 60).
    homing_time_s : float
        Duration of a homing cycle.
    firmware_steps_per_degree : float, optional
        Initial ``$100``; defaults to ``steps_per_degree`` (a correctly set-up board).
    baud : int
        The board's baud rate; a client whose port is set to another rate gets garbage both ways.
    faults : FaultRates, optional
        Random fault probabilities (default: none).  Change later with :meth:`set_faults`.
    slow_factor : float
        Speed divisor of a "slow" move.
    reconnect_delay_s : float
        Time a disconnected board stays away.
    foreign_reply : str, optional
        Turn the simulator into a different device that answers every line
        (and the reset byte) with this text, e.g. ``"echo:Unknown command"``.
    start_angle_deg : float
        Physical table angle at power-up (the firmware counter starts at 0 there).
    seed : int
        Seed of the fault schedule (see the module docstring).
    tick_s : float, optional
        Virtual clock: mechanics advance this many seconds per status report
        received, and only then.  ``None`` (default) runs them in real time.
    late_replies : float
        Fraction of reply lines held back ``late_reply_s`` before they are sent
        (chosen by the schedule, stream ``"late"``; not a fault: the line arrives
        intact), as a device slowed down by a loaded computer.
    late_reply_s : float
        How long a late reply is held back, in seconds.

    Attributes
    ----------
    port : str
        Stable path to open with pyserial (a symlink to the current pty slave).
    fault_counts : collections.Counter
        Number of faults injected, by kind.
    fault_log : list of tuple
        Every fault injected, in order: ``(kind, where)`` with ``where`` the
        schedule index (``(epoch, n)`` for a reply line, the count for a
        received line or a move) or ``"forced"``/``"scripted"``.
    """

    def __init__(
        self,
        *,
        steps_per_degree: float = 80.0,
        backlash_deg: float = 0.0,
        max_rate_deg_s: float = 90.0,
        homing_time_s: float = 0.2,
        firmware_steps_per_degree: float | None = None,
        baud: int = 115200,
        faults: FaultRates | None = None,
        slow_factor: float = 3.0,
        reconnect_delay_s: float = 0.05,
        foreign_reply: str | None = None,
        start_angle_deg: float = 37.0,
        seed: int = 0,
        tick_s: float | None = None,
        late_replies: float = 0.0,
        late_reply_s: float = 0.04,
    ) -> None:
        _check_mechanics(steps_per_degree, backlash_deg, max_rate_deg_s, tick_s)
        self._baud_flag = getattr(termios, f"B{baud}", None)
        if self._baud_flag is None:
            raise ValueError(f"baud {baud!r} is not a standard rate")
        self.steps_per_degree = float(steps_per_degree)
        self.play = int(round(backlash_deg * steps_per_degree))
        self.max_rate_deg_s = float(max_rate_deg_s)
        self.homing_time_s = float(homing_time_s)
        self.slow_factor = float(slow_factor)
        self.reconnect_delay_s = float(reconnect_delay_s)
        self.foreign_reply = foreign_reply
        self.baud = baud
        self.faults = faults or FaultRates()
        self.fault_counts: Counter[str] = Counter()
        self.fault_log: list[tuple[str, object]] = []
        self.seed = seed
        self.tick_s = tick_s
        self.late_replies, self.late_reply_s = float(late_replies), float(late_reply_s)
        self._vclock = 0.0
        self._noise_rng = random.Random(seed)  # wrong-baud noise: content only, never a fault decision
        self._epoch = 0  # command lines + reset bytes received
        self._sent_in_epoch = 0  # reply lines sent since the epoch began
        self._lines_received = 0
        self._moves_planned = 0
        self._forced: deque[str] = deque()
        self._rewrites: list[tuple[str, str, bool]] = []
        self._drop_patterns: list[re.Pattern] = []
        self._lock = threading.RLock()
        self._power_up(float(firmware_steps_per_degree or steps_per_degree), start_angle_deg)
        # pty and thread
        self._dir = Path(tempfile.mkdtemp(prefix="grblsim-"))
        self.port = str(self._dir / "ttyGRBL")
        self._master: int | None = None
        self._slave: int | None = None
        self._wake_r, self._wake_w = os.pipe()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._open_pty()
        self._boot_messages()

    def _power_up(self, firmware_steps_per_degree: float, start_angle_deg: float) -> None:
        """Firmware settings, mechanics (motor steps from the home switch) and state of a board just powered up."""
        self._settings = {  # $N=value
            0: 10.0, 22: 1.0, 23: 1.0, 100: firmware_steps_per_degree,
            110: self.max_rate_deg_s * 60.0, 120: 1000.0, 130: 360.0,
        }
        start = int(round(start_angle_deg * self.steps_per_degree))
        self.motor = start
        self.table = start + self.play // 2
        self.counter_zero = start
        self._active: _Segment | None = None
        self._queue: deque[int] = deque()
        self._absolute = True
        self._feed_set = False
        self.state = "Alarm"  # homing lock at power-up ($22=1)
        self._critical = False  # hard alarm: everything but reset ignored
        self._homing_done_at: float | None = None
        self._pending_lines: deque[str] = deque()
        self._line_buf = bytearray()
        self._pending_event: tuple[float, str] | None = None  # (time, "alarm"|"disconnect")
        self._reconnect_at: float | None = None

    # -- public -----------------------------------------------------------------------------
    def start(self) -> GrblSimulator:
        """Start serving the pty (idempotent)."""
        if self._thread is None:
            self._thread = threading.Thread(target=self._serve, name="grbl-sim", daemon=True)
            self._thread.start()
        return self

    def close(self) -> None:
        """Stop the thread and release the pty; safe to call twice."""
        self._stop.set()
        try:
            os.write(self._wake_w, b"x")
        except OSError:
            pass
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
        with self._lock:
            self._close_pty()
        for fd in (self._wake_r, self._wake_w):
            try:
                os.close(fd)
            except OSError:
                pass
        self._wake_r = self._wake_w = -1
        try:
            os.unlink(self.port)
        except OSError:
            pass
        try:
            self._dir.rmdir()
        except OSError:
            pass

    def __enter__(self) -> GrblSimulator:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    def set_faults(self, faults: FaultRates) -> None:
        """Replace the random fault probabilities."""
        with self._lock:
            self.faults = faults

    def inject(self, kind: str) -> None:
        """Force one fault: a motion fault hits the next move, a line fault the next reply line."""
        if kind not in MOTION_FAULTS + LINE_FAULTS:
            raise ValueError(f"unknown fault {kind!r}; choose from {MOTION_FAULTS + LINE_FAULTS}")
        with self._lock:
            self._forced.append(kind)

    def rewrite_command(self, old: str, new: str, *, drop_ok: bool = False) -> None:
        """Script line noise toward the board: the next received line ``old`` executes as ``new``.

        Lines are compared as the firmware reads them (spaces removed, upper
        case).  With ``drop_ok`` the ``ok`` answering it is lost as well.
        """
        with self._lock:
            self._rewrites.append((_normal(old), _normal(new), drop_ok))

    def drop_reply(self, pattern: str) -> None:
        """Script a lost reply: the next line sent that matches the regular expression ``pattern`` is dropped."""
        with self._lock:
            self._drop_patterns.append(re.compile(pattern))

    @property
    def table_angle_deg(self) -> float:
        """Physical table angle in degrees from the home switch (what a camera sees), now."""
        with self._lock:
            self._advance(self._now())
            return self.table / self.steps_per_degree

    @property
    def is_moving(self) -> bool:
        """True while the motor is commanded to move (Run, Home, or a stalled Run)."""
        with self._lock:
            self._advance(self._now())
            return self.state in ("Run", "Home")

    def settled(self) -> bool:
        """True when every byte a client sent has been read and answered (replies the mechanics defer aside).

        A driver's reply deadline may rely on it (``GrblTurntable(settled=...)``):
        past it, a reply not received is one the firmware never sent or the line lost.
        """
        with self._lock:  # the serving thread reads and answers a chunk under this lock
            if self._master is None:
                return True
            ready, _, _ = select.select([self._master], [], [], 0)
            return not ready

    @property
    def connected(self) -> bool:
        with self._lock:
            return self._master is not None

    def _now(self) -> float:
        """The mechanics clock: virtual (``tick_s``) or ``time.monotonic()``."""
        return self._vclock if self.tick_s is not None else time.monotonic()

    def _schedule(self, stream: str, index) -> random.Random:
        """The generator of one scheduled decision: a function of ``(seed, stream, index)`` only."""
        return random.Random(f"{self.seed}/{stream}/{index}")

    # -- pty ----------------------------------------------------------------------------------
    def _open_pty(self) -> None:
        master, slave = os.openpty()
        tty.setraw(slave)  # no echo, no newline translation: a UART is a byte pipe
        os.set_blocking(master, False)
        self._master, self._slave = master, slave
        tmp = self._dir / "ttyGRBL.new"
        if tmp.is_symlink():
            tmp.unlink()
        os.symlink(os.ttyname(slave), tmp)
        os.replace(tmp, self.port)

    def _close_pty(self) -> None:
        for fd in (self._master, self._slave):
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self._master = self._slave = None

    def _baud_matches(self) -> bool:
        try:
            return termios.tcgetattr(self._slave)[4] == self._baud_flag
        except (termios.error, TypeError):
            return True

    # -- serving ------------------------------------------------------------------------------
    def _serve(self) -> None:
        while not self._stop.is_set():
            with self._lock:
                now = time.monotonic()
                self._advance(self._now())
                if self._master is None and self._reconnect_at is not None and now >= self._reconnect_at:
                    self._reconnect()
                master = self._master
                wait = self._next_wakeup(now)
            fds = [self._wake_r] + ([master] if master is not None else [])
            try:
                ready, _, _ = select.select(fds, [], [], wait)
            except (OSError, ValueError):
                continue
            if self._wake_r in ready:
                os.read(self._wake_r, 64)
            if master is not None and master in ready:
                with self._lock:
                    if self._master != master:
                        continue
                    try:
                        data = os.read(master, 4096)
                    except BlockingIOError:
                        continue
                    except OSError:
                        data = b""
                    self._advance(self._now())
                    self._receive(data)

    def _next_wakeup(self, now: float) -> float:
        times = [now + 0.05]
        if self._reconnect_at is not None:
            times.append(self._reconnect_at)
        if self.tick_s is None:  # real-time mechanics: wake for their events too
            if self._active is not None and self._active.end_time() is not None:
                times.append(self._active.end_time())
            if self._homing_done_at is not None:
                times.append(self._homing_done_at)
            if self._pending_event is not None:
                times.append(self._pending_event[0])
        return max(0.0, min(times) - now)

    def _send(self, text: str, *, faultable: bool = True) -> None:
        data = text.encode("ascii") + b"\r\n"
        index = (self._epoch, self._sent_in_epoch)
        self._sent_in_epoch += 1
        if faultable:
            for pattern in self._drop_patterns:
                if pattern.search(text):
                    self._drop_patterns.remove(pattern)
                    self._log("drop", "scripted")
                    return
            kind, rng = self._line_fault(index)
            if kind == "drop":
                return
            if kind == "garble":
                data = self._garble(data, rng)
        if self.late_replies and self._schedule("late", index).random() < self.late_replies:
            time.sleep(self.late_reply_s)  # holding the lock: the client's settled() waits for this line too
        self._write(data)

    def _write(self, data: bytes) -> None:
        if self._master is None:
            return
        if not self._baud_matches():
            data = bytes(self._noise_rng.randrange(128, 256) for _ in data)
        try:
            os.write(self._master, data)
        except OSError:  # tty buffer full (nobody reading): bytes lost like a UART overrun
            pass

    def _log(self, kind: str, where) -> None:
        self.fault_counts[kind] += 1
        self.fault_log.append((kind, where))

    def _line_fault(self, index: tuple[int, int]) -> tuple[str | None, random.Random]:
        """The fault (``"drop"``, ``"garble"`` or None) scheduled for the reply line at ``index``."""
        rng = self._schedule("tx", index)
        u_drop, u_garble = rng.random(), rng.random()
        if self._forced and self._forced[0] in LINE_FAULTS:
            kind, where = self._forced.popleft(), "forced"
        elif u_drop < self.faults.drop:
            kind, where = "drop", index
        elif u_garble < self.faults.garble:
            kind, where = "garble", index
        else:
            return None, rng
        self._log(kind, where)
        return kind, rng

    @staticmethod
    def _garble(data: bytes, rng: random.Random) -> bytes:
        out = bytearray(data)
        for _ in range(rng.randint(1, 3)):
            i = rng.randrange(len(out) - 2 or 1)
            out[i] = rng.choice(b"~#%&*@\x00\xff\x7f0123456789.:|<>")
        return bytes(out)

    def _receive(self, data: bytes) -> None:
        if not data:
            return
        if not self._baud_matches():  # framing errors: the board sees noise and answers noise
            self._write(bytes(len(data)))
            return
        for byte in data:
            ch = bytes([byte])
            if self.foreign_reply is not None:
                if ch in (b"\n", gp.RESET):
                    self._send(self.foreign_reply, faultable=False)
                continue
            if ch == gp.RESET:
                self._new_epoch()
                self._soft_reset()
            elif ch == gp.STATUS_QUERY:
                if self.tick_s is not None:
                    self._vclock += self.tick_s
                    self._advance(self._vclock)
                self._report_status()
            elif ch == gp.FEED_HOLD:
                self._feed_hold()
            elif ch == gp.CYCLE_START:
                self._cycle_start()
            elif ch in (b"\n", b"\r"):
                # like GRBL, every line end (\r or \n) ends a line, and an empty line is answered "ok";
                # it runs before any byte after it (so replies depend on the byte order, not on the chunking)
                self._pending_lines.append(self._line_buf.decode("ascii", errors="replace"))
                self._line_buf.clear()
                self._run_pending_lines()
            else:
                self._line_buf += ch

    def _new_epoch(self) -> None:
        self._epoch += 1
        self._sent_in_epoch = 0

    def _run_pending_lines(self) -> None:
        while self._pending_lines and self.state != "Home":
            line = self._pending_lines.popleft()
            self._new_epoch()
            if self._critical:
                continue  # GRBL ignores everything but reset after a hard alarm
            index = self._lines_received
            self._lines_received += 1
            line = self._noisy_line(line, index)
            self._execute(_normal(line))

    def _noisy_line(self, line: str, index: int) -> str:
        """A received line after line noise: a scripted rewrite, or the garble scheduled for line ``index``."""
        for rule in self._rewrites:
            old, new, drop_ok = rule
            if _normal(line) == old:
                self._rewrites.remove(rule)
                self._log("garble", "scripted")
                if drop_ok:
                    self._drop_patterns.insert(0, re.compile(r"^ok$"))
                return new
        rng = self._schedule("rx", index)
        if line.strip() and rng.random() < self.faults.garble:
            self._log("garble", ("rx", index))
            chars = list(line)
            chars[rng.randrange(len(chars))] = rng.choice("9#X.")
            return "".join(chars)
        return line

    # -- firmware -----------------------------------------------------------------------------
    def _boot_messages(self) -> None:
        self._write(b"\r\n")
        self._send("Grbl 1.1h ['$' for help]")
        if self.state == "Alarm":
            self._send("[MSG:'$H'|'$X' to unlock]")

    def _mpos(self) -> float:
        return (self.motor - self.counter_zero) / self._settings[100]

    def _report_status(self) -> None:
        state = self.state
        sub = 0 if state in ("Hold", "Door") else None
        self._send(gp.format_status(state, self._mpos(), sub))

    def _soft_reset(self) -> None:
        if self.state in ("Run", "Home"):
            code = 3 if self.state == "Run" else 6
            self._send(f"ALARM:{code}")
            self.state = "Alarm"
        self._active = None
        self._queue.clear()
        self._pending_lines.clear()
        self._line_buf.clear()
        self._homing_done_at = None
        self._pending_event = None
        self._critical = False
        if self.state != "Alarm":
            self.state = "Idle"
        self._boot_messages()

    def _feed_hold(self) -> None:
        if self.state == "Run" and self._active is not None:
            seg = self._active
            if seg.stall_after is not None:
                return  # a hung controller does not react to feed hold
            self._queue.appendleft(seg.target)
            self._active = None
            self.state = "Hold"

    def _cycle_start(self) -> None:
        if self.state == "Hold":
            self.state = "Idle"
            self._start_next(self._now())

    def _execute(self, line: str) -> None:
        if line == "":
            self._send("ok")
        elif line.startswith("$"):
            self._dollar(line)
        elif self.state == "Alarm":
            self._send("error:9")
        else:
            self._gcode(line)

    def _dollar(self, line: str) -> None:
        if line == "$$":
            for key, value in sorted(self._settings.items()):
                self._send(f"${key}={value:.3f}" if key >= 100 else f"${key}={int(value)}")
            self._send("ok")
        elif line == "$X":
            if self.state == "Alarm":
                self.state = "Idle"
                self._send("[MSG:Caution: Unlocked]")
            self._send("ok")
        elif line == "$H":
            if self.state not in ("Idle", "Alarm"):
                self._send("error:8")
                return
            self.state = "Home"
            self._homing_done_at = self._now() + self.homing_time_s
        elif m := re.fullmatch(r"\$(\d+)=([-+]?\d*\.?\d+)", line):
            key, value = int(m.group(1)), float(m.group(2))
            if self.state not in ("Idle", "Alarm"):
                self._send("error:8")
            elif value < 0:
                self._send("error:4")
            elif key in (100, 110) and value == 0:
                self._send("error:3")
            else:
                self._settings[key] = value
                self._send("ok")
        else:
            self._send("error:3")

    def _gcode(self, line: str) -> None:
        words = _WORD_RE.findall(line)
        if not words or "".join(a + b for a, b in words) != line:
            self._send("error:1" if not line[:1].isalpha() else "error:2")
            return
        target = None
        rapid = True
        for letter, value in words:
            v = float(value)
            if letter == "G":
                if v in (90.0, 91.0):
                    self._absolute = v == 90.0
                elif v in (0.0, 1.0):
                    rapid = v == 0.0
                elif v not in (21.0, 94.0):
                    self._send("error:20")
                    return
            elif letter == "X":
                target = v
            elif letter == "F":
                if v <= 0:
                    self._send("error:4")
                    return
                self._feed_set = True
            else:
                self._send("error:20")
                return
        if not rapid and not self._feed_set:
            self._send("error:22")
            return
        if target is not None:
            base = self._queue[-1] if self._queue else (self._active.target if self._active else self.motor)
            steps = int(round(target * self._settings[100]))  # GRBL: lround(target * steps_per_mm)
            motor_target = self.counter_zero + steps if self._absolute else base + steps
            self._queue.append(motor_target)
            if self.state == "Idle":
                self._start_next(self._now())
        self._send("ok")

    def _motion_fault(self) -> tuple[str | None, float]:
        """The fault scheduled for the next planned move, and the fraction of the move where it strikes."""
        index = self._moves_planned
        self._moves_planned += 1
        rng = self._schedule("move", index)
        draws = [rng.random() for _ in MOTION_FAULTS]
        frac = rng.uniform(0.1, 0.9)
        if self._forced and self._forced[0] in MOTION_FAULTS:
            kind, where = self._forced.popleft(), "forced"
        else:
            kind = next((k for k, u in zip(MOTION_FAULTS, draws) if u < getattr(self.faults, k)), None)
            where = ("move", index)
        if kind is not None:
            self._log(kind, where)
        return kind, frac

    def _start_next(self, t0: float) -> None:
        while self._queue:
            target = self._queue.popleft()
            if target == self.motor:
                continue
            rate = self._settings[110] / 60.0 * self.steps_per_degree
            seg = _Segment(self.motor, target, t0, rate)
            kind, frac = self._motion_fault()
            if kind == "slow":
                seg.steps_per_s = rate / self.slow_factor
            elif kind == "stall":
                seg.stall_after = int(frac * seg.total)
            elif kind in ("alarm", "disconnect"):
                self._pending_event = (t0 + frac * seg.total / rate, kind)
            self._active = seg
            self.state = "Run"
            return
        self._active = None
        self.state = "Idle"

    def _move_motor(self, new_motor: int) -> None:
        if new_motor > self.motor:
            self.table = max(self.table, new_motor)
        elif new_motor < self.motor:
            self.table = min(self.table, new_motor + self.play)
        self.motor = new_motor

    def _advance(self, now: float) -> None:
        """Bring mechanics and firmware state up to time ``now`` (events in time order)."""
        while True:
            event_t = self._pending_event[0] if self._pending_event else math.inf
            seg = self._active
            seg_end = seg.end_time() if seg is not None else None
            if self.state == "Home" and self._homing_done_at is not None and self._homing_done_at <= now:
                self._homing_done_at = None
                self._move_motor(-(self.play + 50))  # seek the switch from +, then pull off with a + approach
                self._move_motor(0)
                self.counter_zero = 0
                self.state = "Idle"
                self._send("ok")
                self._run_pending_lines()
                continue
            if seg is None:
                if self._pending_event is not None and event_t <= now and self.state != "Run":
                    self._pending_event = None
                return
            if event_t <= now and (seg_end is None or event_t <= seg_end):
                self._move_motor(seg.start + seg.direction * seg.steps_done(event_t))
                kind = self._pending_event[1]
                self._pending_event = None
                self._active = None
                self._queue.clear()
                if kind == "alarm":
                    self.state = "Alarm"
                    self._critical = True
                    self._send("ALARM:1", faultable=False)
                    self._send("[MSG:Reset to continue]", faultable=False)
                else:
                    self._disconnect(now)
                continue
            if seg_end is not None and seg_end <= now:
                self._move_motor(seg.target)
                self._start_next(seg_end)
                continue
            self._move_motor(seg.start + seg.direction * seg.steps_done(now))
            return

    def _disconnect(self, now: float) -> None:
        self.state = "Off"
        self._close_pty()
        self._reconnect_at = time.monotonic() + self.reconnect_delay_s  # the USB bus runs in real time

    def _reconnect(self) -> None:
        """The board powers up again: counter zero here, homing lock, greeting on a fresh pty."""
        self._reconnect_at = None
        self._new_epoch()
        self.counter_zero = self.motor
        self._queue.clear()
        self._pending_lines.clear()
        self._line_buf.clear()
        self._critical = False
        self.state = "Alarm"
        self._open_pty()
        self._boot_messages()


def _normal(line: str) -> str:
    """A command line as the firmware reads it: surrounding and inner spaces removed, upper case."""
    return line.strip().upper().replace(" ", "")
