"""Plain-array inputs of the fitter: an environment (lighting) and a scene (lighting + one sphere image).

Conventions (``../shared/docs/MATH.md``): world frame right-handed, orthographic
camera along +z, view direction ``v = (0, 0, 1)``; radiance linear, float, one
column per colour channel.  ``fit`` never reads files: ``capture`` builds these
from ``hdr`` outputs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Environment:
    """Distant lighting as discrete samples of the sphere of directions.

    Attributes
    ----------
    dirs : (M, 3) float64
        Unit directions the light arrives FROM (world frame).
    radiance : (M, C) float64
        Radiance arriving from each direction, linear.
    solid_angle : (M,) float64
        Solid angle of each sample in steradians (0 where unseen).
    """

    dirs: np.ndarray
    radiance: np.ndarray
    solid_angle: np.ndarray

    @property
    def channels(self) -> int:
        return self.radiance.shape[1]


@dataclass(frozen=True)
class Scene:
    """One lighting condition and the sphere pixels observed under it.

    Attributes
    ----------
    env : Environment
        The lighting of this scene.
    normals : (N, 3) float64
        Unit surface normals of the observed sphere pixels (MATH.md image convention).
    radiance : (N, C) float64
        Observed linear radiance of those pixels (same channels as ``env``).
    weights : (N,) float64
        Per-pixel least-squares weight in [0, 1] (0 = ignore: limb, clipped, NaN).
    """

    env: Environment
    normals: np.ndarray
    radiance: np.ndarray
    weights: np.ndarray
