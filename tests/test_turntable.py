"""GRBL turntable driver against the firmware simulator, over real pyserial on a real pseudo-terminal."""

from __future__ import annotations

import random
import time

import pytest

from brdfrig.rig.errors import DeviceBusy, DeviceNotFound, DeviceRefused, DeviceTimeout, RigError
from brdfrig.rig.grbl_protocol import parse_reply
from brdfrig.rig.turntable import GrblTurntable, Turntable
from brdfrig.sim.grbl import FaultRates, GrblSimulator
from brdfrig.sim.soak import SOAK_DRIVER_TIMING, fault_soak

SPD = 80.0  # steps per degree: 1.8 deg motor, 16 microsteps, 1:2 belt... (0.0125 deg per step)
STEP = 1.0 / SPD

# Driver timing for a fast simulator: every wait is short so that faults cost milliseconds; with the simulator's
# ``settled`` (passed wherever a simulator serves) a short reply deadline never fires while a reply is on its way.
FAST = SOAK_DRIVER_TIMING
# Generous deadlines for tests that inject no faults (a loaded CI machine must not cause spurious timeouts).
SAFE = {**FAST, "reply_timeout_s": 1.0, "stall_timeout_s": 1.0, "move_margin_s": 2.0, "connect_timeout_s": 2.0,
        "homing_timeout_s": 2.0}


def fast_sim(**kw) -> GrblSimulator:
    """A fast simulator; homing lasts 2 status polls on the virtual clock (``tick_s``), 20 ms in real time.

    Tests whose subject is not the wall clock pass ``tick_s``: homing and motion then advance per status report,
    whatever the machine's load."""
    opts = dict(steps_per_degree=SPD, backlash_deg=0.5, max_rate_deg_s=1e5,
                homing_time_s=0.002 if kw.get("tick_s") else 0.02, reconnect_delay_s=0.01)
    opts.update(kw)
    return GrblSimulator(**opts)


def test_reply_parser_classifies_grbl_lines():
    assert parse_reply("ok").kind == "ok"
    assert parse_reply("error:9").code == 9
    assert parse_reply("ALARM:1").kind == "alarm"
    st = parse_reply("<Hold:0|MPos:-12.500,0.000,0.000|FS:0,0>").status
    assert (st.state, st.substate, st.mpos) == ("Hold", 0, -12.5)
    assert parse_reply("Grbl 1.1h ['$' for help]").kind == "greeting"
    assert parse_reply("$100=80.000").setting == (100, 80.0)
    for junk in ("o#", "<Idle|MPos:1.0#0,0.000,0.000>", "<Idle|MPos:12.3\ufffd,0.000,0.000|FS:0,0>", "error:x"):
        assert parse_reply(junk).kind == "garbage", junk


def test_home_move_and_readback_match_the_mechanics():
    with fast_sim(max_rate_deg_s=3600.0) as sim, GrblTurntable(sim.port, 115200, SPD, 0.5, **SAFE) as table:
        assert isinstance(table, Turntable)
        assert table.position_deg is None  # nothing confirmed before homing
        with pytest.raises(DeviceRefused, match="not homed"):
            table.move_to(10.0)
        assert table.home() == 0.0 and sim.table_angle_deg == 0.0
        t0 = time.monotonic()
        assert table.move_to(90.0) == 90.0
        assert time.monotonic() - t0 >= 90.0 / 3600.0  # the motion took (simulated) time
        assert sim.table_angle_deg == 90.0
        # going down, the driver overshoots by the play and comes back up: the table lands on target
        assert table.move_to(45.0) == 45.0 and sim.table_angle_deg == 45.0
        assert table.move_to(45.3) == pytest.approx(45.3, abs=STEP / 2)
        assert abs(sim.table_angle_deg - 45.3) <= STEP / 2
        table.stop()
        assert not sim.is_moving
        assert table.position_deg is None  # with play, a stop leaves the angle known only within the play


def test_without_compensation_the_simulated_play_shows():
    """Oracle for the mechanics: coming down without compensation leaves the table ``play`` above target."""
    with fast_sim(tick_s=0.001) as sim, GrblTurntable(sim.port, 115200, SPD, 0.0, **SAFE) as table:
        table.home()
        table.move_to(30.0)
        table.move_to(20.0)
        assert sim.table_angle_deg == pytest.approx(20.5, abs=1e-9)
        table.stop()  # no play configured: the stopped position stays confirmed
        assert table.position_deg == 20.0 and not sim.is_moving


