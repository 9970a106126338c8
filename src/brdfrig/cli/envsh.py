"""``brdfrig envsh``: project a lat-long environment map to SH and compare reconstructions.

The figure shows the original map next to its SH reconstruction at each band
limit (like figure 5 of the seed paper), all tone-mapped with the same
exposure, each titled with its relative error (solid-angle-weighted RMS over
the sphere, relative to the map's RMS).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from brdfrig.cli._output import add_output_arguments, check_output
from brdfrig.errors import InputError

DEFAULT_BANDS = (5, 15, 35)
WINDOW_CHOICES = ("none", "hann", "lanczos")


def parse_bands(text: str) -> tuple[int, ...]:
    """``"5,15,35"`` -> ``(5, 15, 35)`` (sorted, unique, each in 0..200)."""
    try:
        bands = sorted({int(b) for b in text.split(",") if b.strip()})
    except ValueError:
        raise InputError(f"--bands must be comma-separated integers, got {text!r}") from None
    if not bands or bands[0] < 0 or bands[-1] > 200:
        raise InputError(f"--bands must list band limits in 0..200, got {text!r}")
    return tuple(bands)


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "envsh",
        help="project an environment map to spherical harmonics and plot reconstructions",
        description="Project a lat-long environment map (OpenEXR LatLong layout) to real spherical harmonics and "
        "write a PNG comparing it with its reconstruction at each band limit (seed paper, figure 5).",
    )
    p.add_argument("env", metavar="ENV", type=Path, help="lat-long environment map (.hdr or .exr, OpenEXR LatLong layout)")
    p.add_argument("--bands", default=",".join(map(str, DEFAULT_BANDS)), help="band limits to show (default: 5,15,35)")
    p.add_argument("--window", choices=WINDOW_CHOICES, default="none", help="taper against ringing (default: none)")
    add_output_arguments(p, "FIG.png", "figure to write (PNG)")
    p.set_defaults(func=run)


def tone_map(rgb, exposure: float):
    """Linear radiance -> displayable sRGB-like values in [0, 1] (scale, clip, gamma 1/2.2)."""
    import numpy as np

    return np.clip(rgb * exposure, 0.0, 1.0) ** (1 / 2.2)


def run(args: argparse.Namespace) -> int:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    from tqdm import tqdm

    from brdfrig.fit.shproject import project_latlong, reconstruct_latlong, sh_window
    from brdfrig.hdr.envmap import latlong_directions
    from brdfrig.report.figures import save_png
    from brdfrig.hdr.exr import read_image

    bands = parse_bands(args.bands)
    out = check_output(args.output, [args.env], suffixes=(".png",), writes="a PNG figure", no_clobber=args.no_clobber,
                       option="--output")
    image = read_image(args.env).astype(np.float64)
    if image.shape[2] == 1:
        image = np.repeat(image, 3, axis=2)
    h, w, _ = image.shape
    if w <= 2 * bands[-1]:
        raise InputError(f"{args.env}: a map {w} pixels wide resolves band limits up to {(w - 1) // 2}, not {bands[-1]}")
    _, solid = latlong_directions(h, w)
    norm = np.sqrt((solid[..., None] * image**2).sum())
    if norm == 0:
        raise InputError(f"{args.env}: the map is black")

    coeffs = project_latlong(image, bands[-1])
    panels = [(f"original ({w}x{h})", image)]
    errors = []
    for lmax in tqdm(bands, desc="envsh", file=sys.stderr):
        factors = np.repeat(sh_window(lmax, args.window), 2 * np.arange(lmax + 1) + 1)
        rec = reconstruct_latlong(coeffs[: (lmax + 1) ** 2] * factors[:, None], h, w)
        err = np.sqrt((solid[..., None] * (rec - image) ** 2).sum()) / norm
        errors.append(err)
        window = "" if args.window == "none" else f", {args.window}"
        panels.append((f"l <= {lmax}{window}: relative RMS error {100 * err:.1f}%", rec))

    luminance = image @ np.array([0.2126, 0.7152, 0.0722])
    exposure = 1.0 / max(float(np.percentile(luminance, 99)), 1e-12)
    cols = 2
    rows = (len(panels) + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(6.4 * cols, 3.4 * rows), squeeze=False)
    for ax, (title, img) in zip(axes.ravel(), panels):
        ax.imshow(tone_map(img, exposure), interpolation="nearest")
        ax.set_title(title, fontsize=10)
        ax.set_axis_off()
    for ax in axes.ravel()[len(panels) :]:
        ax.set_visible(False)
    fig.suptitle(f"{Path(args.env).name}: spherical-harmonic reconstructions (same exposure)", fontsize=11)
    fig.tight_layout()
    save_png(fig, out)
    for lmax, err in zip(bands, errors):
        print(f"l <= {lmax:3d}: relative RMS error {100 * err:6.2f}%")
    print(f"wrote {out}")
    return 0
