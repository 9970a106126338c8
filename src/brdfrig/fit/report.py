"""The fit report of :func:`brdfrig.fit.fitter.fit_brdf` as dataclasses.

:meth:`FitReport.to_dict` gives the JSON layout stored under ``"report"`` in the BRDF file
(:mod:`brdfrig.fit.brdffile`); :meth:`FitReport.from_dict` reads it back.  A candidate's
linear-system statistics (:class:`SystemStats`) are stored flat in its dict, beside the
candidate's own keys.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields

__all__ = ["PixelCounts", "SystemStats", "RelightEstimate", "Candidate", "FitReport", "format_report", "summary_line"]


@dataclass
class PixelCounts:
    """Pixels of all scenes: total, excluded per reason, and used by the fit."""

    pixels: int
    weight_zero: int
    non_finite: int
    beyond_limb_margin: int
    used: int


@dataclass
class SystemStats:
    """The streamed linear system of a linear candidate (``diffuse``, ``lobe``, ``full``, ``full+prior``).

    ``rank``, ``condition_number`` (column-equilibrated), ``condition_number_regularised`` (Tikhonov
    only) and ``tikhonov_lambda_rel`` are per colour channel; ``reduced_stream`` is None or how the rows
    were streamed in a reduced basis; ``train_relative_rms`` is the weighted relative RMS residual on
    the rows used.
    """

    unknowns: int
    bands: list[int]
    lmax: int
    pmax: int | None
    solver: str
    rank: list[int]
    condition_number: list[float]
    condition_number_regularised: list[float] | None
    full_rank: bool
    reduced_stream: str | None
    tikhonov_lambda_rel: list[float] | None
    tikhonov_lambda_min_rel: float | None
    rows_used: int
    rows_available: int
    stopping_rule_converged: bool
    train_relative_rms: float


@dataclass
class RelightEstimate:
    """Estimated relative RMS error of relighting under lighting other than the fit's.

    Attributes
    ----------
    value : float or None
        The estimate (relative RMS over sphere pixels); None when none could be made.
    method : str
        How it was obtained (``"leave-one-scene-out"``, ``"rotated-lighting spread"``, ...).
    detail : str
        One line: what was compared, over which lightings or scenes.
    """

    value: float | None
    method: str
    detail: str = ""

    @property
    def how(self) -> str:
        """``"method: detail"``: how the estimate was obtained, as reports and the benchmark print it."""
        return f"{self.method}: {self.detail}"


@dataclass
class Candidate:
    """One model fitted (or skipped) by ``fit_brdf``.

    Attributes
    ----------
    name : str
        Model name (:data:`brdfrig.fit.registry.MODELS`).
    skipped : str or None
        Why it was not fitted (then every other field keeps its default).
    heldout_relative_rms : float or None
        Weighted relative RMS error on the held-out pixels (same lighting as the fit).
    full_rank : bool
        The pixel system reached full rank (linear models) or the fit calls itself determined.
    determined : bool
        Lighting analysis and pixels both determine the fit.
    seconds : float
        Wall clock of the fit.
    system : SystemStats or None
        Linear models only.
    prior : str or None
        ``full+prior``, ``bivariate+prior``: the candidate it is regularised toward.
    fit_report : dict or None
        Single-model fits (``microfacet``, ...): the fit's own report (its parameters).
    plausibility : dict or None
        :func:`brdfrig.fit.models.plausibility` of the fitted BRDF.
    radiance_check : str or None
        None when every radiance the fit predicted (held-out pixels, other lightings) is finite and
        non-negative; else what failed.
    relight : RelightEstimate or None
        Estimated relighting error under other lighting.
    """

    name: str
    skipped: str | None = None
    heldout_relative_rms: float | None = None
    full_rank: bool = False
    determined: bool = False
    seconds: float = 0.0
    system: SystemStats | None = None
    prior: str | None = None
    fit_report: dict | None = None
    plausibility: dict | None = None
    radiance_check: str | None = None
    relight: RelightEstimate | None = None

    @property
    def fitted(self) -> bool:
        return self.skipped is None

    def to_dict(self) -> dict:
        """JSON layout: the candidate's fields, its system statistics flat beside them, unset ones left out."""
        out = {k: v for k, v in asdict(self).items() if k not in ("name", "system", "relight") and v is not None}
        if self.system is not None:
            out.update(asdict(self.system))
        if self.relight is not None:
            out["relight"] = asdict(self.relight)
        return out

    @classmethod
    def from_dict(cls, name: str, d: dict) -> "Candidate":
        own = {f.name for f in fields(cls)} - {"name", "system", "relight"}
        system_keys = [f.name for f in fields(SystemStats)]
        system = SystemStats(**{k: d[k] for k in system_keys}) if all(k in d for k in system_keys) else None
        relight = RelightEstimate(**d["relight"]) if d.get("relight") else None
        return cls(name=name, system=system, relight=relight, **{k: d[k] for k in own if k in d})


