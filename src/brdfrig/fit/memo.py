"""Renders kept by what they were computed from, for fits that ask for the same render again.

A render over a pixel set and a lighting (a lobe's columns at one roughness, a design block) depends only on
their content and the render's own parameters, never on the radiance being fitted.  The candidates of one
``auto`` fit render many of the same columns (every family searches the same roughness grid on the same
pixels), and so do the fits of different materials seen on one sphere under one lighting (a benchmark).
:class:`RenderMemo` keeps those renders by a key the caller builds from
:func:`brdfrig.fit.scene.content_digest` and the parameters, least recently used dropped first past a byte
budget.  A kept array is read-only: a caller that writes into it is a bug, and numpy says so.

:data:`RENDERS` is the process's memo of the fitters' column renders (:mod:`brdfrig.fit.microfacet`,
:mod:`brdfrig.fit.pbr_fit`, the fit designs of :mod:`brdfrig.fit.bivariate`).  Written by hand: the keys are
content digests the callers already compute, and :func:`functools.lru_cache` bounds entries, not bytes.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from typing import Callable, Hashable

import numpy as np

__all__ = ["RenderMemo", "RENDERS", "RENDERS_BYTES"]

RENDERS_BYTES = 512 << 20
"""Byte budget of :data:`RENDERS`: a 2000-pixel lobe render of three channels is 0.1-0.6 MB, a fit design block
of 512 pixels at 24 x 8 nodes 4.7 MB."""


class RenderMemo:
    """Arrays by key, least recently used dropped first while their bytes exceed ``max_bytes``.

    Parameters
    ----------
    max_bytes : int
        Budget; an array larger than the whole budget is computed and returned, never kept.
    second_sight : bool
        Keep an array only when its key is asked for the second time (for large renders that a single fit
        needs once); the keys seen are remembered, the latest ``seen_keys`` of them.
    seen_keys : int
        How many first-sight keys are remembered (``second_sight`` only).
    """

    def __init__(self, max_bytes: int, *, second_sight: bool = False, seen_keys: int = 4096) -> None:
        self.max_bytes = int(max_bytes)
        self.second_sight = second_sight
        self.seen_keys = seen_keys
        self._kept: OrderedDict = OrderedDict()
        self._seen: OrderedDict = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self._kept)

    def __contains__(self, key: Hashable) -> bool:
        return key in self._kept

    def clear(self) -> None:
        """Forget every kept array and every key seen."""
        with self._lock:
            self._kept.clear()
            self._seen.clear()
            self._bytes = 0

    def first_sight(self, key: Hashable) -> bool:
        """Whether ``key`` is neither kept nor seen before (``second_sight``: the call marks it seen); always
        False without ``second_sight``."""
        if not self.second_sight:
            return False
        with self._lock:
            if key in self._kept or key in self._seen:
                return False
            self._seen[key] = None
            while len(self._seen) > self.seen_keys:
                self._seen.popitem(last=False)
            return True

    def get(self, key: Hashable, compute: Callable[[], np.ndarray]) -> np.ndarray:
        """The array kept for ``key``, or ``compute()`` (kept, read-only, as the policy allows)."""
        with self._lock:
            if key in self._kept:
                self._kept.move_to_end(key)
                return self._kept[key]
        value = compute()
        if self.first_sight(key) or value.nbytes > self.max_bytes:
            return value
        value.flags.writeable = False
        with self._lock:
            if key not in self._kept:
                self._kept[key] = value
                self._bytes += value.nbytes
            while self._bytes > self.max_bytes:
                _, old = self._kept.popitem(last=False)
                self._bytes -= old.nbytes
        return value


RENDERS = RenderMemo(RENDERS_BYTES)
