"""Ground-truth renders cached on disk, keyed by every input and the renderer's source.

One cache serves ``brdfrig bench`` (analytic materials) and ``brdfrig bench --measured``
(measured materials, :mod:`brdfrig.evaluate.measured`): the renderer and the source
files it depends on are parameters, so a changed input or renderer gives a new key
and a stale render is never reused.
"""

from __future__ import annotations

import hashlib
import io
import json
from pathlib import Path
from types import ModuleType
from typing import Callable, Iterable

import numpy as np

from brdfrig.fit.scene import hash_arrays

__all__ = ["CachedGroundTruth", "brdf_identity"]


def brdf_identity(brdf) -> bytes:
    """Bytes that identify a BRDF's values: class, ``kind`` and ``kernel_params()`` when it has them
    (analytic families), else its ``to_dict()`` as sorted JSON (any :class:`brdfrig.fit.brdf.FittedBRDF`)."""
    name = type(brdf).__qualname__.encode()
    if hasattr(brdf, "kernel_params"):
        params = np.ascontiguousarray(brdf.kernel_params(), dtype=np.float64)
        return name + f":{int(brdf.kind)}:{params.shape}".encode() + params.tobytes()
    from brdfrig.fit.brdffile import jsonable

    return name + b":" + json.dumps(jsonable(brdf.to_dict()), sort_keys=True).encode()


class CachedGroundTruth:
    """A ground-truth renderer with its renders cached as ``.npy`` files in a directory.

    Parameters
    ----------
    directory : path
        Where the ``gt-<sha256>.npy`` files live (created on first write).
    render : callable or None
        ``(brdf, normals (N, 3), env) -> (N, C)`` radiance; None: :func:`brdfrig.fit.groundtruth.render_groundtruth`.
        For a BRDF whose ``stacks_lightings`` is true it must also render under stacked lightings
        (:func:`brdfrig.fit.scene.stack_lightings`, C = every lighting's channels), as the default does.
    sources : iterable of modules or None
        Modules whose source files enter the key (None: ``fit/groundtruth.py`` and ``fit/analytic.py``).

    The key is the sha256 of the sources, of the BRDF (:func:`brdf_identity`, or the ``identity``
    bytes the caller passes, e.g. a material file's hash), the normals, the environment's
    directions, radiance, solid angles and whether it carries its lat-long map, and the view.
    A cached file that does not load, has the wrong shape or holds non-finite values is
    rendered again.  ``hits``/``misses`` count cache use.
    """

    def __init__(self, directory: Path, render: Callable | None = None, sources: Iterable[ModuleType] | None = None):
        self.directory = Path(directory)
        self.hits = 0
        self.misses = 0
        self._render = render
        self._sources = None if sources is None else tuple(sources)
        self._code = None

    def _renderer(self) -> Callable:
        if self._render is None:
            from brdfrig.fit.groundtruth import render_groundtruth

            self._render = render_groundtruth
        return self._render

    def _source_bytes(self) -> bytes:
        if self._code is None:
            sources = self._sources
            if sources is None:
                import brdfrig.fit.analytic
                import brdfrig.fit.groundtruth

                sources = (brdfrig.fit.groundtruth, brdfrig.fit.analytic)
            self._code = b"".join(Path(m.__file__).read_bytes() for m in sources)
        return self._code

    def key(self, brdf, normals, env, view=(0.0, 0.0, 1.0), identity: bytes | None = None) -> str:
        """Hex sha256 of the render's inputs and the renderer's source."""
        h = hashlib.sha256(self._source_bytes())
        h.update(brdf_identity(brdf) if identity is None else b"id:" + bytes(identity))
        h.update(b"latlong" if getattr(env, "latlong", None) is not None else b"samples")
        hash_arrays(h, (normals, env.dirs, env.radiance, env.solid_angle, view))
        return h.hexdigest()

    def __call__(self, brdf, normals, env, identity: bytes | None = None) -> np.ndarray:
        """The render of ``brdf`` at ``normals`` under ``env`` (view +z): from the cache, else rendered and stored."""
        return self.renders(brdf, normals, [env], identity)[0]

    def renders(self, brdf, normals, envs, identity: bytes | None = None) -> list[np.ndarray]:
        """The render of ``brdf`` at ``normals`` under each of ``envs`` (view +z), each from the cache or rendered and
        stored.  Missing renders under lightings on the same samples are rendered in one call under them stacked
        (:func:`brdfrig.fit.scene.stack_lightings`) when the BRDF's ``stacks_lightings`` is true."""
        from brdfrig.fit.scene import render_per_lighting

        paths = [self.directory / f"gt-{self.key(brdf, normals, env, identity=identity)}.npy" for env in envs]
        out = [self._load(path, (len(normals), env.channels)) for path, env in zip(paths, envs)]
        missing = [k for k, image in enumerate(out) if image is None]
        self.hits += len(envs) - len(missing)
        self.misses += len(missing)
        render = self._renderer()
        images = render_per_lighting(lambda env: render(brdf, normals, env), [envs[k] for k in missing],
                                     bool(getattr(brdf, "stacks_lightings", False)))
        for k, image in zip(missing, images):
            self._store(paths[k], image)
            out[k] = image
        return out

    @staticmethod
    def _load(path: Path, shape: tuple[int, int]) -> np.ndarray | None:
        """The cached render at ``path``, or None if absent, unreadable, of another shape or not finite."""
        if not path.is_file():
            return None
        try:
            cached = np.load(path)
        except (OSError, ValueError, EOFError):
            return None
        return cached if cached.shape == shape and np.all(np.isfinite(cached)) else None

    def _store(self, path: Path, image: np.ndarray) -> None:
        from brdfrig._atomic import write_bytes as atomic_write_bytes

        buf = io.BytesIO()
        np.save(buf, np.ascontiguousarray(image))
        self.directory.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(path, buf.getvalue())
