"""A simulated camera photographing the simulated bench, writing real camera files.

It reads the PHYSICAL table angle from the table simulator's mechanics (not
what the driver believes), takes the bench's true radiance at that angle, and
models a sensor:

* signal in electrons ``e = radiance * t * (8 / N)^2 * sensitivity * full_well_e``
  (so at f/8, ISO 100 and ``sensitivity`` 1 a radiance of 1 fills the well in 1 s),
  Poisson shot noise, Gaussian read noise ``read_noise_e``;
* ISO gain ``iso / 100`` from electrons to raw units, black level, white level,
  clipping, 16-bit integers;
* output ``"dng"``: an RGGB Bayer mosaic through :func:`brdfrig.hdr.dng.write_dng` (linear raw,
  what :func:`brdfrig.hdr.raw.decode_raw` reads back as ``radiance * t`` at ISO 100, f/8);
  or ``"tiff"``: a demosaiced 16-bit RGB TIFF with an optional non-linear response
  ``v ** (1 / response_gamma)`` (an in-camera JPEG-like curve), EXIF inside.

Both carry ExposureTime, FNumber and ISO in their metadata.  Noise is
deterministic given ``seed`` and the capture count.
"""

from __future__ import annotations

import hashlib
import math
import os
from pathlib import Path

import numpy as np

from brdfrig._atomic import temp_path
from brdfrig.rig.camera import Camera, check_exposure, free_name
from brdfrig.sim.bench import SimBench

__all__ = ["SimulatedCamera"]

_CFA_CHANNEL = np.array([[0, 1], [1, 2]])  # RGGB


