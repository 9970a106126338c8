"""Tables, summary statistics, PNGs and JSON of a measured-materials benchmark run, and its checkpoint.

Errors are the headline relight probe's (the first of ``--relight-probes``) unless a
column says otherwise; statistics are over the tuning materials (not held out) and,
separately, the held-out ones (``*`` in the tables).  Percentiles: numpy's linear
interpolation.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from brdfrig.errors import InputError
from brdfrig.evaluate.measured import scene_label
from brdfrig.evaluate.measured_run import MeasuredResult

__all__ = ["summarize", "noise_ratios", "table_vs_microfacet", "format_table", "format_summary", "format_report", "report_title", "report_sections", "result_to_json", "write_outputs", "write_partial", "result_from_json",
           "setup_to_json", "load_partial",
           "plot_errors", "plot_worst"]

AUTO = "auto"
PICK_RTOL = 1.1
"""``auto`` picks well on a material when its error is within this factor of the best model's."""
ESTIMATE_FACTOR = 2.0
"""A reported estimate is good when within this factor of the measured error."""
NOISE_FACTOR = 1.2
"""Noise is tolerated when it raises an error statistic (or a material's error) by at most this factor."""
MATERIAL_GROUPS = {
    "felts": r"felt",
    "satins": r"satin",
    "paints": r"irid_|vch_|cm_|ilm_|metallic",
    "papers": r"paper|cardboard|notebook|bluebook|bindercover",
}
"""Groups of materials that are not GGX-like (issue 10), as regular expressions searched in the material's name:
felts, satins, paints (iridescent flake, colour-changing, metallic and ILM paints of the RGL set) and papers
(RGL and Nielsen papers, cardboards, binder and book covers)."""
TABLES = ("bivariate", "bivariate+prior", "bivariate+measured", "bivariate+blend")
"""The data-driven table models weighed against ``microfacet`` per material group."""


def _groups(result: MeasuredResult):
    """``(scenes, noise) -> {material: {model: CaseResult}}``, materials by name."""
    out: dict = {}
    for c in sorted(result.cases, key=lambda c: c.material):
        out.setdefault((c.scenes, c.noise), {}).setdefault(c.material, {})[c.model] = c
    return out


def _stats(values) -> dict:
    """Median, p90, worst of the finite values; ``failed`` counts the others (failed fits, NaN)."""
    values = [x for x in values if x is not None]
    v = np.asarray([x for x in values if math.isfinite(x)], dtype=np.float64)
    failed = len(values) - len(v)
    if not len(v):
        return {"n": 0, "failed": failed, "median": None, "p90": None, "worst": None}
    return {"n": int(len(v)), "failed": failed, "median": float(np.median(v)), "p90": float(np.percentile(v, 90)),
            "worst": float(v.max())}


def _median(values) -> float | None:
    v = [x for x in values if x is not None and math.isfinite(x)]
    return float(np.median(v)) if v else None


def summarize(result: MeasuredResult) -> list[dict]:
    """One dict per (scenes, noise, model, subset) with error statistics, fit seconds and, for ``auto``,
    how often it is within :data:`PICK_RTOL` of the best model and its estimate within :data:`ESTIMATE_FACTOR`."""
    rows = []
    for (scenes, noise), by_mat in _groups(result).items():
        for subset, held in (("tuning", False), ("held-out", True)):
            mats = {k: v for k, v in by_mat.items() if v and next(iter(v.values())).held_out == held}
            if not mats:
                continue
            for model in result.models:
                cases = [v[model] for v in mats.values() if model in v]
                row = {"scenes": scenes, "noise": noise, "model": model, "subset": subset,
                       **_stats([c.error for c in cases]),
                       "fit_seconds_median": _median([c.fit_seconds for c in cases]),
                       "fit_seconds_total": float(np.nansum([c.fit_seconds for c in cases]))}
                for probe in result.setup.relight_probes[1:]:
                    row[f"{probe}"] = _stats([c.errors.get(probe) for c in cases])
                if model == AUTO:
                    row.update(_auto_quality(mats, result.setup.relight_probes[1:]))
                rows.append(row)
    return rows


