"""Fit stored sessions again: one session (:func:`refit_session`) or many on a Dask cluster (:func:`refit_batch`).

A refit holds the session's writer lock, writes a new ``results/fit-NNN`` atomically
(:meth:`brdfrig.session.store.SessionStore.commit_results`) and records every sample's
fit in the material library (:mod:`brdfrig.session.library`).

Batches run one Dask task per session on a ``LocalCluster`` of worker processes or on
a running scheduler.  Tasks take and return only paths and small summaries (never
image arrays): the workers read the sessions from storage they share with the client.
A task is idempotent within its batch: its results directory carries the batch id in
``stats.json``, so a task retried after a worker died re-uses a fit it had already
committed instead of fitting twice; the catalogue's unique (results directory,
sample) key records nothing twice.
"""

from __future__ import annotations

import json
import time
import uuid
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

from brdfrig.session.config import FitPreset, fit_preset_from_dict
from brdfrig.session.library import Library
from brdfrig.session.store import find_sessions

__all__ = ["SessionRefit", "BatchResult", "refit_session", "refit_batch", "record"]

TASK_RETRIES = 2
"""How many times Dask re-runs a task whose worker died (a failing fit is not retried: it raises the same)."""


@dataclass
class SessionRefit:
    """Summary of one session's refit: small, picklable, what a batch task returns."""

    session: str
    results_dir: str
    samples: list[dict] = field(default_factory=list)
    seconds: float = 0.0
    reused: bool = False


@dataclass
class BatchResult:
    """Every session of a batch: the refits that succeeded and the one-line reasons of those that failed."""

    done: list[SessionRefit] = field(default_factory=list)
    failed: dict[str, str] = field(default_factory=dict)
    seconds: float = 0.0


def _summary(session_dir: Path, results_dir: Path, seconds: float, reused: bool) -> SessionRefit:
    stats = json.loads((results_dir / "stats.json").read_text())
    samples = []
    for name, s in stats["samples"].items():
        report = s.get("report", {})
        samples.append({"sample": name, "model": s["model"], "requested_model": stats["fit"].get("model"),
                        "image_error": s.get("self_relative_rms_mean"),
                        "relighting_estimate": (report.get("relight") or {}).get("value"),
                        "seconds": report.get("seconds"), "brdf_path": str(results_dir / s["brdf"]),
                        **{k: stats["fit"].get(k) for k in ("lmax", "pmax", "solver")}})
    return SessionRefit(str(session_dir), str(results_dir), samples, seconds, reused)


def _committed(session_dir: Path, batch_id: str) -> Path | None:
    """The results directory this batch already committed for the session, if any."""
    for stats in sorted((session_dir / "results").glob("fit-*/stats.json")):
        try:
            if json.loads(stats.read_text()).get("batch") == batch_id:
                return stats.parent
        except (OSError, ValueError):
            continue
    return None


def refit_session(session_dir, fit: FitPreset | None = None, *, progress: bool = False,
                  echo: Callable[[str], None] = print, batch_id: str | None = None, figures: bool = True) -> SessionRefit:
    """Verify a stored session and fit it again under its writer lock; return the summary.

    Parameters
    ----------
    session_dir : path-like
        The session.
    fit : FitPreset or None
        Fit settings (None: the session's own).
    progress, echo
        Progress bars on stderr; where the pipeline's lines go.
    batch_id : str or None
        Batch this refit belongs to; a results directory this batch committed already is reused.
    figures : bool
        Write the PNG figures and the HTML report (False: BRDF files and ``stats.json`` only).
    """
    from brdfrig.session.pipeline import run_pipeline
    from brdfrig.session.store import SessionStore

    t0 = time.perf_counter()
    session_dir = Path(session_dir).resolve()
    with SessionStore.open(session_dir).locked():
        done = _committed(session_dir, batch_id) if batch_id else None
        if done is not None:
            return _summary(session_dir, done, time.perf_counter() - t0, reused=True)
        result = run_pipeline(session_dir, fit, progress=progress, echo=echo, figures=figures, batch_id=batch_id)
    return _summary(session_dir, result.results_dir, time.perf_counter() - t0, reused=False)


