"""Benchmark: the scaling table, 1 and 2 ranks, DOFs 1e4 ... 1e6, m = 1 and m = 2.

Runs `parefg run square` (one dynamic contact step of dt = 0.025, friction on) through
mpirun with 1 and 2 ranks for each (degree, h) case, REPEATS times, and reads
summary.json: the median time of each phase (mesh, mls, assembly, factorization, solve,
output, total), the speedup t1 / t2, and the peak RSS of the largest rank with its
KB per DOF (peak RSS per rank x ranks / DOFs).  A case is ``DEGREE:H[:SOLVER]``: SOLVER
"direct" or "iterative" (CG + GAMG, at its own default supports: 2.4 at m = 2, README
"Iterative solver").  Each run gets
``--max-memory`` of the budget's own estimate's order (MAX_MEMORY_GB), so the budget
never refuses a case the machine holds.  KB/DOF by phase (retained and peak per phase)
is measured by scripts/bench/bench_memory_per_dof.py.

Prints markdown tables and writes results/bench_scaling.csv.

    nice .venv/bin/python scripts/bench/bench_scaling.py \
        --cases 1:0.0125,1:0.00625,2:0.0125:iterative --repeats 1
"""

import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import benchlib

PAREFG = str(Path(sys.executable).with_name("parefg"))
PHASES = (
    "mesh",
    "neighbours",
    "mls",
    "assembly",
    "factorization",
    "solve",
    "output",
    "errors",
    "total",
)
MAX_MEMORY_GB = 20  # the machine's 24 GB less the system: the budget is not under test here
DEFAULT_CASES = "1:0.0125,1:0.00625,2:0.025,2:0.0125,1:0.003125:iterative,2:0.00625:iterative"


def parse_case(text: str) -> tuple[int, float, str]:
    """``"1:0.0125"`` -> (1, 0.0125, "direct"); ``"2:0.01:iterative"`` -> (2, 0.01, "iterative")."""
    parts = text.split(":")
    solver = parts[2] if len(parts) > 2 else "direct"
    return int(parts[0]), float(parts[1]), solver


def run(ranks: int, degree: int, h: float, solver: str, out: Path, scene: str = "square") -> dict:
    """summary.json of one run of ``scene`` (the square) on ``ranks`` ranks."""
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")
    env["OMPI_MCA_rmaps_base_oversubscribe"] = "1"
    sets = [
        f"discretization.degree={degree}",
        f"discretization.h={h!r}",
        "time.T=0.025",
        "time.dt=0.025",
        "output.every=0",  # the final step only: the phases are timed, not a time series
    ]
    command = ["mpirun", "-n", str(ranks), PAREFG, "run", scene, "--quiet", "--out", str(out)]
    command += [arg for s in sets for arg in ("--set", s)]
    command += ["--solver", solver, "--max-memory", str(MAX_MEMORY_GB)]
    subprocess.run(command, check=True, env=env, stdin=subprocess.DEVNULL)
    return json.loads((out / "summary.json").read_text())


def measure(case: str, ranks: int, repeats: int, tmp: Path) -> dict:
    """One table row: medians over ``repeats`` runs of one case on ``ranks`` ranks."""
    degree, h, solver = parse_case(case)
    runs = [run(ranks, degree, h, solver, tmp / f"{case}-np{ranks}-{i}") for i in range(repeats)]
    peak = max(r["peak_rss_mb"] for r in runs)
    row = {"degree": degree, "h": h, "solver": solver, "ranks": ranks}
    row.update(dofs=runs[0]["n_dofs"], peak_rss_mb=round(peak))
    row["kb_per_dof"] = round(peak * 1024 * ranks / runs[0]["n_dofs"], 1)
    row.update({p: round(statistics.median(r["timings"][p] for r in runs), 3) for p in PHASES})
    print(f"{case}: {ranks} rank(s) {row['dofs']} DOFs {peak:.0f} MB total {row['total']} s",
          flush=True)  # fmt: skip
    return row


def print_tables(rows: list[dict]) -> None:
    """The memory table and the time-by-phase table (1 and 2 ranks side by side)."""
    print("\n| m | solver | DOFs | RSS/rank 1 rank [MB] | 2 ranks | KB/DOF 1 rank | 2 ranks |")
    print("|---|---|---|---|---|---|---|")
    pairs = list(zip(rows[0::2], rows[1::2], strict=True))
    for one, two in pairs:
        print(
            f"| {one['degree']} | {one['solver']} | {one['dofs']} | {one['peak_rss_mb']} | "
            f"{two['peak_rss_mb']} | {one['kb_per_dof']} | {two['kb_per_dof']} |"
        )
    print("\n| m | solver | DOFs | phase | 1 rank [s] | 2 ranks [s] | speedup |")
    print("|---|---|---|---|---|---|---|")
    for one, two in pairs:
        for p in PHASES:
            speedup = f"{one[p] / two[p]:.2f}" if two[p] > 0 else "-"
            print(
                f"| {one['degree']} | {one['solver']} | {one['dofs']} | {p} | {one[p]:.2f} | "
                f"{two[p]:.2f} | {speedup} |"
            )


def main():
    parser = benchlib.parser(__doc__, repeats=1)
    parser.add_argument("--cases", default=DEFAULT_CASES, help="DEGREE:H[:SOLVER],...")
    parser.add_argument("--ranks", default="1,2", help="rank counts, e.g. 1,2")
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for case in args.cases.split(","):
            for ranks in (int(r) for r in args.ranks.split(",")):
                rows.append(measure(case, ranks, args.repeats, Path(tmp)))
                benchlib.write_csv(args.out, "bench_scaling.csv", rows)  # kept if interrupted
    if args.ranks == "1,2":
        print_tables(rows)
    print(f"wrote {benchlib.write_csv(args.out, 'bench_scaling.csv', rows)}")


if __name__ == "__main__":
    main()