def noise_ratios(result: MeasuredResult, model: str = AUTO) -> list[dict]:
    """``model``'s errors with noise against noise-free, on the materials run both ways (same scene count).

    One dict per (scenes, noise > 0): the ratios of the median, p90 and worst errors (noisy / noise-free), the
    median per-material ratio, the materials whose error grew by more than :data:`NOISE_FACTOR` (largest ratio
    first) and every material's ``[noise-free, noisy]`` error.
    """
    groups = _groups(result)
    rows = []
    for (scenes, noise), by_mat in groups.items():
        clean = groups.get((scenes, 0.0))
        if noise == 0 or clean is None:
            continue
        pairs = {m: (clean[m][model].error, v[model].error) for m, v in by_mat.items()
                 if model in v and m in clean and model in clean[m]}
        pairs = {m: p for m, p in pairs.items() if all(math.isfinite(x) for x in p)}
        if not pairs:
            continue
        a, b = _stats([p[0] for p in pairs.values()]), _stats([p[1] for p in pairs.values()])
        ratio = {k: (b[k] / a[k] if a[k] else math.inf) for k in ("median", "p90", "worst")}
        per = {m: (y / x if x > 0 else math.inf) for m, (x, y) in pairs.items()}
        rows.append({"scenes": scenes, "noise": noise, "model": model, "n": len(pairs), "noise_free": a, "noisy": b,
                     "ratio": ratio, "median_material_ratio": float(np.median(list(per.values()))),
                     f"over_{NOISE_FACTOR}x": sorted((m for m, r in per.items() if r > NOISE_FACTOR), key=lambda m: -per[m]),
                     "errors": {m: list(p) for m, p in pairs.items()}})
    return rows


def table_vs_microfacet(result: MeasuredResult) -> list[dict]:
    """Per (scenes, noise), table model (:data:`TABLES`) and material group (:data:`MATERIAL_GROUPS`): on how many
    of the group's materials the table relights better than ``microfacet``, and both medians.  Empty without
    ``microfacet``."""
    import re

    rows = []
    if "microfacet" not in result.models:
        return rows
    for (scenes, noise), by_mat in _groups(result).items():
        for table in (t for t in TABLES if t in result.models):
            for group, pattern in MATERIAL_GROUPS.items():
                pairs = [(v[table].error, v["microfacet"].error) for m, v in by_mat.items()
                         if re.search(pattern, m) and table in v and "microfacet" in v]
                pairs = [p for p in pairs if all(math.isfinite(x) for x in p)]
                if pairs:
                    t, mf = np.array(pairs).T
                    rows.append({"scenes": scenes, "noise": noise, "table": table, "group": group, "n": len(pairs),
                                 "table_better": int(np.sum(t < mf)), "table_median": float(np.median(t)),
                                 "microfacet_median": float(np.median(mf))})
    return rows


def _estimate_within(case, probe: str | None = None) -> bool:
    """The case's reported estimate is within :data:`ESTIMATE_FACTOR` of its measured error under ``probe``
    (None: the headline probe)."""
    error = case.error if probe is None else case.errors.get(probe, math.nan)
    estimate = case.estimate_for(probe)
    ratio = estimate / error if error > 0 else (1.0 if estimate == 0 else math.inf)
    return 1 / ESTIMATE_FACTOR <= ratio <= ESTIMATE_FACTOR


def _auto_quality(mats: dict, others: tuple[str, ...]) -> dict:
    """``auto``'s picks (materials where other models ran too) and estimates (within :data:`ESTIMATE_FACTOR` of
    the headline probe's error, and of each probe's in ``others``)."""
    picks, compared, estimates, n_est = 0, 0, 0, 0
    under = dict.fromkeys(others, 0)
    for by_model in mats.values():
        auto = by_model.get(AUTO)
        rivals = [c.error for m, c in by_model.items() if m != AUTO and math.isfinite(c.error)]
        if auto is None or auto.failure:
            continue
        if rivals:
            compared += 1
            picks += auto.error <= PICK_RTOL * min(rivals) + 1e-12
        if auto.estimate is not None:
            n_est += 1
            estimates += _estimate_within(auto)
            for probe in others:
                under[probe] += _estimate_within(auto, probe)
    return {"auto_within_1.1x_of_best": picks, "auto_compared": compared, "estimates_reported": n_est,
            "estimates_within_2x": estimates, "estimates_within_2x_under": under}


