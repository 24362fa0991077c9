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

import json
import os
import pathlib
import xml.etree.ElementTree as ET

import h5py
import numpy as np

from parefg.errors import InputError

H5_NAME = "result.h5"
# XDMF number types by numpy kind; XDMF calls 1-byte integers Char / UChar (status is int8)
XDMF_NUMBER_TYPES = {"f": "Float", "i": "Int", "u": "UInt"}
XDMF_BYTE_TYPES = {"i": "Char", "u": "UChar", "b": "UChar"}
XDMF_NAME = "result.xdmf"
# growable 1-D float columns of /history, NaN where a row lacked the column
GROWING_FLOATS = dict(maxshape=(None,), dtype=np.float64, chunks=(256,), fillvalue=np.nan)
# result.xdmf around the snapshots, as ElementTree indents the whole document
XDMF_HEAD = (
    '<?xml version="1.0"?>\n<Xdmf Version="3.0">\n  <Domain>\n'
    '    <Grid Name="TimeSeries" GridType="Collection" CollectionType="Temporal">\n'
)
XDMF_TAIL = "    </Grid>\n  </Domain>\n</Xdmf>\n"
HISTORY_BLOCK = 256  # per-step rows kept in memory before they are stored
SNAPSHOT_LEVEL = 3  # Xdmf > Domain > Grid (temporal) > Grid (snapshot)
# HDF5 1.8 file format: groups keep their links in a fractal heap and a B-tree v2, so
# flushing a group of k outputs writes the changed blocks only; the 1.6 symbol-table
# groups rewrite their whole name heap (O(k) bytes per output, quadratic in all).
# HDF5 >= 1.8 (2008) reads it, as does ParaView.
LIBVER = ("v108", "v108")


class ResultWriter:
    """Collective writer of ``result.h5`` and ``result.xdmf`` in ``out_dir``.

    The HDF5 file is opened with h5py's MPI-IO driver on more than one rank (every rank
    writes its own rows, independent I/O) and with the default driver on one rank. Dataset
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
        self.node_rows = _PointRows.checked(comm, node_rows, self.n_nodes, "node")
        self.contact_rows = _PointRows.checked(comm, contact_rows, self.n_contact, "contact")
        self.n_outputs = 0
        self.xdmf_bytes_written = 0  # bytes handed to the XDMF file (rank 0), for tests
        self._layouts: dict[str, tuple] = {}  # field path pattern -> agreed (trailing, dtype)
        self.history_rows = 0  # rows stored in /history
        self._pending_rows: list[dict] = []  # rows not stored yet (rank 0 keeps them)
        self._n_pending = 0
        self.file = _open_h5(comm, self.h5_path)
        self._write_points("mesh/coordinates", self.node_rows, node_coords)
        _raise_on_all(comm, node_original_index is None, "node_original_index given on some ranks")
        if node_original_index is not None:
            index = np.asarray(node_original_index, dtype=np.int64)
            self._write_points("mesh/original_index", self.node_rows, index)
        if self.n_contact > 0:
            self._write_points("contact/coordinates", self.contact_rows, contact_coords)
        for name, dtype in (("steps/time", np.float64), ("steps/step", np.int64)):
            self.file.create_dataset(name, shape=(0,), maxshape=(None,), dtype=dtype, chunks=(64,))
        self.file.create_group("history")
        _store_attributes(self.file, comm.bcast(metadata, root=0))
        self.flush()
        self._xdmf = _XdmfIndex.create(comm, self.xdmf_path)

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
            _append_scalar(self.comm, self.file[name], value)
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
        history = self.file["history"]
        for column in sorted(set().union(*rows) - set(history)):
            history.create_dataset(column, shape=(self.history_rows,), **GROWING_FLOATS)
        first, last = self.history_rows, self.history_rows + len(rows)
        for column in sorted(history):
            dataset = history[column]
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
        _store_attributes(self.file, self.comm.bcast(metadata, root=0))
        self.file.close()
        self.file = None
        self._xdmf.close()

    def _write_points(self, path: str, rows: "_PointRows", values) -> tuple:
        """Create dataset ``path`` with one row per global point and write this rank's rows."""
        values = np.asarray(values)
        trailing, dtype = _agreed_layout(self.comm, path, values, rows.n_local)
        dataset = self.file.create_dataset(path, shape=(rows.n_global, *trailing), dtype=dtype)
        rows.write(dataset, values)
        return trailing, dtype

    def _write_fields(self, path_pattern: str, rows: "_PointRows", fields: dict) -> list:
        """Write every field under ``path_pattern.format(name)``; return their XDMF specs.

        The ranks agree on the names and layouts through one allgather per call once the
        layouts are known (the first output checks each layout field by field).
        """
        names = sorted(fields)
        key = path_pattern.split("/")[0]
        known = self._layouts.get(key)
        if known is None:
            _raise_on_all(self.comm, names, "field names differ between ranks")
        else:
            layout = [(name, *_layout(fields[name])) for name in names]
            same = layout == known and all(fields[name].shape[0] == rows.n_local for name in names)
            _raise_on_all(self.comm, same, f"{key}: names, shapes or dtypes changed", agree=False)
        specs = []
        for name in names:
            path = path_pattern.format(name)
            values = np.asarray(fields[name])
            if known is None:
                trailing, dtype = _agreed_layout(self.comm, path, values, rows.n_local)
            else:
                trailing, dtype = values.shape[1:], values.dtype
            dataset = self.file.create_dataset(path, shape=(rows.n_global, *trailing), dtype=dtype)
            rows.write(dataset, values)
            specs.append((name, path, trailing, dtype))
        self._layouts[key] = [(name, *_layout(fields[name])) for name in names]
        return specs