def test_simulator_and_driver_agree_after_3000_random_moves_with_backlash():
    rng = random.Random(7)
    with fast_sim(backlash_deg=0.75, max_rate_deg_s=1e7, tick_s=0.001) as sim, \
            GrblTurntable(sim.port, 115200, SPD, 0.75, **SAFE) as table:
        table.home()
        worst = 0.0
        for _ in range(3000):
            reported = table.move_to(rng.uniform(-720.0, 720.0))
            worst = max(worst, abs(reported - sim.table_angle_deg))
        print(f"3000 moves: worst |driver - mechanics| = {worst / STEP:.3f} steps")
        assert worst <= STEP + 1e-9


@pytest.mark.parametrize("seed", [11, 12])
def test_random_faults_never_yield_a_wrong_confirmed_position(seed):
    """Seeded fault schedule (count-indexed, virtual clock): every claim checked against the mechanics.

    CI runs 2 x 400 faults; ``benchmarks/bench_turntable_faults.py`` runs 10,000.
    """
    result = fault_soak(400, seed)
    print(f"seed {seed}: faults {dict(result.faults)}; outcomes {dict(result.outcomes)}; "
          f"journal {dict(result.journal)}; {result.elapsed_s:.1f} s")
    assert result.wrong == [] and result.left_moving == 0
    assert result.n_faults >= 400
    assert all(result.faults[k] >= 5 for k in ("drop", "garble", "stall", "slow", "disconnect", "alarm"))
    assert result.outcomes["reached"] > 80 and result.outcomes["DeviceTimeout"] > 0
    assert result.outcomes["DeviceRefused"] > 0 and result.outcomes["DeviceDisconnected"] > 0
    # every retry the driver made was journalled
    assert result.journal["turntable_resync"] > 0 and result.journal["turntable_reapproach"] > 0


def test_late_replies_do_not_change_the_exchange():
    """Replies held back 40 ms (beyond the 15 ms reply timeout: a loaded machine) on 5% of the lines.

    The seed must replay the same run: the same faults at the same schedule indices (any byte sent
    differently shifts them), the same outcomes and journal (bar how many looks a reconnecting port
    took to reappear, which is real time), no wrong confirmation.
    """
    prompt, late = fault_soak(60, 21), fault_soak(60, 21, late_replies=0.05)
    assert len(prompt.fault_log) >= 60 and prompt.fault_log == late.fault_log
    for run in (prompt, late):
        del run.journal["turntable_reconnect"]
    assert prompt.outcomes == late.outcomes and prompt.journal == late.journal
    assert prompt.wrong == late.wrong == [] and prompt.left_moving == late.left_moving == 0


def _bytes_script(sim: GrblSimulator) -> tuple[bytes, list]:
    """Send a fixed byte sequence to ``sim`` (reset, settings, homing, moves, status polls); return what came back."""
    import serial

    script = [b"\x18", b"$$\n", b"$H\n"] + [b"?"] * 5
    for i in range(12):
        script += [f"G90 G0 X{(37 * i) % 200 - 50:.6f}\n".encode()] + [b"?"] * 6
    received = bytearray()
    with serial.Serial(sim.port, 115200, timeout=0.005) as port:
        for chunk in script:
            port.write(chunk)
            received += port.read(4096)  # keep the pty drained; the replies depend only on the bytes sent
        port.timeout = 0.05
        while data := port.read(4096):
            received += data
    return bytes(received), list(sim.fault_log)


def test_fault_schedule_depends_only_on_the_seed_and_the_bytes_sent():
    rates = FaultRates(drop=0.15, garble=0.15, slow=0.3)
    runs = []
    for seed in (5, 5, 6):
        with fast_sim(seed=seed, tick_s=0.001, faults=rates) as sim:
            runs.append(_bytes_script(sim))
    (out_a, log_a), (out_b, log_b), (_, log_c) = runs
    assert len(log_a) >= 10 and {k for k, _ in log_a} == {"drop", "garble", "slow"}
    assert log_a == log_b and out_a == out_b  # the same run meets the same faults, byte for byte
    assert log_c != log_a  # and the seed is what chooses them


