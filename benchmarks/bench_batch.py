"""Batch refit on a Dask LocalCluster against a sequential loop over the same stored sessions.

Run ``python benchmarks/bench_batch.py [--sessions 20] [--workers 2] [--dir DIR]``.  Makes
``--sessions`` simulated sessions (different seeds; the sample set alternates), then refits
them twice from the same stored state: one :func:`brdfrig.session.refit.refit_session` after
another, and as one ``refit_batch`` on ``--workers`` processes.  Prints the wall times, their
ratio, and checks that each batch fit equals the sequential fit of the same session.
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from brdfrig.cli.demo import DEMO_CONFIG, _quick
from brdfrig.session.config import load_session_config, session_config_from_dict
from brdfrig.session.library import Library
from brdfrig.session.refit import refit_batch, refit_session
from brdfrig.devices import open_rig
from brdfrig.session.runner import run_session

OVERRIDES = {"model": "diffuse", "lmax": 4}


def make_sessions(root: Path, count: int) -> list[Path]:
    base = json.loads(json.dumps(_quick(load_session_config(DEMO_CONFIG)).to_dict()))
    plan = {k: v for k, v in base["plan"].items() if v is not None and k not in ("probe_rotations", "scenes")}
    out = []
    for seed in range(count):
        samples = plan["samples"] if seed % 2 == 0 else plan["samples"][:1]
        doc = {"session": {"name": f"sim-{seed:02d}"}, "rig": {**base["rig"], "sim": {**base["rig"]["sim"], "seed": seed}},
               "plan": {**plan, "samples": samples, "scene_angles": [0.0, 90.0]}, "fit": base["fit"]}
        run_session(session_config_from_dict(doc, "bench"), root / f"s{seed:02d}", rig_factory=open_rig, prompt=None,
                    progress=False)
        out.append(root / f"s{seed:02d}")
    return out


def _coefficients(results: Path) -> dict[str, np.ndarray]:
    from brdfrig.fit.brdffile import load_brdf

    return {p.name: np.asarray(load_brdf(p)[0].to_dict()["coefficients"], float) for p in sorted(results.glob("*.brdf.json"))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sessions", type=int, default=20)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--dir", help="work directory (default: a temporary one)")
    args = parser.parse_args()
    work = Path(args.dir or tempfile.mkdtemp(prefix="brdfrig-bench-batch-"))
    t0 = time.perf_counter()
    sessions = make_sessions(work / "seq", args.sessions)
    print(f"made {len(sessions)} sessions in {time.perf_counter() - t0:.0f} s")
    shutil.copytree(work / "seq", work / "batch")
    from brdfrig.session.refit import preset_for

    t0 = time.perf_counter()
    seq = [refit_session(s, preset_for(s, OVERRIDES), echo=lambda _: None) for s in sessions]
    t_seq = time.perf_counter() - t0
    with Library(work / "library.sqlite") as lib:
        batch = refit_batch(work / "batch", OVERRIDES, library=lib, workers=args.workers, progress=True)
    same = all(
        all(np.allclose(a, b, rtol=1e-10, atol=1e-14) for a, b in zip(_coefficients(Path(r.results_dir)).values(),
                                                                       _coefficients(Path(b_.results_dir)).values()))
        for r, b_ in zip(seq, batch.done))
    print(f"\n{'run':<28} {'sessions':>8} {'wall s':>8}")
    print(f"{'sequential refit_session':<28} {len(seq):>8} {t_seq:>8.1f}")
    print(f"{f'refit_batch, {args.workers} workers':<28} {len(batch.done):>8} {batch.seconds:>8.1f}")
    print(f"speed-up (sequential / batch): {t_seq / batch.seconds:.2f}x; failed: {len(batch.failed)}; "
          f"fits identical to the sequential ones: {same}")


if __name__ == "__main__":
    main()
