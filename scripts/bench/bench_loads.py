"""Benchmark: run_scene on the square scene with time-separable loads against per-point loads.

The same scene twice in one process: as loaded (its body force, tractions, Dirichlet
value and friction bound split as sum_k a_k(t) f_k(x), parefg.scene.separable: F_k
integrated once, a step forms F(t) with one maxpy) and with every split removed
(parefg.scene.separable.without_splits: the data evaluated at every quadrature point
and integrated at every step).  Runs alternate between the two, after one warm-up run
of each; prints the median wall time of run_scene per case, the ratio, and the relative
change of the errors between the two paths beside its yardstick: the change that scaling
the per-point F(t) by 1 + 1e-15 causes (the errors' sensitivity to round-off in the
loads, which grows with m and 1/h); writes results/bench_loads_np<P>.csv.

    .venv/bin/python scripts/bench/bench_loads.py [--repeats 3]
    mpirun -n 2 .venv/bin/python scripts/bench/bench_loads.py
"""

import os
import statistics
import sys
import tempfile
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import benchlib  # noqa: E402
import petsc4py  # noqa: E402

import parefg  # noqa: E402, F401  (PETSC_DIR)

petsc4py.init(sys.argv[:1])
from mpi4py import MPI  # noqa: E402

from parefg.run import run_scene  # noqa: E402
from parefg.scene.loader import load_scene  # noqa: E402
from parefg.scene.separable import without_splits  # noqa: E402
from parefg.timestepping.loads import ExternalLoads  # noqa: E402

CASES = [(2, 8, 0.025), (3, 8, 0.0125), (3, 16, 0.003125)]  # (m, 1/h, dt)


def timed_run(comm, scene) -> tuple[float, dict]:
    """Wall time of one run_scene (final output only) and its summary.  Collective."""
    directory = tempfile.mkdtemp() if comm.rank == 0 else None
    directory = comm.bcast(directory, root=0)
    comm.Barrier()
    start = time.perf_counter()
    summary = run_scene(comm, scene, out=os.path.join(directory, "run"), quiet=True)
    elapsed = comm.allreduce(time.perf_counter() - start, op=MPI.MAX)
    return elapsed, summary


def perturbed_errors(comm, scene, factor: float) -> dict:
    """The errors of a run whose loads F(t) are scaled by ``factor``.  Collective."""
    forces = ExternalLoads.forces

    def scaled(self, t, out):
        forces(self, t, out).scale(factor)
        return out

    ExternalLoads.forces = scaled  # type: ignore[method-assign]
    try:
        return timed_run(comm, scene)[1]["errors"]
    finally:
        ExternalLoads.forces = forces  # type: ignore[method-assign]


def change(errors: dict, reference: dict) -> float:
    """Largest relative change of the L2 and H1 errors."""
    return max(abs(errors[k] - reference[k]) / reference[k] for k in ("l2_rel", "h1_rel"))


def main() -> None:
    args = benchlib.parser(__doc__, repeats=3).parse_args()
    comm = MPI.COMM_WORLD
    rows = []
    for m, n, dt in CASES:
        overrides = [
            f"discretization.degree={m}",
            f"discretization.h={1.0 / n!r}",
            f"time.dt={dt!r}",
            "output.every=0",
        ]
        scenes = {"separable": load_scene("square", overrides)}
        scenes["per_point"] = without_splits(scenes["separable"])
        times: dict[str, list[float]] = {name: [] for name in scenes}
        errors = {}
        for name, scene in scenes.items():  # warm-up: numba and PETSc caches
            errors[name] = timed_run(comm, scene)[1]["errors"]
        for _ in range(args.repeats):
            for name, scene in scenes.items():
                times[name].append(timed_run(comm, scene)[0])
        fast, slow = (statistics.median(times[k]) for k in ("separable", "per_point"))
        nudged = perturbed_errors(comm, scenes["per_point"], 1.0 + 1e-15)
        rows.append(
            {
                "case": f"m={m} h=1/{n} dt={dt:g}",
                "steps": round(1.0 / dt),
                "per_point_s": round(slow, 3),
                "separable_s": round(fast, 3),
                "ratio": round(slow / fast, 3),
                "h1_rel": errors["separable"]["h1_rel"],
                "error_change": change(errors["separable"], errors["per_point"]),
                "roundoff_change": change(nudged, errors["per_point"]),
            }
        )
    if comm.rank == 0:
        print(f"square scene, {comm.size} rank(s), medians of {args.repeats} run_scene calls")
        print(f"{'case':24} {'steps':>5} {'per-point':>10} {'separable':>10} {'ratio':>6}"
              f" {'h1_rel':>10} {'err change':>10} {'F*(1+1e-15)':>11}")  # fmt: skip
        for row in rows:
            print(
                f"{row['case']:24} {row['steps']:5d} {row['per_point_s']:10.3f}"
                f" {row['separable_s']:10.3f} {row['ratio']:6.2f} {row['h1_rel']:10.3e}"
                f" {row['error_change']:10.1e} {row['roundoff_change']:11.1e}"
            )
        path = benchlib.write_csv(args.out, f"bench_loads_np{comm.size}.csv", rows)
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
