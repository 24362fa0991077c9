"""File blocks of distributed point sets: each rank writes and reads one contiguous block.

The rows of a point array on disk follow a global, rank-independent order (nodes by their
index in the input cloud, Gamma_C points by their global row), while a rank's points are
scattered over that order (the partition renumbers them).  Rank r reads and writes the
contiguous block ``blocks[r]:blocks[r + 1]`` of the file rows, as large as its own share of
the points (the PETSc ownership: blocks follow the ranks' counts), so every HDF5 transfer is
one hyperslab per rank (independent MPI-IO: :data:`COLLECTIVE_TRANSFERS`).  The values
between a rank's points and its block move with one ``Alltoallv`` per array: a rank sends
and receives at most its own share, and no rank ever holds more than its share (nothing
is gathered to rank 0).
"""

from __future__ import annotations

import h5py
import numpy as np
from mpi4py import MPI

from parefg.parallel import raise_unless_everywhere

# Each rank's rows are one contiguous hyperslab, which independent MPI-IO writes in one
# request; two-phase collective transfers add a synchronisation and gain nothing for it.
# (Timings on the loaded machine of this change were dominated by its load: the same code
# took 0.04-5 s per output, scripts/bench/bench_parallel_io.py; not a measured speed-up.)
# File and dataset creation, resizes, attributes, flush and close stay collective (HDF5
# requires it); every rank still makes every transfer call.
COLLECTIVE_TRANSFERS = False


class BlockRows:
    """This rank's points of a point set and the file block it writes and reads.

    Parameters
    ----------
    comm : mpi4py.MPI.Comm
        Communicator of the run.
    rows : ndarray, shape (n_local,)
        Global row of each of this rank's points; over all ranks a permutation of
        0..n_global-1 (checked: ValueError on every rank otherwise).
    n_global : int
        Number of points on all ranks.
    what : str
        Name of the point set in the error message ("node", "contact").

    Construction is collective (one allgather, one Alltoall and one Alltoallv of the rows);
    :meth:`to_block` and :meth:`from_block` are collective (one Alltoallv each).
    """

    def __init__(self, comm, rows, n_global: int, what: str = "point"):
        rows = np.asarray(rows, dtype=np.int64).reshape(-1)
        self.comm, self.n_global, self.n_local = comm, int(n_global), rows.size
        counts = np.array(comm.allgather(rows.size), dtype=np.int64)
        self.blocks = np.concatenate([[0], np.cumsum(counts)])  # (size + 1,)
        self.first = int(self.blocks[comm.rank])
        self.n_block = int(counts[comm.rank])
        # sorted by row, this rank's points come grouped by the rank whose block holds them
        self.send_order = np.argsort(rows, kind="stable")  # (n_local,)
        sorted_rows = rows[self.send_order]
        edges = np.searchsorted(sorted_rows, self.blocks[1:-1])  # rows out of range: end ranks
        self.send_counts = np.diff(np.concatenate([[0], edges, [rows.size]]))  # (size,)
        self.recv_counts = np.empty(comm.size, dtype=np.int64)
        comm.Alltoall(self.send_counts, self.recv_counts)
        self.positions = _exchange(comm, sorted_rows, self.send_counts, self.recv_counts)
        del sorted_rows  # (only the order and the positions are kept: 16 B per point)
        self.positions -= self.first  # (n_block,) block position of each received value
        total = int(self.blocks[-1])
        in_block = (self.positions >= 0) & (self.positions < self.n_block)
        hits = np.bincount(self.positions[in_block], minlength=self.n_block)
        each_once = bool(np.all(in_block)) and bool(np.all(hits == 1))
        in_range = bool(np.all((rows >= 0) & (rows < self.n_global)))
        message = f"{what} rows must split 0..{self.n_global - 1} between ranks, got {total} rows"
        raise_unless_everywhere(
            comm, total == self.n_global and in_range and each_once, ValueError(message)
        )

    def to_block(self, values: np.ndarray) -> np.ndarray:
        """This rank's file block (n_block, ...) of ``values`` (n_local, ...).  Collective."""
        values = np.asarray(values)
        sent = np.ascontiguousarray(values[self.send_order])
        received = _exchange(self.comm, sent, self.send_counts, self.recv_counts)
        block = np.empty((self.n_block, *values.shape[1:]), dtype=values.dtype)
        block[self.positions] = received
        return block

    def from_block(self, block: np.ndarray) -> np.ndarray:
        """The values (n_local, ...) at this rank's points of its file block.  Collective."""
        block = np.asarray(block)
        sent = np.ascontiguousarray(block[self.positions])
        received = _exchange(self.comm, sent, self.recv_counts, self.send_counts)
        values = np.empty((self.n_local, *block.shape[1:]), dtype=block.dtype)
        values[self.send_order] = received
        return values

    def write(self, dataset, values: np.ndarray) -> None:
        """Write ``values`` (n_local, ...) to the rows of ``dataset``; collective."""
        write_block(dataset, self.first, self.to_block(values))

    def read(self, dataset) -> np.ndarray:
        """The rows of ``dataset`` at this rank's points, (n_local, ...); collective.

        Reads this rank's block only (one hyperslab), then moves its rows to their owners.
        """
        block = read_block(dataset, self.first, self.n_block)
        return self.from_block(block)


