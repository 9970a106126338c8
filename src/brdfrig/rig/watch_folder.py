"""Camera backend for vendor tethering software that drops each new picture into a folder.

The vendor application (Canon EOS Utility, Nikon Camera Control, Capture
One...) owns the camera: it sets the exposure and fires the shutter, either on
the operator's click or on its own schedule.  This backend only waits for the
file: a *new* name (not present when the backend opened or at the previous
capture), with a camera-file extension, whose size and modification time have
not changed for ``stable_s`` and which can be opened; it then copies it into
the destination (written atomically by ``brdfrig._atomic``) and leaves the original
where the vendor software expects it.
"""

from __future__ import annotations

import math
import os
import shutil
import time
from pathlib import Path
from typing import Callable

from brdfrig._atomic import temp_path
from brdfrig.rig.camera import Camera, check_exposure, free_name
from brdfrig.rig.errors import DeviceTimeout

__all__ = ["WatchFolderCamera", "CAMERA_EXTENSIONS"]

CAMERA_EXTENSIONS = (".dng", ".cr2", ".cr3", ".nef", ".arw", ".raf", ".orf", ".rw2", ".pef", ".tif", ".tiff")


class WatchFolderCamera(Camera):
    """Waits for complete new files in ``watch_dir``.

    Parameters
    ----------
    watch_dir : path
        Folder the vendor software writes into (must exist).
    timeout_s : float
        Longest wait for one new, complete file.
    stable_s : float
        A file is complete once its size and mtime stayed unchanged this long.
    poll_s : float
        Folder polling interval.
    extensions : tuple of str
        Lower-case suffixes that count as camera files (partial ``.tmp`` etc. never do).
    trigger : callable, optional
        Called with a message (exposure to use) at each capture, e.g. to prompt the operator
        or to ask the vendor software to shoot.
    """

    def __init__(self, watch_dir: str | os.PathLike, *, timeout_s: float = 60.0, stable_s: float = 1.0,
                 poll_s: float = 0.2, extensions: tuple[str, ...] = CAMERA_EXTENSIONS,
                 trigger: Callable[[str], object] | None = None) -> None:
        for name, value in (("timeout_s", timeout_s), ("stable_s", stable_s), ("poll_s", poll_s)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number of seconds, got {value!r}")
        self.watch_dir = Path(watch_dir)
        self.timeout_s, self.stable_s, self.poll_s = float(timeout_s), float(stable_s), float(poll_s)
        self.extensions = tuple(e.lower() for e in extensions)
        self.trigger = trigger
        self.exposure: tuple[float, float, float] | None = None
        self._seen: set[str] | None = None

    def _camera_files(self) -> dict[str, os.stat_result]:
        out = {}
        with os.scandir(self.watch_dir) as entries:
            for e in entries:
                if e.name.startswith(".") or not e.name.lower().endswith(self.extensions):
                    continue
                try:
                    if e.is_file():
                        out[e.name] = e.stat()
                except FileNotFoundError:
                    continue
        return out

    def open(self) -> None:
        """Remember the files already there (they are not new captures)."""
        if not self.watch_dir.is_dir():
            raise OSError(f"watch_dir {str(self.watch_dir)!r} is not an existing folder")
        self._seen = set(self._camera_files())

    def close(self) -> None:
        self._seen = None

    def set_exposure(self, time_s: float, iso: float, f_number: float) -> None:
        """Record the exposure the vendor software must use (it is announced through ``trigger``)."""
        self.exposure = check_exposure(time_s, iso, f_number)

    def capture(self, dest_dir: str | os.PathLike) -> Path:
        """Wait for the next complete new file, copy it into ``dest_dir`` and return the copy's path."""
        if self._seen is None:
            self.open()
        dest = Path(dest_dir)
        if not dest.is_dir():
            raise OSError(f"capture destination {str(dest)!r} is not a directory")
        if self.trigger is not None:
            t, iso, f = self.exposure or (float("nan"),) * 3
            self.trigger(f"shoot one frame: {t:g} s, ISO {iso:g}, f/{f:g} (into {self.watch_dir})")
        deadline = time.monotonic() + self.timeout_s
        last: dict[str, tuple[int, int, float]] = {}  # name -> (size, mtime_ns, time first seen so)
        while True:
            now = time.monotonic()
            for name, st in sorted(self._camera_files().items(), key=lambda kv: kv[1].st_mtime_ns):
                if name in self._seen:
                    continue
                sig = (st.st_size, st.st_mtime_ns)
                if last.get(name, (None, None, 0.0))[:2] != sig:
                    last[name] = (*sig, now)
                elif st.st_size > 0 and now - last[name][2] >= self.stable_s:
                    return self._take(name, dest)
            if now > deadline:
                raise DeviceTimeout(
                    f"no new complete camera file appeared in watch_dir {str(self.watch_dir)!r} within "
                    f"{self.timeout_s:g} s (timeout_s)"
                )
            time.sleep(self.poll_s)

    def _take(self, name: str, dest: Path) -> Path:
        target = free_name(dest, name)
        with temp_path(target, overwrite=False) as tmp:
            shutil.copy2(self.watch_dir / name, tmp)  # open + read proves the writer let go of it
        self._seen.add(name)
        return target