def _pct(x) -> str:
    """A fraction as a percentage in 6 characters (``>9999`` beyond; ``-`` for None)."""
    if x is None:
        return "     -"
    return f"{100 * x:6.2f}" if 100 * x < 1000 else (f"{100 * x:6.0f}" if 100 * x < 1e5 else " >1e5")


def _cell(case) -> str:
    if case is None:
        return "-"
    return "FAIL" if case.failure else _pct(case.error)


def format_table(result: MeasuredResult) -> str:
    """Per-material relighting errors (%, headline probe), one column per model, one block per (scenes, noise)."""
    probe = result.setup.relight_probes[0]
    lines = []
    width = max([len(m.name) for m in result.materials] + [8]) + 1
    for (scenes, noise), by_mat in _groups(result).items():
        lines.append(f"-- {scene_label(scenes, result.setup.arrangement)}, noise {noise:g}: relighting error (%) under {probe}; "
                     f"fit under {result.setup.fit_probe}; * = held out from tuning")
        head = f"{'material':<{width}} " + " ".join(f"{m[:10]:>10}" for m in result.models)
        lines.append(head + "  auto chose   estimate")
        for name, by_model in by_mat.items():
            held = next(iter(by_model.values())).held_out
            cells = " ".join(f"{_cell(by_model.get(m)):>10}" for m in result.models)
            auto = by_model.get(AUTO)
            tail = "" if auto is None else f"  {auto.chosen_model[:11]:<11} {_pct(auto.estimate_for())}"
            lines.append(f"{name + ('*' if held else ''):<{width}} {cells}{tail}")
    return "\n".join(lines)


def format_summary(result: MeasuredResult) -> str:
    """Median / p90 / worst (%) per model and subset, median fit seconds, auto's pick and estimate quality."""
    probe = result.setup.relight_probes[0]
    others = result.setup.relight_probes[1:]
    lines = [f"{'scenes':>6} {'noise':>5} {'subset':<8} {'model':<14} {'n':>3} {'median':>7} {'p90':>7} {'worst':>7}"
             f" {'fit_s':>6}" + "".join(f"  {p + ' med/worst':>16}" for p in others) + "  notes"]
    for r in summarize(result):
        extra = "".join(f"  {_pct(r[p]['median']).strip():>7}/{_pct(r[p]['worst']).strip():<8}" for p in others)
        note = ""
        if r["model"] == AUTO:
            picks = (f"within {PICK_RTOL}x of best on {r['auto_within_1.1x_of_best']}/{r['auto_compared']}; "
                     if r["auto_compared"] else "no other model to compare; ")
            under = "".join(f", of the error under {p} on {k}" for p, k in r["estimates_within_2x_under"].items())
            note = (f"{picks}estimate within {ESTIMATE_FACTOR:g}x on {r['estimates_within_2x']}/{r['estimates_reported']} "
                    f"reported{under}")
        fit_s = "-" if r["fit_seconds_median"] is None else f"{r['fit_seconds_median']:.2f}"
        if r["failed"]:
            note = f"{r['failed']} FAILED; " + note
        lines.append(f"{r['scenes']:>6} {r['noise']:>5g} {r['subset']:<8} {r['model'][:14]:<14} {r['n']:>3} "
                     f"{_pct(r['median']):>7} {_pct(r['p90']):>7} {_pct(r['worst']):>7} {fit_s:>6}{extra}  {note}")
    text = f"Summary: relighting error (%) under {probe} (other probes: median/worst)\n" + "\n".join(lines)
    noise = noise_ratios(result)
    if noise:
        text += f"\n\nNoise: {AUTO} with noise against noise-free on the same materials (ratio; tolerated: {NOISE_FACTOR}x)"
        for r in noise:
            over = r[f"over_{NOISE_FACTOR}x"]
            listed = ", ".join(f"{m} {100 * r['errors'][m][0]:.2f} -> {100 * r['errors'][m][1]:.2f}%" for m in over[:5])
            text += (f"\n  {scene_label(r['scenes'], result.setup.arrangement)}, noise {r['noise']:g}, {r['n']} materials: median {_pct(r['noisy']['median']).strip()}% "
                     f"({r['ratio']['median']:.2f}x), p90 {_pct(r['noisy']['p90']).strip()}% ({r['ratio']['p90']:.2f}x), "
                     f"worst {_pct(r['noisy']['worst']).strip()}% ({r['ratio']['worst']:.2f}x); per material median "
                     f"{r['median_material_ratio']:.2f}x, over {NOISE_FACTOR}x on {len(over)}" + (f" ({listed})" if over else ""))
    groups = table_vs_microfacet(result)
    if groups:
        text += "\n\nTables against microfacet on the groups that are not GGX-like (table better on k of n; medians %)"
        for r in groups:
            text += (f"\n  {scene_label(r['scenes'], result.setup.arrangement)}, noise {r['noise']:g}, {r['table']:<18} {r['group']:<7} {r['table_better']:>2} of "
                     f"{r['n']:<2}  {_pct(r['table_median']).strip()} vs {_pct(r['microfacet_median']).strip()}")
    return text


