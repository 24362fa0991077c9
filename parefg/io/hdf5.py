"""HDF5 plumbing of ``result.h5``: rows of distributed point sets, layouts, attributes.

Rows of point arrays follow a global, rank-independent order; each rank writes its own
rows (independent I/O with h5py's MPI-IO driver on more than one rank).  See
:mod:`parefg.io.output` for the file layout.
"""

from __future__ import annotations

import json
import pathlib

import h5py
import numpy as np

from parefg.parallel import raise_unless_everywhere, same_everywhere

# growable 1-D float columns of /history, NaN where a row lacked the column
GROWING_FLOATS = dict(maxshape=(None,), dtype=np.float64, chunks=(256,), fillvalue=np.nan)
# HDF5 1.8 file format: groups keep their links in a fractal heap and a B-tree v2, so
# flushing a group of k outputs writes the changed blocks only; the 1.6 symbol-table
# groups rewrite their whole name heap (O(k) bytes per output, quadratic in all).
# HDF5 >= 1.8 (2008) reads it, as does ParaView.
LIBVER = ("v108", "v108")


class PointRows:
    """This rank's rows of a point set, sorted once for writing (HDF5 needs rising indices)."""

    def __init__(self, rows, n_global: int):
        rows = np.asarray(rows, dtype=np.int64).reshape(-1)
        self.n_global = n_global
        self.n_local = rows.size
        # order that sorts this rank's rows: data is permuted the same way before writing
        self.order = np.argsort(rows, kind="stable")
        self.sorted_rows = rows[self.order]  # (n_local,)
        span = self.sorted_rows[-1] - self.sorted_rows[0] + 1 if rows.size else 0
        self.contiguous = rows.size > 0 and span == rows.size

    @classmethod
    def checked(cls, comm, rows, n_global: int, what: str) -> PointRows:
        """Build after checking on every rank that the rows split 0..n_global-1; collective."""
        point_rows = cls(rows, n_global)
        sorted_rows = point_rows.sorted_rows
        in_range = bool(np.all((sorted_rows >= 0) & (sorted_rows < n_global)))
        unique = bool(np.all(np.diff(sorted_rows) > 0))
        total = comm.allreduce(sorted_rows.size)
        message = f"{what} rows must split 0..{n_global - 1} between ranks, got {total} rows"
        raise_unless_everywhere(
            comm, in_range and unique and total == n_global, ValueError(message)
        )
        return point_rows

    def write(self, dataset, values: np.ndarray) -> None:
        """Write ``values`` (n_local, ...) to this rank's rows of ``dataset`` (independent I/O)."""
        if self.n_local == 0:
            return
        values = np.ascontiguousarray(values[self.order], dtype=dataset.dtype)
        if self.contiguous:
            first = int(self.sorted_rows[0])
            dataset[first : first + self.n_local] = values
            return
        # (n_local * n_components, ndim) file coordinates of every value, row-major like values
        n_components = values.size // self.n_local
        coordinates = np.repeat(self.sorted_rows, n_components)[:, None]
        if values.ndim == 2:
            columns = np.tile(np.arange(n_components), self.n_local)[:, None]
            coordinates = np.hstack([coordinates, columns])
        file_space = dataset.id.get_space()
        file_space.select_elements(coordinates.astype(np.uint64))
        memory_space = h5py.h5s.create_simple((values.size,))
        dataset.id.write(memory_space, file_space, values.reshape(-1))


def layout_of(values) -> tuple:
    """(trailing shape, dtype string) of a point array."""
    values = np.asarray(values)
    return values.shape[1:], values.dtype.str


def agreed_layout(comm, path: str, values: np.ndarray, n_local: int) -> tuple:
    """Trailing shape and dtype of a point array, checked equal on every rank; collective."""
    local_ok = values.ndim in (1, 2) and values.shape[0] == n_local
    layout = (values.shape[1:], values.dtype.str)
    message = f"{path}: need one row per owned point, shape (n_owned,) or (n_owned, c)"
    raise_unless_everywhere(comm, local_ok, ValueError(message))
    if not same_everywhere(comm, layout):
        raise ValueError(f"{path}: shape or dtype differs between ranks")
    return values.shape[1:], values.dtype


def append_scalar(comm, dataset, value) -> None:
    """Grow a 1-D dataset by one entry and set it (resize collective, write by rank 0)."""
    n = dataset.shape[0]
    dataset.resize((n + 1,))
    if comm.rank == 0:
        dataset[n] = value


def open_h5(comm, path: pathlib.Path):
    """Create ``path`` (never overwriting) with the MPI-IO driver on > 1 rank; collective."""
    if comm.size == 1:
        return h5py.File(path, "w-", libver=LIBVER)
    if not h5py.get_config().mpi:
        raise RuntimeError("h5py lacks MPI support; run under mpirun with Debian's h5py-mpi")
    return h5py.File(path, "w-", driver="mpio", comm=comm, libver=LIBVER)


def store_attributes(h5file, metadata: dict) -> None:
    """Store metadata as root attributes; collective, same values on every rank.

    Scalars (numbers, strings, booleans) are stored as they are; a nested dict ``d`` under
    key ``key`` is stored as the JSON string ``key_json`` and each scalar leaf as the flat
    attribute ``key.a.b``; other values (lists) as JSON strings.
    """
    for key, value in metadata.items():
        if isinstance(value, dict):
            h5file.attrs[f"{key}_json"] = json.dumps(value, default=_to_json)
            for flat_key, leaf in _flatten(value, key):
                h5file.attrs[flat_key] = leaf
        elif _is_scalar(value):
            h5file.attrs[key] = value
        elif value is not None:
            h5file.attrs[key] = json.dumps(value, default=_to_json)


def _flatten(tree: dict, prefix: str):
    """Yield ("prefix.a.b", leaf) for every scalar leaf of a nested dict."""
    for key, value in tree.items():
        name = f"{prefix}.{key}"
        if isinstance(value, dict):
            yield from _flatten(value, name)
        elif _is_scalar(value):
            yield name, value


def _is_scalar(value) -> bool:
    return isinstance(value, (bool, int, float, str, np.generic))


def _to_json(value):
    """JSON fallback for numpy scalars and arrays, paths and the like."""
    if isinstance(value, (np.generic, np.ndarray)):
        return value.tolist()
    return str(value)
