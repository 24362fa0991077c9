"""Benchmark: peak memory per rank and time by phase against DOFs, on 1 and 2 ranks.

Runs ``parefg run square`` through mpirun for each degree m, spacing h and rank count:
dynamic contact with friction, two time steps (T = 0.1, dt = 0.05), output at the final
step only, CG + GAMG for the steps and CG + Jacobi for the mass solve (no factorization:
the numbers are the discretization's, not a direct solver's).  Reads summary.json: peak
RSS of the largest rank, and the phase times.  KB/DOF is (peak RSS - the RSS of a tiny
run) summed over the ranks, per DOF.  Prints a markdown table and writes
results/bench_scale_memory.csv.  Each case runs once (the big ones need GBs):

    nice .venv/bin/python scripts/bench/bench_scale_memory.py --degree 1 --h 0.01 --ranks 1,2
"""

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import benchlib

PAREFG = str(Path(sys.executable).with_name("parefg"))
PHASES = ("mesh", "neighbours", "mls", "assembly", "factorization", "solve", "output", "total")
SOLVER = ["-ksp_type", "cg", "-pc_type", "gamg", "-mass_ksp_type", "cg", "-mass_pc_type", "jacobi"]
TINY_H = 0.25
MPI_ENV = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")


def run(ranks: int, degree: int, h: float, out: Path, max_memory: float) -> dict:
    sets = {
        "discretization.degree": degree,
        "discretization.h": repr(h),
        "time.T": "0.1",
        "time.dt": "0.05",
        "output.every": "0",
    }
    command = ["mpirun", "-n", str(ranks), PAREFG, "run", "square", "--quiet", "--out", str(out)]
    command += [arg for key, value in sets.items() for arg in ("--set", f"{key}={value}")]
    command += ["--max-memory", str(max_memory), *SOLVER]
    subprocess.run(command, check=True, env=MPI_ENV, capture_output=True, text=True)
    return json.loads((out / "summary.json").read_text())


def main():
    parser = benchlib.parser(__doc__, repeats=1)
    parser.add_argument("--degree", default="1")
    parser.add_argument("--h", default="0.01,0.003125")
    parser.add_argument("--ranks", default="1,2")
    parser.add_argument("--max-memory", type=float, default=20.0, help="GB (parefg --max-memory)")
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for degree in (int(m) for m in args.degree.split(",")):
            for ranks in (int(r) for r in args.ranks.split(",")):
                tiny = run(ranks, degree, TINY_H, Path(tmp) / f"tiny-{degree}-{ranks}", 20.0)
                for h in (float(v) for v in args.h.split(",")):
                    out = Path(tmp) / f"m{degree}-h{h}-np{ranks}"
                    summary = run(ranks, degree, h, out, args.max_memory)
                    dofs, peak = summary["n_dofs"], summary["peak_rss_mb"]
                    row = {"degree": degree, "ranks": ranks, "h": h, "dofs": dofs}
                    row["peak_rss_mb"] = peak
                    row["kb_per_dof"] = (peak - tiny["peak_rss_mb"]) * 1.024**2 * 1e3 * ranks / dofs
                    row["newton"] = summary["newton_iterations"]
                    row["linear"] = summary["linear_iterations"]
                    row.update({p: summary["timings"].get(p, 0.0) for p in PHASES})
                    rows.append(row)
                    print(f"m {degree} np {ranks} h {h}: {dofs} DOFs, {peak:.0f} MB", flush=True)
    print("\n| m | ranks | DOFs | peak RSS/rank [MB] | KB/DOF | " + " | ".join(PHASES) + " |")
    print("|---|---|---|---|---|" + "---|" * len(PHASES))
    for r in rows:
        times = " | ".join(f"{r[p]:.1f}" for p in PHASES)
        print(
            f"| {r['degree']} | {r['ranks']} | {r['dofs']} | {r['peak_rss_mb']:.0f} | "
            f"{r['kb_per_dof']:.1f} | {times} |"
        )
    benchlib.write_csv(args.out, "bench_scale_memory.csv", rows)


if __name__ == "__main__":
    main()