def report_title(result: MeasuredResult) -> str:
    """The report's first line: materials, sphere size, probes, models."""
    s = result.setup
    return (f"brdfrig measured benchmark: {len(result.materials)} materials, {s.size} px spheres, "
            f"fit {s.fit_probe}, relight {','.join(s.relight_probes)} ({2 * s.env_rows}x{s.env_rows}), "
            f"models {','.join(result.models)}")


def report_sections(result: MeasuredResult) -> list[tuple[str, str]]:
    """``(heading, text)`` of the report after its title: the table, the summary, failed fits (if any), time."""
    sections = [("Per material", format_table(result)), ("Summary", format_summary(result))]
    failures = [f"  {c.material} {c.model} ({scene_label(c.scenes, result.setup.arrangement)}, noise {c.noise:g}): {c.failure}"
                for c in result.cases if c.failure]
    if failures:
        sections.append(("Failed fits", "Failed fits:\n" + "\n".join(failures)))
    phases = ", ".join(f"{k} {v:.1f} s" for k, v in result.phases.items())
    cache = f"ground truth: {result.cache_misses} rendered, {result.cache_hits} from the cache"
    summed = f" (phases summed over {result.workers} worker processes)" if result.workers > 1 else ""
    resumed = f"; {result.resumed} material run(s) resumed from an earlier session" if result.resumed else ""
    return sections + [("Time", f"Time{summed}: {phases}; {cache}{resumed}")]


def format_report(result: MeasuredResult) -> str:
    """Title, table, summary and where the time went (as printed)."""
    return "\n\n".join([report_title(result)] + [text for _, text in report_sections(result)])


def setup_to_json(setup, scene_counts, noises, models, seed: int) -> dict:
    """The ``"setup"`` of :func:`result_to_json`: what makes two runs' cases comparable."""
    return {"size": setup.size, "fit_probe": setup.fit_probe, "relight_probes": list(setup.relight_probes),
            "env_rows": setup.env_rows, "scene_counts": list(scene_counts), "arrangement": setup.arrangement, "noises": list(noises), "models": list(models),
            "seed": seed}


def result_to_json(result: MeasuredResult) -> dict:
    """Every number of a run (cases without their images, summary, setup, phases)."""
    s = result.setup
    cases = [{"material": c.material, "model": c.model, "chosen_model": c.chosen_model, "scenes": c.scenes,
              "noise": c.noise, "held_out": c.held_out, "errors": c.errors, "fit_seconds": c.fit_seconds, "cpu_seconds": c.cpu_seconds,
              "estimate": c.estimate, "estimate_method": c.estimate_method, "lighting_estimates": c.lighting_estimates,
              "lighting_estimate_details": c.lighting_estimate_details,
              "failure": c.failure, "fit_file": c.fit_file} for c in result.cases]
    return {"setup": setup_to_json(s, result.scene_counts, result.noises, result.models, result.seed),
            "materials": [{"name": m.name, "path": str(m.path) if m.path else None, "held_out": m.held_out}
                          for m in result.materials],
            "summary": summarize(result), "noise_ratios": noise_ratios(result), "table_vs_microfacet": table_vs_microfacet(result),
            "cases": cases, "phases_seconds": result.phases, "workers": result.workers,
            "cache": {"hits": result.cache_hits, "misses": result.cache_misses}}


