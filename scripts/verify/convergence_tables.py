"""Convergence studies of the manufactured scenes "square" and "z" (SPEC 6), as markdown tables.

Runs, through :func:`parefg.run.run_scene` (so also under ``mpirun -n P``):

* L2 / H1 relative errors vs h for m = 1 and m = 2 (dt = 0.0125, time error below space error);
* L2 vs dt at h = 1/32, m = 2 (Newmark beta = gamma = 1/2: second order);
* L2 / H1 vs alpha_contact = 1 .. 1e4 E/h at h = 1/16, m = 2.

Prints markdown tables with rates fitted by least squares on log-log data (the last column,
"rate", is the slope between consecutive rows) and writes one CSV per study to results/.

Usage: ``.venv/bin/python scripts/verify/convergence_tables.py [--quick] [--out results]``
"""

from __future__ import annotations

import argparse
import csv
import tempfile
from pathlib import Path

import numpy as np
from mpi4py import MPI

from parefg.run import run_scene
from parefg.scene.loader import load_scene

SCENES = ("square", "z")


def studies(quick: bool) -> list[tuple[str, str, list[float], list[str]]]:
    """(study name, varied key, values, fixed overrides) for each table."""
    sizes = [0.125, 0.0625] if quick else [0.125, 0.0625, 0.03125]
    return [
        ("h, m = 1", "discretization.h", sizes, ["discretization.degree=1", "time.dt=0.0125"]),
        ("h, m = 2", "discretization.h", sizes, ["discretization.degree=2", "time.dt=0.0125"]),
        ("dt, m = 2, h = 1/32", "time.dt", [0.1, 0.05, 0.025, 0.0125],
         ["discretization.h=0.03125"]),
        ("alpha_contact (x E/h), m = 2, h = 1/16", "penalty.alpha_contact", [1, 10, 100, 1e3, 1e4],
         ["discretization.h=0.0625"]),
    ]  # fmt: skip


def run_case(comm, scene_name: str, overrides: list[str], workdir: Path, tag: str) -> dict:
    """One run; returns its summary (errors, timings, iterations).  Collective."""
    scene = load_scene(scene_name, overrides)
    out = workdir / tag if comm.rank == 0 else None
    return run_scene(comm, scene, out=str(comm.bcast(out)), quiet=True)


def pairwise_rates(xs, ys) -> list[float]:
    logs = np.log(np.asarray([xs, ys], dtype=float))
    return [np.nan] + list(np.diff(logs[1]) / np.diff(logs[0]))


def fitted(xs, ys) -> float:
    return float(np.polyfit(np.log(xs), np.log(ys), 1)[0])


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
        f"| fitted | | {fitted(xs, [r['l2_rel'] for r in rows]):.2f} | "
        f"| {fitted(xs, [r['h1_rel'] for r in rows]):.2f} | | |"
    )
    return "\n".join(lines).replace("| nan |", "| |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="two sizes only (a smoke run)")
    parser.add_argument("--out", default="results", help="directory for the CSV files")
    args = parser.parse_args()
    comm = MPI.COMM_WORLD
    results = Path(args.out)
    with tempfile.TemporaryDirectory() as workdir:
        for s_index, (study, key, values, fixed) in enumerate(studies(args.quick)):
            all_rows = []
            for scene_name in SCENES:
                rows = []
                for v_index, value in enumerate(values):
                    setting = value / 0.0625 if key == "penalty.alpha_contact" else value
                    tag = f"{s_index}-{scene_name}-{v_index}"
                    summary = run_case(comm, scene_name, [*fixed, f"{key}={setting}"],
                                       Path(workdir), tag)  # fmt: skip
                    rows.append(
                        {"scene": scene_name, "study": study, "value": value,
                         **summary["errors"], "newton": summary["newton_iterations"],
                         "seconds": summary["timings"]["total"]}
                    )  # fmt: skip
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
