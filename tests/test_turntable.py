"""GRBL turntable driver against the firmware simulator, over real pyserial on a real pseudo-terminal."""

from __future__ import annotations

import random
import time
from collections import Counter

import pytest

from brdfrig.rig.errors import DeviceNotFound, DeviceRefused, DeviceTimeout, RigError
from brdfrig.rig.grbl_protocol import parse_reply
from brdfrig.sim.grbl import FaultRates, GrblSimulator
from brdfrig.rig.turntable import GrblTurntable, Turntable

SPD = 80.0  # steps per degree: 1.8 deg motor, 16 microsteps, 1:2 belt... (0.0125 deg per step)
STEP = 1.0 / SPD

# Driver timing for a fast simulator: every wait is short so that faults cost milliseconds.
FAST = dict(poll_interval_s=0.001, reply_timeout_s=0.015, stall_timeout_s=0.015, move_margin_s=0.1,
            resync_quiet_s=0.005, reconnect_delay_s=0.02, reconnect_attempts=5, connect_timeout_s=0.1,
            homing_timeout_s=0.1)
# Generous deadlines for tests that inject no faults (a loaded CI machine must not cause spurious timeouts).
SAFE = {**FAST, "reply_timeout_s": 1.0, "stall_timeout_s": 1.0, "move_margin_s": 2.0, "connect_timeout_s": 2.0,
        "homing_timeout_s": 2.0}


def fast_sim(**kw) -> GrblSimulator:
    opts = dict(steps_per_degree=SPD, backlash_deg=0.5, max_rate_deg_s=1e5, homing_time_s=0.002,
                reconnect_delay_s=0.01)
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
    with fast_sim() as sim, GrblTurntable(sim.port, 115200, SPD, 0.0, **SAFE) as table:
        table.home()
        table.move_to(30.0)
        table.move_to(20.0)
        assert sim.table_angle_deg == pytest.approx(20.5, abs=1e-9)
        table.stop()  # no play configured: the stopped position stays confirmed
        assert table.position_deg == 20.0 and not sim.is_moving


def test_simulator_and_driver_agree_after_10000_random_moves_with_backlash():
    rng = random.Random(7)
    with fast_sim(backlash_deg=0.75, max_rate_deg_s=1e7) as sim, GrblTurntable(sim.port, 115200, SPD, 0.75, **SAFE) as table:
        table.home()
        worst = 0.0
        for _ in range(10_000):
            reported = table.move_to(rng.uniform(-720.0, 720.0))
            worst = max(worst, abs(reported - sim.table_angle_deg))
        print(f"10000 moves: worst |driver - mechanics| = {worst / STEP:.3f} steps")
        assert worst <= STEP + 1e-9


def test_1000_random_faults_never_yield_a_wrong_confirmed_position():
    rates = FaultRates(drop=0.06, garble=0.06, stall=0.1, slow=0.1, disconnect=0.06, alarm=0.1)
    outcomes: Counter[str] = Counter()
    rng = random.Random(3)
    with fast_sim(max_rate_deg_s=1e5, seed=11) as sim:
        table = GrblTurntable(sim.port, 115200, SPD, 0.5, **FAST)
        table.connect()
        table.home()
        sim.set_faults(rates)
        while sum(sim.fault_counts.values()) < 1000:
            target = rng.uniform(-90.0, 270.0)
            try:
                reported = table.move_to(target)
            except RigError as exc:
                outcomes[type(exc).__name__] += 1
                assert not sim.is_moving, f"table left moving after {exc!r}"
                if table.position_deg is not None:  # whatever is still claimed must be true
                    assert abs(sim.table_angle_deg - table.position_deg) <= STEP + 1e-9
                for _ in range(30):  # recover (faults stay on)
                    try:
                        table.home()
                        break
                    except RigError:
                        outcomes["home retried"] += 1
                else:
                    pytest.fail("could not home again after 30 attempts")
                continue
            outcomes["reached"] += 1
            assert reported == pytest.approx(round(target * SPD) / SPD, abs=1e-9)
            assert abs(sim.table_angle_deg - reported) <= STEP + 1e-9, (reported, sim.table_angle_deg)
            assert table.position_deg == reported
        table.close()
    print(f"faults injected: {dict(sim.fault_counts)}; outcomes: {dict(outcomes)}")
    assert sum(sim.fault_counts.values()) >= 1000
    assert all(sim.fault_counts[k] > 20 for k in ("drop", "garble", "stall", "slow", "disconnect", "alarm"))
    assert outcomes["reached"] > 200 and outcomes["DeviceTimeout"] > 0 and outcomes["DeviceRefused"] > 0
    assert outcomes["DeviceDisconnected"] > 0


@pytest.mark.parametrize("fault, error", [("stall", DeviceTimeout), ("alarm", DeviceRefused)])
def test_injected_motion_fault_stops_the_table_and_forgets_the_position(fault, error):
    with fast_sim(max_rate_deg_s=2000.0) as sim, GrblTurntable(sim.port, 115200, SPD, 0.5, **FAST) as table:
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
    with fast_sim() as sim, GrblTurntable(sim.port, 115200, SPD, 0.5, **FAST) as table:
        table.home()
        for fault in ("drop", "garble", "drop", "garble", "slow"):
            sim.inject(fault)
            target = 10.0 + 7.0 * len(sim.fault_counts)
            assert table.move_to(target) == target and sim.table_angle_deg == target


def test_disconnect_during_move_then_reconnect_by_homing():
    with fast_sim(max_rate_deg_s=2000.0, reconnect_delay_s=0.05) as sim:
        table = GrblTurntable(sim.port, 115200, SPD, 0.5, **FAST)
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
            GrblTurntable(sim.port, 9600, SPD, **FAST).connect()
        assert not sim.is_moving


def test_a_device_answering_something_else_is_named():
    with fast_sim(foreign_reply="echo:Unknown command") as sim:
        with pytest.raises(DeviceNotFound, match="not a GRBL 1.1 controller.*Unknown command"):
            GrblTurntable(sim.port, 115200, SPD, **FAST).connect()


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
    with fast_sim() as sim, GrblTurntable(sim.port, 115200, SPD, **SAFE) as table:
        table.home()
        table.move_to(5.0)
        with pytest.raises(ValueError, match="angle"):
            table.move_to(float("inf"))
        assert sim.table_angle_deg == 5.0 and table.position_deg == 5.0


def test_firmware_steps_per_unit_is_corrected_on_connect():
    with fast_sim(firmware_steps_per_degree=250.0) as sim, GrblTurntable(sim.port, 115200, SPD, **SAFE) as table:
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
            assert time.monotonic() - t0 < 0.5
    finally:
        stop.set()
        thread.join()
        os.close(master)
        os.close(slave)