def result_from_json(data: dict) -> MeasuredResult:
    """The :class:`MeasuredResult` of a :func:`result_to_json` dict (``measured.json`` or the partial file read
    back), without ground truths or relit images: enough for :func:`format_table` and :func:`format_summary`."""
    from brdfrig.evaluate.measured import CaseResult, CaseSetup, Material

    s = data["setup"]
    setup = CaseSetup(int(s["size"]), s["fit_probe"], tuple(s["relight_probes"]), int(s["env_rows"]),
                      arrangement=s.get("arrangement", "turns"))  # runs before tilts existed only turned
    cases = [CaseResult(c["material"], c["model"], c["chosen_model"], c["scenes"], c["noise"],
                        {k: (math.nan if v is None else v) for k, v in c["errors"].items()},
                        math.nan if c["fit_seconds"] is None else c["fit_seconds"], c["estimate"], c["held_out"],
                        estimate_method=c.get("estimate_method", ""), lighting_estimates=c.get("lighting_estimates", {}),
                        lighting_estimate_details=c.get("lighting_estimate_details", {}),
                        cpu_seconds=c.get("cpu_seconds"),
                        failure=c.get("failure"), fit_file=c.get("fit_file")) for c in data["cases"]]
    done = {c.material for c in cases}
    materials = [Material(m["name"], None, None, m["held_out"]) for m in data["materials"] if m["name"] in done]
    cache = data.get("cache", {})
    return MeasuredResult(cases, setup, tuple(s["scene_counts"]), tuple(s["noises"]), tuple(s["models"]), materials,
                          phases=dict(data.get("phases_seconds", {})), workers=int(data.get("workers", 1)),
                          cache_hits=int(cache.get("hits", 0)), cache_misses=int(cache.get("misses", 0)),
                          seed=int(s.get("seed", 0)))


def load_partial(out: Path, setup: dict, materials: list[str]) -> MeasuredResult:
    """The cases of the unfinished run in ``out`` (its :data:`PARTIAL_JSON`), to be continued by a run whose
    :func:`setup_to_json` is ``setup`` over the material names ``materials`` (in any order).

    Raises :class:`~brdfrig.errors.InputError` naming the file when it is unreadable, or the first setting
    in which the two runs differ (their cases would not be comparable).
    """
    path = Path(out) / PARTIAL_JSON
    try:
        data = json.loads(path.read_text())
        saved, names = data["setup"], [m["name"] for m in data["materials"]]
        result = result_from_json(data)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise InputError(f"{path}: not a readable checkpoint of the measured benchmark ({exc!r})") from exc
    again = "resume it with the same options, or give another --out"
    for key, value in setup.items():
        if saved.get(key) != value:
            raise InputError(f"{path}: the unfinished run has {key} {saved.get(key)!r}, this run {value!r}; {again}")
    there, here = sorted(set(names) - set(materials)), sorted(set(materials) - set(names))
    if there or here:
        raise InputError(f"{path}: the unfinished run has other materials (only there: {there}, only here: {here}); {again}")
    return result


PLOT_CEILING = 2.0
"""Relative errors above this are drawn at it in :func:`plot_errors` (an unregularised fit can reach 1e6)."""


def percent_tick(value: float, _pos=None) -> str:
    """Axis label of a relative error ``value`` as a percentage to three significant digits (0.002 -> ``0.2%``)."""
    return f"{100 * value:.3g}%"


