"""Random-fault soak of the turntable driver: N faults over the pty, count the wrong confirmed positions.

    .venv/bin/python benchmarks/bench_turntable_faults.py                 # 10 seeds x 1,000 faults
    .venv/bin/python benchmarks/bench_turntable_faults.py --faults 10000 --seeds 1
    .venv/bin/python benchmarks/bench_turntable_faults.py --faults 100 --seeds 3 4 --replay 2 --late 0.05

Each seed fixes the random targets and the simulator's count-indexed fault
schedule (``brdfrig.sim.soak.fault_soak``).  Prints one line per seed and the
total; exits 1 if any claimed position (move, home, position kept after an
error) was off the simulated table by more than one motor step, or the table
was left moving after an error.  ``--replay K`` runs every seed K times and
says whether the simulator's fault logs were identical (they are however loaded
the machine: the driver's reply deadlines wait for the simulator to settle);
``--late F`` holds back a fraction F of the reply lines 40 ms (beyond the 15 ms
reply timeout) in the replays, which must not change them either.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter

from brdfrig.sim.soak import fault_soak


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--faults", type=int, default=1000, help="faults per seed (default 1000)")
    parser.add_argument("--seeds", type=int, nargs="+", default=list(range(1, 11)), help="seeds (default 1..10)")
    parser.add_argument("--replay", type=int, default=1, help="runs per seed, fault logs compared (default 1)")
    parser.add_argument("--late", type=float, default=0.0, help="fraction of replies held back 40 ms in replays")
    args = parser.parse_args(argv)
    total_faults, outcomes, kinds, wrong, moving = 0, Counter(), Counter(), [], 0
    t0 = time.monotonic()
    for seed in args.seeds:
        runs = [fault_soak(args.faults, seed, late_replies=args.late if i else 0.0) for i in range(args.replay)]
        if args.replay > 1:
            same = sum(run.fault_log == runs[0].fault_log for run in runs[1:])
            print(f"seed {seed:3d}: {same} of {args.replay - 1} replays met the same {len(runs[0].fault_log)} "
                  "faults in the same order")
        r = runs[0]
        wrong += [w for run in runs[1:] for w in run.wrong]
        moving += sum(run.left_moving for run in runs[1:])
        total_faults += r.n_faults
        outcomes.update(r.outcomes)
        kinds.update(r.faults)
        wrong += r.wrong
        moving += r.left_moving
        print(f"seed {seed:3d}: {r.n_faults} faults in {r.elapsed_s:6.1f} s, {r.outcomes['reached']} moves reached, "
              f"{len(r.wrong)} wrong confirmations, {r.left_moving} left moving", flush=True)
        for what, claimed, table in r.wrong:
            print(f"    WRONG: {what} claimed {claimed:.4f} deg, table at {table:.4f} deg")
    elapsed = time.monotonic() - t0
    print(f"total: {total_faults} faults ({dict(kinds)}) in {elapsed:.0f} s; outcomes {dict(outcomes)}; "
          f"wrong confirmed positions: {len(wrong)}; left moving: {moving}")
    return 1 if wrong or moving else 0


if __name__ == "__main__":
    sys.exit(main())