class _XdmfIndex:
    """result.xdmf, grown in place on rank 0: the head, the snapshots, the closing tags.

    Every append is one ``pwrite`` of (new snapshot + closing tags) at the offset of the
    closing tags, so the file is a complete XDMF document before and after it.  A short
    write (disk full) puts the closing tags back and raises OSError.
    """

    def __init__(self, comm, descriptor: int | None, tail_offset: int):
        self.comm, self.descriptor, self.tail_offset = comm, descriptor, tail_offset

    @classmethod
    def create(cls, comm, path: pathlib.Path) -> "_XdmfIndex":
        """Write an XDMF document with no snapshot; collective (rank 0 writes)."""
        descriptor, error = None, None
        if comm.rank == 0:
            try:
                descriptor = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
                os.write(descriptor, (XDMF_HEAD + XDMF_TAIL).encode())
            except OSError as failure:
                error = f"cannot write {path}: {failure.strerror}"
        error = comm.bcast(error, root=0)
        if error:
            raise OSError(error)
        return cls(comm, descriptor, len(XDMF_HEAD))

    def append(self, snapshot: str) -> int:
        """Add one snapshot; collective (rank 0 writes).  Returns the bytes written."""
        written, error = 0, None
        if self.comm.rank == 0:
            data = (snapshot + XDMF_TAIL).encode()
            try:
                written = os.pwrite(self.descriptor, data, self.tail_offset)
                if written != len(data):
                    raise OSError(f"short write ({written} of {len(data)} bytes)")
                self.tail_offset += len(data) - len(XDMF_TAIL)
            except OSError as failure:
                self._restore_tail()
                error = f"cannot append to {XDMF_NAME}: {failure}"
        error = self.comm.bcast(error, root=0)
        if error:
            raise OSError(error)
        return written

    def _restore_tail(self) -> None:
        """Cut the file back to the last complete snapshot and close it again (rank 0)."""
        os.pwrite(self.descriptor, XDMF_TAIL.encode(), self.tail_offset)
        os.ftruncate(self.descriptor, self.tail_offset + len(XDMF_TAIL))

    def close(self) -> None:
        if self.descriptor is not None:
            os.close(self.descriptor)
            self.descriptor = None


class _PointRows:
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
    def checked(cls, comm, rows, n_global: int, what: str) -> "_PointRows":
        """Build after checking on every rank that the rows split 0..n_global-1; collective."""
        point_rows = cls(rows, n_global)
        sorted_rows = point_rows.sorted_rows
        in_range = bool(np.all((sorted_rows >= 0) & (sorted_rows < n_global)))
        unique = bool(np.all(np.diff(sorted_rows) > 0))
        total = comm.allreduce(sorted_rows.size)
        message = f"{what} rows must split 0..{n_global - 1} between ranks, got {total} rows"
        _raise_on_all(comm, in_range and unique and total == n_global, message, agree=False)
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


def _raise_on_all(comm, local, message: str, agree: bool = True) -> None:
    """Raise ValueError on every rank if the check fails anywhere; collective.

    With ``agree`` the values ``local`` must be equal on all ranks, otherwise ``local`` is a
    bool that must be true on all ranks. Deciding together keeps ranks out of a collective
    call that some ranks would skip.
    """
    values = comm.allgather(local)
    failed = any(value != values[0] for value in values) if agree else not all(values)
    if failed:
        raise ValueError(message)


def _layout(values) -> tuple:
    """(trailing shape, dtype string) of a point array."""
    values = np.asarray(values)
    return values.shape[1:], values.dtype.str


