"""Random-fault soak of the GRBL turntable driver against the firmware simulator, over a real pty.

:func:`fault_soak` drives :class:`brdfrig.rig.turntable.GrblTurntable` to random
targets while :class:`brdfrig.sim.grbl.GrblSimulator` injects faults from its
seeded, count-indexed schedule (virtual clock, and the driver's reply
deadlines wait for the simulator to settle, so neither the schedule nor the
exchange depends on the machine's load), re-homing after every error, until ``n_faults`` faults
have been injected.  After every confirmation (a move's return value, a
home, a position still claimed after an error) it compares the claim with the
simulator's physical table angle: the driver's promise is that no claim is
ever off by more than one motor step.  Used by ``tests/test_turntable.py``
and ``benchmarks/bench_turntable_faults.py``.
"""

from __future__ import annotations

import random
import time
from collections import Counter
from dataclasses import dataclass, field

from brdfrig.rig.errors import RigError
from brdfrig.rig.turntable import GrblTurntable
from brdfrig.sim.grbl import FaultRates, GrblSimulator

__all__ = ["SOAK_RATES", "SOAK_DRIVER_TIMING", "SoakResult", "fault_soak"]

#: Fault probabilities of the soak: every kind the simulator knows, often.
SOAK_RATES = FaultRates(drop=0.06, garble=0.06, stall=0.1, slow=0.1, disconnect=0.06, alarm=0.1)

#: Driver timing for the fast simulator: every wait is short so that a fault costs milliseconds.  With the
#: simulator's ``settled`` the reply deadlines pass only once it has answered everything, and motion and homing
#: waits are counted in polls, so the exchange does not depend on how loaded the machine is.  Only waiting for a
#: disconnected port to reappear is real time (up to 50 x 20 ms; how many looks it takes is journalled).
SOAK_DRIVER_TIMING = dict(poll_interval_s=0.001, reply_timeout_s=0.015, stall_timeout_s=0.015, move_margin_s=0.1,
                          resync_quiet_s=0.005, reconnect_delay_s=0.02, reconnect_attempts=50,
                          connect_timeout_s=0.1, homing_timeout_s=0.1)


@dataclass
class SoakResult:
    """What a soak did and found.

    ``wrong`` lists every false claim as ``(what, claimed_deg, table_deg)``;
    ``left_moving`` counts errors after which the table was still moving;
    ``fault_log`` is the simulator's (see ``GrblSimulator.fault_log``).
    """

    seed: int
    faults: Counter = field(default_factory=Counter)
    outcomes: Counter = field(default_factory=Counter)
    wrong: list[tuple[str, float, float]] = field(default_factory=list)
    left_moving: int = 0
    journal: Counter = field(default_factory=Counter)
    fault_log: list = field(default_factory=list)
    elapsed_s: float = 0.0

    @property
    def n_faults(self) -> int:
        return sum(self.faults.values())


def fault_soak(n_faults: int, seed: int, *, steps_per_degree: float = 80.0, backlash_deg: float = 0.5,
               rates: FaultRates = SOAK_RATES, max_homing_attempts: int = 30,
               timing: dict = SOAK_DRIVER_TIMING, late_replies: float = 0.0) -> SoakResult:
    """Run random moves until the simulator has injected ``n_faults`` faults; see the module docstring.

    ``seed`` fixes the targets and the simulator's fault schedule; ``timing`` is
    the driver's; ``late_replies`` the fraction of reply lines the simulator holds
    back (``GrblSimulator(late_replies=...)``), which must not change the run.
    Raises ``RuntimeError`` if the table cannot be homed again in ``max_homing_attempts``.
    """
    result = SoakResult(seed)
    step = 1.0 / steps_per_degree
    rng = random.Random(seed)
    t0 = time.monotonic()

    def check(what: str, claimed: float | None, sim: GrblSimulator) -> None:
        if claimed is not None and abs(sim.table_angle_deg - claimed) > step + 1e-9:
            result.wrong.append((what, claimed, sim.table_angle_deg))

    def journal(event: str, **_fields) -> None:
        result.journal[event] += 1

    with GrblSimulator(steps_per_degree=steps_per_degree, backlash_deg=backlash_deg, max_rate_deg_s=1e5,
                       homing_time_s=0.002, reconnect_delay_s=0.01, seed=seed, tick_s=0.001,
                       late_replies=late_replies) as sim:
        table = GrblTurntable(sim.port, 115200, steps_per_degree, backlash_deg, journal=journal,
                              settled=sim.settled, **timing)
        table.connect()
        table.home()
        sim.set_faults(rates)
        try:
            while sum(sim.fault_counts.values()) < n_faults:
                target = rng.uniform(-90.0, 270.0)
                try:
                    reported = table.move_to(target)
                    result.outcomes["reached"] += 1
                    check(f"move_to({target:.4f})", reported, sim)
                    continue
                except RigError as exc:
                    result.outcomes[type(exc).__name__] += 1
                    result.left_moving += sim.is_moving
                    check(f"position after {type(exc).__name__}", table.position_deg, sim)
                for _ in range(max_homing_attempts):
                    try:
                        check("home()", table.home(), sim)
                        break
                    except RigError:
                        result.outcomes["home retried"] += 1
                else:
                    raise RuntimeError(f"could not home again after {max_homing_attempts} attempts (seed {seed})")
        finally:
            table.close()
        result.faults = Counter(sim.fault_counts)
        result.fault_log = list(sim.fault_log)
    result.elapsed_s = time.monotonic() - t0
    return result
