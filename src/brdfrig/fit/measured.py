"""Measured isotropic BRDFs: Rusinkiewicz coordinates, MERL tables and the neural fits of measurements.

Coordinates (Rusinkiewicz 1998).  For unit directions ``wi``, ``wo`` and normal
``n``: the half vector ``h = (wi + wo) / |wi + wo|`` at angle ``theta_h`` from
``n``; the difference vector ``d`` is ``wi`` expressed in the half vector's
frame (rotate ``wi`` by ``-phi_h`` about ``n``, then by ``-theta_h`` about the
binormal), ``d = (sin td cos pd, sin td sin pd, cos td)``.  With the tangent
``t`` along the projection of ``h`` on the tangent plane (so ``phi_h = 0``) and
``b = n x t``, ``d = (wi . (cos th t - sin th n), wi . b, wi . h)``; when
``h = n`` the tangent is ``e_y x n`` normalised (``+x`` for ``n = +z``), or ``e_x x n`` near ``n = +-y``.
``phi_d`` is returned in ``[0, 2 pi)``.  Reciprocity (swapping ``wi`` and
``wo``) sends ``phi_d`` to ``phi_d + pi``, so an isotropic reciprocal BRDF is a
function of ``phi_d mod pi``.

Two BRDF classes implement :class:`brdfrig.fit.brdf.FittedBRDF` plus
``rho(wi, wo, n)``; values are in 1/sr (no cosine factor) and 0 when either
direction is at or below the horizon:

- :class:`TabulatedBRDF` on MERL's grid (Matusik et al. 2003): ``(90, 90, 180, C)``
  samples at ``th = (ith / 90)^2 pi/2``, ``td = itd / 90 pi/2``,
  ``pd = ipd / 180 pi``; NaN marks a missing sample.  Evaluation interpolates
  ``log1p(rho)`` in index space: along the sqrt-spaced ``ith = 90 sqrt(th / (pi/2))``
  Catmull-Rom (cubic) below node 12 (``th`` < 1.6 deg, where highlights are
  sharp) and linear above; linear along ``itd`` and along ``phi_d mod pi``
  (periodic, 180 samples); clamped to the last sample beyond ``ith, itd = 89``,
  then ``rho = max(expm1(.), 0)``.  (Trilinear interpolation of ``rho`` itself
  overestimates the sharpest measured highlights, which span a few ``theta_h``
  samples, by 2-5% of a rendered sphere; this rule renders them within 0.15% of
  the network they were tabulated from, tests/test_measured.py.)  Missing
  samples take the value of the nearest present sample in index space
  (Euclidean, per channel) before interpolating.
- :class:`NeuralBRDF`: the small networks of Sztrajman et al. 2021 in
  ``../shared/data/measured`` (``NAME.h5`` weights + ``NAME.json`` Keras layout):
  ``rho = max(exp(relu(relu(x W1 + b1) W2 + b2) W3 + b3) - 1, 0)`` with
  ``x = (h, d)`` at ``phi_h = 0``, ``h = (sin th, 0, cos th)``.  The networks
  are not exactly reciprocal (they were fitted to MERL-grid data, which is: a
  lookup folds ``phi_d`` mod pi), so ``NeuralBRDF.rho`` is the reciprocal part,
  the mean of the network at ``phi_d`` and ``phi_d + pi`` (measured difference
  between the two: median 2% on a paper, 16% on a clear-coated paint, at
  ``cos theta > 0.5``); :meth:`NeuralBRDF.network` is the raw network.

MERL ``.binary`` files (:func:`read_merl`, :func:`write_merl`): three int32
``(90, 90, 180)``, then ``3 x 1,458,000`` float64, channel-planar (R, G, B),
index ``ipd + 180 (itd + 90 ith)``; stored values times the channel scales
:data:`MERL_SCALES` are 1/sr; a negative stored value marks a missing sample
(NaN in the table; NaN is written as -1).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numba
import numpy as np

from brdfrig._atomic import write_bytes
from brdfrig.errors import InputError
from brdfrig.fit.brdf import register_model
from brdfrig.fit.groundtruth import render_tabulated
from brdfrig.fit.merl import _HALF_PI, CUBIC_NODES, half_diff, table_lookup
from brdfrig.fit.scene import Environment

__all__ = [
    "CUBIC_NODES",
    "MERL_SHAPE",
    "MERL_SCALES",
    "half_diff",
    "rusinkiewicz_coordinates",
    "rusinkiewicz_directions",
    "merl_grid",
    "table_lookup",
    "TabulatedBRDF",
    "NeuralBRDF",
    "read_merl",
    "write_merl",
    "tabulate",
    "load_measured",
]

MERL_SHAPE = (90, 90, 180)
"""Samples in (theta_h, theta_d, phi_d) of a MERL table."""

MERL_SCALES = (1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0)
"""Stored MERL value times these (R, G, B) gives the BRDF in 1/sr."""

_NET_SHAPES = ((6, 21), (21,), (21, 21), (21,), (21, 3), (3,))
_NET_ACTIVATIONS = ("relu", "relu", "linear")


# ----------------------------------------------------------------------------- coordinates
# The scalar kernels half_diff and table_lookup live in brdfrig.fit.merl (shared with the renderer).


@numba.njit(cache=True, fastmath=False, parallel=True)
def _half_diff_many(wi, wo, n):
    m = wi.shape[0]
    out = np.empty((m, 3))
    for k in numba.prange(m):
        th, td, pd = half_diff(wi[k, 0], wi[k, 1], wi[k, 2], wo[k, 0], wo[k, 1], wo[k, 2], n[k, 0], n[k, 1], n[k, 2])
        out[k, 0], out[k, 1], out[k, 2] = th, td, pd
    return out


def rusinkiewicz_coordinates(wi, wo, n) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(theta_h, theta_d, phi_d)`` of unit directions ``wi``, ``wo`` and normals ``n``, each (..., 3), broadcast.

    Returns three arrays of the broadcast shape without the last axis (radians;
    ``phi_d`` in [0, 2 pi)).
    """
    wi, wo, n = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (wi, wo, n)))
    shape = wi.shape[:-1]
    flat = [np.array(a.reshape(-1, 3), order="C") for a in (wi, wo, n)]
    out = _half_diff_many(*flat)
    return out[:, 0].reshape(shape), out[:, 1].reshape(shape), out[:, 2].reshape(shape)


