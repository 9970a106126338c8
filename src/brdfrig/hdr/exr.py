"""OpenEXR and Radiance HDR image I/O.

EXR files are written and read through the OpenEXR Python bindings
(``OpenEXR.File``); Radiance ``.hdr`` and other formats are read through
OpenImageIO.  No hand-written parsers.

Layout of the EXR files brdfrig writes:

- colour as channels ``R, G, B`` (3 channels) or ``Y`` (1 channel), float32
  (or half with ``half=True``), linear radiance;
- extra per-pixel images as channels ``<name>`` (2-D) or ``<name>.R``,
  ``<name>.G``, ``<name>.B`` (3 channels), e.g. ``variance.R`` or ``mask``;
- metadata as typed header attributes ``brdfrig:<key>``: numbers as ``double``
  (Python float) or ``int`` attributes, strings as ``string``; lists, dicts,
  booleans and None as JSON text, their keys listed in ``brdfrig:json_keys``
  (files without that attribute, from older brdfrig, hold JSON text in every
  ``brdfrig:`` attribute and are read as such); plus ``brdfrig:tool_version``;
- standard OpenEXR attributes where known: ``expTime`` (s), ``aperture``
  (f-number), ``isoSpeed``, ``chromaticities`` (the colour space's primaries
  and white point, CIE 1931 xy);
- lat-long environment maps carry the standard ``envmap = LATLONG`` attribute.

The writer is atomic (:mod:`brdfrig._atomic`): a failure never leaves a
partial or corrupt output; it refuses (``InputError``) NaN/inf in any channel
and negative colour values, so garbage is never written.  Every reader raises
:class:`brdfrig.errors.InputError` (a ``ValueError``) naming the file for a
missing channel, a truncated or corrupt file or (unless allowed) NaN/inf pixels.
"""

from __future__ import annotations

import contextlib
import json
import os
from importlib import metadata
from pathlib import Path

import numpy as np

from brdfrig._atomic import temp_path
from brdfrig.errors import InputError

__all__ = ["write_exr", "read_exr", "read_exr_attributes", "read_image", "read_oiio", "check_output_values", "ATTRIBUTE_PREFIX",
           "STANDARD_ATTRIBUTES"]

ATTRIBUTE_PREFIX = "brdfrig:"
_JSON_KEYS = "json_keys"
_RGB = ("R", "G", "B")
#: Standard OpenEXR attributes ``write_exr`` sets, with the number of float values each holds.
STANDARD_ATTRIBUTES = {"expTime": 1, "aperture": 1, "isoSpeed": 1, "chromaticities": 8}
_INT32 = (-(2 ** 31), 2 ** 31 - 1)


def _tool_version() -> str:
    try:
        return metadata.version("brdfrig")
    except metadata.PackageNotFoundError:
        return "unknown"


def _colour_names(channels: int, path: Path, what: str) -> tuple[str, ...]:
    if channels == 3:
        return _RGB
    if channels == 1:
        return ("Y",)
    raise ValueError(f"{path}: {what} must have 1 or 3 colour channels, got {channels}")


def _channels(path: Path, rgb: np.ndarray, extra_channels, dtype, allow_nonfinite: bool) -> dict[str, np.ndarray]:
    """The named contiguous planes of an EXR (colour, then extra images), each checked unless ``allow_nonfinite``."""
    channels: dict[str, np.ndarray] = {}
    for name, plane in zip(_colour_names(rgb.shape[2], path, "image"), np.moveaxis(rgb, 2, 0)):
        channels[name] = np.ascontiguousarray(plane, dtype=dtype)
    for key, image in (extra_channels or {}).items():
        image = np.asarray(image)
        if image.shape[:2] != rgb.shape[:2] or image.ndim not in (2, 3):
            raise ValueError(f"{path}: extra channel {key!r} has shape {image.shape}, image is {rgb.shape[:2]}")
        if not allow_nonfinite:
            check_output_values(image, path, f"channel {key!r}")
        if image.ndim == 2:
            channels[key] = np.ascontiguousarray(image, dtype=dtype)
        else:
            for name, plane in zip(_colour_names(image.shape[2], path, f"extra channel {key!r}"),
                                   np.moveaxis(image, 2, 0)):
                channels[f"{key}.{name}"] = np.ascontiguousarray(plane, dtype=dtype)
    return channels


