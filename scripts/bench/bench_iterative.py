"""Iterative against direct step solves: iteration counts against h, errors and time (issue 12).

For each setting (the defaults, and support s = 2.2 with penalty 100 E/h: the better
conditioned choice of issue 12), degree m and h, the square scene runs ``--steps`` steps
with ``solver.method = "direct"`` and ``"iterative"`` (in-process, serial).  Two tables
(printed, and written as CSV to --out):

1. iterations.csv -- CG to 1e-8 (true residual, relative to |b|) on the step Jacobian after
   the first step (contact rows included), for a fixed right-hand side, with the
   iterative method's GAMG, with hypre BoomerAMG and with Jacobi; GAMG's levels.
2. runs.csv -- per run: CG iterations per Newton iteration, the relative difference of the
   L2 and H1 errors iterative vs direct, and both solve times.

Usage: ``python scripts/bench/bench_iterative.py [--out DIR] [--degrees 1,2,3]
[--max-n 128] [--max-n-defaults 32] [--steps 2] [--settings defaults,...]``.  Serial;
minutes.  On a loaded machine the times are noisy: compare the ratio within one row.
"""

import numpy as np
from benchlib import parser, write_csv
from mpi4py import MPI
from petsc4py import PETSc

from parefg.errors import SolverError
from parefg.parallel import set_from_options
from parefg.run import prepare
from parefg.timestepping.linear_solver import SOLVER_METHODS

COMM = MPI.COMM_WORLD
# the better conditioned setting: s = 2.2 (m = 3 needs more: its MLS moment matrix is
# singular at 2.2), alpha = 100 E/h (E = 1) for every penalty
BETTER_SUPPORT = {1: 2.2, 2: 2.2, 3: 3.2}
SETTINGS = {
    "defaults": lambda m, n: [],
    "s=2.2 alpha=100E/h": lambda m, n: [
        f"discretization.support={BETTER_SUPPORT[m]}",
        f"penalty.alpha={100 * n}",
    ],
}
PRECONDITIONERS = {
    "gamg": SOLVER_METHODS["iterative"].step,
    "hypre": {"ksp_type": "cg", "ksp_norm_type": "unpreconditioned", "pc_type": "hypre"},
    "jacobi": {"ksp_type": "cg", "ksp_norm_type": "unpreconditioned", "pc_type": "jacobi"},
}
MAX_IT = 20000


def _run(overrides: list[str], steps: int):
    """The simulation after ``steps`` steps, its errors and its solve time (s)."""
    sim = prepare(COMM, "square", overrides)
    state = sim.start()
    for n in range(1, steps + 1):
        state = sim.step(state, n)
    errors = sim.errors(state.u, steps * sim.scene.time.dt)
    return sim, errors, sim.timings["solve"]


def _cg_iterations(matrix: PETSc.Mat, options: dict[str, str]) -> tuple[int, int]:
    """CG iterations to 1e-8 on ``matrix`` for a fixed right-hand side; levels (GAMG)."""
    ksp = PETSc.KSP().create(COMM)
    ksp.setOperators(matrix)
    set_from_options(ksp, "bench_", {**options, "ksp_rtol": "1e-8", "ksp_max_it": str(MAX_IT)})
    b = matrix.createVecLeft()
    start, stop = b.getOwnershipRange()
    b.setArray(np.cos(np.arange(start, stop) * 0.7) + 1.0)  # the same for every rank count
    x = matrix.createVecRight()
    ksp.solve(b, x)
    iterations = ksp.getIterationNumber() if ksp.getConvergedReason() > 0 else -1
    levels = ksp.getPC().getMGLevels() if ksp.getPC().getType() == "gamg" else 0
    ksp.destroy()
    return iterations, levels


def _case(setting: str, degree: int, n: int, steps: int) -> tuple[dict, dict]:
    base = [
        f"discretization.h={1 / n}",
        f"discretization.degree={degree}",
        f"time.T={steps * 0.05}",
        *SETTINGS[setting](degree, n),
    ]
    direct, direct_errors, direct_time = _run([*base, "solver.method=direct"], steps)
    row = {"setting": setting, "m": degree, "n": n, "dofs": direct.disc.n_dofs}
    table = dict(row)
    try:
        iterative, errors, iterative_time = _run([*base, "solver.method=iterative"], steps)
    except SolverError as error:  # a clear failure is a result too
        if COMM.rank == 0:
            print(f"{setting} m={degree} h=1/{n}: iterative run failed: {error}", flush=True)
        return None, None
    jacobian = iterative.solver.jacobian
    for name, options in PRECONDITIONERS.items():
        table[name], levels = _cg_iterations(jacobian, options)
        if name == "gamg":
            table["gamg_levels"] = levels
    row["cg_per_newton"] = iterative.linear_iterations / max(iterative.newton_iterations, 1)
    for key in ("l2_rel", "h1_rel"):
        row[f"{key}_direct"] = direct_errors[key]
        row[f"{key}_diff"] = abs(errors[key] - direct_errors[key]) / direct_errors[key]
    row.update(time_direct=direct_time, time_iterative=iterative_time)
    return table, row


def main() -> None:
    args = _arguments()
    tables, rows = [], []
    for setting in args.settings.split(","):
        for degree in map(int, args.degrees.split(",")):
            # the defaults at m >= 2 need thousands of CG iterations: kept to coarse h
            defaults = args.max_n if degree == 1 else args.max_n_defaults
            largest = defaults if setting == "defaults" else args.max_n
            for n in (16, 32, 64, 128):
                if n > largest or (degree == 3 and n > args.max_n_cubic):
                    continue
                table, row = _case(setting, degree, n, args.steps)
                if table is None:
                    continue
                tables.append(table)
                rows.append(row)
                _print_row(table, row)
    if COMM.rank == 0:
        paths = [
            write_csv(args.out, "iterations.csv", tables),
            write_csv(args.out, "runs.csv", rows),
        ]
        print("CSV:", *paths)


def _print_row(table: dict, row: dict) -> None:
    if COMM.rank != 0:
        return
    print(
        f"{table['setting']:>15} m={table['m']} h=1/{table['n']:<4} dofs {table['dofs']:>6}  "
        f"CG to 1e-8: gamg {table['gamg']:>6} ({table['gamg_levels']} levels) "
        f"hypre {table['hypre']:>6} jacobi {table['jacobi']:>6} | run: CG/Newton "
        f"{row['cg_per_newton']:7.1f}  L2 diff {row['l2_rel_diff']:.1e}  "
        f"H1 diff {row['h1_rel_diff']:.1e}  solve {row['time_direct']:.2f} s direct, "
        f"{row['time_iterative']:.2f} s iterative",
        flush=True,
    )


def _arguments():
    cli = parser(__doc__, repeats=1)
    cli.add_argument("--degrees", default="1,2,3")
    cli.add_argument("--settings", default=",".join(SETTINGS), help="comma-separated")
    cli.add_argument("--max-n", type=int, default=128, help="finest 1/h (s = 2.2 setting)")
    cli.add_argument("--max-n-defaults", type=int, default=32, help="finest 1/h, defaults, m >= 2")
    cli.add_argument("--max-n-cubic", type=int, default=64, help="finest 1/h at m = 3")
    cli.add_argument("--steps", type=int, default=2)
    return cli.parse_args()


if __name__ == "__main__":
    main()
