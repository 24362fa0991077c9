"""HDF5 plumbing of ``result.h5``: opening, layouts, growing columns, attributes.

Rows of point arrays follow a global, rank-independent order; each rank writes one block
of them collectively (:mod:`parefg.io.rows`, h5py's MPI-IO driver on more than one rank).
See :mod:`parefg.io.output` for the file layout.
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


def open_h5(comm, path: pathlib.Path, mode: str = "w-"):
    """Open ``path`` (default: create, never overwriting) with the MPI-IO driver on > 1 rank.

    Collective.  ``mode`` as h5py's ("r" to read, "w" to replace a scratch file).
    """
    if comm.size == 1:
        return h5py.File(path, mode, libver=LIBVER)
    if not h5py.get_config().mpi:
        raise RuntimeError("h5py lacks MPI support; run under mpirun with Debian's h5py-mpi")
    return h5py.File(path, mode, driver="mpio", comm=comm, libver=LIBVER)


def store_attributes(h5file, metadata: dict) -> None:
    """Store metadata as root attributes; collective, same values on every rank.

    Scalars (numbers, strings, booleans) are stored as they are; a nested dict ``d`` under
    key ``key`` is stored as the JSON string ``key_json`` and each scalar leaf as the flat
    attribute ``key.a.b``; other values (lists) as JSON strings.
    """
    attrs = h5file.attrs  # one manager: h5py builds a new one at every .attrs
    for key, value in metadata.items():
        if isinstance(value, dict):
            attrs[f"{key}_json"] = json.dumps(value, default=_to_json)
            for flat_key, leaf in _flatten(value, key):
                attrs[flat_key] = leaf
        elif _is_scalar(value):
            attrs[key] = value
        elif value is not None:
            attrs[key] = json.dumps(value, default=_to_json)


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