def write_exr(
    path: str | os.PathLike,
    rgb: np.ndarray,
    extra_channels: dict[str, np.ndarray] | None = None,
    attributes: dict | None = None,
    *,
    half: bool = False,
    latlong: bool = False,
    standard: dict | None = None,
    overwrite: bool = True,
    allow_nonfinite: bool = False,
) -> Path:
    """Write a linear image (plus extra per-pixel channels and metadata) to an EXR file, atomically.

    Parameters
    ----------
    path : path-like
        Output file (conventionally ``.exr``).
    rgb : (H, W, C) or (H, W) array, C in {1, 3}
        Linear radiance; stored as ``R, G, B`` or ``Y``.
    extra_channels : dict of name -> (H, W) or (H, W, C) array, optional
        Extra images, e.g. ``{"variance": var (H,W,3), "mask": m (H,W)}``;
        a 3-channel image is stored as ``name.R``, ``name.G``, ``name.B``.
    attributes : dict, optional
        JSON-serialisable metadata, stored as typed ``brdfrig:<key>``
        attributes (see the module docstring); keys are bare names (no
        ``brdfrig`` prefix); ``tool_version`` is added automatically.
    half : bool
        Store every channel as 16-bit half floats instead of float32.
    latlong : bool
        Mark the file as a lat-long environment map (``envmap`` attribute,
        OpenEXR ``LatLongMap`` convention, see MATH.md).
    standard : dict, optional
        Standard OpenEXR attributes, names from :data:`STANDARD_ATTRIBUTES`:
        ``expTime`` (s), ``aperture`` (f-number), ``isoSpeed`` (positive
        floats), ``chromaticities`` (8 floats: red, green, blue, white xy).
    overwrite : bool
        Replace an existing ``path`` (else ``FileExistsError``, nothing written).
    allow_nonfinite : bool
        Write NaN/inf and negative colour values (test files only); by default
        they raise :class:`~brdfrig.errors.InputError` before anything is written.

    Returns
    -------
    Path
        The path written.
    """
    import OpenEXR

    path = Path(path)
    rgb = np.asarray(rgb)
    if rgb.ndim == 2:
        rgb = rgb[:, :, None]
    if rgb.ndim != 3:
        raise ValueError(f"{path}: image must be (H, W) or (H, W, C), got shape {rgb.shape}")
    if not allow_nonfinite:
        check_output_values(rgb, path, "the image", nonnegative=True)
    channels = _channels(path, rgb, extra_channels, np.float16 if half else np.float32, allow_nonfinite)
    header: dict = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage,
                    **_typed_attributes(path, {"tool_version": _tool_version(), **(attributes or {})}),
                    **_standard_attributes(path, standard or {})}
    if latlong:
        header["envmap"] = OpenEXR.ENVMAP_LATLONG

    with temp_path(path, overwrite=overwrite) as tmp:
        with OpenEXR.File(header, channels) as exr:
            exr.write(str(tmp))
    return path


def _typed_attributes(path: Path, attributes: dict) -> dict:
    """``brdfrig:<key>`` header entries: float -> double, int -> int, str -> string, anything else JSON text."""
    header, json_keys = {}, []
    for key, value in attributes.items():
        if key.startswith(("brdfrig:", "brdfrig_")) or key == _JSON_KEYS:
            raise ValueError(f"{path}: attribute key {key!r}: give the bare name, the writer adds {ATTRIBUTE_PREFIX!r}")
        if isinstance(value, (bool, np.bool_)) or value is None:
            value = None if value is None else bool(value)
        elif isinstance(value, (float, np.floating)):
            header[ATTRIBUTE_PREFIX + key] = np.array([value], dtype=np.float64)  # a 'double' attribute
            continue
        elif isinstance(value, (int, np.integer)) and _INT32[0] <= value <= _INT32[1]:
            header[ATTRIBUTE_PREFIX + key] = int(value)
            continue
        elif isinstance(value, str):
            header[ATTRIBUTE_PREFIX + key] = value
            continue
        try:
            header[ATTRIBUTE_PREFIX + key] = json.dumps(value)
        except TypeError as exc:
            raise ValueError(f"{path}: attribute {key!r} is not JSON-serialisable: {exc}") from None
        json_keys.append(key)
    header[ATTRIBUTE_PREFIX + _JSON_KEYS] = json.dumps(json_keys)
    return header


