"""Tethered camera over USB through python-gphoto2 (optional extra: ``pip install brdfrig[gphoto2]``).

Field failures handled here (bounded, with a settle time between attempts):

* ``GP_ERROR_CAMERA_BUSY`` (-110, "PTP Device Busy"): the camera is still
  applying a setting or writing the last file -> wait, retry the call;
* ``GP_ERROR_IO_USB_CLAIM`` (-53): another process holds the USB interface
  (often the desktop's gvfs-gphoto2 volume monitor) -> wait, re-initialise;
* I/O errors (-7, -34, -35, -10 timeout, -51, -31, -113) -> ``exit()`` then
  ``init()`` again, retry;
* ``GP_ERROR_MODEL_NOT_FOUND`` (-105, what ``init()`` raises when nothing is
  plugged in) and ``GP_ERROR_IO_USB_FIND`` (-52) -> "no camera found".

The library's errors become :mod:`brdfrig.rig.errors` types with a message saying what to do.
"""

from __future__ import annotations

import logging
import math
import os
import re
import time
from pathlib import Path
from typing import Callable

from brdfrig._atomic import temp_path
from brdfrig.rig.camera import Camera, check_exposure, free_name
from brdfrig.rig.errors import DeviceBusy, DeviceDisconnected, DeviceNotFound, DeviceRefused

__all__ = ["GphotoCamera", "parse_choice"]

log = logging.getLogger(__name__)

SHUTTER_WIDGETS = ("shutterspeed", "shutterspeed2", "exposuretime")
ISO_WIDGETS = ("iso", "isospeed")
APERTURE_WIDGETS = ("aperture", "f-number", "fnumber")


def parse_choice(text: str) -> float | None:
    """Numeric value of a gphoto2 menu choice: ``"1/125"`` -> 0.008, ``"30.0000s"`` -> 30, ``"f/5.6"`` -> 5.6.

    Returns None for non-numeric choices ("Auto", "bulb").
    """
    t = text.strip().lower().removeprefix("f/").removesuffix("s").strip()
    m = re.fullmatch(r"(\d+(?:\.\d+)?)\s*/\s*(\d+(?:\.\d+)?)", t)
    if m:
        den = float(m.group(2))
        return float(m.group(1)) / den if den else None
    try:
        value = float(t)
    except ValueError:
        return None
    return value if math.isfinite(value) and value > 0 else None


