"""Benchmark: peak memory per rank at a fixed number of DOFs per rank, p = 1, 2, 4, 8 (issue 13).

Runs `parefg run square` (or ``--scene z``; m = 1 by default, CG + GAMG, one dynamic contact
step) under
``mpirun -n p`` (oversubscribed; scripts/bench/bench_scaling.py's run) with h chosen so
that the DOFs per rank stay near ``--dofs-per-rank``, and reads summary.json: the peak
RSS of the largest rank and the phase times.  Flat memory per rank means no rank holds
more as p grows; growth at fixed N/p is what every rank replicates (today the node
cloud, its partition and the MLS node arrays: O(N) per rank).  With 2 cores, p > 2 is
oversubscribed: the bytes are right, the times are not (they are printed for
completeness, not to be read as scaling).

Prints a markdown table and writes results/bench_weak_memory.csv.

    .venv/bin/python scripts/bench/bench_weak_memory.py [--ranks 1,2,4,8] \
        [--dofs-per-rank 25000] [--degree 1] [--repeats 1] [--scene square|z]
"""

import math
import statistics
import tempfile
from pathlib import Path

import benchlib
from bench_scaling import run  # the same one-step `parefg run square` under mpirun

PHASES = ("mesh", "mls", "assembly", "solve", "total")


# the domains' areas: about area / h^2 nodes
AREAS = {"square": 1.0, "z": 0.7}


def spacing(dofs: int, scene: str = "square") -> int:
    """1/h at which ``scene``'s domain has about ``dofs`` DOFs (the unit square: (n + 1)^2
    nodes; the Z: about 0.7 n^2)."""
    if scene == "square":
        return max(2, round(math.sqrt(dofs / 2.0)) - 1)
    return max(8, round(math.sqrt(dofs / (2.0 * AREAS[scene]))))


def main() -> None:
    cli = benchlib.parser(__doc__, repeats=1)
    cli.add_argument("--ranks", default="1,2,4,8")
    cli.add_argument("--dofs-per-rank", type=int, default=25000)
    cli.add_argument("--degree", type=int, default=1)
    cli.add_argument("--scene", choices=sorted(AREAS), default="square")
    args = cli.parse_args()
    rows = []
    for ranks in map(int, args.ranks.split(",")):
        n = spacing(args.dofs_per_rank * ranks, args.scene)
        summaries = []
        for _ in range(args.repeats):
            with tempfile.TemporaryDirectory() as tmp:
                run_dir = Path(tmp) / "run"
                summaries.append(run(ranks, args.degree, 1.0 / n, "iterative", run_dir, args.scene))
        dofs = summaries[0]["n_dofs"]
        rss = statistics.median(s["peak_rss_mb"] for s in summaries)
        row = {"scene": args.scene, "ranks": ranks, "m": args.degree, "h": f"1/{n}", "dofs": dofs}
        row.update(dofs_per_rank=dofs // ranks, peak_rss_mb_per_rank=rss)
        row.update(kb_per_owned_dof=1024 * rss / (dofs / ranks))
        for name in PHASES:
            row[f"{name}_s"] = statistics.median(s["timings"].get(name, 0.0) for s in summaries)
        rows.append(row)
        print(
            f"p = {ranks}: {dofs} DOFs ({dofs // ranks} per rank), peak RSS per rank "
            f"{rss:.0f} MB, {row['kb_per_owned_dof']:.1f} KB per owned DOF",
            flush=True,
        )
    print(
        "\n| ranks | h | DOFs | DOFs per rank | peak RSS per rank [MB] | KB per owned DOF | "
        + " | ".join(f"{p} [s]" for p in PHASES)
        + " |"
    )
    print("|---" * (6 + len(PHASES)) + "|")
    for r in rows:
        times = " | ".join(f"{r[f'{p}_s']:.2f}" for p in PHASES)
        print(
            f"| {r['ranks']} | {r['h']} | {r['dofs']} | {r['dofs_per_rank']} | "
            f"{r['peak_rss_mb_per_rank']:.0f} | {r['kb_per_owned_dof']:.1f} | {times} |"
        )
    print("CSV:", benchlib.write_csv(args.out, "bench_weak_memory.csv", rows))


if __name__ == "__main__":
    main()