@dataclass
class FitReport:
    """What ``fit_brdf`` did and why: inputs, identifiability, every candidate, the choice, warnings.

    ``relight`` is the chosen model's :class:`RelightEstimate`; ``selection`` names the criterion
    ``auto`` ranked the candidates by (or ``"requested"``); ``pixel_noise`` is the image's relative pixel
    noise estimated from its pixels (:mod:`brdfrig.fit.noise`; ``auto`` from one image only, None otherwise
    or when too few); ``stage_seconds`` has wall-clock seconds per stage (:data:`brdfrig.fit.stream.STAGES`).
    """

    chosen_model: str
    reason: str
    requested_model: str
    solver: str
    lmax: int
    pmax: int
    n_scenes: int
    pixels: PixelCounts
    limb_margin_max_theta_deg: float
    heldout_pixels: int
    stopping_rule: str
    unobservable_bands: list[int]
    identifiability: dict
    identifiability_summary: str
    candidates: dict[str, Candidate]
    selection: str
    relight: RelightEstimate | None
    pixel_noise: float | None = None
    warnings: list[str] = field(default_factory=list)
    seconds: float = 0.0
    stage_seconds: dict[str, float] = field(default_factory=dict)

    @property
    def chosen(self) -> Candidate:
        """The chosen model's candidate entry."""
        return self.candidates[self.chosen_model]

    def to_dict(self) -> dict:
        """The JSON layout (plain dicts and lists; numpy-free once :func:`brdfrig.fit.brdffile.jsonable` ran)."""
        out = {f.name: getattr(self, f.name) for f in fields(self)}
        out["pixels"] = asdict(self.pixels)
        out["candidates"] = {k: c.to_dict() for k, c in self.candidates.items()}
        out["relight"] = None if self.relight is None else asdict(self.relight)
        return out

    @classmethod
    def from_dict(cls, d: dict) -> "FitReport":
        """Inverse of :meth:`to_dict` (e.g. the ``report`` of a loaded BRDF file).

        Raises
        ------
        ValueError
            If a key is missing or of the wrong shape.
        """
        try:
            kw = {f.name: d[f.name] for f in fields(cls) if f.name in d}
            kw["pixels"] = PixelCounts(**d["pixels"])
            kw["candidates"] = {k: Candidate.from_dict(k, c) for k, c in d["candidates"].items()}
            kw["relight"] = RelightEstimate(**d["relight"]) if d.get("relight") else None
            return cls(**kw)
        except (KeyError, TypeError, AttributeError) as exc:
            raise ValueError(f"not a fit report: {exc!r}") from exc


def _channels(values) -> str:
    """Per-channel values as ``(a, b, c)`` with 3 significant digits."""
    return "(" + ", ".join(f"{v:.3g}" for v in values) + ")"


