"""Collective HDF5 output and checkpoints: file blocks per rank, nothing gathered to rank 0.

Run serially and under ``mpirun -n 2``; the memory test is the one that tells a gather
from block I/O, and it does so on 2 ranks (on one rank a gather holds no more than the
rank's own share).
"""

import tracemalloc
from pathlib import Path

import h5py
import numpy as np
import pytest
from mpi4py import MPI

from parefg.io.checkpoint import read_checkpoint, write_checkpoint
from parefg.io.hdf5 import open_h5
from parefg.io.rows import BlockRows
from parefg.run import prepare

N_ROWS = 37


def _scattered_rows(comm, n):
    """Interleaved, shuffled rows of this rank (rank, rank + P, ...): no block of its own."""
    return np.random.default_rng(comm.rank).permutation(np.arange(comm.rank, n, comm.size))


def test_file_blocks_hold_the_global_order_and_come_back(comm):
    """to_block gives this rank's slice of the global array; from_block inverts it."""
    rows = _scattered_rows(comm, N_ROWS)
    full = np.random.default_rng(3).standard_normal((N_ROWS, 2))  # (n, 2) global order
    status = (np.arange(N_ROWS) % 3).astype(np.int8)  # a 1-byte field moves as well
    plan = BlockRows(comm, rows, N_ROWS)
    assert plan.n_block == rows.size  # the block is as large as the rank's share
    first = plan.first
    block = plan.to_block(full[rows])
    np.testing.assert_array_equal(block, full[first : first + rows.size])
    np.testing.assert_array_equal(plan.to_block(status[rows]), status[first : first + rows.size])
    np.testing.assert_array_equal(plan.from_block(block), full[rows])
    blocks = comm.allgather((first, rows.size))
    assert sorted(blocks)[0][0] == 0 and sum(size for _, size in blocks) == N_ROWS


@pytest.mark.parametrize("case", ["repeated row", "row out of range", "missing row"])
def test_rows_that_are_not_a_split_fail_on_every_rank(comm, case):
    rows = _scattered_rows(comm, N_ROWS)
    if comm.rank == comm.size - 1:
        rows = {
            "repeated row": np.append(rows[1:], 0),  # row 0 twice (rank 0's on 2 ranks)
            "row out of range": np.append(rows[1:], N_ROWS + 3),
            "missing row": rows[1:],
        }[case]
    with pytest.raises(ValueError, match="node rows must split"):
        BlockRows(comm, rows, N_ROWS, "node")


@pytest.mark.parametrize("split", ["scattered", "all on the last rank"])
def test_collective_write_and_read_of_scattered_rows(comm, tmp_path, split):
    """Each rank writes its rows into one dataset and reads them back (hyperslabs); a rank
    without rows still takes part in the collective transfers."""
    path = Path(comm.bcast(str(tmp_path), root=0)) / "blocks.h5"
    rows = _scattered_rows(comm, N_ROWS)
    if split != "scattered":
        everything = np.arange(N_ROWS)[::-1]
        rows = everything if comm.rank == comm.size - 1 else everything[:0]
    full = np.arange(2 * N_ROWS, dtype=float).reshape(N_ROWS, 2)
    plan = BlockRows(comm, rows, N_ROWS)
    with open_h5(comm, path) as handle:
        dataset = handle.create_dataset("a", shape=(N_ROWS, 2), dtype=np.float64)
        plan.write(dataset, full[rows])
    with open_h5(comm, path, "r") as handle:
        np.testing.assert_array_equal(plan.read(handle["a"]), full[rows])
    comm.Barrier()
    with h5py.File(path, "r") as handle:
        np.testing.assert_array_equal(handle["a"][()], full)


@pytest.fixture(scope="module")
def stepped():
    """A started square run (m = 1, 1681 nodes, contact) after two steps, and its state."""
    comm = MPI.COMM_WORLD
    sim = prepare(comm, "square", ["discretization.h=0.025", "discretization.degree=1"])
    state = sim.start()
    for n in (1, 2):
        state = sim.step(state, n)
    return sim, state


def _peak_bytes(task) -> int:
    """This rank's peak Python/numpy allocation during ``task()`` above what it held."""
    tracemalloc.start()
    held = tracemalloc.get_traced_memory()[0]
    try:
        task()
        return tracemalloc.get_traced_memory()[1] - held
    finally:
        tracemalloc.stop()


def test_no_rank_holds_more_than_its_share_during_a_checkpoint(comm, tmp_path, stepped):
    """Rank 0's (and every rank's) peak allocation while writing and reading a checkpoint
    stays below 2.5 times the bytes of its own share of the checkpoint's arrays.

    Block I/O holds the snapshot (u, v, a, slip, contact level: about 0.8 of the share)
    and one array's exchange buffers: measured 1.8-2.3 shares on 1 and 2 ranks.
    Gathering the arrays to rank 0 and broadcasting them back on a restart holds the
    whole cloud's u, v, a and node positions there and their pickles: measured 3.4
    (write) and 5.1-5.4 (read) shares on 2 ranks (on 1 rank a gather is no larger than
    the share, so the serial pass cannot tell them apart).
    """
    sim, state = stepped
    path = Path(comm.bcast(str(tmp_path), root=0)) / "checkpoint.h5"
    share = 4 * sim.disc.nodes.points.nbytes  # u, v, a and the node positions, this rank
    share += 2 * sim.law.slip.nbytes  # slip and the contact level
    comm.Barrier()
    written = _peak_bytes(lambda: write_checkpoint(comm, path, sim, state, 2))
    read = _peak_bytes(lambda: read_checkpoint(comm, path, sim))
    assert written < 2.5 * share, (written, share)
    assert read < 2.5 * share, (read, share)


def test_snapshot_restore_round_trip_through_a_checkpoint(comm, tmp_path, stepped):
    """The checkpoint read back restores the snapshot it was written from, on this rank."""
    sim, state = stepped
    path = Path(comm.bcast(str(tmp_path), root=0)) / "checkpoint.h5"
    before = sim.snapshot(state, 2)
    write_checkpoint(comm, path, sim, state, 2)
    loaded = read_checkpoint(comm, path, sim)
    for name in ("u", "v", "a", "slip", "contact_level"):
        np.testing.assert_array_equal(loaded[name], before[name])
    assert loaded["step"] == 2 and loaded["time"] == pytest.approx(2 * sim.scene.time.dt)
    assert loaded["history"] == before["history"]
    assert comm.allreduce(bool(np.any(before["slip"] != 0)), op=MPI.LOR)  # a sliding state
    restored = sim.restore(loaded)
    for name in ("u", "v", "a"):
        np.testing.assert_array_equal(getattr(restored, name).getArray(), before[name].ravel())
    np.testing.assert_array_equal(sim.law.slip, before["slip"])
