"""`brdfrig library`: the catalogue of sessions and fits (add, list, show).

The catalogue is one SQLite file: `--library FILE`, else the environment variable
BRDFRIG_LIBRARY, else a per-user file (`~/.local/share/brdfrig/library.sqlite`).
Every refit records its fits there.
"""

from __future__ import annotations


from brdfrig.cli._command import add_command
from brdfrig.ranges import Range

__all__ = ["register", "add_library_argument", "open_library"]


def add_library_argument(parser) -> None:
    """``--library FILE`` (shared by every command that records fits)."""
    parser.add_argument("--library", metavar="FILE",
                        help="catalogue file (default: $BRDFRIG_LIBRARY, else ~/.local/share/brdfrig/library.sqlite)")


def open_library(args):
    """The catalogue named by ``args.library`` (or the default)."""
    from brdfrig.session.library import Library, default_library_path

    return Library(args.library or default_library_path())


def register(subparsers) -> None:
    p = add_command(subparsers, "library", "catalogue of measured sessions and their fits", __doc__)
    sub = p.add_subparsers(dest="library_command", required=True, metavar="ACTION")
    add = sub.add_parser("add", help="register every session found below a directory (each verified first)")
    add.add_argument("root", help="directory to search for sessions")
    ls = sub.add_parser("list", help="list catalogued fits, newest first")
    ls.add_argument("--model", help="only fits of this model")
    ls.add_argument("--max-error", type=Range(0, 1e6).arg(), metavar="E",
                    help="only fits whose relighting estimate (else image error) is at most E (e.g. 0.05 = 5%%)")
    ls.add_argument("--sample", metavar="NAME", help="only this sample")
    ls.add_argument("--since", metavar="DATE", help="only fits recorded on or after DATE (YYYY-MM-DD)")
    ls.add_argument("--json", action="store_true", help="print JSON instead of a table")
    show = sub.add_parser("show", help="one session: its samples and every fit of it")
    show.add_argument("name", help="session name or directory")
    show.add_argument("--json", action="store_true", help="print JSON instead of text")
    for q in (add, ls, show):
        add_library_argument(q)
    p.set_defaults(func=run)


def _pct(v) -> str:
    return "-" if v is None else f"{100 * v:.2f}%"


def _table(fits) -> str:
    rows = [("session", "sample", "model", "lmax", "image err", "relight est", "recorded")]
    rows += [(f.session, f.sample, f.model, str(f.lmax), _pct(f.image_error), _pct(f.relighting_estimate),
              f.recorded) for f in fits]
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows)


def run(args) -> int:
    import json
    from dataclasses import asdict

    from brdfrig.errors import InputError

    with open_library(args) as lib:
        if args.library_command == "add":
            for name, added in lib.add_root(args.root):
                print(f"{'added' if added else 'known'}: {name}")
            return 0
        if args.library_command == "list":
            if args.since is not None and not _is_date(args.since):
                raise InputError(f"--since must be a date YYYY-MM-DD, got {args.since!r}")
            fits = lib.fits(model=args.model, max_error=args.max_error, sample=args.sample, since=args.since)
            print(json.dumps([asdict(f) for f in fits], indent=1) if args.json else _table(fits))
            return 0
        sessions = [s for s in lib.sessions() if args.name in (s["name"], s["root"])]
        if not sessions:
            raise InputError(f"no session {args.name!r} in the library {lib.path}")
        fits = lib.fits(session=args.name)
        if args.json:
            print(json.dumps({"sessions": sessions, "fits": [asdict(f) for f in fits]}, indent=1))
        else:
            for s in sessions:
                print(f"{s['name']}  {s['root']}\n  samples: {', '.join(s['samples']) or '-'}; created {s['created']}")
            print(_table(fits))
    return 0


def _is_date(text: str) -> bool:
    import datetime as dt

    try:
        dt.date.fromisoformat(text[:10])
    except ValueError:
        return False
    return True
