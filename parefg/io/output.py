"""Results on disk: one HDF5 file per run plus an XDMF index for ParaView (SPEC 7).

Layout of ``result.h5`` (rows of node arrays follow the global node order, independent of
the rank count; output index k counts output steps 0, 1, 2, ... and is written ``%04d``)::

    /                              attrs: params_json (effective scene as JSON), version,
                                   mpi_ranks, every scalar leaf of a nested dict as a flat
                                   attribute "<key>.<sub>..." (e.g. "params.time.dt"), and
                                   what close() adds (timings, errors, counts)
    /mesh/coordinates              (n_nodes, 2)   float64  node positions x_I
    /mesh/original_index           (n_nodes,)     int64    optional: row -> index in the input cloud
    /contact/coordinates           (n_contact, 2) float64  Gamma_C quadrature points
                                                           (no /contact group when n_contact = 0)
    /steps/time                    (n_out,)       float64  time t of output k
    /steps/step                    (n_out,)       int64    time-step number n of output k
    /fields/<name>/<k>             (n_nodes,) or (n_nodes, 2)    u_h, velocity, acceleration,
                                                                 von Mises ... at the nodes
    /contact_fields/<name>/<k>     (n_contact,) or (n_contact, 2) gap, normal_pressure,
                                   tangential_traction, status (int8: 0 open, 1 stick, 2 slip)
    /history/<column>              (n_rows,)      float64  one row per time step; NaN where a row
                                                           lacked the column

``result.xdmf`` (XDMF 3) is a Temporal collection with one Spatial collection per output
step, holding a Polyvertex grid "nodes" and, when there is a contact boundary, a Polyvertex
grid "contact"; scalars are Scalar attributes, 2-vectors Vector attributes, centred on the
points. Every DataItem points into ``result.h5`` by a relative path.

Crash safety: each :meth:`ResultWriter.write_step` flushes the HDF5 file and then appends
its snapshot to the XDMF file in place: one write at the offset of the closing tags puts
the new ``<Grid>`` and the closing tags back (the file is a complete document before and
after the write), so a run that dies later leaves both readable up to that step.  The
cost of an output does not depend on how many came before it (no rewrite of the index).
"""

from __future__ import annotations

import pathlib
from typing import Any

import numpy as np

from parefg.errors import InputError
from parefg.io.hdf5 import (
    GROWING_FLOATS,
    agreed_layout,
    append_scalar,
    layout_of,
    open_h5,
    store_attributes,
)
from parefg.io.rows import BlockRows
from parefg.io.xdmf import H5_NAME, XDMF_NAME, XdmfIndex, snapshot_text
from parefg.parallel import call_on_root, raise_unless_everywhere, same_everywhere

HISTORY_BLOCK = 256  # per-step rows kept in memory before they are stored


