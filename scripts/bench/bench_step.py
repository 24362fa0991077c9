"""Benchmark: cost of a contact time step relative to its floor, one reused-factorization solve.

For each case (square scene, SPEC 6), run the time loop and record each step's solve
time; then time a single solve with the step operator's existing factorization (the
floor of any step). Prints medians over the steps and repeats, the ratio step / floor,
Newton iterations and factorizations; writes results/bench_step_np<P>.csv.

    .venv/bin/python scripts/bench/bench_step.py [--repeats 3]
    mpirun -n 2 .venv/bin/python scripts/bench/bench_step.py
"""

import statistics
import sys
import time

import benchlib
import petsc4py

import parefg  # noqa: F401  (PETSC_DIR)

petsc4py.init(sys.argv[:1])
from mpi4py import MPI  # noqa: E402

from parefg.run import prepare  # noqa: E402

CASES = [
    (
        "m=1 h=1/64 dt=0.025",
        ["discretization.degree=1", "discretization.h=0.015625", "time.dt=0.025"],
    ),
    ("m=2 h=1/32 dt=0.025", ["discretization.h=0.03125", "time.dt=0.025"]),
    ("m=2 h=1/48 dt=0.025", ["discretization.h=0.0208333333333", "time.dt=0.025"]),
]


def step_times(comm, overrides):
    """Per-step solve times, the floor (one solve with the reused factor), counts."""
    sim = prepare(comm, "square", overrides)
    scene = sim.scene
    state, times = sim.start(), []
    for n in range(1, scene.n_steps + 1):
        before = sim.timings["solve"]
        state = sim.step(state, n)
        times.append(sim.timings["solve"] - before)
    ksp = sim.solver.snes.getKSP()
    rhs, x = sim.a_const.createVecs()
    rhs.set(1.0)
    floor = []
    for _ in range(5):
        comm.Barrier()
        tic = time.perf_counter()
        ksp.solve(rhs, x)
        floor.append(time.perf_counter() - tic)
    return times, statistics.median(floor), sim


def main():
    parser = benchlib.parser(__doc__, repeats=3)
    args = parser.parse_args()
    comm = MPI.COMM_WORLD
    rows = []
    for label, overrides in CASES:
        steps, floors = [], []
        for _ in range(args.repeats):
            times, floor, sim = step_times(comm, overrides)
            steps += times
            floors.append(floor)
        step, floor = statistics.median(steps), statistics.median(floors)
        rows.append(
            {
                "case": label,
                "dofs": sim.disc.n_dofs,
                "median_step_s": step,
                "floor_solve_s": floor,
                "ratio": step / floor,
                "newton_per_step": sim.newton_iterations / sim.scene.n_steps,
                "factorizations": sim.solver.factorizations,
                "steps": sim.scene.n_steps,
            }
        )
    if comm.rank == 0:
        print(f"ranks {comm.size}; medians over all steps of {args.repeats} runs\n")
        print(
            "| case | DOFs | step [ms] | floor solve [ms] | step / floor | Newton per step "
            "| factorizations / steps |"
        )
        print("|---|---|---|---|---|---|---|")
        for r in rows:
            print(
                f"| {r['case']} | {r['dofs']} | {1e3 * r['median_step_s']:.2f} | "
                f"{1e3 * r['floor_solve_s']:.2f} | {r['ratio']:.2f} | {r['newton_per_step']:.2f} "
                f"| {r['factorizations']} / {r['steps']} |"
            )
        benchlib.write_csv(args.out, f"bench_step_np{comm.size}.csv", rows)


if __name__ == "__main__":
    main()
