"""Iterative against direct step solves: iteration counts against h, errors and time (issue 12).

For each setting (the iterative method's defaults, whose support at m = 2 is 2.4, and
``--supports``: other MLS supports per degree, by default the direct solver's 3.2 at
m = 2), degree m and h, the square scene runs ``--steps`` steps with ``solver.method =
"iterative"``, then ``"direct"`` on the same discretization (support, integration and
quadrature of the iterative run; in-process, serial).  One table (printed, and written
as CSV to --out/iterative.csv), per run:

* CG iterations per step of the iterative run (median / max over the steps; the step
  tolerance is relative to the step's forces, so these are what a user's run costs);
* CG to 1e-8 (true residual, relative to |b|) on the step Jacobian after the last step
  (contact rows included), for a fixed right-hand side, with the method's preconditioner
  for the degree (GAMG and its levels; at m = 3 its finest level smooths with overlapping
  additive Schwarz) and with ``--preconditioners`` (GAMG, plain hypre BoomerAMG, Jacobi);
* the L2 and H1 errors of both runs and their relative difference, and both solve times.

Usage: ``python scripts/bench/bench_iterative.py [--out DIR] [--degrees 1,2,3]
[--max-n 128] [--max-n-defaults 32] [--supports 2:3.2] [--steps 4]``.  Serial; minutes.
On a loaded machine the times are noisy: compare the ratio within one row; iteration
counts do not depend on the load.
"""

import numpy as np
from benchlib import parser, write_csv
from mpi4py import MPI
from petsc4py import PETSc

from parefg.errors import SolverError
from parefg.parallel import set_from_options
from parefg.run import prepare
from parefg.timestepping.linear_solver import SOLVER_METHODS, set_up_step_ksp