class ResultWriter:
    """Collective writer of ``result.h5`` and ``result.xdmf`` in ``out_dir``.

    The HDF5 file is opened with h5py's MPI-IO driver on more than one rank and with the
    default driver on one rank.  Each point array is written by all ranks together, every
    rank one hyperslab: the block of file rows as large as its share of the points, filled
    from the other ranks by one Alltoallv (:class:`~parefg.io.rows.BlockRows`; no rank
    holds more than its share, nothing is gathered to rank 0).  Dataset
    creation, resizing, attributes and flushes are collective: every rank makes the same
    calls. Values that must agree across ranks (metadata, history rows, step and time) are
    taken from rank 0.

    Parameters
    ----------
    comm : mpi4py.MPI.Comm
        Communicator of the run.
    out_dir : pathlib.Path
        Directory of the run (created if missing).
    node_coords : ndarray, shape (n_owned, 2)
        Positions of this rank's nodes.
    node_rows : ndarray, shape (n_owned,)
        Global row of each owned node; over all ranks a permutation of 0..n_nodes-1.
    n_nodes : int
        Number of nodes in the whole cloud.
    contact_coords : ndarray, shape (n_c_local, 2)
        This rank's Gamma_C quadrature points.
    contact_rows : ndarray, shape (n_c_local,)
        Their global rows; over all ranks a permutation of 0..n_contact-1.
    n_contact : int
        Number of Gamma_C quadrature points in total (0: no contact group).
    metadata : dict
        "params" (effective scene, nested dict), "version", "mpi_ranks", ... stored as
        root attributes (see the module docstring).
    node_original_index : ndarray, shape (n_owned,), optional
        Index of each owned node in the input cloud, stored as /mesh/original_index.

    Raises
    ------
    InputError
        If ``result.h5`` or ``result.xdmf`` already exists in ``out_dir`` (never overwrite).
    ValueError
        If the rows or shapes are inconsistent (raised on every rank).
    """

    def __init__(
        self,
        comm,
        out_dir: pathlib.Path,
        *,
        node_coords,
        node_rows,
        n_nodes,
        contact_coords,
        contact_rows,
        n_contact,
        metadata: dict,
        node_original_index=None,
    ):
        self.comm = comm
        self.h5_path = pathlib.Path(out_dir) / H5_NAME
        self.xdmf_path = pathlib.Path(out_dir) / XDMF_NAME
        self.n_nodes = int(n_nodes)
        self.n_contact = int(n_contact)
        _refuse_existing(comm, self.h5_path, self.xdmf_path)
        self.node_rows = BlockRows(comm, node_rows, self.n_nodes, "node")
        self.contact_rows = BlockRows(comm, contact_rows, self.n_contact, "contact")
        self.n_outputs = 0
        self.xdmf_bytes_written = 0  # bytes handed to the XDMF file (rank 0), for tests
        self._layouts: dict[str, list[tuple]] = {}  # field group -> agreed (name, trailing, dtype)
        self.history_rows = 0  # rows stored in /history
        # /history's datasets by column: h5py's group lookups cost ~50 us each, and every
        # output step stores its rows (a step's history cost halved on the default scene)
        self._history_columns: dict[str, Any] = {}
        self._pending_rows: list[dict] = []  # rows not stored yet (rank 0 keeps them)
        self._n_pending = 0
        self.file = open_h5(comm, self.h5_path)
        self._write_points("mesh/coordinates", self.node_rows, node_coords)
        if not same_everywhere(comm, node_original_index is None):
            raise ValueError("node_original_index given on some ranks")
        if node_original_index is not None:
            index = np.asarray(node_original_index, dtype=np.int64)
            self._write_points("mesh/original_index", self.node_rows, index)
        if self.n_contact > 0:
            self._write_points("contact/coordinates", self.contact_rows, contact_coords)
        for name, dtype in (("steps/time", np.float64), ("steps/step", np.int64)):
            self.file.create_dataset(name, shape=(0,), maxshape=(None,), dtype=dtype, chunks=(64,))
        self.file.create_group("history")
        store_attributes(self.file, comm.bcast(metadata, root=0))
        self.flush()
        self._xdmf = XdmfIndex.create(comm, self.xdmf_path)

    def write_step(self, step: int, time: float, node_fields: dict, contact_fields: dict) -> None:
        """Store the fields of one output step; collective.

        Parameters
        ----------
        step : int
            Time-step number n (rank 0's value is stored).
        time : float
            Time t_n (rank 0's value is stored).
        node_fields : dict of str -> ndarray, shape (n_owned,) or (n_owned, 2)
            Values at this rank's nodes; the same names, dtypes and trailing shapes on every
            rank.
        contact_fields : dict of str -> ndarray, shape (n_c_local,) or (n_c_local, 2)
            Values at this rank's Gamma_C points; ignored when ``n_contact == 0``.

        Flushes ``result.h5``, then appends the step to ``result.xdmf``: a later crash
        leaves both readable up to this step.  Its cost does not grow with the number of
        outputs written before.
        """
        k = self.n_outputs
        step, time = self.comm.bcast((int(step), float(time)), root=0)
        node_specs = self._write_fields(f"fields/{{}}/{k:04d}", self.node_rows, node_fields)
        contact_specs = []
        if self.n_contact > 0:
            contact_specs = self._write_fields(
                f"contact_fields/{{}}/{k:04d}", self.contact_rows, contact_fields
            )
        for name, value in (("steps/time", time), ("steps/step", step)):
            append_scalar(self.comm, self.file[name], value)
        self.n_outputs += 1
        self.flush()
        text = snapshot_text(k, step, time, node_specs, contact_specs, self.n_nodes, self.n_contact)
        self.xdmf_bytes_written += self._xdmf.append(text)

    def append_history(self, row: dict) -> None:
        """Append one row of the per-step table to /history; collective.

        Parameters
        ----------
        row : dict of str -> float
            time, newton_iterations, linear_iterations, active_contact_points,
            kinetic_energy, elastic_energy, penalty_energy, dissipated_energy,
            external_work and any extra columns (rank 0's values are stored). A column
            reads NaN in rows that lack it (also in rows before it first appeared).

        Rows are kept in memory and stored in blocks of HISTORY_BLOCK rows, and by the
        next write_step, flush or close (rows come every time step; one HDF5 resize per
        column and block instead of per row).  Collective, without communication until
        a block is stored.
        """
        if self.comm.rank == 0:
            self._pending_rows.append({str(key): float(value) for key, value in row.items()})
        self._n_pending += 1
        if self._n_pending >= HISTORY_BLOCK:
            self._store_history()

    def _store_history(self) -> None:
        """Append the pending rows (rank 0's values) to /history; collective."""
        if self._n_pending == 0:
            return
        rows = self.comm.bcast(self._pending_rows, root=0)
        self._pending_rows, self._n_pending = [], 0
        columns = self._history_columns
        for column in sorted(set().union(*rows) - set(columns)):
            columns[column] = self.file["history"].create_dataset(
                column, shape=(self.history_rows,), **GROWING_FLOATS
            )
        first, last = self.history_rows, self.history_rows + len(rows)
        for column in sorted(columns):
            dataset = columns[column]
            dataset.resize((last,))
            if self.comm.rank == 0:
                dataset[first:last] = [row.get(column, np.nan) for row in rows]
        self.history_rows = last

    def flush(self) -> None:
        """Push everything written so far (pending history rows too) to disk; collective."""
        self._store_history()
        self.file.flush()

    def close(self, metadata: dict) -> None:
        """Store the final attributes (timings, errors, counts) and close; collective.

        Parameters
        ----------
        metadata : dict
            Scalars become root attributes; nested dicts become "<key>_json" plus flat
            "<key>.<sub>" attributes (rank 0's values are stored).
        """
        if self.file is None:
            return
        self._store_history()
        store_attributes(self.file, self.comm.bcast(metadata, root=0))
        self.file.close()
        self.file = None
        self._xdmf.close()

    def _write_points(self, path: str, rows: BlockRows, values) -> tuple:
        """Create dataset ``path`` with one row per global point and write this rank's rows."""
        values = np.asarray(values)
        trailing, dtype = agreed_layout(self.comm, path, values, rows.n_local)
        dataset = self.file.create_dataset(path, shape=(rows.n_global, *trailing), dtype=dtype)
        rows.write(dataset, values)
        return trailing, dtype

    def _write_fields(self, path_pattern: str, rows: BlockRows, fields: dict) -> list:
        """Write every field under ``path_pattern.format(name)``; return their XDMF specs.

        The ranks agree on the names and layouts through one allgather per call once the
        layouts are known (the first output checks each layout field by field).
        """
        names = sorted(fields)
        key = path_pattern.split("/")[0]
        known = self._layouts.get(key)
        if known is None:
            if not same_everywhere(self.comm, names):
                raise ValueError("field names differ between ranks")
        else:
            layout = [(name, *layout_of(fields[name])) for name in names]
            same = layout == known and all(fields[name].shape[0] == rows.n_local for name in names)
            changed = ValueError(f"{key}: names, shapes or dtypes changed")
            raise_unless_everywhere(self.comm, same, changed)
        specs = []
        for name in names:
            path = path_pattern.format(name)
            values = np.asarray(fields[name])
            if known is None:
                trailing, dtype = agreed_layout(self.comm, path, values, rows.n_local)
            else:
                trailing, dtype = values.shape[1:], values.dtype
            if self.comm.size == 1:  # created with its values: one HDF5 call less per field
                self.file.create_dataset(path, data=rows.to_block(values.astype(dtype, copy=False)))
            else:
                shape = (rows.n_global, *trailing)
                rows.write(self.file.create_dataset(path, shape=shape, dtype=dtype), values)
            specs.append((name, path, trailing, dtype))
        self._layouts[key] = [(name, *layout_of(fields[name])) for name in names]
        return specs


def _refuse_existing(comm, *paths: pathlib.Path) -> None:
    """Create the run directory; raise InputError on every rank if a result exists."""
    call_on_root(comm, _refuse_existing_here, *paths)


def _refuse_existing_here(*paths: pathlib.Path) -> None:
    """:func:`_refuse_existing` on one rank."""
    paths[0].parent.mkdir(parents=True, exist_ok=True)
    existing = next((str(path) for path in paths if path.exists()), None)
    if existing is not None:
        raise InputError(f"{existing} already exists; choose another --out directory")
