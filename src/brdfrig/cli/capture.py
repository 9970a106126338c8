"""`brdfrig capture run PLAN.toml --out DIR` and `brdfrig capture resume DIR`: shoot a session, then fit it.

`run` validates the plan, prints it (shots, expected time, how many scenes the
requested model needs) and shoots it into a new session directory; `resume`
finishes a stopped or killed session without reshooting what is stored and
verified.  When the session is complete both run the pipeline (merge, probe,
fit, BRDF files and figures) unless `--no-fit`.  Both hold the session's
writer lock from before the first write until the fit ends: a session in use
by another process is refused ("session DIR in use by PID N", exit 2) before
anything is written.
"""

from __future__ import annotations

import sys

__all__ = ["register", "run"]


from brdfrig.cli._command import add_command, add_progress_argument
from brdfrig.cli.library import add_library_argument


def register(subparsers) -> None:
    parser = add_command(subparsers, "capture", "shoot a capture session on the rig, or resume one", __doc__)
    sub = parser.add_subparsers(dest="capture_command", required=True, metavar="ACTION")
    p_run = sub.add_parser("run", help="run a session plan into a new session directory")
    p_run.add_argument("plan", help="session plan TOML file (e.g. from `brdfrig template plan-bench`)")
    p_run.add_argument("--out", required=True, help="new session directory (must not exist, or be empty)")
    p_run.add_argument("--rig", help="rig TOML file whose [rig] replaces the plan's")
    p_run.add_argument("--fit", dest="fit_file", help="fit preset TOML file whose [fit] replaces the plan's")
    p_run.add_argument("--dry-run", action="store_true", help="print the plan and exit without shooting")
    p_resume = sub.add_parser("resume", help="finish a stopped or killed session")
    p_resume.add_argument("dir", help="session directory")
    for p in (p_run, p_resume):
        p.add_argument("--yes", action="store_true",
                       help="do not prompt between operator scenes (assume each is set up)")
        p.add_argument("--no-fit", action="store_true", help="stop after shooting; fit later with `brdfrig refit`")
        add_progress_argument(p)
        add_library_argument(p)
    parser.set_defaults(func=run)


def run(args) -> int:
    from brdfrig.devices import open_rig, preflight
    from brdfrig.session.runner import resume_session, run_session

    prompt = None if args.yes else input
    progress = not args.no_progress

    def echo(text: str) -> None:
        print(text, flush=True)

    if args.capture_command == "run":
        from brdfrig.session.config import load_session_config
        from brdfrig.session.plan import build_plan, describe_plan

        config = load_session_config(args.plan, args.rig, args.fit_file)
        if args.dry_run:
            from brdfrig.devices import preflight

            preflight(config)
            echo(describe_plan(build_plan(config)))
            return 0
        preflight(config)
        run_session(config, args.out, rig_factory=open_rig, prompt=prompt, progress=progress, echo=echo,
                    then=lambda status, store: _after_shooting(args, status, store, echo))
        return 0
    resume_session(args.dir, rig_factory=open_rig, prompt=prompt, progress=progress, echo=echo,
                   then=lambda status, store: _after_shooting(args, status, store, echo))
    return 0


def _after_shooting(args, status: str, store, echo) -> None:
    """Report the shooting's outcome and fit a complete session (run as ``then``: the shooting's writer lock is held)."""
    progress = not args.no_progress
    if status != "complete":
        echo(f"session paused at an operator prompt; continue with `brdfrig capture resume {store.root}`")
        return
    echo(f"session complete: {len(store.files)} files in {store.root} (manifest {store.root / 'manifest.json'})")
    if args.no_fit:
        echo(f"fit it with `brdfrig refit {store.root}`")
        return
    from brdfrig.cli.library import open_library
    from brdfrig.errors import on_disk_full
    from brdfrig.session.refit import record, refit_session

    with on_disk_full(f"the shots are stored; free some space, then run `brdfrig refit {store.root}`"):
        refit = refit_session(store.root, progress=progress, echo=echo)
    with open_library(args) as library:
        record(library, refit)
    echo(f"results in {refit.results_dir}")


if __name__ == "__main__":
    sys.exit("use `brdfrig capture ...`")
