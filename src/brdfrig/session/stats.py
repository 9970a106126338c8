"""A results directory's ``stats.json``: every number the commands printed about a fit, in one JSON file.

The pipeline writes it (:func:`brdfrig.session.pipeline.run_pipeline`); commands that compute more numbers
about the same results (``brdfrig demo``'s held-out relighting table) add them with :func:`update_stats`.
"""

from __future__ import annotations

import json
from pathlib import Path

from brdfrig._atomic import write_bytes
from brdfrig.errors import StoreError

__all__ = ["STATS_NAME", "read_stats", "update_stats"]

STATS_NAME = "stats.json"


def read_stats(results_dir) -> dict:
    """The ``stats.json`` of a results directory.

    Raises
    ------
    StoreError
        If it is missing or not a JSON object (the file is named).
    """
    path = Path(results_dir) / STATS_NAME
    try:
        doc = json.loads(path.read_text())
    except FileNotFoundError:
        raise StoreError(f"{path}: no such file (not a results directory of brdfrig?)") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise StoreError(f"{path}: corrupt JSON ({exc})") from None
    if not isinstance(doc, dict):
        raise StoreError(f"{path}: not a JSON object")
    return doc


def update_stats(results_dir, entries: dict) -> Path:
    """Add (or replace) top-level ``entries`` in a results directory's ``stats.json``, atomically.

    Values go through :func:`brdfrig.fit.brdffile.jsonable` (numpy values, paths); the old file stays
    whole if anything fails.

    Returns
    -------
    Path
        The ``stats.json`` written.
    """
    from brdfrig.fit.brdffile import jsonable

    path = Path(results_dir) / STATS_NAME
    doc = {**read_stats(results_dir), **jsonable(entries)}
    return write_bytes(path, json.dumps(doc, indent=1, allow_nan=False).encode())
