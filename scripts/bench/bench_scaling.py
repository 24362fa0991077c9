"""Benchmark: strong scaling 1 -> 2 ranks per phase, and peak memory per rank against DOFs.

Runs `parefg run square` (m = 1, two time steps, contact and friction on) through
mpirun with 1 and 2 ranks for each h, REPEATS times, and reads summary.json: median
phase times (mesh, mls, assembly, factorization, solve, output, total), speedups
t1 / t2 and parallel efficiency t1 / (2 t2), and peak RSS of the largest rank.
Prints markdown tables and writes results/bench_scaling.csv.

    .venv/bin/python scripts/bench/bench_scaling.py [--h 0.0125,0.00625,0.003125] [--repeats 3]
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
PHASES = ("mesh", "mls", "assembly", "factorization", "solve", "output", "total")


def run(ranks: int, h: float, out: Path) -> dict:
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")
    command = [
        "mpirun",
        "-n",
        str(ranks),
        PAREFG,
        "run",
        "square",
        "--quiet",
        "--out",
        str(out),
        "--set",
        "discretization.degree=1",
        "--set",
        f"discretization.h={h}",
        "--set",
        "time.T=0.05",
        "--set",
        "time.dt=0.025",
        "--set",
        "output.every=0",  # the final step only: the phases are timed, not a time series
    ]
    subprocess.run(command, check=True, env=env, capture_output=True, text=True)
    return json.loads((out / "summary.json").read_text())


def main():
    parser = benchlib.parser(__doc__, repeats=3)
    parser.add_argument("--h", default="0.0125,0.00625,0.003125")
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for h in (float(v) for v in args.h.split(",")):
            for ranks in (1, 2):
                runs = [
                    run(ranks, h, Path(tmp) / f"h{h}-np{ranks}-{i}") for i in range(args.repeats)
                ]
                row = {
                    "h": h,
                    "ranks": ranks,
                    "dofs": runs[0]["n_dofs"],
                    "peak_rss_mb": max(r["peak_rss_mb"] for r in runs),
                }
                row.update({p: statistics.median(r["timings"][p] for r in runs) for p in PHASES})
                rows.append(row)
                print(
                    f"h {h}: {ranks} rank(s) {row['dofs']} DOFs total {row['total']:.2f} s",
                    flush=True,
                )
    print("\n| DOFs | phase | 1 rank [s] | 2 ranks [s] | speedup | efficiency |")
    print("|---|---|---|---|---|---|")
    for one, two in zip(rows[0::2], rows[1::2], strict=True):
        for p in PHASES:
            speedup = one[p] / two[p] if two[p] > 0 else float("nan")
            print(
                f"| {one['dofs']} | {p} | {one[p]:.3f} | {two[p]:.3f} | {speedup:.2f} | "
                f"{speedup / 2:.0%} |"
            )
    print("\n| DOFs | peak RSS per rank, 1 rank [MB] | 2 ranks [MB] |")
    print("|---|---|---|")
    for one, two in zip(rows[0::2], rows[1::2], strict=True):
        print(f"| {one['dofs']} | {one['peak_rss_mb']:.0f} | {two['peak_rss_mb']:.0f} |")
    benchlib.write_csv(args.out, "bench_scaling.csv", rows)


if __name__ == "__main__":
    main()
