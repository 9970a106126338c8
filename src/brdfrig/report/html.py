"""Self-contained HTML reports (every image inlined as a PNG data URI): a fit's, and a benchmark's page.

A fit's report (:func:`report_html`): the summary (model, why, estimated relighting error),
the fitted scenes (measured / rendered / difference), the fitted BRDF relit under the three
standard lightings (:func:`brdfrig.lighting.standard_lightings`), BRDF plots
(:mod:`brdfrig.report.plots`), the candidates and fit statistics, the identifiability table,
warnings and the exports made.  A session's report holds one such part per sample.

A benchmark's page (:func:`page_html`): its figures and its printed tables, section by section.
"""

from __future__ import annotations

import base64
import html
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["SampleReport", "relit_spheres", "report_html", "write_report", "page_html", "write_page"]

RELIGHT_SIZE = 96
"""Side (pixels) of the relit spheres."""

_CSS = """
body { font-family: sans-serif; margin: 2em; color: #222; max-width: 1200px; }
h1 { font-size: 1.6em; } h2 { font-size: 1.25em; border-bottom: 1px solid #ccc; margin-top: 1.6em; }
table { border-collapse: collapse; font-size: 0.85em; margin: 0.6em 0; }
td, th { border: 1px solid #ccc; padding: 3px 8px; text-align: right; } th { background: #f0f0f0; }
td.l, th.l { text-align: left; } .warn { color: #a00; } figure { display: inline-block; margin: 0.4em; }
pre { font-size: 0.8em; overflow-x: auto; }
figcaption { font-size: 0.8em; text-align: center; } img { max-width: 100%; } .summary { font-size: 1.05em; }
"""


@dataclass
class SampleReport:
    """What the report shows of one fitted sample.

    Attributes
    ----------
    name : str
        Sample name.
    brdf : FittedBRDF
        The fitted BRDF.
    report : dict
        The fit report (:meth:`brdfrig.fit.report.FitReport.to_dict` layout).
    fit_png : bytes or None
        The measured / rendered / difference figure of the fitted scenes.
    exports : list of dict
        Exports made of this fit (``{"format", "path", "error"}``).
    """

    name: str
    brdf: object
    report: dict
    fit_png: bytes | None = None
    exports: list = field(default_factory=list)


def _img(png: bytes, alt: str, width: int | None = None) -> str:
    size = f' width="{width}"' if width else ""
    return f'<img alt="{html.escape(alt)}"{size} src="data:image/png;base64,{base64.b64encode(png).decode()}">'


