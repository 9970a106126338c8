"""``brdfrig refit DIR [fit options]``: reprocess a stored session offline.

The session's raw files are verified against its manifest first; any file
that is missing or fails its sha256 is named and nothing is processed.
Merged brackets are reused from the session's cache when their inputs are
unchanged.  Results go to a new ``DIR/results/fit-NNN`` (earlier results are
kept).
"""

from __future__ import annotations

import argparse

__all__ = ["register", "run"]


def register(subparsers) -> None:
    from brdfrig.session.config import FIT_MODELS, FIT_SOLVERS

    parser = subparsers.add_parser("refit", help="verify a stored session and fit it again (offline)",
                                   description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("dir", help="session directory")
    parser.add_argument("--preset", help="fit preset TOML file ([fit] table); options below override it")
    parser.add_argument("--model", choices=FIT_MODELS)
    parser.add_argument("--lmax", type=int, help="lighting band limit")
    parser.add_argument("--pmax", type=int, help="outgoing band limit (full model)")
    parser.add_argument("--solver", choices=FIT_SOLVERS)
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")
    parser.set_defaults(func=run)


def run(args) -> int:
    from dataclasses import asdict

    from brdfrig.session.config import fit_preset_from_dict, load_fit_preset
    from brdfrig.session.pipeline import open_verified, run_pipeline

    _, config = open_verified(args.dir)  # refuses a session whose files fail their checksums
    base = load_fit_preset(args.preset) if args.preset else config.fit
    overrides = {k: getattr(args, k) for k in ("model", "lmax", "pmax", "solver") if getattr(args, k) is not None}
    fit = fit_preset_from_dict({**asdict(base), **overrides}, "the command line")
    result = run_pipeline(args.dir, fit, progress=not args.no_progress, echo=lambda t: print(t, flush=True))
    print(f"results in {result.results_dir}")
    return 0
