"""Benchmark: cost of output.every = 1 against the number of outputs (it must be linear).

The small square scene (h = 1/4, m = 1, no contact, dt = 1e-4) run for each step count
with an output at every step, through run_scene; the output phase of summary.json
(fields, HDF5 flushes, the XDMF index, the per-step table) divided by the number of
outputs must not grow with it. Prints a table and writes results/bench_output_np<P>.csv.

    nice .venv/bin/python scripts/bench/bench_output.py [--steps 1000,10000]
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

SMALL = ["discretization.h=0.25", "discretization.degree=1", "time.dt=1e-4", "output.every=1"]
FREE = ['boundary.bottom.type="dirichlet"']


def timed_run(comm, n_steps: int) -> dict:
    """Summary timings of one run of ``n_steps`` steps, each one an output step."""
    scene = load_scene("square", [*SMALL, *FREE, f"time.T={n_steps * 1e-4!r}"])
    with tempfile.TemporaryDirectory() as scratch:
        out = Path(comm.bcast(scratch, root=0)) / "run"
        summary = run_scene(comm, scene, out=str(out), quiet=True)
        xdmf_bytes = (out / "result.xdmf").stat().st_size if comm.rank == 0 else 0
    outputs = n_steps + 1  # t = 0 and every step
    timings = summary["timings"]
    return {
        "steps": n_steps,
        "outputs": outputs,
        "output_s": timings["output"],
        "per_output_ms": 1e3 * timings["output"] / outputs,
        "solve_s": timings["solve"],
        "total_s": timings["total"],
        "xdmf_mb": xdmf_bytes / 2**20,
    }


def main():
    parser = benchlib.parser(__doc__, repeats=1)
    parser.add_argument("--steps", default="1000,10000", help="step counts to run")
    args = parser.parse_args()
    comm = MPI.COMM_WORLD
    rows = [timed_run(comm, int(n)) for n in args.steps.split(",")]
    if comm.rank == 0:
        print(f"ranks {comm.size}; output.every = 1\n")
        header = "| steps | outputs | output [s] | per output [ms] | solve [s] | total [s] "
        print(header + "| XDMF [MiB] |")
        print("|---|---|---|---|---|---|---|")
        for r in rows:
            print(
                f"| {r['steps']} | {r['outputs']} | {r['output_s']:.2f} | "
                f"{r['per_output_ms']:.2f} | {r['solve_s']:.2f} | {r['total_s']:.2f} | "
                f"{r['xdmf_mb']:.2f} |"
            )
        benchlib.write_csv(args.out, f"bench_output_np{comm.size}.csv", rows)


if __name__ == "__main__":
    main()
