"""`brdfrig demo [--dir DIR] [--quick]`: a complete bench session on the simulated rig, end to end.

What it does, in order:

1. loads the shipped sim-bench session (`brdfrig template sim-bench`) (the turntable carries the whole rig, so each
   table angle is a new lighting; enough scenes for the full model) and prints
   the plan;
2. shoots it: the GRBL firmware simulator on a pseudo-terminal driven by the
   real turntable driver, and the simulated camera writing DNG files, into a
   crash-safe session directory (interrupt it with Ctrl-C and continue with
   `brdfrig capture resume DIR`);
3. runs the pipeline: merge, probe, fit each sample, BRDF files and figures;
4. relights each fitted sample under a lighting the fit never saw and compares
   with the simulator's true BRDF rendered by brute-force quadrature; targets: <= 2% relative RMS for
   diffuse samples, <= 8% for glossy ones.  Exit status 1 if a target is missed.  The table (and the
   capture's file count and times) is added to the results' `stats.json` as `demo`.

`--quick` shrinks the session (fewer scenes, smaller frame) for smoke tests;
its numbers are not held to the targets.
"""

from __future__ import annotations

import time
from pathlib import Path

from brdfrig.cli._command import add_command, add_progress_argument

__all__ = ["register", "run", "DEMO_CONFIG", "TARGETS"]

DEMO_CONFIG = Path(__file__).resolve().parents[1] / "config" / "sim-bench.toml"
#: Relighting error targets (relative RMS) by kind of true BRDF.
TARGETS = {"diffuse": 0.02, "glossy": 0.08}
#: Size (pixels) of the sphere image on which relighting is scored.
SCORE_SIZE = 96


def register(subparsers) -> None:
    parser = add_command(subparsers, "demo", "simulated bench session end to end (the README's main job)", __doc__)
    parser.add_argument("--dir", help="session directory to create (default: a new temporary directory)")
    parser.add_argument("--quick", action="store_true", help="reduced session for smoke tests (targets not enforced)")
    add_progress_argument(parser)
    parser.set_defaults(func=run)


def _quick(config):
    """A reduced copy of the demo session: half-size frame, coarser lighting, 4 scenes, lobe model at band limit 4."""
    from brdfrig.session.config import session_config_from_dict

    d = config.to_dict()
    scale = 0.5

    def circle(c):
        return [v * scale for v in c]

    plan = {k: v for k, v in d["plan"].items() if k not in ("probe_rotations", "scenes") and v is not None}
    plan["scene_angles"] = [0.0, 90.0, 180.0, 270.0]
    plan["probe"] = {k: v for k, v in {**plan["probe"], "circle": circle(plan["probe"]["circle"])}.items()
                     if v is not None}
    plan["samples"] = [{"name": s["name"], "circle": circle(s["circle"])} for s in plan["samples"]]
    doc = {
        "session": {"name": d["name"] + "-quick", "notes": d["notes"]},
        "rig": {**d["rig"], "sim": {**d["rig"]["sim"], "scale": d["rig"]["sim"].get("scale", 1.0) * scale,
                                    "env_height": 32}},
        "plan": plan,
        "fit": {**d["fit"], "model": "lobe", "lmax": 4, "pmax": 4},
    }
    return session_config_from_dict(doc, f"{config.source} (--quick)")


def relighting_errors(config, samples) -> list[dict]:
    """Relight each fitted sample under the bench's held-out lighting; compare with its true BRDF.

    Returns one dict per sample: ``name``, ``kind`` (diffuse|glossy), ``error`` (relative RMS), ``target``.
    """
    import numpy as np

    from brdfrig.fit.metrics import relative_rms
    from brdfrig.fit.groundtruth import render_groundtruth
    from brdfrig.devices import sim_bench
    from brdfrig.hdr.sphere import sphere_pixels

    bench = sim_bench(config)
    env = bench.heldout_environment()
    px = sphere_pixels((SCORE_SIZE, SCORE_SIZE), (SCORE_SIZE / 2, SCORE_SIZE / 2, SCORE_SIZE / 2))
    keep = px.weights > 0
    normals = np.asarray(px.normals)[keep]
    rows = []
    for s in samples:
        truth_brdf = bench.true_brdf(s.name)
        kind = "diffuse" if type(truth_brdf).__name__ == "Lambertian" else "glossy"
        truth = render_groundtruth(truth_brdf, normals, env)
        pred = s.brdf.predict(env, normals)
        rows.append({"name": s.name, "kind": kind, "model": s.brdf.model, "error": relative_rms(pred, truth),
                     "target": TARGETS[kind]})
    return rows


def run(args) -> int:
    import tempfile

    from brdfrig.session.config import load_session_config
    from brdfrig.session.pipeline import run_pipeline
    from brdfrig.session.stats import update_stats
    from brdfrig.devices import open_rig, preflight
    from brdfrig.session.runner import run_session

    t0 = time.monotonic()

    def echo(text: str) -> None:
        print(text, flush=True)

    config = load_session_config(DEMO_CONFIG)
    if args.quick:
        config = _quick(config)
    out = Path(args.dir) if args.dir else Path(tempfile.mkdtemp(prefix="brdfrig-demo-")) / "session"
    echo(f"brdfrig demo: simulated bench session -> {out}")
    preflight(config)
    status, store = run_session(config, out, rig_factory=open_rig, prompt=None, progress=not args.no_progress,
                                echo=echo)
    capture_s = time.monotonic() - t0
    echo(f"captured {len(store.files)} files in {capture_s:.0f} s")
    result = run_pipeline(out, progress=not args.no_progress, echo=echo)
    rows = relighting_errors(config, result.samples)
    echo("\nrelighting under a lighting the fit never saw, against the simulator's true BRDF:")
    echo(f"  {'sample':<12} {'kind':<8} {'model':<12} {'error':>8} {'target':>8}")
    ok = True
    for r in rows:
        passed = r["error"] <= r["target"]
        ok &= passed
        echo(f"  {r['name']:<12} {r['kind']:<8} {r['model']:<12} {100 * r['error']:7.2f}% {100 * r['target']:7.1f}%"
             f"  {'ok' if passed else 'MISSED'}")
    echo(f"\nsession: {out}\nresults: {result.results_dir}")
    for s in result.samples:
        echo(f"  {s.name}: BRDF {s.brdf_path}  figure {s.figure_path}")
    total_s = time.monotonic() - t0
    update_stats(result.results_dir, {"demo": {
        "relighting_heldout": [{**r, "passed": r["error"] <= r["target"]} for r in rows], "targets_met": bool(ok),
        "quick": bool(args.quick), "captured_files": len(store.files), "capture_s": capture_s, "total_s": total_s}})
    echo(f"total time {total_s:.0f} s")
    if not ok and not args.quick:
        echo("a relighting target was missed")
        return 1
    return 0
