"""Is a lat-long lighting map the right way round for the sphere image taken under it?

A map exported mirrored left-right (a common mistake) or turned about its up
axis is still a valid map, and the fitter would fit it: worse, but silently.
:func:`check_orientation` fits the sphere pixels with a cheap linear model (the
``lobe`` model at a low band limit, on a box-downsampled copy of the map) under
the map as given, mirrored, turned by 90, 180 and 270 degrees and mirrored +
turned 180 degrees, and compares the relative RMS residuals.  A real sphere
under the right map leaves a small residual (0.2-3% on the three probes of
``../shared/data/probes`` with Lambertian and GGX spheres, ``tests/test_orientation.py``);
the wrong variants leave 1.2-26%, and the variant that undoes the mistake
leaves what the right map does.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from brdfrig.fit.metrics import relative_rms
from brdfrig.fit.scene import Scene
from brdfrig.fit.shproject import project_environment
from brdfrig.fit.system import ModelSpec, design_rows
from brdfrig.lighting import environment_from_latlong

__all__ = ["VARIANTS", "OrientationCheck", "check_orientation"]

AS_GIVEN = "as given"
VARIANTS = {
    AS_GIVEN: lambda im: im,
    "mirrored left-right": lambda im: im[:, ::-1],
    "turned 90 deg": lambda im: np.roll(im, im.shape[1] // 4, axis=1),
    "turned 180 deg": lambda im: np.roll(im, im.shape[1] // 2, axis=1),
    "turned 270 deg": lambda im: np.roll(im, 3 * im.shape[1] // 4, axis=1),
    "mirrored and turned 180 deg": lambda im: np.roll(im[:, ::-1], im.shape[1] // 2, axis=1),
}
"""Transformations of a lat-long image (H, W, C): column flips and rolls (turns about the map's up axis)."""

BETTER = 0.5  # another variant's residual below this fraction of the given map's ...
FLOOR = 0.01  # ... while the given map's exceeds 1%: warn


@dataclass(frozen=True)
class OrientationCheck:
    """Relative RMS residual of the cheap fit under each variant of the map (:data:`VARIANTS` keys)."""

    residuals: dict[str, float]

    @property
    def best(self) -> str:
        return min(self.residuals, key=self.residuals.get)

    def warning(self, name: str) -> str | None:
        """A one-line warning naming the map file ``name`` when another orientation fits much better, else None."""
        given, best = self.residuals[AS_GIVEN], self.best
        if best == AS_GIVEN or given <= FLOOR or self.residuals[best] >= BETTER * given:
            return None
        return (f"{name}: the sphere image fits this lighting much better {best} ({100 * self.residuals[best]:.2g}% "
                f"residual vs {100 * given:.2g}% as given): was the map exported {best}?")


def _box(image: np.ndarray, factor: int) -> np.ndarray:
    h, w, c = image.shape
    f = max(1, min(factor, h // 8))
    return image[: h - h % f, : w - w % f].reshape(h // f, f, w // f, f, c).mean(axis=(1, 3))


def check_orientation(scene: Scene, *, lmax: int = 4, downsample: int = 4, max_pixels: int = 4000
                      ) -> OrientationCheck | None:
    """Residuals of a ``lobe`` fit at band ``lmax`` under every variant of the scene's lat-long map.

    Parameters
    ----------
    scene : Scene
        A sphere image under a lighting built from a lat-long map (``scene.env.latlong``).
    lmax : int
        Band limit of the cheap fit (the map is box-downsampled by ``downsample``).
    max_pixels : int
        Sphere pixels used at most (evenly spaced).

    Returns
    -------
    OrientationCheck, or None when the lighting has no lat-long map (a mirror-ball probe).
    """
    latlong = scene.env.latlong
    if latlong is None:
        return None
    small = _box(np.asarray(latlong.image, np.float64), downsample)
    coeffs = [project_environment(environment_from_latlong(f(small), latlong.rotation), lmax)
              for f in VARIANTS.values()]
    use = np.flatnonzero(scene.weights > 0)
    use = use[np.linspace(0, len(use) - 1, min(len(use), max_pixels)).astype(int)] if len(use) else use
    normals, b, w = scene.normals[use], scene.radiance[use], scene.weights[use]
    k = len(VARIANTS)
    spec = ModelSpec("lobe", lmax, 0)
    a = design_rows(spec, coeffs, np.repeat(np.arange(k), len(use)), np.tile(normals, (k, 1)))
    residuals = {}
    for v, name in enumerate(VARIANTS):
        av = a[v * len(use):(v + 1) * len(use)]
        pred = np.empty_like(b)
        for c in range(b.shape[1]):  # weighted normal equations: small (2 lmax + 1 unknowns), no LAPACK threads
            aw = av[:, :, c] * w[:, None]
            gram = aw.T @ av[:, :, c]
            x = np.linalg.solve(gram + 1e-12 * np.trace(gram) * np.eye(len(gram)), aw.T @ b[:, c])
            pred[:, c] = av[:, :, c] @ x
        residuals[name] = relative_rms(pred, b, w)
    return OrientationCheck(residuals)