def _standard_attributes(path: Path, standard: dict) -> dict:
    """The standard OpenEXR attributes (float, or a tuple of 8 floats for ``chromaticities``), checked."""
    header = {}
    for key, value in standard.items():
        if key not in STANDARD_ATTRIBUTES:
            raise ValueError(f"{path}: unknown standard EXR attribute {key!r} "
                             f"(expected one of {', '.join(STANDARD_ATTRIBUTES)})")
        values = np.atleast_1d(np.asarray(value, dtype=np.float64))
        positive = key != "chromaticities"
        if values.shape != (STANDARD_ATTRIBUTES[key],) or not np.all(np.isfinite(values)) \
                or (positive and not values[0] > 0):
            raise ValueError(f"{path}: EXR attribute {key!r} must be {STANDARD_ATTRIBUTES[key]} finite "
                             f"{'positive ' if positive else ''}number(s), got {value!r}")
        header[key] = float(values[0]) if positive else tuple(float(v) for v in values)
    return header


def _decode_attributes(header: dict) -> dict:
    """The header's attributes as Python values (``brdfrig:`` prefix removed, JSON text decoded)."""
    prefixed = {k[len(ATTRIBUTE_PREFIX):]: v for k, v in header.items() if k.startswith(ATTRIBUTE_PREFIX)}
    if _JSON_KEYS in prefixed:
        json_keys = set(json.loads(prefixed.pop(_JSON_KEYS)))
    else:  # an older file: every brdfrig attribute is JSON text
        json_keys = {k for k, v in prefixed.items() if isinstance(v, str)}
    attributes: dict = {}
    for key, value in prefixed.items():
        if key in json_keys:
            try:
                value = json.loads(value)
            except (TypeError, json.JSONDecodeError):
                pass
        elif isinstance(value, np.ndarray) and value.size == 1:
            value = float(value.reshape(-1)[0])
        attributes[key] = value
    for key, value in header.items():
        if key.startswith(ATTRIBUTE_PREFIX):
            continue
        if isinstance(value, (str, int, float)) or key == "chromaticities":
            attributes[key] = value
    return attributes


def check_output_values(image: np.ndarray, path, what: str, *, nonnegative: bool = False) -> None:
    """Refuse to write garbage: :class:`InputError` naming ``path`` if ``image`` has NaN/inf (or negative) values.

    ``nonnegative`` applies to radiance; values beyond float32's range count as inf.
    """
    image = np.asarray(image)
    big = np.finfo(np.float32).max
    bad = ~np.isfinite(image) | (np.abs(image) > big) if image.dtype.kind == "f" else np.zeros(image.shape, bool)
    if bad.any():
        idx = np.argwhere(bad)[0]
        raise InputError(f"{path}: refusing to write {int(bad.sum())} NaN/inf value(s) in {what} "
                         f"(first at row {idx[0]}, col {idx[1]}): the inputs or options give no valid result")
    if nonnegative and (image < 0).any():
        neg = image < 0
        idx = np.argwhere(neg)[0]
        raise InputError(f"{path}: refusing to write {int(neg.sum())} negative radiance value(s) in {what} "
                         f"(min {float(image.min()):.3g}, first at row {idx[0]}, col {idx[1]}): do the inputs have "
                         "negative pixels?")


def _check_finite(image: np.ndarray, path: Path, what: str) -> None:
    bad = ~np.isfinite(image)
    if bad.any():
        idx = np.argwhere(bad)[0]
        raise InputError(f"{path}: {int(bad.sum())} NaN/inf values in {what} (first at row {idx[0]}, col {idx[1]})")


@contextlib.contextmanager
def _open_exr(path: Path, **options):
    """``OpenEXR.File(path, **options)``: FileNotFoundError if there is no such file, and any error while the
    ``with`` block reads it an InputError naming the file."""
    import OpenEXR

    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such EXR file")
    try:
        with OpenEXR.File(str(path), **options) as exr:
            yield exr
    except Exception as exc:  # OpenEXR raises RuntimeError/OSError variants for corrupt data
        raise InputError(f"{path}: not a readable EXR file (truncated or corrupt?): {exc}") from None


