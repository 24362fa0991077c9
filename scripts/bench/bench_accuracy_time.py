"""Benchmark: run time against accuracy on the square scene (SPEC 6), vs the FEM bar.

For each configuration, run the scene in-process (imports excluded, like the GetFEM
reference: mesh, MLS, assembly, time loop and output of the final step included; the
default time series of ~50 frames is switched off, as in `parefg sweep`) REPEATS times and report
the median wall time with the relative L2 and H1 errors at T.  The baseline measured in the
same run is the default scene (`parefg run square`); times are also given as ratios to it.
The fastest case reaching each accuracy target is printed; the comparison with GetFEM,
measured in the same run, is scripts/bench/getfem_side_by_side.py.

    .venv/bin/python scripts/bench/bench_accuracy_time.py [--repeats 3] [--out results/]
"""

import statistics
import sys
import tempfile
import time
from pathlib import Path

import benchlib
import petsc4py

import parefg  # noqa: F401  (PETSC_DIR)

petsc4py.init(sys.argv[:1])
from mpi4py import MPI  # noqa: E402

from parefg.run import run_scene  # noqa: E402
from parefg.scene.loader import load_scene  # noqa: E402

TARGETS = (1e-3, 1e-4, 1e-5)  # relative H1 errors
FINAL_STEP_ONLY = "output.every=0"
CASES = [  # (label, overrides)
    ("default scene", []),
    ("m=2 h=1/8 dt=0.05", ["discretization.h=0.125", "time.dt=0.05"]),
    ("m=2 h=1/8 dt=0.025", ["discretization.h=0.125", "time.dt=0.025"]),
    ("m=2 h=1/16 dt=0.025", ["discretization.h=0.0625", "time.dt=0.025"]),
    ("m=2 h=1/24 dt=0.0125", ["discretization.h=0.041666666666666664", "time.dt=0.0125"]),
    ("m=2 h=1/32 dt=0.0125", ["discretization.h=0.03125", "time.dt=0.0125"]),
    (
        "m=1 h=1/32 dt=0.025",
        ["discretization.h=0.03125", "discretization.degree=1", "time.dt=0.025"],
    ),
    (
        "m=1 h=1/64 dt=0.0125",
        ["discretization.h=0.015625", "discretization.degree=1", "time.dt=0.0125"],
    ),
    (
        "m=3 h=1/6 dt=0.025",
        ["discretization.h=0.16666666666666666", "discretization.degree=3", "time.dt=0.025"],
    ),
    (
        "m=3 h=1/8 dt=0.0125",
        ["discretization.h=0.125", "discretization.degree=3", "time.dt=0.0125"],
    ),
    (
        "m=3 h=1/14 dt=0.003125",
        [
            "discretization.h=0.07142857142857142",
            "discretization.degree=3",
            "time.dt=0.003125",
        ],
    ),
]


def measure(comm, overrides, repeats):
    times, summary = [], None
    for _ in range(repeats):
        scene = load_scene("square", [FINAL_STEP_ONLY, *overrides])
        with tempfile.TemporaryDirectory() as tmp:
            tic = time.perf_counter()
            summary = run_scene(comm, scene, out=str(Path(tmp) / "run"), quiet=True)
            times.append(time.perf_counter() - tic)
    return statistics.median(times), summary


def main():
    parser = benchlib.parser(__doc__, repeats=3)
    args = parser.parse_args()
    comm = MPI.COMM_WORLD
    rows = []
    measure(comm, [], 1)  # warm-up: first gmsh/PETSc use
    for label, overrides in CASES:
        seconds, s = measure(comm, overrides, args.repeats)
        rows.append(
            {
                "case": label,
                "dofs": s["n_dofs"],
                "steps": s["n_steps"],
                "l2_rel": s["errors"]["l2_rel"],
                "h1_rel": s["errors"]["h1_rel"],
                "median_s": seconds,
                "newton": s["newton_iterations"],
                "factorizations": s["factorizations"],
            }
        )
    baseline = rows[0]["median_s"]
    if comm.rank == 0:
        print(
            f"ranks {comm.size}, median of {args.repeats}; baseline = default scene "
            f"({baseline:.3f} s)\n"
        )
        print(
            "| case | DOFs | steps | L2 rel | H1 rel | median time [s] | x baseline "
            "| Newton | factorizations |"
        )
        print("|---|---|---|---|---|---|---|---|---|")
        for r in rows:
            print(
                f"| {r['case']} | {r['dofs']} | {r['steps']} | {r['l2_rel']:.2e} "
                f"| {r['h1_rel']:.2e} | "
                f"{r['median_s']:.2f} | {r['median_s'] / baseline:.2f} | {r['newton']} | "
                f"{r['factorizations']} |"
            )
        print("\nfastest case reaching each target:")
        for target in TARGETS:
            hits = [r for r in rows if r["h1_rel"] <= target]
            best = min(hits, key=lambda r: r["median_s"]) if hits else None
            ours = f"{best['case']}: {best['median_s']:.2f} s" if best else "not reached"
            print(f"  H1 <= {target:g}: {ours}")
        benchlib.write_csv(args.out, f"bench_accuracy_time_np{comm.size}.csv", rows)


if __name__ == "__main__":
    main()