def plot_errors(result: MeasuredResult, path: Path) -> Path:
    """PNG: relighting error per material (x) per model (markers), one panel per (scenes, noise), log scale,
    clipped at :data:`PLOT_CEILING`."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from brdfrig.report.figures import save_png

    groups = _groups(result)
    fig, axes = plt.subplots(len(groups), 1, figsize=(max(8.0, 0.22 * len(result.materials) + 3), 3.6 * len(groups)),
                             squeeze=False)
    for ax, ((scenes, noise), by_mat) in zip(axes[:, 0], groups.items()):
        names = list(by_mat)
        x = np.arange(len(names))
        for model, marker in zip(result.models, "os^Dv<>px*h+"):
            y = [by_mat[n][model].error if model in by_mat[n] else np.nan for n in names]
            style = dict(ms=9, mfc="none", mew=1.5) if model == AUTO else dict(ms=4, alpha=0.8)
            ax.plot(x, np.clip(y, 1e-5, PLOT_CEILING), marker, label=model, **style)
        ax.set_xticks(x, [n + ("*" if next(iter(by_mat[n].values())).held_out else "") for n in names],
                      rotation=90, fontsize=6)
        if any(math.isfinite(c.error) for v in by_mat.values() for c in v.values()):
            ax.set_yscale("log")
        ax.set_ylim(top=1.5 * PLOT_CEILING)
        ax.set_ylabel("relighting error")
        ax.set_title(f"{scene_label(scenes, result.setup.arrangement)}, noise {noise:g}: fit {result.setup.fit_probe}, "
                     f"relight {result.setup.relight_probes[0]} (* held out; errors above "
                     f"{PLOT_CEILING:.0%} drawn at {PLOT_CEILING:.0%})", fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7, ncol=4)
    fig.tight_layout()
    return save_png(fig, path, dpi=100)


def plot_estimates(result: MeasuredResult, path: Path) -> Path | None:
    """PNG: ``auto``'s reported relighting estimate for each relight probe against its measured relighting error
    there, log-log, one colour per (scenes, noise), one marker per probe, the held-out materials filled; the line
    of equality and the :data:`ESTIMATE_FACTOR` band.  None when no ``auto`` case reported an estimate."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    from brdfrig.report.figures import save_png

    probes = result.setup.relight_probes
    cases = [c for c in result.cases if c.model == AUTO and not c.failure]
    points = [(c, p, c.errors[p], est) for c in cases for p in probes
              if (est := c.estimate_for(p)) and c.errors.get(p, 0) > 0]
    if not points:
        return None
    fig, ax = plt.subplots(figsize=(5.2, 5.0))
    for k, (scenes, noise) in enumerate(sorted({(c.scenes, c.noise) for c, *_ in points})):
        for j, probe in enumerate(probes):
            group = [(c, x, y) for c, p, x, y in points if (c.scenes, c.noise) == (scenes, noise) and p == probe]
            inside = sum(_estimate_within(c, probe) for c, _, _ in group)
            for held, fill in ((False, "none"), (True, None)):
                pts = [(x, y) for c, x, y in group if c.held_out == held]
                if pts:
                    x, y = np.array(pts).T
                    label = (f"{scene_label(scenes, result.setup.arrangement)}, noise {noise:g}, {probe}: "
                             f"{inside}/{len(group)} within {ESTIMATE_FACTOR:g}x") if not held else f"{probe}, held out"
                    ax.plot(x, y, "os^D"[j % 4], color=f"C{k}", mfc=fill, ms=5, label=label)
    lo = 0.5 * min(min(x, y) for *_, x, y in points)
    hi = 2.0 * max(max(x, y) for *_, x, y in points)
    line = np.array([lo, hi])
    ax.plot(line, line, "k-", lw=0.8)
    ax.fill_between(line, line / ESTIMATE_FACTOR, line * ESTIMATE_FACTOR, color="0.85", zorder=0)
    ax.set(xscale="log", yscale="log", xlim=(lo, hi), ylim=(lo, hi), xlabel="measured relighting error under the probe",
           ylabel="reported estimate for that lighting", title=f"auto: estimate vs measured (band: within {ESTIMATE_FACTOR:g}x)")
    for axis in (ax.xaxis, ax.yaxis):
        axis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
        axis.set_major_formatter(FuncFormatter(percent_tick))
        axis.set_minor_formatter(NullFormatter())
    ax.tick_params(labelsize=8)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    return save_png(fig, path, dpi=100)


def _image(truth, values: np.ndarray) -> np.ndarray:
    img = np.zeros((truth.setup.size, truth.setup.size, values.shape[1]))
    img[truth.rows, truth.cols] = values
    return img


WORST_COUNT = 5
"""Materials ``worst.png`` shows."""


def worst_model(result: MeasuredResult) -> str:
    """The model ``worst.png`` shows: ``auto`` if the run has it, else its first model."""
    return AUTO if AUTO in result.models else result.models[0]


