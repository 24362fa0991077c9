"""Benchmark: cost of a contact time step relative to its floor, one reused-factorization solve.

For each case (square scene, SPEC 6), run the time loop and record each step's solve
time and whole-step time (loads, predictor, solve, update, energies, checks); then time
a single solve with the step operator's existing factorization (the floor of any step),
one product with the step operator (the unit of a residual evaluation) and one
evaluation of the loads F(t) (expressions at every quadrature point, integrated).
Prints medians over the steps and repeats, the ratios step / floor, Newton iterations
and factorizations; writes results/bench_step_np<P>.csv.  A second table splits the
whole step into its parts (the loads, the solve, the energy row, the contact
acceleration, the state check, the rest: predictor, right-hand side, gate, update),
timed by wrapping the simulation's methods; its medians need not add up to the step's.
``--compare-snes`` also times the solve with SNES taking every step (no reused-factorization
step), interleaved with the default in one process.

    .venv/bin/python scripts/bench/bench_step.py [--repeats 3] [--compare-snes]
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


def case(degree, n, dt):
    """Label and overrides of the square scene at m = degree, h = 1/n."""
    overrides = [f"discretization.degree={degree}", f"discretization.h={1.0 / n!r}"]
    return f"m={degree} h=1/{n} dt={dt}", [*overrides, f"time.dt={dt!r}"]


# the small sizes of the GetFEM comparison (scripts/bench/getfem_side_by_side.py), where a
# step's Python and petsc4py calls weigh most, and the larger m = 1 and 2 cases
CASES = [
    *(case(degree, n, 0.0125) for degree in (2, 3) for n in (8, 16, 32)),
    case(1, 64, 0.025),
    case(2, 48, 0.025),
]

# the parts of a step: the Simulation's (or its solver's) method timed for each
PARTS = {
    "loads": ("sim", "external_forces"),
    "solve": ("solver", "solve"),
    "energy row": ("sim", "_record"),
    "contact acceleration": ("sim", "_contact_acceleration"),
    "state check": ("sim", "_check_state"),
}


def median_call(comm, function, repeats=5):
    """Median wall time of ``function()`` over ``repeats`` calls, all ranks in step."""
    times = []
    for _ in range(repeats):
        comm.Barrier()
        tic = time.perf_counter()
        function()
        times.append(time.perf_counter() - tic)
    return statistics.median(times)


def time_parts(sim, current):
    """Wrap the methods of :data:`PARTS` on the instances, adding their times to ``current``."""
    for part, (owner, name) in PARTS.items():
        target = sim if owner == "sim" else sim.solver
        method = getattr(target, name)

        def timed(*args, _method=method, _part=part, **kwargs):
            tic = time.perf_counter()
            try:
                return _method(*args, **kwargs)
            finally:
                current[_part] += time.perf_counter() - tic

        setattr(target, name, timed)


def step_times(comm, overrides):
    """Per-step solve and whole-step times, the floor (one solve with the reused factor),
    the unit costs outside the solve (one operator product, one load evaluation) and the
    parts of each step."""
    sim = prepare(comm, "square", overrides)
    scene = sim.scene
    state, solves, steps = sim.start(), [], []
    current = dict.fromkeys(PARTS, 0.0)
    time_parts(sim, current)
    parts: dict[str, list[float]] = {part: [] for part in [*PARTS, "rest"]}
    for n in range(1, scene.time.n_steps + 1):
        current.update(dict.fromkeys(PARTS, 0.0))
        before, tic = sim.timings["solve"], time.perf_counter()
        state = sim.step(state, n)
        steps.append(time.perf_counter() - tic)
        solves.append(sim.timings["solve"] - before)
        for part, value in current.items():
            parts[part].append(value)
        parts["rest"].append(steps[-1] - sum(current.values()))
    ksp = sim.solver.snes.getKSP()
    rhs, x = sim.a_const.createVecs()
    rhs.set(1.0)
    units = {
        "floor": median_call(comm, lambda: ksp.solve(rhs, x)),
        "mult": median_call(comm, lambda: sim.a_const.mult(rhs, x)),
        "forces": median_call(comm, lambda: sim.external_forces(scene.time.T, x)),
    }
    return solves, steps, units, parts, sim


def reused_against_snes(comm, overrides):
    """Median solve part of a step with the reused-factorization step and with SNES taking
    every step: two simulations stepped alternately in one process (the same load on both).
    """
    sims = [prepare(comm, "square", overrides) for _ in range(2)]
    sims[1].solver._reuse = False
    states = [sim.start() for sim in sims]
    solves: list[list[float]] = [[], []]
    for n in range(1, sims[0].scene.time.n_steps + 1):
        for i, sim in enumerate(sims):
            before = sim.timings["solve"]
            states[i] = sim.step(states[i], n)
            solves[i].append(sim.timings["solve"] - before)
    return [statistics.median(times) for times in solves]


def compare_snes(comm):
    """Print the solve part of a step with and without the reused-factorization step."""
    rows = [(label, *reused_against_snes(comm, overrides)) for label, overrides in CASES]
    if comm.rank == 0:
        print("\nsolve part of a step [ms]: reused-factorization step against SNES every step\n")
        print("| case | reused | SNES | reused / SNES |\n|---|---|---|---|")
        for label, reused, snes in rows:
            print(f"| {label} | {1e3 * reused:.3f} | {1e3 * snes:.3f} | {reused / snes:.2f} |")


def main():
    parser = benchlib.parser(__doc__, repeats=3)
    parser.add_argument(
        "--compare-snes", action="store_true", help="also time the steps SNES takes alone"
    )
    args = parser.parse_args()
    comm = MPI.COMM_WORLD
    rows, part_rows = [], []
    for label, overrides in CASES:
        solves, steps, units = [], [], {"floor": [], "mult": [], "forces": []}
        parts: dict[str, list[float]] = {}
        for _ in range(args.repeats):
            run_solves, run_steps, run_units, run_parts, sim = step_times(comm, overrides)
            solves += run_solves
            steps += run_steps
            for key, value in run_units.items():
                units[key].append(value)
            for key, value in run_parts.items():
                parts.setdefault(key, []).extend(value)
        part_rows.append(
            {"case": label, **{key: statistics.median(value) for key, value in parts.items()}}
        )
        step, floor = statistics.median(solves), statistics.median(units["floor"])
        rows.append(
            {
                "case": label,
                "dofs": sim.disc.n_dofs,
                "median_step_s": step,
                "floor_solve_s": floor,
                "ratio": step / floor,
                "median_whole_step_s": statistics.median(steps),
                "whole_ratio": statistics.median(steps) / floor,
                "operator_mult_s": statistics.median(units["mult"]),
                "load_evaluation_s": statistics.median(units["forces"]),
                "newton_per_step": sim.newton_iterations / sim.scene.time.n_steps,
                "factorizations": sim.solver.factorizations,
                "steps": sim.scene.time.n_steps,
            }
        )
    if comm.rank == 0:
        print(f"ranks {comm.size}; medians over all steps of {args.repeats} runs\n")
        print(
            "| case | DOFs | solve part of a step [ms] | whole step [ms] | floor solve [ms] "
            "| solve / floor | whole / floor | operator mult [ms] | load F(t) [ms] "
            "| Newton per step | factorizations / steps |"
        )
        print("|---|---|---|---|---|---|---|---|---|---|---|")
        for r in rows:
            print(
                f"| {r['case']} | {r['dofs']} | {1e3 * r['median_step_s']:.2f} | "
                f"{1e3 * r['median_whole_step_s']:.2f} | {1e3 * r['floor_solve_s']:.2f} | "
                f"{r['ratio']:.2f} | {r['whole_ratio']:.2f} | {1e3 * r['operator_mult_s']:.2f} | "
                f"{1e3 * r['load_evaluation_s']:.2f} | {r['newton_per_step']:.2f} "
                f"| {r['factorizations']} / {r['steps']} |"
            )
        print(f"\nparts of a step [ms], medians over all steps of {args.repeats} runs\n")
        names = [*PARTS, "rest"]
        print("| case | " + " | ".join(names) + " |")
        print("|---|" + "---|" * len(names))
        for r in part_rows:
            print(f"| {r['case']} | " + " | ".join(f"{1e3 * r[n]:.3f}" for n in names) + " |")
        benchlib.write_csv(args.out, f"bench_step_np{comm.size}.csv", rows)
        benchlib.write_csv(args.out, f"bench_step_parts_np{comm.size}.csv", part_rows)
    if args.compare_snes:
        compare_snes(comm)


if __name__ == "__main__":
    main()