class SimulatedCamera(Camera):
    """Camera backend over a :class:`brdfrig.sim.bench.SimBench`.

    Parameters
    ----------
    bench : SimBench
        What is photographed.
    table_state : object with ``table_angle_deg``, optional
        The table simulator (:class:`brdfrig.sim.grbl.GrblSimulator`): its physical angle is read at
        each capture.  None: a bench without a table (angle 0).
    full_well_e, read_noise_e : float
        Electrons at the white level (ISO 100), read-noise sigma in electrons.
    black_level, white_level : int
        Raw units (16-bit).
    sensitivity : float
        Overall scale of the signal (> 0).
    file_format : {"dng", "tiff"}
    response_gamma : float
        TIFF only: encoding exponent of the non-linear response (1 = linear).
    seed : int
        Noise seed.
    """

    def __init__(self, bench: SimBench, table_state=None, *, full_well_e: float = 4000.0, read_noise_e: float = 4.0,
                 black_level: int = 512, white_level: int = 16383, sensitivity: float = 1.0,
                 file_format: str = "dng", response_gamma: float = 1.0, seed: int = 0) -> None:
        for name, value in (("full_well_e", full_well_e), ("sensitivity", sensitivity),
                            ("response_gamma", response_gamma)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number, got {value!r}")
        if not (isinstance(read_noise_e, (int, float)) and math.isfinite(read_noise_e) and read_noise_e >= 0):
            raise ValueError(f"read_noise_e must be a number >= 0, got {read_noise_e!r}")
        if not (isinstance(black_level, int) and isinstance(white_level, int) and 0 <= black_level < white_level <= 65535):
            raise ValueError(f"need integers 0 <= black_level < white_level <= 65535, got {black_level}, {white_level}")
        if file_format not in ("dng", "tiff"):
            raise ValueError(f"file_format must be 'dng' or 'tiff', got {file_format!r}")
        if file_format == "dng" and response_gamma != 1.0:
            raise ValueError("response_gamma applies to file_format='tiff' only (a DNG is linear raw)")
        if table_state is not None and not hasattr(table_state, "table_angle_deg"):
            raise ValueError("table_state must expose the physical angle as .table_angle_deg (a GrblSimulator)")
        self.bench = bench
        self.table_state = table_state
        self.full_well_e, self.read_noise_e = float(full_well_e), float(read_noise_e)
        self.black_level, self.white_level = black_level, white_level
        self.sensitivity = float(sensitivity)
        self.file_format = file_format
        self.response_gamma = float(response_gamma)
        self.seed = int(seed)
        self.exposure: tuple[float, float, float] | None = None
        self.captures = 0
        self.last_angle_deg: float | None = None

    def begin_shot(self, key: str) -> None:
        """Make the noise of the next captures a function of the shot's key, not of the capture count.

        Noise is drawn from ``(seed, captures)``; ``captures`` restarts at a number derived from the key.
        """
        self.captures = int.from_bytes(hashlib.sha256(key.encode()).digest()[:4], "little")

    def set_exposure(self, time_s: float, iso: float, f_number: float) -> None:
        self.exposure = check_exposure(time_s, iso, f_number)

    def expected_value(self, radiance: np.ndarray) -> np.ndarray:
        """Noise-free, unclipped normalised sensor value (1.0 = white level) for a radiance, at the set exposure."""
        if self.exposure is None:
            raise ValueError("set_exposure() must be called before capturing")
        t, iso, f = self.exposure
        return np.asarray(radiance, np.float64) * t * (8.0 / f) ** 2 * self.sensitivity * (iso / 100.0)

    def capture(self, dest_dir: str | os.PathLike) -> Path:
        """Photograph the bench at the table's physical angle; write the file; return its path."""
        dest = Path(dest_dir)
        if not dest.is_dir():
            raise OSError(f"capture destination {str(dest)!r} is not a directory")
        if self.exposure is None:
            raise ValueError("set_exposure() must be called before capturing")
        t, iso, f = self.exposure
        angle = float(self.table_state.table_angle_deg) if self.table_state is not None else 0.0
        self.last_angle_deg = angle
        radiance = self.bench.radiance(angle)
        rng = np.random.default_rng([self.seed, self.captures])
        self.captures += 1
        gain = iso / 100.0
        electrons = np.clip(self.expected_value(radiance) / gain, 0.0, None) * self.full_well_e
        if self.file_format == "dng":
            electrons = electrons[np.arange(electrons.shape[0])[:, None], np.arange(electrons.shape[1])[None, :],
                                  _CFA_CHANNEL[np.arange(electrons.shape[0])[:, None] % 2,
                                               np.arange(electrons.shape[1])[None, :] % 2]]
        # cap the Poisson mean far above saturation (it would clip anyway) so huge highlights cannot overflow
        signal = rng.poisson(np.minimum(electrons, 1e3 * self.full_well_e)).astype(np.float64)
        signal += rng.normal(0.0, self.read_noise_e, signal.shape)
        value = signal / self.full_well_e * gain  # 1.0 = white level
        span = self.white_level - self.black_level
        if self.file_format == "dng":
            from brdfrig.hdr.dng import write_dng

            raw = np.clip(np.round(self.black_level + value * span), 0, self.white_level).astype(np.uint16)
            path = free_name(dest, f"SIM_{self.captures:05d}.dng")
            write_dng(path, raw, pattern="RGGB", black_level=self.black_level, white_level=self.white_level,
                      exposure_time_s=t, f_number=f, iso=iso, make="brdfrig", model="SimulatedCamera")
            return path
        encoded = np.clip(value, 0.0, 1.0) ** (1.0 / self.response_gamma)
        return self._write_tiff(free_name(dest, f"SIM_{self.captures:05d}.tif"),
                                np.round(encoded * 65535).astype(np.uint16), t, iso, f)

    @staticmethod
    def _write_tiff(path: Path, rgb16: np.ndarray, t: float, iso: float, f: float) -> Path:
        """16-bit RGB TIFF with the exposure tags (EXIF numbering, in IFD0), written atomically."""
        from fractions import Fraction

        import tifffile

        def rational(x: float) -> tuple[int, int]:
            q = Fraction(x).limit_denominator(1_000_000)
            return q.numerator, q.denominator

        tags = [(33434, "2I", 1, rational(t), True),  # ExposureTime
                (33437, "2I", 1, rational(f), True),  # FNumber
                (34855, "H", 1, int(round(iso)), True),  # ISOSpeedRatings
                (271, "s", 0, "brdfrig", True), (272, "s", 0, "SimulatedCamera", True)]
        with temp_path(path, overwrite=False) as tmp:
            tifffile.imwrite(tmp, rgb16, photometric="rgb", extratags=tags, metadata=None)
        return path