def headline_cases(result: MeasuredResult, model: str) -> list:
    """The cases of ``model`` at the run's first scene count and first noise level, worst (largest error) first,
    failed ones (NaN error) last."""
    scenes, noise = result.scene_counts[0], result.noises[0]
    group = [c for c in result.cases if c.model == model and c.scenes == scenes and c.noise == noise]
    return sorted(group, key=lambda c: math.inf if math.isnan(c.error) else -c.error)


def plot_worst(result: MeasuredResult, path: Path, model: str = AUTO, count: int = WORST_COUNT) -> Path | None:
    """PNG: reference vs relit sphere (and |difference| x4) of the ``count`` worst materials of ``model``
    (:func:`headline_cases`), under the headline probe; same exposure per row.  Only cases with images are drawn
    (a resumed run's earlier cases have them where they were relit again; the title says when some lack them)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from brdfrig.report.figures import save_png

    scenes, noise = result.scene_counts[0], result.noises[0]
    group = headline_cases(result, model)
    imaged = [c for c in group if (scenes, c.material) in result.truths and c.relit]
    cases = imaged[:count]
    if not cases:
        return None
    probe = result.setup.relight_probes[0]
    fig, axes = plt.subplots(len(cases), 3, figsize=(6.6, 2.3 * len(cases)), squeeze=False)
    for row, case in zip(axes, cases):
        truth = result.truths[(scenes, case.material)]
        ref, relit = truth.relight[probe][1], case.relit[probe]
        scale = np.percentile(ref, 99) or 1.0
        for ax, (title, values) in zip(row, (("reference", ref), (f"{case.chosen_model} {100 * case.error:.1f}%", relit),
                                             ("|diff| x4", 4 * np.abs(relit - ref)))):
            ax.imshow(np.clip(_image(truth, values) / scale, 0, 1) ** (1 / 2.2))
            ax.set_title(f"{case.material}: {title}" if title == "reference" else title, fontsize=7)
            ax.axis("off")
    complete = [id(c) for c in cases] == [id(c) for c in group[:count]]
    among = "" if complete else f" among the {len(imaged)} with images"
    fig.suptitle(f"worst {len(cases)} of {model}{among} ({scene_label(scenes, result.setup.arrangement)}, noise {noise:g}, relit under {probe})", fontsize=8)
    fig.tight_layout()
    return save_png(fig, path, dpi=100)


PARTIAL_JSON = "measured.partial.json"


def write_partial(result: MeasuredResult, out: Path) -> Path:
    """Write the cases so far to ``out/measured.partial.json`` (same layout as ``measured.json``)."""
    from brdfrig._atomic import write_bytes as atomic_write_bytes
    from brdfrig.fit.brdffile import jsonable

    Path(out).mkdir(parents=True, exist_ok=True)
    return atomic_write_bytes(Path(out) / PARTIAL_JSON, json.dumps(jsonable(result_to_json(result)), indent=1).encode())


def write_outputs(result: MeasuredResult, out: Path) -> list[Path]:
    """Write ``errors.png``, ``worst.png``, ``estimates.png`` (if ``auto`` reported estimates), ``report.html``
    (those figures and the printed report) and ``measured.json`` into ``out``."""
    from brdfrig.fit.brdffile import jsonable
    from brdfrig._atomic import write_bytes as atomic_write_bytes
    from brdfrig.report.html import write_page

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    worst_of = worst_model(result)
    figures = [("Relighting error per material and model", plot_errors(result, out / "errors.png")),
               (f"The worst materials of {worst_of} (at most five): reference, relit, difference",
                plot_worst(result, out / "worst.png", worst_of)),
               ("auto: reported estimate against measured error", plot_estimates(result, out / "estimates.png"))]
    figures = [(h, p) for h, p in figures if p is not None]
    paths = [p for _, p in figures]
    paths.append(write_page(out / "report.html", report_title(result), figures + report_sections(result)))
    paths.append(atomic_write_bytes(out / "measured.json", json.dumps(jsonable(result_to_json(result)), indent=1).encode()))
    (out / PARTIAL_JSON).unlink(missing_ok=True)
    return paths
