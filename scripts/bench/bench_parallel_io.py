"""Benchmark: what output and checkpoint move to rank 0, its peak memory, and their time.

The square scene (m = 1, h = 1/223: 50176 nodes, 100352 DOFs; --h to change) is set up
and started; then, with the fields of the initial state computed once, it times
``ResultWriter.write_step`` (--repeats outputs into one result.h5), ``write_checkpoint``
and ``read_checkpoint``, each the median of --repeats calls.  Every call runs on a
communicator that counts the bytes rank 0 receives from the other ranks through mpi4py
(pickled gather / allgather / bcast / allreduce and the buffer Gather(v) / Allgather(v) /
Alltoall(v) / Bcast; also the most any rank receives), and tracemalloc gives rank 0's
peak Python/numpy allocation above what it held before the call.  Byte counts leave
out what the MPI-IO library moves between ranks inside a collective write (ROMIO/OMPIO
two-phase I/O, bounded by its collective buffer).  Prints a table and writes
results/bench_parallel_io_np<P>.csv.

    nice .venv/bin/python scripts/bench/bench_parallel_io.py
    mpirun -n 2 nice .venv/bin/python scripts/bench/bench_parallel_io.py

It calls the writer run.py creates (:func:`parefg.run.result_writer`), write_checkpoint
and read_checkpoint.
"""

import pickle
import statistics
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import benchlib
import numpy as np
import petsc4py

import parefg  # noqa: F401  (PETSC_DIR)

petsc4py.init(sys.argv[:1])
from mpi4py import MPI  # noqa: E402

from parefg.io.checkpoint import read_checkpoint, write_checkpoint  # noqa: E402
from parefg.io.observers import output_fields  # noqa: E402
from parefg.run import prepare, result_writer  # noqa: E402


class CountingComm(MPI.Intracomm):
    """COMM_WORLD's handle, counting the bytes this rank receives from the other ranks."""

    received = 0

    def _count(self, n_bytes) -> None:
        self.received += int(n_bytes)

    def gather(self, obj, root=0):
        pieces = super().gather(obj, root=root)
        if self.rank == root:
            self._count(sum(len(pickle.dumps(p)) for r, p in enumerate(pieces) if r != root))
        return pieces

    def allgather(self, obj):
        pieces = super().allgather(obj)
        self._count(sum(len(pickle.dumps(p)) for r, p in enumerate(pieces) if r != self.rank))
        return pieces

    def bcast(self, obj, root=0):
        result = super().bcast(obj, root=root)
        if self.rank != root:
            self._count(len(pickle.dumps(result)))
        return result

    def allreduce(self, obj, op=MPI.SUM):
        result = super().allreduce(obj, op=op)
        self._count((self.size - 1) * len(pickle.dumps(result)))
        return result

    def _received_buffer(self, recv, per_rank: bool) -> None:
        """Bytes of a receive buffer spec except this rank's own part."""
        if isinstance(recv, np.ndarray):
            share = 0 if not per_rank else recv.nbytes // self.size
            self._count(recv.nbytes - share)
            return
        buffer, layout, datatype = recv
        counts = np.asarray(layout[0])
        self._count((counts.sum() - counts[self.rank]) * datatype.Get_size())

    def Alltoallv(self, send, recv):
        super().Alltoallv(send, recv)
        self._received_buffer(recv, per_rank=True)

    def Alltoall(self, send, recv):
        super().Alltoall(send, recv)
        self._received_buffer(recv, per_rank=True)

    def Gatherv(self, send, recv, root=0):
        super().Gatherv(send, recv, root=root)
        if self.rank == root:
            self._received_buffer(recv, per_rank=True)

    def Allgatherv(self, send, recv):
        super().Allgatherv(send, recv)
        self._received_buffer(recv, per_rank=True)

    def Bcast(self, buf, root=0):
        super().Bcast(buf, root=root)
        if self.rank != root:
            self._count(np.asarray(buf[0] if isinstance(buf, list) else buf).nbytes)


def measured(comm: CountingComm, task, repeats: int) -> dict:
    """Median seconds of ``task()``, rank 0's received bytes and peak allocation per call."""
    seconds, received, peaks = [], [], []
    for _ in range(repeats):
        comm.Barrier()
        before = comm.received
        tracemalloc.start()
        tracemalloc.reset_peak()
        held = tracemalloc.get_traced_memory()[0]
        start = time.perf_counter()
        task()
        comm.Barrier()
        seconds.append(time.perf_counter() - start)
        peaks.append(tracemalloc.get_traced_memory()[1] - held)
        tracemalloc.stop()
        received.append(comm.received - before)
    world = MPI.COMM_WORLD  # not counted
    most_received = world.allreduce(statistics.median(received), op=MPI.MAX)
    return {
        "ms": 1e3 * statistics.median(seconds),
        "rank0_received_mb": statistics.median(received) / 2**20,
        "max_received_mb": most_received / 2**20,
        "rank0_peak_mb": statistics.median(peaks) / 2**20,
    }


def main():
    parser = benchlib.parser(__doc__, repeats=5)
    parser.add_argument("--h", type=float, default=1 / 223, help="node spacing")
    args = parser.parse_args()
    # PETSc takes no Comm subclass: the run is set up on COMM_WORLD, the I/O counts
    comm = CountingComm(MPI.COMM_WORLD)
    world = MPI.COMM_WORLD
    sim = prepare(world, "square", [f"discretization.h={args.h!r}", "discretization.degree=1"])
    state = sim.start()
    node_fields, contact_fields = output_fields(sim, state)
    field_mb = sum(np.asarray(v).nbytes for v in node_fields.values()) / 2**20
    field_mb = comm.allreduce(field_mb)
    rows = []
    with tempfile.TemporaryDirectory() as scratch:
        root = Path(comm.bcast(scratch, root=0))
        writer = result_writer(comm, sim, root / "run")
        steps = iter(range(1, 10**6))

        def output():
            writer.write_step(next(steps), 0.0, node_fields, contact_fields)

        rows.append({"operation": "output (write_step)", **measured(comm, output, args.repeats)})
        writer.close({})
        path = root / "checkpoint.h5"

        def checkpoint():
            write_checkpoint(comm, path, sim, state, 0)

        def restart():
            read_checkpoint(comm, path, sim)

        rows.append({"operation": "checkpoint write", **measured(comm, checkpoint, args.repeats)})
        rows.append({"operation": "checkpoint read", **measured(comm, restart, args.repeats)})
    if comm.rank == 0:
        print(
            f"ranks {comm.size}; {sim.disc.n_nodes} nodes, {sim.disc.n_dofs} DOFs, "
            f"{sim.disc.n_contact} contact points; node fields {field_mb:.1f} MiB per output; "
            f"median of {args.repeats}\n"
        )
        header = "| operation | time [ms] | bytes to rank 0 [MiB] | most to one rank [MiB] "
        print(header + "| rank 0 peak alloc [MiB] |")
        print("|---|---|---|---|---|")
        for r in rows:
            print(
                f"| {r['operation']} | {r['ms']:.1f} | {r['rank0_received_mb']:.2f} | "
                f"{r['max_received_mb']:.2f} | {r['rank0_peak_mb']:.2f} |"
            )
        for r in rows:
            r.update(ranks=comm.size, n_dofs=sim.disc.n_dofs)
        benchlib.write_csv(args.out, f"bench_parallel_io_np{comm.size}.csv", rows)


if __name__ == "__main__":
    main()
