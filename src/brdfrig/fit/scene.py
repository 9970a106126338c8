"""Plain-array inputs of the fitter: an environment (lighting) and a scene (lighting + one sphere image).

Conventions (``docs/MATH.md``): world frame right-handed, orthographic
camera along +z, view direction ``v = (0, 0, 1)``; radiance linear, float, one
column per colour channel.  ``fit`` never reads files: ``capture`` builds these
from ``hdr`` outputs.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class LatLongMap:
    """A lat-long radiance map kept whole, so that quadrature can subdivide its cells.

    Attributes
    ----------
    image : (H, W, C) float64
        Radiance per cell, constant over the cell, in the lat-long convention of
        MATH.md (OpenEXR ``LatLongMap``, cell centres at ``(col + 0.5) / W``,
        ``(row + 0.5) / H``; row 0 is +y).
    rotation : (3, 3) float64
        World direction of a map direction ``d``: ``rotation @ d`` (identity when the
        map frame is the world frame; a turned rig gives another rotation).
    """

    image: np.ndarray
    rotation: np.ndarray


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
    latlong : LatLongMap or None
        The map these samples are the cell centres of (row-major, ``dirs`` =
        ``rotation @`` cell-centre directions), when they came from one; None for
        other sample sets.  Lets renderers integrate sharp lobes over cells
        instead of sampling cell centres (MATH.md pitfall 9).
    lightings : int
        How many lightings the channels hold, side by side on the same samples (:func:`stack_lightings`):
        channel ``k * C + c`` is channel ``c`` of lighting ``k``, ``C = channels / lightings``.
    """

    dirs: np.ndarray
    radiance: np.ndarray
    solid_angle: np.ndarray
    latlong: LatLongMap | None = None
    lightings: int = 1

    @property
    def channels(self) -> int:
        return self.radiance.shape[1]

    def check_channels(self, brdf_channels: int) -> None:
        """ValueError unless a BRDF of ``brdf_channels`` channels fits this environment: one per channel of each of
        its :attr:`lightings`."""
        if brdf_channels * self.lightings != self.channels:
            raise ValueError(f"BRDF has {brdf_channels} channels but the environment has {self.channels}"
                             + (f" ({self.lightings} lightings)" if self.lightings > 1 else ""))

    def rotated(self, rotation: np.ndarray) -> "Environment":
        """The same lighting turned by the (3, 3) rotation matrix ``rotation`` (directions ``rotation @ d``).

        When the turn carries every cell of the lat-long map onto another (about the map's pole by a whole
        number of columns, for one), the result keeps this environment's samples and permutes their radiance
        (:func:`cell_permutation`), so it stacks with it (:func:`stack_lightings`); otherwise its samples turn.
        """
        rot = np.asarray(rotation, dtype=np.float64)
        perm = cell_permutation(self, rot)
        if perm is not None:
            h, w, c = self.latlong.image.shape
            image = self.latlong.image.reshape(h * w, c)[perm].reshape(h, w, c)
            return Environment(self.dirs, np.asarray(self.radiance)[perm], np.asarray(self.solid_angle)[perm],
                               LatLongMap(image, self.latlong.rotation), self.lightings)
        latlong = None if self.latlong is None else LatLongMap(self.latlong.image, rot @ self.latlong.rotation)
        return Environment(np.asarray(self.dirs) @ rot.T, self.radiance, self.solid_angle, latlong, self.lightings)


CELL_MATCH = 1e-12
"""A turned cell centre lands on a cell centre when their directions' dot product is above ``1 - CELL_MATCH``
(1.4e-6 radians)."""


