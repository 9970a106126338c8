"""Camera interface shared by the gphoto2, watched-folder and simulated backends.

A camera sets an exposure (shutter time, ISO, aperture), takes a picture and
leaves the camera's own file (RAW/DNG/TIFF, with the exposure metadata inside)
in a destination folder, returning its path.  Files appear atomically: a
reader never sees a partial file under the returned name.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Protocol, Self, runtime_checkable

__all__ = ["Camera", "check_exposure", "free_name"]


@runtime_checkable
class Camera(Protocol):
    """A still camera that writes one file per capture.

    The backends subclass it explicitly and so inherit its defaults: a no-op :meth:`begin_shot`,
    :meth:`open` and :meth:`close`, and a context manager that opens and closes the camera.
    """

    def open(self) -> None:
        """Connect to the camera (default: nothing to connect)."""

    def close(self) -> None:
        """Release the camera; never raises (default: nothing to release)."""

    def __enter__(self) -> Self:
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def begin_shot(self, key: str) -> None:
        """Hook called by the session runner before each shot's capture with the shot's key
        (:func:`brdfrig.session.plan.shot_key`); a real camera ignores it.  The simulator derives its
        noise from it, so a resumed session writes exactly the files an uninterrupted one would."""

    def set_exposure(self, time_s: float, iso: float, f_number: float) -> None:
        """Set shutter time (seconds), ISO and aperture (f-number) for the next captures."""

    def capture(self, dest_dir: str | os.PathLike) -> Path:
        """Take one picture; return the path of the complete file written into ``dest_dir``."""


def check_exposure(time_s: float, iso: float, f_number: float) -> tuple[float, float, float]:
    """Validate exposure settings; return them as floats.

    Raises
    ------
    ValueError
        Naming the setting: ``exposure time`` must be > 0 s, ``iso`` > 0, ``f_number`` > 0 (all finite).
    """
    out = []
    for name, value in (("exposure time (time_s)", time_s), ("iso", iso), ("f_number", f_number)):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
            raise ValueError(f"{name} must be a positive finite number, got {value!r}")
        out.append(float(value))
    return out[0], out[1], out[2]


def free_name(dest_dir: Path, name: str) -> Path:
    """``dest_dir / name``, or ``stem-1.ext``, ``stem-2.ext``... if taken (a capture never overwrites)."""
    path = dest_dir / name
    stem, suffix = path.stem, path.suffix
    k = 1
    while path.exists():
        path = dest_dir / f"{stem}-{k}{suffix}"
        k += 1
    return path