def _parameters(fit_report: dict, limit: int = 6) -> str:
    """A single-model fit's per-channel parameters (lists of numbers), at most ``limit`` of them."""
    items = [(k, v) for k, v in fit_report.items() if isinstance(v, list) and 0 < len(v) <= 4
             and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)
             and not any(w in k for w in ("samples", "pixels", "renders", "fraction", "lambda"))]
    return " ".join(f"{k} {_channels(v)}" for k, v in items[:limit])


def _references(entry: dict | None, limit: int = 3) -> str:
    """The measured materials carrying most of a reference prior (share averaged over the channels), or ''."""
    if not entry:
        return ""
    share: dict[str, float] = {}
    for ch in entry["channels"]:
        for r in ch["references"]:
            share[r["name"]] = share.get(r["name"], 0.0) + r["share"] / len(entry["channels"])
    top = sorted(share.items(), key=lambda kv: -kv[1])[:limit]
    return "prior: " + ", ".join(f"{name} {100 * v:.0f}%" for name, v in top)


def _pct(value: float | None) -> str:
    return "-" if value is None else f"{100 * value:.2f}%"


def _undetermined(c: Candidate) -> str:
    """"not determined", with the shape parameters a single-model fit left on a search bound."""
    bound = [k for k, on in ((c.fit_report or {}).get("at_bound") or {}).items() if on]
    return "not determined" + (f": {', '.join(bound)} on a search bound" if bound else "")


def format_report(report: FitReport) -> list[str]:
    """The lines ``brdfrig fit`` prints: pixels, one line per candidate, the choice and the relighting estimate."""
    lines = [f"pixels: {asdict(report.pixels)}"]
    if report.pixel_noise is not None:
        lines.append(f"pixel noise (estimated from the image): {_pct(report.pixel_noise)}")
    lines += [f"  {'model':10s} {'held-out':>9s} {'relight est.':>12s}  system / parameters"]
    for name, c in report.candidates.items():
        if not c.fitted:
            lines.append(f"  {name:10s} skipped: {c.skipped}")
            continue
        est = None if c.relight is None else c.relight.value
        text = f"  {name:10s} {_pct(c.heldout_relative_rms):>9s} {_pct(est):>12s} "
        if c.system is not None:
            text += f" rank {min(c.system.rank)}/{c.system.unknowns}, cond {max(c.system.condition_number):.3g}"
        elif c.fit_report is not None:
            text += " " + _parameters(c.fit_report) + _references(c.fit_report.get("references"))
        flags = [f for f, on in ((_undetermined(c), not c.determined), ("implausible", c.plausibility is not None
                 and not c.plausibility["plausible"]), (c.radiance_check, c.radiance_check is not None)) if on]
        lines.append(text + "".join(f"  [{f}]" for f in flags))
    lines.append(f"model: {report.chosen_model} ({report.reason})")
    rel = report.relight
    if rel is not None and rel.value is not None:
        lines.append(f"estimated relighting error under other lighting: {_pct(rel.value)} ({rel.how})")
        for name, key, what in (("bivariate+measured", "resampled_tables", "the references' resampled tables"),
                                (report.chosen_model, "fold_spread", "the fit's refits on the folds")):
            if key in ((report.candidates.get(name) or Candidate(name)).fit_report or {}):
                lines.append(f"  for a given lighting, 'brdfrig render --lighting' estimates it from {what}")
    else:
        lines.append(f"estimated relighting error under other lighting: none ({rel.detail if rel else 'not estimated'})")
    return lines


def summary_line(report: FitReport) -> str:
    """One line: chosen model and why, rank and condition number, relighting estimate."""
    c = report.chosen
    text = f"model {report.chosen_model} ({report.reason})"
    if c.system is not None:
        text += f", rank {min(c.system.rank)} of {c.system.unknowns} unknowns, condition number {max(c.system.condition_number):.3g}"
    if report.relight is not None and report.relight.value is not None:
        text += f", estimated relighting error {_pct(report.relight.value)} ({report.relight.method})"
    return text