def rusinkiewicz_directions(theta_h, theta_d, phi_d) -> tuple[np.ndarray, np.ndarray]:
    """Unit ``(wi, wo)`` (..., 3) in the normal's local frame (``n = +z``, ``phi_h = 0``) of the given angles.

    Inverse of :func:`rusinkiewicz_coordinates` for ``n = (0, 0, 1)`` and ``h``
    in the x-z half plane: ``wi = Ry(th) d``, ``wo = Ry(th) (-d_x, -d_y, d_z)``.
    """
    th, td, pd = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (theta_h, theta_d, phi_d)))
    st, ct = np.sin(th), np.cos(th)
    dx, dy, dz = np.sin(td) * np.cos(pd), np.sin(td) * np.sin(pd), np.cos(td)

    def rot(x, y, z):  # Ry(th): x' = cos x + sin z, z' = -sin x + cos z
        return np.stack([ct * x + st * z, y, -st * x + ct * z], axis=-1)

    return rot(dx, dy, dz), rot(-dx, -dy, dz)


def merl_grid() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sample angles (radians) of the MERL grid: ``theta_h`` (90,), ``theta_d`` (90,), ``phi_d`` (180,)."""
    i = np.arange(90, dtype=np.float64)
    return (i / 90.0) ** 2 * _HALF_PI, i / 90.0 * _HALF_PI, np.arange(180, dtype=np.float64) / 180.0 * math.pi


# ----------------------------------------------------------------------------- table interpolation


@numba.njit(cache=True, fastmath=False, parallel=True)
def _table_rho_many(log_table, wi, wo, n):
    """rho (M, C) of a filled log1p table at world directions (M, 3); 0 at or below either horizon."""
    m = wi.shape[0]
    out = np.zeros((m, log_table.shape[3]))
    for k in numba.prange(m):
        ci = wi[k, 0] * n[k, 0] + wi[k, 1] * n[k, 1] + wi[k, 2] * n[k, 2]
        co = wo[k, 0] * n[k, 0] + wo[k, 1] * n[k, 1] + wo[k, 2] * n[k, 2]
        if ci <= 0.0 or co <= 0.0:
            continue
        th, td, pd = half_diff(wi[k, 0], wi[k, 1], wi[k, 2], wo[k, 0], wo[k, 1], wo[k, 2], n[k, 0], n[k, 1], n[k, 2])
        table_lookup(log_table, th, td, pd, out[k])
    return out


def _fill_missing(table: np.ndarray) -> np.ndarray:
    """Copy of ``table`` with each NaN replaced by the nearest present sample of its channel (index space)."""
    from scipy.ndimage import distance_transform_edt

    filled = np.array(table, dtype=np.float64, order="C")
    for c in range(filled.shape[3]):
        missing = np.isnan(filled[..., c])
        if missing.any():
            idx = distance_transform_edt(missing, return_distances=False, return_indices=True)
            filled[..., c] = filled[..., c][tuple(idx)]
    return filled


def _flat_dirs(wi, wo, n) -> list[np.ndarray]:
    wi, wo, n = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (wi, wo, n)))
    return [np.array(a.reshape(-1, 3), order="C") for a in (wi, wo, n)]


def _local_angles_to_dirs(theta_i, theta_o, delta_phi) -> tuple[np.ndarray, np.ndarray, tuple]:
    """Local ``wi`` (phi_i = 0), ``wo`` (phi_o = delta_phi) as (M, 3) and the broadcast shape."""
    ti, to, dp = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (theta_i, theta_o, delta_phi)))
    wi = np.stack([np.sin(ti), np.zeros_like(ti), np.cos(ti)], axis=-1).reshape(-1, 3)
    wo = np.stack([np.sin(to) * np.cos(dp), np.sin(to) * np.sin(dp), np.cos(to)], axis=-1).reshape(-1, 3)
    return wi, wo, ti.shape


class _MeasuredBRDF:
    """Shared ``evaluate`` of the measured BRDFs (through ``rho`` in the local frame)."""

    channels: int
    stacks_lightings = True
    """``predict`` renders under stacked lightings (:func:`brdfrig.fit.scene.stack_lightings`)."""

    def rho(self, wi, wo, n) -> np.ndarray:
        raise NotImplementedError

    def evaluate(self, theta_i, theta_o, delta_phi) -> np.ndarray:
        """BRDF (1/sr) at polar angles ``theta_i``, ``theta_o`` and ``delta_phi = phi_o - phi_i`` (radians).

        Returns shape ``broadcast(theta_i, theta_o, delta_phi).shape + (C,)``.
        """
        wi, wo, shape = _local_angles_to_dirs(theta_i, theta_o, delta_phi)
        return self.rho(wi, wo, np.array([0.0, 0.0, 1.0])).reshape(shape + (self.channels,))


@register_model("tabulated")
class TabulatedBRDF(_MeasuredBRDF):
    """An isotropic BRDF tabulated on MERL's (theta_h, theta_d, phi_d) grid.

    Parameters
    ----------
    table : (90, 90, 180, C) array_like
        BRDF values in 1/sr; NaN marks a missing sample (kept as NaN in
        :attr:`table`; :attr:`filled` has it from the nearest present sample,
        :attr:`log_filled` is ``log1p(filled)``, what evaluation interpolates).
    source : str or Path, optional
        File the table was read from (stored by :meth:`to_dict`).
    name : str
        What to call the table in error messages.

    Raises
    ------
    InputError (a ValueError)
        Wrong shape, infinite or negative values, or no present sample in a channel.
    """

    model = "tabulated"

    def __init__(self, table, source=None, *, name: str = "table") -> None:
        t = np.array(table, dtype=np.float64)
        if t.ndim != 4 or t.shape[:3] != MERL_SHAPE or t.shape[3] < 1:
            raise InputError(f"{name}: expected a (90, 90, 180, C) table, got shape {t.shape}")
        if np.isinf(t).any():
            raise InputError(f"{name}: {int(np.isinf(t).sum())} infinite value(s)")
        if (t < 0).any():
            raise InputError(f"{name}: {int((t < 0).sum())} negative value(s) (mark missing samples NaN)")
        empty = np.isnan(t).reshape(-1, t.shape[3]).all(axis=0)
        if empty.any():
            raise InputError(f"{name}: channel(s) {np.flatnonzero(empty).tolist()} have no present sample")
        t.setflags(write=False)
        self.table = t
        self.filled = _fill_missing(t)
        self.filled.setflags(write=False)
        self.log_filled = np.log1p(self.filled)
        self.log_filled.setflags(write=False)
        self.source = None if source is None else str(source)

    @property
    def channels(self) -> int:
        return self.table.shape[3]

    @property
    def missing(self) -> int:
        """Number of missing (NaN) samples over all channels."""
        return int(np.isnan(self.table).sum())

    def rho(self, wi, wo, n) -> np.ndarray:
        """BRDF (1/sr) for unit ``wi``, ``wo``, ``n`` (..., 3), broadcast -> (M, C); 0 at or below either horizon."""
        return _table_rho_many(self.log_filled, *_flat_dirs(wi, wo, n))

    def predict(self, env: Environment, normals: np.ndarray) -> np.ndarray:
        """Radiance (N, C) seen from ``v = (0, 0, 1)``: :func:`brdfrig.fit.groundtruth.render_tabulated`."""
        return render_tabulated(self, normals, env)

    def to_dict(self) -> dict:
        """``{"model": "tabulated", "source": path}``; InputError for a table not read from a file."""
        if self.source is None:
            raise InputError("a TabulatedBRDF not read from a file has no JSON form: write it with write_merl first")
        return {"model": self.model, "source": self.source}

    @classmethod
    def from_dict(cls, d: dict) -> "TabulatedBRDF":
        return read_merl(d["source"])


# ----------------------------------------------------------------------------- neural fits


def _check_layout(json_path: Path) -> None:
    """InputError unless ``json_path`` describes Dense 6 -> 21 (relu) -> 21 (relu) -> 3 (linear)."""
    try:
        doc = json.loads(json_path.read_text())
        layers = doc["config"]["layers"] if isinstance(doc["config"], dict) else doc["config"]
        dense = [layer["config"] for layer in layers if layer["class_name"] == "Dense"]
        found = [(c.get("units"), c.get("activation")) for c in dense]
        n_in = dense[0].get("batch_input_shape", [None, None])[-1]
    except (OSError, json.JSONDecodeError, UnicodeDecodeError, KeyError, TypeError, IndexError) as exc:
        raise InputError(f"{json_path}: not a readable Keras model description ({exc!r})") from exc
    want = [(21, "relu"), (21, "relu"), (3, "linear")]
    if found != want or n_in != 6:
        raise InputError(f"{json_path}: layers {found} with input {n_in}, expected Dense {want} with input 6")


@register_model("neural")
class NeuralBRDF(_MeasuredBRDF):
    """A neural fit of a measured BRDF (Sztrajman et al. 2021), 6 -> 21 -> 21 -> 3.

    Parameters
    ----------
    weights : sequence of six arrays
        ``W1 (6, 21), b1 (21,), W2 (21, 21), b2 (21,), W3 (21, 3), b3 (3,)``.
    source : str or Path, optional
        The ``.h5`` file (stored by :meth:`to_dict`).

    ``predict`` renders the table of the network (:func:`tabulate`, made once and
    kept): the table render agrees with the direct render of the network to a
    fraction of a percent (tests/test_measured.py).
    """

    model = "neural"
    channels = 3

    def __init__(self, weights, source=None) -> None:
        ws = [np.asarray(w, dtype=np.float64) for w in weights]
        shapes = tuple(w.shape for w in ws)
        name = source if source is not None else "network"
        if shapes != _NET_SHAPES:
            raise InputError(f"{name}: layer shapes {shapes}, expected {_NET_SHAPES}")
        if not all(np.isfinite(w).all() for w in ws):
            raise InputError(f"{name}: non-finite weights")
        self.weights = ws
        self.source = None if source is None else str(source)
        self._table: TabulatedBRDF | None = None

    @classmethod
    def load(cls, path) -> "NeuralBRDF":
        """Read ``NAME.h5`` (weights) after checking the layer layout in ``NAME.json`` beside it.

        Raises
        ------
        InputError (a ValueError)
            Missing or unreadable file, other layers or layer shapes.
        """
        import h5py

        path = Path(path)
        json_path = path.with_suffix(".json")
        if not path.is_file():
            raise InputError(f"{path}: no such network file")
        if not json_path.is_file():
            raise InputError(f"{path}: its layout file {json_path.name} is missing")
        _check_layout(json_path)
        try:
            with h5py.File(path, "r") as f:
                ws = [f[f"dense_{i}/dense_{i}/{k}:0"][()] for i in (1, 2, 3) for k in ("kernel", "bias")]
        except (OSError, KeyError) as exc:
            raise InputError(f"{path}: not a readable network weight file ({exc})") from exc
        return cls(ws, source=path)

    def network(self, theta_h, theta_d, phi_d) -> np.ndarray:
        """The network's rho (1/sr, clipped at 0) at Rusinkiewicz angles (broadcast) -> shape + (3,)."""
        th, td, pd = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (theta_h, theta_d, phi_d)))
        shape = th.shape
        th, td, pd = th.ravel(), td.ravel(), pd.ravel()
        w1, b1, w2, b2, w3, b3 = self.weights
        out = np.empty((th.size, 3))
        for s in range(0, th.size, 65536):  # bounded memory: hidden layers of one chunk
            sl = slice(s, s + 65536)
            sd = np.sin(td[sl])
            x = np.stack([np.sin(th[sl]), np.zeros_like(sd), np.cos(th[sl]), sd * np.cos(pd[sl]), sd * np.sin(pd[sl]), np.cos(td[sl])], 1)
            h = np.maximum(np.maximum(x @ w1 + b1, 0.0) @ w2 + b2, 0.0)
            out[sl] = np.maximum(np.expm1(h @ w3 + b3), 0.0)
        return out.reshape(shape + (3,))

    def rho(self, wi, wo, n) -> np.ndarray:
        """Reciprocal BRDF (1/sr) for unit ``wi``, ``wo``, ``n`` (..., 3), broadcast -> (M, 3).

        The mean of the network at ``phi_d`` and ``phi_d + pi`` (i.e. of both orders
        of ``wi`` and ``wo``); 0 at or below either horizon.
        """
        wi, wo, n = _flat_dirs(wi, wo, n)
        above = (np.einsum("ij,ij->i", wi, n) > 0) & (np.einsum("ij,ij->i", wo, n) > 0)
        out = np.zeros((wi.shape[0], 3))
        th, td, pd = _half_diff_many(wi[above], wo[above], n[above]).T
        out[above] = 0.5 * (self.network(th, td, pd) + self.network(th, td, pd + math.pi))
        return out

    def table(self) -> TabulatedBRDF:
        """The network tabulated on the MERL grid (:func:`tabulate`), computed once."""
        if self._table is None:
            self._table = tabulate(self)
        return self._table

    def predict(self, env: Environment, normals: np.ndarray) -> np.ndarray:
        """Radiance (N, 3) seen from ``v = (0, 0, 1)``: the render of :meth:`table`."""
        return self.table().predict(env, normals)

    def to_dict(self) -> dict:
        """``{"model": "neural", "source": path}``; InputError for a network not read from a file."""
        if self.source is None:
            raise InputError("a NeuralBRDF not read from a file has no JSON form")
        return {"model": self.model, "source": self.source}

    @classmethod
    def from_dict(cls, d: dict) -> "NeuralBRDF":
        return cls.load(d["source"])


