"""Reference tables: measured materials on the nodes of the ``bivariate`` table, the prior of ``bivariate+measured``.

One image leaves much of a data-driven table weakly determined (docs/DESIGN.md, History: a table can
reproduce its image better than the true BRDF's own table and still relight 5% off).  ``bivariate+measured``
fills it from real materials: its prior is the non-negative combination of reference tables (each colour
channel of each reference material one column, with a free non-negative weight) that best reproduces the
image, and the table deviates from that prior smoothly where the pixels ask
(:func:`brdfrig.fit.bivariate.fit_bivariate`).  A non-negative combination of BRDFs is a non-negative,
reciprocal BRDF, whatever the camera's colour space.

The shipped set (:func:`shipped`, ``brdfrig/data/reference_tables.npz``) holds the 51 RGL-EPFL materials of
``shared/data/measured/rgl`` (the neural fits of Sztrajman et al. 2021, MIT licence, of the RGL-EPFL
measurements), projected on the nodes by :func:`brdfrig.fit.bivariate.project_to_nodes`; the ``nielsen``
materials are left out so that they measure it.  Rebuild or extend it with::

    python -m brdfrig.fit.references MATERIAL.h5|MATERIAL.binary ... -o FILE.npz

File format (numpy ``.npz``): ``names`` (M,) unicode, ``tables`` (M, 2, C, nh, nd) float32 node values in
1/sr (in-plane, then cross table; :class:`brdfrig.fit.bivariate.BivariateBRDF`), ``format`` = 1.
"""

from __future__ import annotations

import argparse
import io
import sys
import zipfile
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from brdfrig.errors import InputError

__all__ = ["ReferenceTables", "SHIPPED_PATH", "FORMAT", "shipped", "build", "main"]

SHIPPED_PATH = Path(__file__).resolve().parents[1] / "data" / "reference_tables.npz"
"""The reference set shipped with brdfrig (module docstring)."""
FORMAT = 1
"""Version of the ``.npz`` layout."""
SHIPPED_GRID = (32, 12)
"""``(nh, nd)`` of the shipped set: the grid ``bivariate+measured`` fits on."""


@dataclass(frozen=True)
class ReferenceTables:
    """Measured materials as bivariate node tables.

    Parameters
    ----------
    names : tuple of str
        One name per material (``group/stem``, e.g. ``rgl/acrylic_felt_white``), unique.
    tables : (M, 2, C, nh, nd) ndarray
        In-plane and cross node values (1/sr), finite and non-negative, on the ``bivariate`` grid
        (``theta_h`` sqrt-spaced, ``theta_d`` uniform).
    """

    names: tuple[str, ...]
    tables: np.ndarray

    def __post_init__(self) -> None:
        t = np.asarray(self.tables, dtype=np.float64)
        if t.ndim != 5 or t.shape[1] != 2 or t.shape[3] < 3 or t.shape[4] < 3:
            raise ValueError(f"reference tables must have shape (M, 2, C, nh >= 3, nd >= 3), got {t.shape}")
        if len(self.names) != t.shape[0] or len(set(self.names)) != len(self.names):
            raise ValueError(f"reference tables need one unique name per table ({len(self.names)} names, {t.shape[0]} tables)")
        if not np.all(np.isfinite(t)) or np.any(t < 0):
            raise ValueError("reference tables must be finite and non-negative")
        object.__setattr__(self, "names", tuple(str(n) for n in self.names))
        object.__setattr__(self, "tables", t)

    @property
    def grid(self) -> tuple[int, int]:
        """``(nh, nd)``."""
        return int(self.tables.shape[3]), int(self.tables.shape[4])

    def __len__(self) -> int:
        return len(self.names)

    def without(self, names) -> "ReferenceTables":
        """The set less the materials named (names it does not hold are ignored: a benchmark leaves its material out)."""
        drop = set(names)
        keep = [k for k, n in enumerate(self.names) if n not in drop]
        return ReferenceTables(tuple(self.names[k] for k in keep), self.tables[keep])

    def columns(self) -> tuple[np.ndarray, list[tuple[str, int]]]:
        """The prior's columns (2 nh nd, M C), each the in-plane then the cross nodes of one channel of one
        material (the layout of the ``bivariate`` fit's unknowns), and their ``(name, channel)``."""
        m, _, c, nh, nd = self.tables.shape
        cols = np.moveaxis(self.tables, 1, 2).reshape(m * c, 2 * nh * nd)
        return np.ascontiguousarray(cols.T), [(n, k) for n in self.names for k in range(c)]

    def save(self, path: str | Path) -> Path:
        """Write the ``.npz`` file (module docstring) atomically."""
        from brdfrig._atomic import write_bytes

        buf = io.BytesIO()
        np.savez_compressed(buf, names=np.array(self.names), tables=self.tables.astype(np.float32), format=np.int64(FORMAT))
        return write_bytes(path, buf.getvalue())

    @classmethod
    def load(cls, path: str | Path) -> "ReferenceTables":
        """Read a ``.npz`` reference set; :class:`~brdfrig.errors.InputError` naming the file if it is not one."""
        path = Path(path)
        try:
            with np.load(path, allow_pickle=False) as z:
                if "format" not in z.files or int(z["format"]) != FORMAT:
                    raise InputError(f"{path}: not a brdfrig reference-table file of format {FORMAT}")
                return cls(tuple(z["names"].tolist()), z["tables"])
        except FileNotFoundError:
            raise InputError(f"reference tables {path} do not exist") from None
        except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError) as exc:
            raise InputError(f"{path}: unreadable reference tables ({exc})") from None