def record(library: Library, refit: SessionRefit) -> int:
    """Record a refit's samples in the catalogue; return how many rows were new."""
    from brdfrig import __version__

    new = 0
    for s in refit.samples:
        new += library.record_fit(refit.session, s["sample"], model=s["model"], brdf_path=s["brdf_path"],
                                  results_dir=refit.results_dir, version=__version__,
                                  requested_model=s["requested_model"], lmax=s["lmax"], pmax=s["pmax"],
                                  solver=s["solver"], image_error=s["image_error"],
                                  relighting_estimate=s["relighting_estimate"], seconds=s["seconds"])
    return new


def preset_for(session_dir, overrides: dict | None) -> FitPreset | None:
    """The session's own fit preset with ``overrides`` (a partial ``[fit]`` table) applied; None if no overrides."""
    if not overrides:
        return None
    from brdfrig.session.config import stored_session_config
    from brdfrig.session.store import SessionStore

    store = SessionStore.open(session_dir)
    own = stored_session_config(store.config, str(store.root)).fit
    return fit_preset_from_dict({**asdict(own), **overrides}, "the fit options")


def _task(session_dir: str, overrides: dict | None, batch_id: str, figures: bool) -> SessionRefit:
    """What one Dask task runs (a module-level function: workers import it by name)."""
    return refit_session(session_dir, preset_for(session_dir, overrides), progress=False, echo=lambda _line: None,
                         batch_id=batch_id, figures=figures)


def _client(workers: int, scheduler: str | None):
    from dask.distributed import Client, LocalCluster

    if scheduler:
        return Client(scheduler, timeout="30s"), None
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None)
    return Client(cluster), cluster


def refit_batch(root, overrides: dict | None = None, *, library: Library, workers: int = 2,
                scheduler: str | None = None, progress: bool = True, figures: bool = True) -> BatchResult:
    """Refit every session below ``root`` as one Dask task each, recording each fit in ``library``.

    Parameters
    ----------
    root : path-like
        Directory searched for sessions.
    overrides : dict or None
        Fit settings (keys of a ``[fit]`` table) applied over each session's own.
    library : Library
        The catalogue the fits are recorded in (by this process, as tasks finish).
    workers : int
        Worker processes of the local cluster (ignored with ``scheduler``).
    scheduler : str or None
        Address of a running Dask scheduler (``tcp://host:8786``) instead of a local cluster.
    progress : bool
        A progress bar over tasks on stderr.
    figures : bool
        Each session's PNG figures and HTML report (False: BRDF files and ``stats.json`` only).
    """
    import sys

    from dask.distributed import as_completed
    from tqdm import tqdm

    sessions = find_sessions(root)
    batch_id = uuid.uuid4().hex
    out = BatchResult()
    t0 = time.perf_counter()
    client, cluster = _client(workers, scheduler)
    try:
        futures = {client.submit(_task, str(s), overrides, batch_id, figures, key=f"refit-{batch_id}-{i}", pure=False,
                                 retries=TASK_RETRIES): s for i, s in enumerate(sessions)}
        bar = tqdm(total=len(futures), desc="refit", unit="session", file=sys.stderr, disable=not progress,
                   dynamic_ncols=True)
        for fut in as_completed(futures):
            try:
                refit = fut.result()
            except Exception as exc:  # the task's own error: reported per session, the others go on
                out.failed[str(futures[fut])] = f"{type(exc).__name__}: {exc}".splitlines()[0]
            else:
                record(library, refit)
                out.done.append(refit)
            bar.update()
        bar.close()
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    out.done.sort(key=lambda r: r.session)
    out.seconds = time.perf_counter() - t0
    return out
