"""Convergence studies of the manufactured scenes "square" and "z" (SPEC 6), as markdown tables.

Each study of each scene is one ``parefg sweep`` along one axis, run through
:func:`parefg.sweep.run_cases` (so also under ``mpirun -n P``):

* L2 / H1 relative errors vs h for m = 1, 2, 3 with the exact solution made quadratic in t
  (:data:`TIME_EXACT`), which Newmark 1/2-1/2 integrates without time error: the dynamic
  runs' spatial rates;
* L2 / H1 relative errors vs h for m = 1, 2 and 3 (dt = 0.0125: below the space error at m = 1,
  the floor of the L2 error at m = 2 and 3);
* L2 vs dt at h = 1/32, m = 2 (Newmark beta = gamma = 1/2: second order);
* L2 / H1 vs alpha_contact = 1 .. 1e4 E/h at h = 1/16, m = 2 (the penalty contact).

Prints markdown tables with the rates of :func:`parefg.sweep.fitted_rate` (least squares on
log-log data: the "fitted" row over all rows, each "rate" column between consecutive rows) and
writes one CSV per study to results/.

Usage:
``.venv/bin/python scripts/verify/convergence_tables.py [--quick] [--out results] [--only TEXT]``
"""

from __future__ import annotations

import argparse
import csv
import tempfile
from pathlib import Path

import numpy as np
from mpi4py import MPI

from parefg.sweep import fitted_rate, run_cases

SCENES = ("square", "z")


# The scenes' exact solution with (1 - cos t) replaced by t^2: same signs (contact everywhere
# on y = 0, sliding), same zero initial state, and quadratic in t, which Newmark 1/2-1/2
# integrates exactly (a constant acceleration), so the error of a dynamic run is the
# spatial error alone, at any dt.
TIME_EXACT = 'exact.u=["t**2 * (1 + x) * exp(y)", "-t**2 * y * exp(x)"]'


def studies(quick: bool) -> list[tuple[str, str, list[float], list[str]]]:
    """(study name, varied key, values, fixed overrides) for each table."""
    sizes = [0.125, 0.0625] if quick else [0.125, 0.0625, 0.03125]
    time_exact = [
        (f"h, m = {m}, u quadratic in t (no time error), dt = 0.05", "discretization.h", sizes,
         [f"discretization.degree={m}", "time.dt=0.05", TIME_EXACT])
        for m in (1, 2, 3)
    ]  # fmt: skip
    return time_exact + [
        ("h, m = 1", "discretization.h", sizes, ["discretization.degree=1", "time.dt=0.0125"]),
        ("h, m = 2", "discretization.h", sizes, ["discretization.degree=2", "time.dt=0.0125"]),
        ("h, m = 3", "discretization.h", sizes, ["discretization.degree=3", "time.dt=0.0125"]),
        ("dt, m = 2, h = 1/32", "time.dt", [0.1, 0.05, 0.025, 0.0125],
         ["discretization.h=0.03125"]),
        ("alpha_contact (x E/h), m = 2, h = 1/16, penalty contact", "penalty.alpha_contact",
         [1, 10, 100, 1e3, 1e4], ["discretization.h=0.0625", "boundary.bottom.method=penalty"]),
    ]  # fmt: skip


def run_study(comm, scene_name: str, key: str, settings: list, fixed: list, out: str) -> list:
    """The rows of a sweep of ``key`` over ``settings`` (``fixed`` overrides).  Collective."""
    vary = [f"{key}={','.join(str(setting) for setting in settings)}"]
    rows, _ = run_cases(comm, scene_name, vary, fixed, out, progress=False)
    return rows


def pairwise_rates(xs, ys) -> list[float]:
    """The rate between each row and the one before (nan for the first row)."""
    return [np.nan] + [fitted_rate(xs[i - 1 : i + 1], ys[i - 1 : i + 1]) for i in range(1, len(xs))]


def table(title: str, key: str, rows: list[dict]) -> str:
    """Markdown table of one study on one scene, with pairwise and fitted rates."""
    xs = [r["value"] for r in rows]
    lines = [f"**{title}**", "", f"| {key} | L2 rel | rate | H1 rel | rate | Newton | time [s] |"]
    lines.append("|---|---|---|---|---|---|---|")
    l2_rates = pairwise_rates(xs, [r["l2_rel"] for r in rows])
    h1_rates = pairwise_rates(xs, [r["h1_rel"] for r in rows])
    for row, l2_rate, h1_rate in zip(rows, l2_rates, h1_rates, strict=True):
        lines.append(
            f"| {row['value']:g} | {row['l2_rel']:.3e} | {l2_rate:.2f} | {row['h1_rel']:.3e} | "
            f"{h1_rate:.2f} | {row['newton']} | {row['seconds']:.2f} |"
        )
    lines.append(
        f"| fitted | | {fitted_rate(xs, [r['l2_rel'] for r in rows]):.2f} | "
        f"| {fitted_rate(xs, [r['h1_rel'] for r in rows]):.2f} | | |"
    )
    return "\n".join(lines).replace("| nan |", "| |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="two sizes only (a smoke run)")
    parser.add_argument("--out", default="results", help="directory for the CSV files")
    parser.add_argument("--only", default="", help="only the studies whose name contains this")
    args = parser.parse_args()
    comm = MPI.COMM_WORLD
    results = Path(args.out)
    with tempfile.TemporaryDirectory() as workdir:
        # every rank writes into rank 0's directory
        workdir = Path(comm.bcast(workdir, root=0))
        for s_index, (study, key, values, fixed) in enumerate(studies(args.quick)):
            if args.only not in study:
                continue
            # alpha_contact is given in units of E/h (h = 1/16)
            settings = [v / 0.0625 if key == "penalty.alpha_contact" else v for v in values]
            all_rows = []
            for scene_name in SCENES:
                out = str(workdir / f"{s_index}-{scene_name}")
                cases = run_study(comm, scene_name, key, settings, fixed, out)
                rows = [
                    {"scene": scene_name, "study": study, "value": value,
                     "l2_rel": case["l2_rel"], "h1_rel": case["h1_rel"],
                     "newton": case["newton"], "seconds": case["time"]}
                    for value, case in zip(values, cases, strict=True)
                ]  # fmt: skip
                if comm.rank == 0:
                    print(table(f"{scene_name}: error vs {study}", key, rows) + "\n", flush=True)
                all_rows += rows
            if comm.rank == 0:
                write_csv(results / f"convergence_{s_index}.csv", all_rows)


def write_csv(path: Path, rows: list[dict]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


if __name__ == "__main__":
    main()
