"""Benchmark: resident memory of a long run at steps 1e3, 1e4, 1e5 (it must stay flat).

A small scene (square, h = 1/4, m = 1: 50 DOFs, dt = 1e-4) run through run_scene with
the output at the final step only, with Gamma_C (semismooth Newton) and without (one
linear solve per step). An observer samples this process's current resident set
(/proc/self/statm; the largest rank's under mpirun) at the chosen steps. Prints a table
and writes results/bench_memory_np<P>.csv.

    nice .venv/bin/python scripts/bench/bench_memory.py [--steps 1000,10000,100000]
"""

import sys
import tempfile
from pathlib import Path

import benchlib
import petsc4py

import parefg  # noqa: F401  (PETSC_DIR)

petsc4py.init(sys.argv[:1])
from mpi4py import MPI  # noqa: E402

from parefg.run import run_scene  # noqa: E402
from parefg.scene.loader import load_scene  # noqa: E402

SMALL = ["discretization.h=0.25", "discretization.degree=1", "time.dt=1e-4", "output.every=0"]
CASES = [("contact", []), ("no contact", ['boundary.bottom.type="dirichlet"'])]


def resident_mb() -> float:
    """Current (not peak) resident set of this process in MiB."""
    with open("/proc/self/statm") as statm:
        return int(statm.read().split()[1]) * 4096 / 2**20


def sample(comm, label: str, overrides: list[str], steps: list[int]) -> list[dict]:
    """Run ``max(steps)`` steps; the largest rank's RSS after each step in ``steps``."""
    rows, wanted = [], set(steps)
    scene = load_scene("square", [*SMALL, f"time.T={max(steps) * 1e-4!r}", *overrides])

    def observer(n, sim, state):
        if n in wanted:
            rss = comm.allreduce(resident_mb(), op=MPI.MAX)
            rows.append({"case": label, "dofs": sim.disc.n_dofs, "step": n, "rss_mb": rss})

    with tempfile.TemporaryDirectory() as scratch:
        out = comm.bcast(scratch, root=0)
        run_scene(comm, scene, out=str(Path(out) / "run"), quiet=True, observers=[observer])
    return rows


def main():
    parser = benchlib.parser(__doc__, repeats=1)
    parser.add_argument("--steps", default="1000,10000,100000", help="steps to sample at")
    args = parser.parse_args()
    comm = MPI.COMM_WORLD
    steps = sorted(int(s) for s in args.steps.split(","))
    rows = [row for label, overrides in CASES for row in sample(comm, label, overrides, steps)]
    if comm.rank == 0:
        print(f"ranks {comm.size}; resident set [MiB] of the largest rank\n")
        print("| case | DOFs | " + " | ".join(f"step {s}" for s in steps) + " |")
        print("|---|---|" + "---|" * len(steps))
        for label, _ in CASES:
            mine = [r for r in rows if r["case"] == label]
            values = " | ".join(f"{r['rss_mb']:.1f}" for r in mine)
            print(f"| {label} | {mine[0]['dofs']} | {values} |")
        benchlib.write_csv(args.out, f"bench_memory_np{comm.size}.csv", rows)


if __name__ == "__main__":
    main()