class GphotoCamera(Camera):
    """A USB-tethered camera driven through libgphoto2.

    Parameters
    ----------
    retries : int
        Extra attempts per operation after a busy/claim/I/O error (>= 0).
    settle_s : float
        Wait before each retry (the camera settling after a setting change).
    gp_module : module, optional
        The ``gphoto2`` module, or a fake with the same API (tests).
    sleep : callable
        ``time.sleep``; injectable so tests do not wait.
    """

    def __init__(self, *, retries: int = 3, settle_s: float = 1.0, gp_module=None,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        if isinstance(retries, bool) or not isinstance(retries, int) or retries < 0:
            raise ValueError(f"retries must be an integer >= 0, got {retries!r}")
        if not (isinstance(settle_s, (int, float)) and math.isfinite(settle_s) and settle_s >= 0):
            raise ValueError(f"settle_s must be a finite number >= 0, got {settle_s!r}")
        if gp_module is None:
            try:
                import gphoto2 as gp_module
            except ImportError as exc:
                raise DeviceNotFound(
                    "the gphoto2 camera backend needs python-gphoto2: pip install 'brdfrig[gphoto2]'"
                ) from exc
        self.gp = gp_module
        self.retries = retries
        self.settle_s = float(settle_s)
        self._sleep = sleep
        self._camera = None
        self.exposure: tuple[float, float, float] | None = None
        self.reinit_count = 0

    # -- lifetime ---------------------------------------------------------------------------
    def open(self) -> None:
        """Find and initialise the camera (retried like every other operation)."""
        self._call("connect", lambda: None)

    def close(self) -> None:
        """Release the camera; never raises."""
        if self._camera is not None:
            try:
                self._camera.exit()
            except self.gp.GPhoto2Error:
                pass
        self._camera = None

    # -- operations -------------------------------------------------------------------------
    def set_exposure(self, time_s: float, iso: float, f_number: float) -> None:
        """Set the nearest available shutter speed, ISO and aperture; the values set are in :attr:`exposure`."""
        time_s, iso, f_number = check_exposure(time_s, iso, f_number)

        def apply():
            config = self._camera.get_config()
            got = [self._set_nearest(config, SHUTTER_WIDGETS, time_s, "exposure time", required=True),
                   self._set_nearest(config, ISO_WIDGETS, iso, "iso", required=True),
                   self._set_nearest(config, APERTURE_WIDGETS, f_number, "f_number", required=False)]
            self._camera.set_config(config)
            return tuple(g if g is not None else w for g, w in zip(got, (time_s, iso, f_number)))

        self.exposure = self._call("set exposure", apply)

    def capture(self, dest_dir: str | os.PathLike) -> Path:
        """Trigger the shutter, download the file into ``dest_dir`` (atomically) and return its path."""
        dest = Path(dest_dir)
        if not dest.is_dir():
            raise OSError(f"capture destination {str(dest)!r} is not a directory")
        shot = self._call("capture", lambda: self._camera.capture(self.gp.GP_CAPTURE_IMAGE))
        target = free_name(dest, shot.name)
        with temp_path(target, overwrite=False) as tmp:

            def download():
                camera_file = self._camera.file_get(shot.folder, shot.name, self.gp.GP_FILE_TYPE_NORMAL)
                camera_file.save(str(tmp))

            self._call(f"download {shot.folder}/{shot.name}", download)
        return target

    # -- internals --------------------------------------------------------------------------
    def _set_nearest(self, config, names, value: float, setting: str, *, required: bool) -> float | None:
        gp = self.gp
        widget = None
        for name in names:
            try:
                widget = config.get_child_by_name(name)
                break
            except gp.GPhoto2Error:
                continue
        if widget is None:
            if required:
                raise DeviceRefused(f"the camera has no {setting} setting (looked for {', '.join(names)})")
            log.info("camera has no %s setting; leaving it to the lens", setting)
            return None
        choices = [(c, parse_choice(c)) for c in widget.get_choices()]
        choices = [(c, v) for c, v in choices if v is not None]
        if not choices:
            raise DeviceRefused(f"the camera offers no numeric {setting} values (is it in manual mode?)")
        text, got = min(choices, key=lambda cv: abs(math.log(cv[1] / value)))
        if abs(math.log2(got / value)) > 1 / 3 + 1e-6:
            log.warning("%s %g is not available; using %s", setting, value, text)
        widget.set_value(text)
        return got

    def _init(self) -> None:
        self.close()
        camera = self.gp.Camera()
        camera.init()
        self._camera = camera

    def _call(self, what: str, fn):
        """Run ``fn`` with (re)initialisation and the bounded retry policy of the module docstring."""
        gp = self.gp
        busy = {gp.GP_ERROR_CAMERA_BUSY}
        claim = {gp.GP_ERROR_IO_USB_CLAIM}
        io = {gp.GP_ERROR_IO, gp.GP_ERROR_IO_READ, gp.GP_ERROR_IO_WRITE, gp.GP_ERROR_TIMEOUT,
              gp.GP_ERROR_IO_USB_CLEAR_HALT, gp.GP_ERROR_IO_INIT, gp.GP_ERROR_CAMERA_ERROR}
        absent = {gp.GP_ERROR_MODEL_NOT_FOUND, gp.GP_ERROR_IO_USB_FIND}
        for attempt in range(self.retries + 1):
            try:
                if self._camera is None:
                    self._init()
                return fn()
            except gp.GPhoto2Error as exc:
                code = exc.code
                if code in absent:
                    self.close()
                    raise DeviceNotFound(
                        f"no camera found ({exc}): plug it in over USB, switch it on and set it to PTP/tethered mode"
                    ) from exc
                last = attempt == self.retries
                if code in busy:
                    if last:
                        raise DeviceBusy(f"camera stayed busy during {what} after {self.retries + 1} attempts: {exc}") from exc
                    log.info("camera busy during %s; retrying in %g s", what, self.settle_s)
                elif code in claim or code in io:
                    self.close()
                    if last:
                        if code in claim:
                            raise DeviceBusy(
                                f"another process holds the camera's USB interface ({exc}); stop it "
                                "(e.g. `pkill -f gvfs-gphoto2-volume-monitor`) and retry"
                            ) from exc
                        raise DeviceDisconnected(f"camera I/O failed during {what} after {self.retries + 1} "
                                                 f"attempts with re-initialisation: {exc}") from exc
                    log.info("camera error %s during %s; re-initialising", code, what)
                    self.reinit_count += 1
                else:
                    raise DeviceRefused(f"camera refused {what}: {exc}") from exc
                self._sleep(self.settle_s)
        raise AssertionError("unreachable")