# ----------------------------------------------------------------------------- files and tabulation


def tabulate(brdf) -> TabulatedBRDF:
    """Tabulate any BRDF with ``rho(wi, wo, n)`` and ``channels`` on the MERL grid.

    Samples where ``wi`` or ``wo`` is at or below the horizon are missing (NaN),
    as in MERL's measurements.
    """
    th, td, pd = np.meshgrid(*merl_grid(), indexing="ij")
    wi, wo = rusinkiewicz_directions(th, td, pd)
    wi, wo = wi.reshape(-1, 3), wo.reshape(-1, 3)
    n = np.array([0.0, 0.0, 1.0])
    values = np.asarray(brdf.rho(wi, wo, n), dtype=np.float64).reshape(MERL_SHAPE + (-1,))
    below = ((wi[:, 2] <= 0) | (wo[:, 2] <= 0)).reshape(MERL_SHAPE)
    values[below] = np.nan
    return TabulatedBRDF(values, name=f"tabulated {getattr(brdf, 'model', type(brdf).__name__)}")


def read_merl(path) -> TabulatedBRDF:
    """Read a MERL ``.binary`` file (layout in the module docstring) as a :class:`TabulatedBRDF` (1/sr).

    Negative (and NaN) stored values are missing samples: NaN in the table.

    Raises
    ------
    InputError (a ValueError)
        Truncated or oversized file, dimensions other than (90, 90, 180), infinite values.
    OSError
        The file cannot be read.
    """
    path = Path(path)
    raw = path.read_bytes()
    if len(raw) < 12:
        raise InputError(f"{path}: {len(raw)} bytes, too short for a MERL header (12 bytes)")
    dims = tuple(int(v) for v in np.frombuffer(raw[:12], dtype="<i4"))
    if dims != MERL_SHAPE:
        raise InputError(f"{path}: MERL dimensions {dims}, expected {MERL_SHAPE}")
    count = 3 * math.prod(MERL_SHAPE)
    if len(raw) != 12 + 8 * count:
        what = "truncated" if len(raw) < 12 + 8 * count else "has trailing bytes"
        raise InputError(f"{path}: {what}: {len(raw)} bytes, expected {12 + 8 * count}")
    data = np.frombuffer(raw, dtype="<f8", offset=12).reshape((3,) + MERL_SHAPE)
    if np.isinf(data).any():
        raise InputError(f"{path}: {int(np.isinf(data).sum())} infinite value(s)")
    table = np.moveaxis(data, 0, -1) * np.asarray(MERL_SCALES)
    table[~(table >= 0)] = np.nan  # negative or NaN stored values: missing
    return TabulatedBRDF(table, source=path, name=str(path))


