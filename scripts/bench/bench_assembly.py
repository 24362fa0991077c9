"""Stiffness + mass assembly throughput: nonzeros of K per second, serial or under mpirun.

For m = 1, 2 at h = 1/32, 1/64 on the square scene, ``build_discretization`` is run
3 times (median); the phases come from ``disc.timings`` (max over ranks) and the
nonzeros from ``disc.stiffness.getInfo()["nz_used"]`` (summed over ranks).  Rank 0
prints a markdown table and writes results/bench_assembly_np<ranks>.csv.

Usage: [mpirun -n 2] .venv/bin/python scripts/bench/bench_assembly.py [--repeats N]
"""

import time

import benchlib
import numpy as np
from mpi4py import MPI

from parefg.discretization.operators import build_discretization
from parefg.scene.loader import load_scene

CASES = [(1, 1 / 32), (1, 1 / 64), (2, 1 / 32), (2, 1 / 64)]
PHASES = ["mesh", "mls", "assembly"]


def bench_case(comm, degree, h, repeats):
    """Median phase times (max over ranks), total nonzeros and nonzeros/s.  Collective."""
    scene = load_scene("square", [f"discretization.degree={degree}", f"discretization.h={h}"])
    samples = []
    for _ in range(repeats):
        comm.Barrier()
        tic = time.perf_counter()
        disc = build_discretization(comm, scene)
        total = time.perf_counter() - tic
        times = {phase: disc.timings[phase] for phase in PHASES} | {"total": total}
        samples.append({key: comm.allreduce(value, op=MPI.MAX) for key, value in times.items()})
        nnz = int(disc.stiffness.getInfo()["nz_used"])  # getInfo() sums over ranks
    row = {key: float(np.median([s[key] for s in samples])) for key in [*PHASES, "total"]}
    row.update(ranks=comm.size, degree=degree, h=h, n_dofs=2 * disc.n_nodes, nnz=nnz)
    row["nnz_per_s"] = nnz / (row["mls"] + row["assembly"])
    return row


def main():
    parser = benchlib.parser(__doc__, repeats=3)
    args = parser.parse_args()
    comm = MPI.COMM_WORLD
    rows = [bench_case(comm, degree, h, args.repeats) for degree, h in CASES]
    if comm.rank != 0:
        return
    print(
        f"square scene, {comm.size} rank(s), median of {args.repeats}; "
        "nnz/s = nnz(K) / (mls + assembly)\n"
    )
    print("| ranks | m | h | dofs | nnz(K) | mesh (s) | mls (s) | assembly (s) | nnz/s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['ranks']} | {r['degree']} | 1/{round(1 / r['h'])} | {r['n_dofs']} | {r['nnz']} "
            f"| {r['mesh']:.3f} | {r['mls']:.3f} | {r['assembly']:.3f} | {r['nnz_per_s']:.3g} |"
        )
    benchlib.write_csv(args.out, f"bench_assembly_np{comm.size}.csv", rows)


if __name__ == "__main__":
    main()