@pytest.mark.parametrize("target, noise", [(-67.15, "X967.150000"), (45.0, "X95.000000")])
def test_resent_final_approach_is_approached_again_from_below(target, noise):
    """Line noise turns the final approach into another valid move and its ``ok`` is lost (issue 11, 1a).

    The firmware then runs pre-move -> wrong target -> true target, the last
    segment downward, so the table stands one backlash above the target while
    the motor reads the target.  The driver must approach again from below.
    """
    events = []
    with fast_sim(tick_s=0.001) as sim, GrblTurntable(sim.port, 115200, SPD, 0.5, settled=sim.settled, **FAST,
                                                     journal=lambda e, **f: events.append((e, f))) as table:
        table.home()
        table.move_to(100.0)
        final = f"G90 G0 X{target:.6f}"
        sim.rewrite_command(final, final.split(" X")[0] + " " + noise, drop_ok=True)
        assert table.move_to(target) == target
        assert abs(sim.table_angle_deg - target) <= STEP / 2, sim.table_angle_deg
        assert table.position_deg == target
    assert sim.fault_log == [("garble", "scripted"), ("drop", "scripted")]
    names = [e for e, _ in events]
    assert ("turntable_resync", final) in [(e, f.get("command")) for e, f in events]
    assert "turntable_reapproach" in names[names.index("turntable_resync"):]


def test_garbled_home_after_power_up_is_not_confirmed():
    """After a disconnect the board counts from 0 where it stands; ``$H`` garbled into ``$X`` with the
    ``[MSG:Caution: Unlocked]`` line lost must not be taken for a homing cycle (issue 11, 1b)."""
    events = []
    with fast_sim(tick_s=0.001) as sim:
        table = GrblTurntable(sim.port, 115200, SPD, 0.5, settled=sim.settled, **FAST,
                              journal=lambda e, **f: events.append((e, f)))
        table.connect()
        table.home()
        table.move_to(65.85)
        sim.inject("disconnect")
        with pytest.raises(RigError):
            table.move_to(200.0)
        assert table.position_deg is None
        lost_at = sim.table_angle_deg
        assert lost_at > 65.85 + 1.0  # the board powered up away from home, counting from 0 there
        sim.rewrite_command("$H", "$X")
        sim.drop_reply("Unlocked")
        assert table.home() == 0.0
        assert abs(sim.table_angle_deg) <= STEP / 2, f"confirmed home with the table at {sim.table_angle_deg}"
        assert table.move_to(30.0) == 30.0 and abs(sim.table_angle_deg - 30.0) <= STEP / 2
        table.close()
    retries = [f for e, f in events if e == "turntable_home_retry"]
    assert len(retries) == 1 and "homing cycle" in retries[0]["reason"], retries


def test_the_port_is_opened_exclusively():
    with fast_sim(tick_s=0.001) as sim, GrblTurntable(sim.port, 115200, SPD, **SAFE) as table:
        table.home()
        with pytest.raises(DeviceBusy, match="in use by another process"):
            GrblTurntable(sim.port, 115200, SPD, **{**FAST, "reconnect_attempts": 1}).connect()
        assert table.move_to(5.0) == 5.0  # the holder is undisturbed


@pytest.mark.parametrize("fault, error", [("stall", DeviceTimeout), ("alarm", DeviceRefused)])
def test_injected_motion_fault_stops_the_table_and_forgets_the_position(fault, error):
    with fast_sim(max_rate_deg_s=2000.0) as sim, \
            GrblTurntable(sim.port, 115200, SPD, 0.5, settled=sim.settled, **FAST) as table:
        table.home()
        sim.inject(fault)
        with pytest.raises(error):
            table.move_to(300.0)
        assert not sim.is_moving
        assert table.position_deg is None and not table.homed
        with pytest.raises(DeviceRefused, match="not homed"):
            table.move_to(1.0)
        table.home()
        assert table.move_to(12.5) == 12.5 and sim.table_angle_deg == 12.5


def test_lost_and_garbled_replies_are_retried_transparently():
    with fast_sim() as sim, GrblTurntable(sim.port, 115200, SPD, 0.5, settled=sim.settled, **FAST) as table:
        table.home()
        for fault in ("drop", "garble", "drop", "garble", "slow"):
            sim.inject(fault)
            target = 10.0 + 7.0 * len(sim.fault_counts)
            assert table.move_to(target) == target and sim.table_angle_deg == target