COMM = MPI.COMM_WORLD
PRECONDITIONERS = {
    "gamg": SOLVER_METHODS["iterative"].step,  # the method's at m = 1, 2
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


def _cg_iterations(matrix: PETSc.Mat, options: dict[str, str], finest=None) -> tuple[int, int]:
    """CG iterations to 1e-8 on ``matrix`` for a fixed right-hand side (-1: no convergence
    in MAX_IT); levels (GAMG).  ``finest``: GAMG's finest level as the method makes it
    (SolverMethod.finest_level, set_up_step_ksp)."""
    ksp = PETSc.KSP().create(COMM)
    ksp.setOperators(matrix)
    set_from_options(ksp, "bench_", {**options, "ksp_rtol": "1e-8", "ksp_max_it": str(MAX_IT)})
    set_up_step_ksp(ksp, finest)
    b = matrix.createVecLeft()
    start, stop = b.getOwnershipRange()
    b.setArray(np.cos(np.arange(start, stop) * 0.7) + 1.0)  # the same for every rank count
    x = matrix.createVecRight()
    ksp.solve(b, x)
    iterations = ksp.getIterationNumber() if ksp.getConvergedReason() > 0 else -1
    levels = ksp.getPC().getMGLevels() if ksp.getPC().getType() == "gamg" else 0
    ksp.destroy()
    return iterations, levels


def _case(setting: str, degree: int, n: int, args) -> dict | None:
    base = [
        f"discretization.h={1 / n}",
        f"discretization.degree={degree}",
        f"time.T={args.steps * 0.05}",
    ]
    if setting != "defaults":
        base.append(f"discretization.support={setting.removeprefix('s=')}")
    try:
        iterative, errors, iterative_time = _run([*base, "solver.method=iterative"], args.steps)
    except SolverError as error:  # a clear failure is a result too
        if COMM.rank == 0:
            print(f"{setting} m={degree} h=1/{n}: iterative run failed: {error}", flush=True)
        return None
    # the direct run on the iterative run's discretization (the iterative method's default
    # support and integration differ from the direct one's: parefg.scene.schema)
    used = iterative.scene.params["discretization"]
    same = [f"discretization.{key}={used[key]}" for key in ("support", "integration", "quadrature")]
    direct, direct_errors, direct_time = _run([*base, *same, "solver.method=direct"], args.steps)
    row = {"setting": setting, "m": degree, "n": n, "dofs": direct.disc.n_dofs}
    row["support"] = used["support"]
    per_step = [r["linear_iterations"] for r in iterative.history]
    row.update(cg_per_step_median=float(np.median(per_step)), cg_per_step_max=max(per_step))
    jacobian = iterative.solver.jacobian
    # the method's own preconditioner for this degree (GAMG; its finest level Schwarz at
    # m = 3, block-smoothing the coarse-trace groups at m = 1, 2)
    method = SOLVER_METHODS["iterative"]
    finest = method.finest_level(degree, iterative.disc.trace_blocks)
    row["method"], row["method_levels"] = _cg_iterations(jacobian, method.step, finest)
    for name in filter(None, args.preconditioners.split(",")):
        row[name], _ = _cg_iterations(jacobian, PRECONDITIONERS[name])
    for key in ("l2_rel", "h1_rel"):
        row[f"{key}_direct"], row[f"{key}_iterative"] = direct_errors[key], errors[key]
        row[f"{key}_diff"] = abs(errors[key] - direct_errors[key]) / direct_errors[key]
    row.update(time_direct=direct_time, time_iterative=iterative_time)
    return row


def _settings(supports: str) -> dict[int, list[str]]:
    """degree -> its settings: "defaults" and each "s=VALUE" of ``--supports m:s,...``."""
    settings = {m: ["defaults"] for m in (1, 2, 3)}
    for item in filter(None, supports.split(",")):
        degree, support = item.split(":")
        settings[int(degree)].append(f"s={support}")
    return settings


def main() -> None:
    args = _arguments()
    rows = []
    settings = _settings(args.supports)
    for degree in map(int, args.degrees.split(",")):
        for setting in settings[degree]:
            # other supports than the method's (wide ones at m = 2, any at m = 3) need
            # hundreds to thousands of CG iterations per step, growing with 1 / h
            wide = setting != "defaults" and (degree == 3 or float(setting[2:]) > 2.6)
            largest = args.max_n_defaults if wide else args.max_n
            for n in (16, 32, 64, 128):
                if n > largest:
                    continue
                row = _case(setting, degree, n, args)
                if row is not None:
                    rows.append(row)
                    _print_row(row)
    if COMM.rank == 0:
        print("CSV:", write_csv(args.out, "iterative.csv", rows))


def _print_row(row: dict) -> None:
    if COMM.rank != 0:
        return
    others = " ".join(f"{name} {row[name]:>5}" for name in PRECONDITIONERS if name in row)
    print(
        f"{row['setting']:>8} (s={row['support']}) m={row['m']} h=1/{row['n']:<4} "
        f"dofs {row['dofs']:>6}  CG per step "
        f"{row['cg_per_step_median']:6.0f} / {row['cg_per_step_max']:>5} | Jacobian to 1e-8: "
        f"method {row['method']:>5} ({row['method_levels']} levels) {others} | L2 "
        f"{row['l2_rel_direct']:.4e} / {row['l2_rel_iterative']:.4e} H1 "
        f"{row['h1_rel_direct']:.4e} / {row['h1_rel_iterative']:.4e} (diff "
        f"{max(row['l2_rel_diff'], row['h1_rel_diff']):.1e}) | solve "
        f"{row['time_direct']:.2f} / {row['time_iterative']:.2f} s",
        flush=True,
    )


def _arguments():
    cli = parser(__doc__, repeats=1)
    cli.add_argument("--degrees", default="1,2,3")
    cli.add_argument("--supports", default="2:3.2", help="extra settings, DEGREE:SUPPORT,...")
    cli.add_argument("--max-n", type=int, default=128, help="finest 1/h")
    cli.add_argument("--max-n-defaults", type=int, default=32, help="finest 1/h, other supports")
    cli.add_argument(
        "--preconditioners", default="gamg,hypre", help="besides the method's: gamg,hypre,jacobi"
    )
    cli.add_argument("--steps", type=int, default=4)
    return cli.parse_args()


if __name__ == "__main__":
    main()
