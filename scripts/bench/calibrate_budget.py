"""Calibration of the memory budget: estimated peak memory against summary.json's peak_rss_mb.

Runs each case with the CLI (2 time steps, in a temporary directory), reads the measured
peak resident memory of the largest rank and the DOF count from summary.json, and prints
them beside the budget's estimate (parefg.discretization.budget.memory_per_rank of the scene's
estimated size) and their ratio.  The estimate should be 0.9-1.5 times the measurement
(direct and iterative, "H:iterative" cases); writes results/calibrate_budget.csv.

    .venv/bin/python scripts/bench/calibrate_budget.py            # about 2 minutes
    .venv/bin/python scripts/bench/calibrate_budget.py --quick    # three small cases
    .venv/bin/python scripts/bench/calibrate_budget.py --large    # 2 and 6 GB, a few minutes
"""

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import benchlib

from parefg.discretization import aot
from parefg.discretization.budget import estimate_scene, memory_per_rank, uses_direct_solver
from parefg.scene.loader import load_scene

PAREFG = str(Path(sys.executable).with_name("parefg"))
H = {"1/16": 1 / 16, "1/32": 1 / 32, "1/48": 1 / 48, "1/64": 1 / 64, "1/96": 1 / 96}
H.update({"1/128": 1 / 128, "1/192": 1 / 192})
# (scene, degree, h, cells, ranks); m = 3 is included for the record
CASES = [
    ("square", 1, "1/32", "quad", 1),
    ("square", 1, "1/64", "quad", 1),
    ("square", 1, "1/96", "quad", 1),
    ("square", 2, "1/16", "quad", 1),
    ("square", 2, "1/32", "quad", 1),
    ("square", 2, "1/64", "quad", 1),
    ("square", 2, "1/96", "quad", 1),
    ("square", 2, "1/32", "tri", 1),
    ("square", 2, "1/64", "quad", 2),
    ("z", 1, "1/64", "quad", 1),
    ("z", 2, "1/48", "quad", 1),
    ("z", 2, "1/32", "tri", 1),
    ("square", 3, "1/32", "quad", 1),
    ("square", 1, "1/64:iterative", "quad", 1),
    ("square", 1, "1/192:iterative", "quad", 1),
    ("square", 1, "1/192:iterative", "quad", 2),
    ("square", 2, "1/64:iterative", "quad", 1),
    ("square", 2, "1/128:iterative", "quad", 2),
]
QUICK = [CASES[0], CASES[4], CASES[9]]
# larger runs (2-6 GB, minutes): the factorization's share grows with N
LARGE = [("square", 1, "1/192", "quad", 1), ("square", 2, "1/128", "quad", 1)]


def overrides(degree: int, h: str, cells: str) -> list[str]:
    """The case's --set values: 2 time steps of the scene's dt (a full run's peak).

    ``h`` = "1/64:iterative": CG + GAMG, at m = 2 with support 2.4 (README "Iterative solver").
    """
    h, _, solver = h.partition(":")
    values = [
        f"discretization.degree={degree}",
        f"discretization.h={H[h]!r}",
        f"discretization.cells={cells}",
        "time.T=0.1",
        "time.dt=0.05",
        f"solver.method={solver or 'direct'}",
    ]
    return values + (["discretization.support=2.4"] if solver and degree == 2 else [])


def measure(scene: str, sets: list[str], ranks: int) -> dict:
    """summary.json of one CLI run (under mpirun for ranks > 1)."""
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")
    env["OMPI_MCA_rmaps_base_oversubscribe"] = "1"
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "run"
        cmd = [PAREFG, "run", scene, "--quiet", "--out", str(out)]
        cmd += [arg for s in sets for arg in ("--set", s)]
        if ranks > 1:
            cmd = ["mpirun", "-n", str(ranks), *cmd]
        subprocess.run(cmd, check=True, env=env, stdin=subprocess.DEVNULL)
        return json.loads((out / "summary.json").read_text())


def main():
    parser = benchlib.parser(__doc__, repeats=1)
    parser.add_argument("--quick", action="store_true", help="three small cases")
    parser.add_argument("--large", action="store_true", help="two large cases (2-6 GB)")
    args = parser.parse_args()
    rows = []
    print("| scene | m | h | cells | ranks | DOFs | estimated MB | measured MB | ratio |")
    print("|---|---|---|---|---|---|---|---|---|")
    cases = QUICK if args.quick else LARGE if args.large else CASES
    for scene_name, degree, h, cells, ranks in cases:
        sets = overrides(degree, h, cells)
        scene = load_scene(scene_name, sets)
        size = estimate_scene(scene)
        estimated = (
            memory_per_rank(size, ranks, uses_direct_solver(scene), jit=not aot.available()) / 2**20
        )
        summary = measure(scene_name, sets, ranks)
        measured = summary["peak_rss_mb"]
        row = dict(
            scene=scene_name,
            degree=degree,
            h=h,
            cells=cells,
            ranks=ranks,
            n_dofs=summary["n_dofs"],
            estimated_dofs=round(size.n_dofs),
            estimated_mb=round(estimated),
            measured_mb=round(measured),
            ratio=round(estimated / measured, 2),
        )
        rows.append(row)
        print(
            f"| {scene_name} | {degree} | {h} | {cells} | {ranks} | {row['n_dofs']} | "
            f"{row['estimated_mb']} | {row['measured_mb']} | {row['ratio']} |",
            flush=True,
        )
    print(f"wrote {benchlib.write_csv(args.out, 'calibrate_budget.csv', rows)}")


if __name__ == "__main__":
    main()