def write_merl(path, brdf: TabulatedBRDF) -> Path:
    """Write a 3-channel :class:`TabulatedBRDF` as a MERL ``.binary`` file (missing samples as -1), atomically.

    ``read_merl`` returns the table bit for bit when its values are stored values
    times :data:`MERL_SCALES` (any table read from a MERL file); other values come
    back within one unit in the last place.
    """
    path = Path(path)
    if brdf.channels != 3:
        raise InputError(f"{path}: MERL files hold 3 channels, the table has {brdf.channels}")
    data = np.moveaxis(brdf.table / np.asarray(MERL_SCALES), -1, 0)
    data = np.where(np.isnan(data), -1.0, data).astype("<f8")
    return write_bytes(path, np.asarray(MERL_SHAPE, dtype="<i4").tobytes() + np.ascontiguousarray(data).tobytes())


def load_measured(path) -> TabulatedBRDF | NeuralBRDF:
    """A measured BRDF from a neural fit (``.h5`` with its ``.json``) or a MERL table (``.binary``)."""
    path = Path(path)
    if path.suffix == ".h5":
        return NeuralBRDF.load(path)
    if path.suffix == ".binary":
        return read_merl(path)
    raise InputError(f"{path}: unknown measured-BRDF file type {path.suffix!r} (expected .h5 or .binary)")