def test_disconnect_during_move_then_reconnect_by_homing():
    with fast_sim(max_rate_deg_s=2000.0, reconnect_delay_s=0.05) as sim:
        table = GrblTurntable(sim.port, 115200, SPD, 0.5, settled=sim.settled, **FAST)
        table.connect()
        table.home()
        sim.inject("disconnect")
        with pytest.raises(RigError):
            table.move_to(200.0)
        assert table.position_deg is None
        assert sim.fault_counts["disconnect"] == 1
        table.home()  # reopens the port: the board came back (new pty) behind the same path
        assert table.move_to(33.0) == 33.0 and sim.table_angle_deg == 33.0
        table.close()


# ------------------------------------------------------------------------------- bad input
def test_wrong_port_names_the_setting():
    table = GrblTurntable("/dev/does-not-exist-brdfrig", 115200, SPD, **{**FAST, "reconnect_attempts": 1})
    with pytest.raises(DeviceNotFound, match="port.*does-not-exist"):
        table.connect()


def test_wrong_baud_names_the_setting_and_leaves_the_table_stopped():
    with fast_sim(baud=115200) as sim:
        with pytest.raises(DeviceNotFound, match="'baud'"):
            GrblTurntable(sim.port, 9600, SPD, settled=sim.settled, **FAST).connect()
        assert not sim.is_moving


def test_a_device_answering_something_else_is_named():
    with fast_sim(foreign_reply="echo:Unknown command") as sim:
        with pytest.raises(DeviceNotFound, match="not a GRBL 1.1 controller.*Unknown command"):
            GrblTurntable(sim.port, 115200, SPD, settled=sim.settled, **FAST).connect()


def test_silent_port_times_out_naming_the_port():
    sim = fast_sim()  # never started: the pty exists but nobody answers
    try:
        with pytest.raises(DeviceTimeout, match="'port'"):
            GrblTurntable(sim.port, 115200, SPD, **FAST).connect()
    finally:
        sim.close()


@pytest.mark.parametrize("kwargs, name", [
    ({"steps_per_degree": -80.0}, "steps_per_degree"),
    ({"steps_per_degree": 0.0}, "steps_per_degree"),
    ({"steps_per_degree": float("nan")}, "steps_per_degree"),
    ({"backlash_deg": -0.1}, "backlash_deg"),
    ({"baud": 0}, "baud"),
    ({"retries": -1}, "retries"),
    ({"reply_timeout_s": 0.0}, "reply_timeout_s"),
])
def test_impossible_settings_are_refused_before_touching_the_port(kwargs, name):
    args = {"port": "/dev/null", "baud": 115200, "steps_per_degree": SPD, **kwargs}
    with pytest.raises(ValueError, match=name):
        GrblTurntable(**args)


def test_non_finite_target_is_refused_and_table_stays_put():
    with fast_sim(tick_s=0.001) as sim, GrblTurntable(sim.port, 115200, SPD, **SAFE) as table:
        table.home()
        table.move_to(5.0)
        with pytest.raises(ValueError, match="angle"):
            table.move_to(float("inf"))
        assert sim.table_angle_deg == 5.0 and table.position_deg == 5.0


def test_firmware_steps_per_unit_is_corrected_on_connect():
    with fast_sim(firmware_steps_per_degree=250.0, tick_s=0.001) as sim, \
            GrblTurntable(sim.port, 115200, SPD, **SAFE) as table:
        table.home()
        assert table.move_to(90.0) == 90.0 and sim.table_angle_deg == 90.0


def test_readline_deadline_holds_while_garbage_trickles_in():
    """pyserial's own readline restarts its timeout on every byte; the link's overall deadline must not."""
    import os
    import threading
    import tty

    from brdfrig.rig.serial_link import SerialLink

    master, slave = os.openpty()
    tty.setraw(slave)
    stop = threading.Event()

    def trickle():
        while not stop.is_set():
            os.write(master, b"#")
            time.sleep(0.005)

    thread = threading.Thread(target=trickle)
    thread.start()
    try:
        with SerialLink(os.ttyname(slave), 115200) as link:
            t0 = time.monotonic()
            with pytest.raises(DeviceTimeout):
                link.readline(time.monotonic() + 0.2)
            assert time.monotonic() - t0 < 5.0  # the trickle never ends: without the deadline this never returns
    finally:
        stop.set()
        thread.join()
        os.close(master)
        os.close(slave)