@lru_cache(maxsize=1)
def shipped() -> ReferenceTables:
    """The reference set shipped with brdfrig (module docstring)."""
    return ReferenceTables.load(SHIPPED_PATH)


def build(paths, grid: tuple[int, int] = SHIPPED_GRID, progress: bool = False) -> ReferenceTables:
    """Reference tables of measured files (neural ``.h5`` with its ``.json``, or MERL ``.binary``), named
    ``parent/stem`` (``_rgb`` dropped), projected on the ``grid`` nodes."""
    from tqdm import tqdm

    from brdfrig.fit.bivariate import project_to_nodes
    from brdfrig.fit.measured import load_measured

    names, tables = [], []
    for path in tqdm([Path(p) for p in paths], desc="reference tables", disable=not progress, leave=False):
        stem = path.stem[: -len("_rgb")] if path.stem.endswith("_rgb") else path.stem
        names.append(f"{path.parent.name}/{stem}")
        tables.append(project_to_nodes(load_measured(path), *grid))
    if not tables:
        raise InputError("no measured material given")
    return ReferenceTables(tuple(names), np.stack(tables))


def main(argv: list[str] | None = None) -> int:
    """``python -m brdfrig.fit.references FILE... -o OUT.npz``: build a reference set (exit 2 on bad input)."""
    parser = argparse.ArgumentParser(prog="python -m brdfrig.fit.references", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("materials", nargs="+", type=Path, help="measured materials (.h5 neural fits, .binary MERL tables)")
    parser.add_argument("-o", "--out", type=Path, required=True, help="the .npz file to write")
    parser.add_argument("--nh", type=int, default=SHIPPED_GRID[0], help="theta_h nodes (default: %(default)s)")
    parser.add_argument("--nd", type=int, default=SHIPPED_GRID[1], help="theta_d nodes (default: %(default)s)")
    args = parser.parse_args(argv)
    try:
        if args.out.resolve() in {p.resolve() for p in args.materials}:
            raise InputError(f"output {args.out} is one of the inputs")
        if args.nh < 3 or args.nd < 3:
            raise InputError(f"--nh and --nd must be >= 3, got {args.nh}, {args.nd}")
        refs = build(args.materials, (args.nh, args.nd), progress=True)
        refs.save(args.out)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"{args.out}: {len(refs)} materials on a {args.nh} x {args.nd} grid")
    return 0


if __name__ == "__main__":
    sys.exit(main())