def _agreed_layout(comm, path: str, values: np.ndarray, n_local: int) -> tuple:
    """Trailing shape and dtype of a point array, checked equal on every rank; collective."""
    local_ok = values.ndim in (1, 2) and values.shape[0] == n_local
    layout = (values.shape[1:], values.dtype.str)
    message = f"{path}: need one row per owned point, shape (n_owned,) or (n_owned, c)"
    _raise_on_all(comm, local_ok, message, agree=False)
    _raise_on_all(comm, layout, f"{path}: shape or dtype differs between ranks")
    return values.shape[1:], values.dtype


def _append_scalar(comm, dataset, value) -> None:
    """Grow a 1-D dataset by one entry and set it (resize collective, write by rank 0)."""
    n = dataset.shape[0]
    dataset.resize((n + 1,))
    if comm.rank == 0:
        dataset[n] = value


def _refuse_existing(comm, *paths: pathlib.Path) -> None:
    """Create the run directory; raise InputError on every rank if a result exists."""
    existing = None
    if comm.rank == 0:
        paths[0].parent.mkdir(parents=True, exist_ok=True)
        existing = next((str(path) for path in paths if path.exists()), None)
    existing = comm.bcast(existing, root=0)
    if existing is not None:
        raise InputError(f"{existing} already exists; choose another --out directory")


def _open_h5(comm, path: pathlib.Path):
    """Create ``path`` (never overwriting) with the MPI-IO driver on > 1 rank; collective."""
    if comm.size == 1:
        return h5py.File(path, "w-", libver=LIBVER)
    if not h5py.get_config().mpi:
        raise RuntimeError("h5py lacks MPI support; run under mpirun with Debian's h5py-mpi")
    return h5py.File(path, "w-", driver="mpio", comm=comm, libver=LIBVER)


def _store_attributes(h5file, metadata: dict) -> None:
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


def xdmf_document(outputs: list, n_nodes: int, n_contact: int) -> str:
    """XDMF 3 text for the output steps ``outputs`` (see :class:`ResultWriter`); local.

    ``outputs`` lists (step, time, node field specs, contact field specs) per output.
    """
    snapshots = (snapshot_text(k, *output, n_nodes, n_contact) for k, output in enumerate(outputs))
    return XDMF_HEAD + "".join(snapshots) + XDMF_TAIL


def snapshot_text(
    k: int, step: int, time: float, node_specs, contact_specs, n_nodes: int, n_contact: int
) -> str:
    """The indented ``<Grid>`` of output ``k`` (one line per element, newline-terminated)."""
    snapshot = ET.Element(
        "Grid", Name=f"output_{k:04d}", GridType="Collection", CollectionType="Spatial"
    )
    ET.SubElement(snapshot, "Time", Value=repr(time))
    ET.SubElement(snapshot, "Information", Name="step", Value=str(step))
    _point_grid(snapshot, "nodes", "mesh/coordinates", n_nodes, node_specs)
    if n_contact > 0:
        _point_grid(snapshot, "contact", "contact/coordinates", n_contact, contact_specs)
    ET.indent(snapshot, level=SNAPSHOT_LEVEL)
    indent = "  " * SNAPSHOT_LEVEL
    return indent + ET.tostring(snapshot, encoding="unicode") + "\n"


def _point_grid(parent, name: str, coordinates: str, n_points: int, specs: list) -> None:
    """A Uniform Polyvertex grid of ``n_points`` points with one attribute per field spec."""
    grid = ET.SubElement(parent, "Grid", Name=name, GridType="Uniform")
    topology = {"TopologyType": "Polyvertex", "NodesPerElement": "1"}
    ET.SubElement(grid, "Topology", topology, NumberOfElements=str(n_points))
    geometry = ET.SubElement(grid, "Geometry", GeometryType="XY")
    _data_item(geometry, coordinates, (n_points, 2), np.dtype(np.float64))
    for field_name, path, trailing, dtype in specs:
        kind = "Scalar" if not trailing else ("Vector" if trailing[0] in (2, 3) else "Matrix")
        attribute = ET.SubElement(
            grid, "Attribute", Name=field_name, AttributeType=kind, Center="Node"
        )
        _data_item(attribute, path, (n_points, *trailing), dtype)


def _data_item(parent, path: str, shape: tuple, dtype: np.dtype) -> None:
    """An HDF DataItem pointing at ``result.h5:/path``."""
    dtype = np.dtype(dtype)
    types = XDMF_BYTE_TYPES if dtype.itemsize == 1 else XDMF_NUMBER_TYPES
    number_type = types[dtype.kind]
    dimensions = " ".join(str(n) for n in shape)
    item = ET.SubElement(parent, "DataItem", Dimensions=dimensions, NumberType=number_type)
    item.attrib.update(Precision=str(dtype.itemsize), Format="HDF")
    item.text = f"{H5_NAME}:/{path}"
