"""brdfrig refit DIR, or brdfrig refit --batch ROOT: fit stored sessions again, offline.

The session's raw files are verified against its manifest first; any file that is
missing or fails its checksum is named and nothing is processed. Merged brackets are
reused from the session's cache when their inputs are unchanged. Results go to a new
DIR/results/fit-NNN, which appears only once complete (earlier results are kept), and
every fit is recorded in the material library (see `brdfrig library`). The session is
locked while it is refit.

With --batch, every session below ROOT is refit as one task on a Dask cluster: a local
one of --workers processes, or a running scheduler given by --scheduler tcp://HOST:8786
whose workers see the same storage. A session that fails does not stop the others; a
table at the end lists each session with its result or its reason.
"""

from __future__ import annotations


__all__ = ["register", "run"]


from brdfrig.cli._command import add_command, add_progress_argument
from brdfrig.cli.library import add_library_argument, open_library


def register(subparsers) -> None:
    from brdfrig.ranges import BANDS, Range
    from brdfrig.session.config import FIT_MODELS, FIT_SOLVERS

    parser = add_command(subparsers, "refit", "verify a stored session and fit it again (offline)", __doc__)
    parser.add_argument("dir", nargs="?", help="session directory")
    parser.add_argument("--batch", metavar="ROOT", help="refit every session found below ROOT on a Dask cluster")
    parser.add_argument("--workers", type=Range(1, 256, integer=True).arg(), default=2,
                        help="worker processes of the local cluster (default 2)")
    parser.add_argument("--scheduler", metavar="ADDRESS", help="use a running Dask scheduler, e.g. tcp://host:8786")
    parser.add_argument("--preset", help="fit preset TOML file ([fit] table); options below override it")
    parser.add_argument("--model", choices=FIT_MODELS)
    parser.add_argument("--lmax", type=BANDS.arg(), help=f"lighting band limit{BANDS.text()}")
    parser.add_argument("--pmax", type=BANDS.arg(), help=f"outgoing band limit (full model){BANDS.text()}")
    parser.add_argument("--solver", choices=FIT_SOLVERS)
    parser.add_argument("--no-figures", action="store_true",
                        help="write the BRDF files and stats.json only, no PNG figures or HTML report (faster batches)")
    add_progress_argument(parser)
    add_library_argument(parser)
    parser.set_defaults(func=run)


def _overrides(args) -> dict:
    """The fit settings given on the command line: the preset file's, then the options'."""
    from dataclasses import asdict

    from brdfrig.session.config import load_fit_preset

    given = asdict(load_fit_preset(args.preset)) if args.preset else {}
    return {**given, **{k: getattr(args, k) for k in ("model", "lmax", "pmax", "solver") if getattr(args, k) is not None}}


def _batch_table(result) -> str:
    rows = [("session", "sample", "model", "image err", "seconds")]
    for r in result.done:
        rows += [(r.session, s["sample"], s["model"], f"{100 * (s['image_error'] or 0):.2f}%", f"{r.seconds:.1f}")
                 for s in r.samples]
    rows += [(name, "-", "FAILED", reason, "") for name, reason in sorted(result.failed.items())]
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows)


def run(args) -> int:
    from brdfrig.errors import InputError, on_disk_full
    from brdfrig.session.pipeline import open_verified
    from brdfrig.session.refit import preset_for, record, refit_batch, refit_session

    if (args.dir is None) == (args.batch is None):
        raise InputError("give either a session directory or --batch ROOT")
    if args.workers < 1:
        raise InputError(f"--workers must be >= 1, got {args.workers}")
    with open_library(args) as library:
        if args.batch is not None:
            result = refit_batch(args.batch, _overrides(args), library=library, workers=args.workers,
                                 scheduler=args.scheduler, progress=not args.no_progress, figures=not args.no_figures)
            print(_batch_table(result))
            print(f"{len(result.done)} session(s) refit, {len(result.failed)} failed, in {result.seconds:.1f} s")
            return 0 if not result.failed else 2
        open_verified(args.dir)  # refuses a session whose files fail their checksums, before anything else
        with on_disk_full(f"free some space, then run `brdfrig refit {args.dir}` again"):
            refit = refit_session(args.dir, preset_for(args.dir, _overrides(args)), progress=not args.no_progress,
                                  echo=lambda t: print(t, flush=True), figures=not args.no_figures)
        record(library, refit)
    print(f"results in {refit.results_dir}")
    return 0