def read_exr(path: str | os.PathLike, *, allow_nonfinite: bool = False
             ) -> tuple[np.ndarray, dict[str, np.ndarray], dict]:
    """Read an EXR written by :func:`write_exr` (or any EXR with R,G,B or Y channels).

    Parameters
    ----------
    path : path-like
        The EXR file.
    allow_nonfinite : bool
        Accept NaN/inf in the colour channels (default: ``ValueError``).

    Returns
    -------
    rgb : (H, W, C) float32
        Colour channels (C = 3 for R,G,B, 1 for Y).
    extra : dict of name -> (H, W) or (H, W, C) float32
        The other channels, grouped back by ``name.R/G/B``.
    attributes : dict
        The ``brdfrig:`` attributes (typed, or JSON-decoded; prefix removed);
        other header attributes of plain types (str, int, float) and
        ``chromaticities`` (tuple of 8 floats) under their own names.
    """
    path = Path(path)
    with _open_exr(path, separate_channels=True) as exr:
        header = dict(exr.header())
        planes = {name: np.array(ch.pixels, dtype=np.float32) for name, ch in exr.channels().items()}
    if all(c in planes for c in _RGB):
        rgb = np.stack([planes.pop(c) for c in _RGB], axis=-1)
    elif "Y" in planes:
        rgb = planes.pop("Y")[:, :, None]
    else:
        raise InputError(f"{path}: no R,G,B or Y channels (has {sorted(planes)})")
    if not allow_nonfinite:
        _check_finite(rgb, path, "the colour channels")
    extra: dict[str, np.ndarray] = {}
    groups = sorted({name.rsplit(".", 1)[0] for name in planes if "." in name})
    for group in groups:
        for names in (_RGB, ("Y",)):
            keys = [f"{group}.{c}" for c in names]
            if all(k in planes for k in keys):
                extra[group] = np.stack([planes.pop(k) for k in keys], axis=-1)
                break
    extra.update(planes)
    return rgb, extra, _decode_attributes(header)


def read_exr_attributes(path: str | os.PathLike) -> dict:
    """The attributes of an EXR file as :func:`read_exr` returns them, reading the header only."""
    path = Path(path)
    with _open_exr(path, header_only=True) as exr:
        header = dict(exr.header())
    return _decode_attributes(header)


def read_image(path: str | os.PathLike, *, allow_nonfinite: bool = False) -> np.ndarray:
    """Read a linear HDR image: EXR through OpenEXR, Radiance ``.hdr`` (and others) through OpenImageIO.

    Parameters
    ----------
    path : path-like
        ``.exr``, ``.hdr``/``.pic`` or any float format OpenImageIO reads.
    allow_nonfinite : bool
        Accept NaN/inf pixels (default: ``ValueError``).

    Returns
    -------
    (H, W, C) float32
        Linear colour, C = 3 (RGB; alpha and extra channels dropped) or 1.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such image file")
    if path.suffix.lower() == ".exr":
        return read_exr(path, allow_nonfinite=allow_nonfinite)[0]
    pixels, _ = read_oiio(path)
    image = pixels[:, :, :3] if pixels.shape[2] >= 3 else pixels[:, :, :1]
    if not allow_nonfinite:
        _check_finite(image, path, "the image")
    return np.ascontiguousarray(image)


@contextlib.contextmanager
def oiio_input(path, what: str = "cannot be read"):
    """An open OpenImageIO ``ImageInput`` of ``path`` for the ``with`` block (closed on exit).

    Raises FileNotFoundError when the file does not exist, InputError ``"{path}: {what}: ..."``
    when OpenImageIO cannot open it.
    """
    import OpenImageIO as oiio

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file")
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise InputError(f"{path}: {what}: {oiio.geterror()}")
    try:
        yield inp
    finally:
        inp.close()


def read_oiio(path: str | os.PathLike) -> tuple[np.ndarray, bool]:
    """Read every channel of an image file through OpenImageIO, as stored (integers scaled to [0, 1]).

    Returns
    -------
    pixels : (H, W, C) float32
    is_float : bool
        Whether the file stores floating-point values (else integers, scaled by their range).
    """
    import OpenImageIO as oiio

    path = Path(path)
    with oiio_input(path, "not a readable image") as inp:
        spec = inp.spec()
        pixels = inp.read_image(0, 0, 0, spec.nchannels, oiio.FLOAT)
        error = inp.geterror() if inp.has_error else ""
        is_float = spec.format.basetype in (oiio.FLOAT, oiio.HALF, oiio.DOUBLE)
    if pixels is None or error:
        raise InputError(f"{path}: truncated or corrupt image: {error or 'no pixels read'}")
    return np.asarray(pixels, dtype=np.float32).reshape(spec.height, spec.width, spec.nchannels), is_float