def relit_spheres(brdf, size: int = RELIGHT_SIZE) -> dict[str, bytes]:
    """PNG of the BRDF's sphere (``size`` px, MATH.md view) under each standard lighting, tone-mapped."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from brdfrig.lighting import standard_lightings
    from brdfrig.report.figures import png_bytes, tone_map

    pix_r, pix_c = np.mgrid[0:size, 0:size]
    dx = (pix_c + 0.5 - size / 2) / (size / 2)
    dy = (size / 2 - (pix_r + 0.5)) / (size / 2)
    inside = dx**2 + dy**2 < 1.0
    normals = np.stack([dx[inside], dy[inside], np.sqrt(1.0 - dx[inside] ** 2 - dy[inside] ** 2)], axis=1)
    out = {}
    for name, env in standard_lightings().items():
        pred = np.maximum(np.nan_to_num(np.asarray(brdf.predict(env, normals), dtype=float)), 0.0)
        img = np.zeros((size, size, pred.shape[1]))
        img[inside] = pred
        fig = plt.figure(figsize=(2, 2))
        ax = fig.add_axes([0, 0, 1, 1])
        ax.imshow(tone_map(img, 1.0 / max(float(np.percentile(pred, 99.5)), 1e-12)))
        ax.axis("off")
        out[name] = png_bytes(fig, dpi=size / 2)
    return out


def _table(header: list[str], rows: list[list], left: int = 1) -> str:
    def cell(tag, i, v):
        cls = ' class="l"' if i < left else ""
        return f"<{tag}{cls}>{html.escape(str(v))}</{tag}>"

    head = "".join(cell("th", i, h) for i, h in enumerate(header))
    body = "".join("<tr>" + "".join(cell("td", i, v) for i, v in enumerate(r)) + "</tr>" for r in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def _pct(v) -> str:
    return "-" if v is None else f"{100 * float(v):.2f}%"


def _candidates(report: dict) -> str:
    rows = []
    for name, c in report.get("candidates", {}).items():
        if c.get("skipped"):
            rows.append([name, "skipped", "", "", c["skipped"]])
            continue
        relight = (c.get("relight") or {}).get("value")
        rank = f"{min(c['rank'])}/{c['unknowns']}" if "rank" in c else ""
        rows.append([name, _pct(c.get("heldout_relative_rms")), _pct(relight), "yes" if c.get("determined") else "no",
                     rank or f"{c.get('seconds', 0):.2f} s"])
    return _table(["model", "held-out error", "relighting estimate", "determined", "rank / time"], rows)


def _identifiability(report: dict) -> str:
    ident = report.get("identifiability") or {}
    rows = [[k, v.get("unknowns", ""), v.get("rank", ""), "yes" if v.get("determined") else "no", v.get("reason", "")]
            for k, v in (ident.get("models") or {}).items()]
    text = f"<pre>{html.escape(report.get('identifiability_summary', ''))}</pre>"
    return text + (_table(["model", "unknowns", "rank", "determined", "why"], rows) if rows else "")


def _sample_html(s: SampleReport, relit: dict[str, bytes], plot_png: bytes) -> str:
    r = s.report
    rel = r.get("relight") or {}
    parts = [f"<h2>{html.escape(s.name)}</h2>",
             f'<p class="summary">model <b>{html.escape(str(r.get("chosen_model", s.brdf.model)))}</b>: '
             f'{html.escape(str(r.get("reason", "")))}<br>estimated relighting error under other lighting: '
             f'<b>{_pct(rel.get("value"))}</b> ({html.escape(str(rel.get("method", "not estimated")))}'
             f'{": " + html.escape(rel["detail"]) if rel.get("detail") else ""})</p>']
    if s.fit_png:
        parts += ["<h3>Fitted scenes: measured, rendered, difference</h3>", _img(s.fit_png, f"{s.name} fit")]
    parts.append("<h3>Relit under the standard lightings</h3>")
    parts += [f"<figure>{_img(png, f'{s.name} under {k}', RELIGHT_SIZE * 2)}<figcaption>{k}</figcaption></figure>"
              for k, png in relit.items()]
    parts += ["<h3>BRDF</h3>", _img(plot_png, f"{s.name} BRDF plots"),
              "<h3>Candidates</h3>", _candidates(r), "<h3>What the lighting determines</h3>", _identifiability(r)]
    if r.get("pixels"):
        parts.append(_table(["pixels", *r["pixels"].keys()], [["count", *r["pixels"].values()]]))
    parts += [f'<p class="warn">warning: {html.escape(w)}</p>' for w in r.get("warnings", [])]
    if s.exports:
        parts += ["<h3>Exports</h3>", _table(["format", "file", "approximation error"],
                                             [[e["format"], e["path"], _pct(e.get("error"))] for e in s.exports])]
    return "\n".join(parts)


def report_html(title: str, samples: list[SampleReport], *, notes: str = "") -> str:
    """The whole report as one HTML string (no external resources)."""
    from brdfrig import __version__
    from brdfrig.report.plots import brdf_figure
    from brdfrig.report.figures import png_bytes

    body = [f"<h1>{html.escape(title)}</h1>",
            f"<p>brdfrig {html.escape(__version__)}{' - ' + html.escape(notes) if notes else ''}</p>"]
    for s in samples:
        plot = png_bytes(brdf_figure({s.name: s.brdf}, title=f"{s.name}: {s.brdf.model}"), dpi=80)
        body.append(_sample_html(s, relit_spheres(s.brdf), plot))
    return _document(title, body)


def _document(title: str, body: list[str]) -> str:
    return (f"<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{html.escape(title)}</title>"
            f"<style>{_CSS}</style></head><body>\n" + "\n".join(body) + "\n</body></html>\n")


def write_report(path, title: str, samples: list[SampleReport], *, notes: str = "") -> Path:
    """Write :func:`report_html` atomically to ``path``."""
    from brdfrig._atomic import write_text

    return write_text(path, report_html(title, samples, notes=notes))


def page_html(title: str, sections: list[tuple[str, str | Path]]) -> str:
    """One HTML page of ``(heading, content)`` sections: a ``str`` is shown as preformatted text (a printed
    table), a :class:`~pathlib.Path` is a PNG file, inlined."""
    body = [f"<h1>{html.escape(title)}</h1>"]
    for heading, content in sections:
        body.append(f"<h2>{html.escape(heading)}</h2>")
        if isinstance(content, Path):
            body.append(_img(content.read_bytes(), heading))
        else:
            body.append(f"<pre>{html.escape(content)}</pre>")
    return _document(title, body)


def write_page(path, title: str, sections: list[tuple[str, str | Path]]) -> Path:
    """Write :func:`page_html` atomically to ``path``."""
    from brdfrig._atomic import write_text

    return write_text(path, page_html(title, sections))