def cell_permutation(env: Environment, rotation: np.ndarray) -> np.ndarray | None:
    """Sample index ``p`` with ``env.dirs[p[i]] = rotation.T @ env.dirs[i]`` (to :data:`CELL_MATCH`): the cell
    whose light the turned lighting sends from sample ``i``.  None unless ``env`` keeps a lat-long map and
    ``rotation`` carries every cell centre onto one.

    The candidate cell of a direction follows the lat-long convention (MATH.md: row 0 at +y, column centres at
    longitude ``-2 pi ((col + 0.5) / W - 0.5)`` from +z toward +x); every match is then checked on the
    directions themselves.
    """
    if env.latlong is None:
        return None
    h, w = env.latlong.image.shape[:2]
    dirs = np.asarray(env.dirs, dtype=np.float64)
    source = dirs @ np.asarray(rotation, dtype=np.float64)
    in_map = source @ np.asarray(env.latlong.rotation, dtype=np.float64)
    row = np.floor((0.5 - np.arcsin(np.clip(in_map[:, 1], -1.0, 1.0)) / np.pi) * h).astype(np.int64)
    col = np.floor((0.5 - np.arctan2(in_map[:, 0], in_map[:, 2]) / (2 * np.pi)) * w).astype(np.int64) % w
    perm = np.clip(row, 0, h - 1) * w + col
    if np.all(np.einsum("ij,ij->i", dirs[perm], source) > 1.0 - CELL_MATCH) and np.unique(perm).size == perm.size:
        return perm
    return None


def same_samples(a: Environment, b: Environment) -> bool:
    """Whether ``a`` and ``b`` light the same samples (directions, solid angles, lat-long map shape and rotation)
    with as many channels per lighting: whether :func:`stack_lightings` can hold both."""
    if not (np.array_equal(a.dirs, b.dirs) and np.array_equal(a.solid_angle, b.solid_angle)
            and a.channels // a.lightings == b.channels // b.lightings and (a.latlong is None) == (b.latlong is None)):
        return False
    return a.latlong is None or (a.latlong.image.shape[:2] == b.latlong.image.shape[:2]
                                 and np.array_equal(a.latlong.rotation, b.latlong.rotation))


def group_by_samples(envs: list[Environment]) -> list[list[int]]:
    """Indices of ``envs`` in groups that share their samples (:func:`same_samples`), in order of first appearance."""
    groups: list[list[int]] = []
    for i, env in enumerate(envs):
        for group in groups:
            if same_samples(envs[group[0]], env):
                group.append(i)
                break
        else:
            groups.append([i])
    return groups


def stack_lightings(envs: list[Environment]) -> Environment:
    """One environment holding every lighting of ``envs`` side by side in its channels (:attr:`Environment.lightings`).

    A render under it evaluates each BRDF value once for all the lightings; its channels split back into the
    lightings' renders in order.  ValueError unless the lightings share their samples (:func:`same_samples`).
    """
    first = envs[0]
    if not all(same_samples(first, env) for env in envs[1:]):
        raise ValueError("only lightings on the same samples stack")
    latlong = None if first.latlong is None else LatLongMap(
        np.concatenate([e.latlong.image for e in envs], axis=2), first.latlong.rotation)
    return Environment(first.dirs, np.concatenate([e.radiance for e in envs], axis=1), first.solid_angle, latlong,
                       sum(e.lightings for e in envs))


def render_per_lighting(render, envs: list[Environment], stack: bool) -> list[np.ndarray]:
    """``render(env)`` as float64 (N, C, ...) for each of ``envs``, in order; with ``stack``, the lightings on the
    same samples (:func:`group_by_samples`) in one call under them stacked (:func:`stack_lightings`), its channels
    (axis 1) split back into theirs."""
    out: list = [None] * len(envs)
    for group in group_by_samples(envs):
        if stack and len(group) > 1:
            image = np.asarray(render(stack_lightings([envs[k] for k in group])), dtype=np.float64)
            parts = np.split(image, len(group), axis=1)
        else:
            parts = [np.asarray(render(envs[k]), dtype=np.float64) for k in group]
        for k, part in zip(group, parts):
            out[k] = part
    return out


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


def content_digest(normals: np.ndarray, env: Environment) -> bytes:
    """Digest of the content of pixel normals and a lighting (map, rotation, samples): the key of what a
    render over them can reuse."""
    h = hashlib.blake2b(digest_size=16)
    parts = [normals, env.dirs, env.radiance, env.solid_angle]
    if env.latlong is not None:
        parts += [env.latlong.image, env.latlong.rotation]
    hash_arrays(h, parts)
    return h.digest()


def hash_arrays(h, arrays) -> None:
    """Feed each array's shape and its float64 C-order bytes, in turn, to ``h`` (a :mod:`hashlib` object)."""
    for a in arrays:
        a = np.ascontiguousarray(a, dtype=np.float64)
        h.update(repr(a.shape).encode())
        h.update(a.tobytes())