def _exchange(comm, send: np.ndarray, send_counts, recv_counts) -> np.ndarray:
    """Block r of ``send`` (send_counts[r] rows) to rank r, as raw bytes.  Collective."""
    row_shape = send.shape[1:]
    if comm.size == 1:
        return send  # the callers never write to what they sent
    row_bytes = send.dtype.itemsize * int(np.prod(row_shape, dtype=np.int64))
    recv = np.empty((int(np.sum(recv_counts)), *row_shape), dtype=send.dtype)
    send_bytes = np.asarray(send_counts, dtype=np.int64) * row_bytes
    recv_bytes = np.asarray(recv_counts, dtype=np.int64) * row_bytes
    send_displs = np.concatenate([[0], np.cumsum(send_bytes)[:-1]])
    recv_displs = np.concatenate([[0], np.cumsum(recv_bytes)[:-1]])
    comm.Alltoallv(
        [send.view(np.uint8).reshape(-1), (send_bytes, send_displs), MPI.BYTE],
        [recv.view(np.uint8).reshape(-1), (recv_bytes, recv_displs), MPI.BYTE],
    )
    return recv


def _transfer(dataset):
    """The transfer property list: collective MPI-IO if COLLECTIVE_TRANSFERS, else default."""
    if dataset.file.driver != "mpio" or not COLLECTIVE_TRANSFERS:
        return None
    dxpl = h5py.h5p.create(h5py.h5p.DATASET_XFER)
    dxpl.set_dxpl_mpio(h5py.h5fd.MPIO_COLLECTIVE)
    return dxpl


def _spaces(dataset, first: int, shape: tuple):
    """(memory, file) dataspaces selecting rows first:first + shape[0] (none if empty)."""
    file_space = dataset.id.get_space()
    memory_space = h5py.h5s.create_simple(shape if shape[0] else (1, *shape[1:]))
    if shape[0]:
        file_space.select_hyperslab((first, *(0 for _ in shape[1:])), shape)
    else:  # a rank without rows still takes part in the collective transfer
        file_space.select_none()
        memory_space.select_none()
    return memory_space, file_space


def write_block(dataset, first: int, block: np.ndarray) -> None:
    """Write ``block`` to rows first:first + len(block) of ``dataset``; collective."""
    block = np.ascontiguousarray(block, dtype=dataset.dtype)
    memory_space, file_space = _spaces(dataset, first, block.shape)
    data = block if block.shape[0] else np.zeros((1, *block.shape[1:]), dtype=dataset.dtype)
    dataset.id.write(memory_space, file_space, data, dxpl=_transfer(dataset))


def read_block(dataset, first: int, n_rows: int) -> np.ndarray:
    """Rows first:first + n_rows of ``dataset``; collective."""
    shape = (n_rows, *dataset.shape[1:])
    memory_space, file_space = _spaces(dataset, first, shape)
    out = np.empty(shape if n_rows else (1, *shape[1:]), dtype=dataset.dtype)
    dataset.id.read(memory_space, file_space, out, dxpl=_transfer(dataset))
    return out[:n_rows]
