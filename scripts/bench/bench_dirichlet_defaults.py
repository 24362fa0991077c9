"""Benchmark: H1 error against run time on the square scene, new defaults vs the old ones.

Old defaults (before issue 12): the Dirichlet penalty alpha_D = 1e4 E/h and
OLD_QUADRATURE Gauss points per cell direction; new: the scene's defaults (Nitsche,
parefg.scene.schema.DEFAULT_QUADRATURE).  Each case (m, h) runs the "square" scene
in-process (`parefg sweep`'s setting: output of the final step only) REPEATS times; the
table gives the median wall time and the errors at T, the CSV every case, the PNG the
H1 error against the median time (one line per degree and setting).

    .venv/bin/python scripts/bench/bench_dirichlet_defaults.py [--repeats 3] [--out results/]
"""

import statistics
import sys
import tempfile
import time

import benchlib
import petsc4py

import parefg  # noqa: F401  (PETSC_DIR)

petsc4py.init(sys.argv[:1])
from mpi4py import MPI  # noqa: E402

from parefg.run import run_scene  # noqa: E402
from parefg.scene.loader import load_scene  # noqa: E402

OLD_QUADRATURE = {1: 3, 2: 5, 3: 7}
SIZES = (0.125, 0.0625, 0.03125)
FINAL_STEP_ONLY = "output.every=0"


def settings(degree: int) -> dict[str, list[str]]:
    """Overrides of the old and the new defaults at MLS degree ``degree``."""
    old = ["boundary.top.method=penalty", f"discretization.quadrature={OLD_QUADRATURE[degree]}"]
    old.append("discretization.integration=gauss")  # VCI is m = 3's default since 2026-12-04
    return {"old": old, "new": []}


def measure(comm, overrides: list[str], repeats: int) -> dict:
    """Median wall time (scene load to final output) and the errors of one case."""
    times, summary = [], {}
    for _ in range(repeats):
        with tempfile.TemporaryDirectory() as out:
            comm.Barrier()
            tic = time.perf_counter()
            scene = load_scene("square", [FINAL_STEP_ONLY, *overrides])
            summary = run_scene(comm, scene, out=out, quiet=True)
            times.append(comm.allreduce(time.perf_counter() - tic, op=MPI.MAX))
    return {
        "time": statistics.median(times),
        "l2_rel": summary["errors"]["l2_rel"],
        "h1_rel": summary["errors"]["h1_rel"],
        "n_dofs": summary["n_dofs"],
    }


def plot(path, rows) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    for degree in sorted({r["degree"] for r in rows}):
        for setting, style in (("old", "--"), ("new", "-")):
            group = [r for r in rows if r["degree"] == degree and r["setting"] == setting]
            ax.loglog([r["time"] for r in group], [r["h1_rel"] for r in group], "o" + style,
                      label=f"m = {degree}, {setting} defaults")  # fmt: skip
    ax.set_xlabel("wall time [s] (median)")
    ax.set_ylabel("relative H1 error at T")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    parser = benchlib.parser(__doc__, repeats=3)
    parser.add_argument("--degrees", default="1,2,3")
    args = parser.parse_args()
    comm = MPI.COMM_WORLD
    rows = []
    for degree in [int(m) for m in args.degrees.split(",")]:
        for setting, extra in settings(degree).items():
            for h in SIZES:
                case = [f"discretization.degree={degree}", f"discretization.h={h}", *extra]
                row = {"degree": degree, "h": h, "setting": setting}
                row.update(measure(comm, case, args.repeats))
                rows.append(row)
                if comm.rank == 0:
                    print(
                        f"| {degree} | {h:.4g} | {setting} | {row['n_dofs']} | "
                        f"{row['l2_rel']:.3e} | {row['h1_rel']:.3e} | {row['time']:.2f} |",
                        flush=True,
                    )
    if comm.rank == 0:
        path = benchlib.write_csv(args.out, "bench_dirichlet_defaults.csv", rows)
        plot(path.with_suffix(".png"), rows)
        print(f"wrote {path} and {path.with_suffix('.png')}")


if __name__ == "__main__":
    main()
