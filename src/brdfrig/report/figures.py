"""Figures of a fit, after the seed's figure 6: measured, rendered, difference, difference x4.

One row per scene shown (at most ``max_rows``, spread over the session), four
columns: the measured sphere, the fitted BRDF rendered under that scene's
measured lighting, ``|measured - rendered|`` and the same magnified by two
f-stops (x4).  All four share one tone map (linear radiance scaled so that the
99.5th percentile of the measured sphere is 1, then sRGB-like gamma 1/2.2), so
the difference images are on the scale of the image itself.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

__all__ = ["fit_figure", "fit_figure_of", "png_bytes", "save_png", "tone_map"]


def tone_map(rgb: np.ndarray, scale: float) -> np.ndarray:
    """Linear radiance (H, W, C) -> displayable (H, W, 3) in [0, 1]: ``clip(rgb * scale) ** (1/2.2)``."""
    img = np.clip(np.nan_to_num(rgb) * scale, 0.0, 1.0) ** (1.0 / 2.2)
    return np.repeat(img, 3, axis=-1) if img.shape[-1] == 1 else img


def _disc_image(rows, cols, values, shape) -> np.ndarray:
    img = np.zeros(shape + (values.shape[1],))
    img[rows, cols] = values
    return img


def fit_figure(path: str | Path, scenes: list, pixels, brdf, *, title: str = "", max_rows: int = 3) -> Path:
    """Write :func:`fit_figure_of` as a PNG (atomically); returns the path."""
    return save_png(fit_figure_of(scenes, pixels, brdf, title=title, max_rows=max_rows), path, dpi=90)


def fit_figure_of(scenes: list, pixels, brdf, *, title: str = "", max_rows: int = 3):
    """The measured / rendered / difference / difference x4 figure (a matplotlib figure).

    Parameters
    ----------
    scenes : list of brdfrig.fit.scene.Scene
        The sample's scenes (lighting + observed pixels) as given to the fitter.
    pixels : SpherePixels-like or list of (rows, cols)
        Row/column of the scenes' pixels (same order as ``Scene.normals``): one object with
        ``rows``/``cols`` for all scenes (a session's sample), or one pair per scene.
    brdf : brdfrig.fit.brdf.FittedBRDF
        The fitted BRDF (rendered with ``brdf.predict``).
    title : str
        Figure title (sample name, model, error).
    max_rows : int
        Scenes shown, evenly spread over the session.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from brdfrig.fit.metrics import relative_rms

    per_scene = pixels if isinstance(pixels, (list, tuple)) else [(pixels.rows, pixels.cols)] * len(scenes)
    shown = sorted(set(np.linspace(0, len(scenes) - 1, min(max_rows, len(scenes))).round().astype(int)))
    fig, axes = plt.subplots(len(shown), 4, figsize=(10, 2.6 * len(shown) + 0.6), squeeze=False)
    for ax_row, s in zip(axes, shown):
        scene = scenes[s]
        rows, cols = (np.asarray(a) for a in per_scene[s])
        r0, c0 = rows.min(), cols.min()
        shape = (int(rows.max() + 1 - r0), int(cols.max() + 1 - c0))
        predicted = brdf.predict(scene.env, scene.normals)
        measured = _disc_image(rows - r0, cols - c0, scene.radiance, shape)
        rendered = _disc_image(rows - r0, cols - c0, predicted, shape)
        w = scene.weights > 0
        scale = 1.0 / max(float(np.percentile(scene.radiance[w], 99.5)), 1e-12) if w.any() else 1.0
        diff = np.abs(measured - rendered)
        err = relative_rms(predicted[w], scene.radiance[w]) if w.any() else float("nan")
        panels = [
            (measured, f"scene {s + 1}: measured"),
            (rendered, "rendered"),
            (diff, f"difference ({100 * err:.1f}% RMS)"),
            (4.0 * diff, "difference x4"),
        ]
        for ax, (img, label) in zip(ax_row, panels):
            ax.imshow(tone_map(img, scale), interpolation="nearest")
            ax.set_title(label, fontsize=9)
            ax.axis("off")
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig


def png_bytes(fig, *, dpi: int = 100) -> bytes:
    """Render a matplotlib figure to PNG bytes and close the figure."""
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    try:
        fig.savefig(buf, format="png", dpi=dpi)
    finally:
        plt.close(fig)
    return buf.getvalue()


def save_png(fig, path: str | Path, *, dpi: int = 100) -> Path:
    """Render a matplotlib figure to PNG, write it atomically (never a partial file) and close the figure."""
    from brdfrig._atomic import write_bytes as atomic_write_bytes

    return atomic_write_bytes(path, png_bytes(fig, dpi=dpi))
