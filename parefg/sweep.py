"""``parefg sweep``: run a grid of cases, tabulate error against wall time (SPEC 8).

Each ``--vary section.key=v1,v2,...`` adds an axis; the cases are their product.  Rank 0
writes sweep.csv, error_vs_time.png (H1 error against run time, points labelled by h and
dt, one colour and one Pareto front -- the smallest error reached within a given time --
per MLS degree) and prints a table with the rates fitted from every
axis that varies h or dt (np.polyfit of log error against log h or log dt).
"""

from __future__ import annotations

import csv
import itertools
from pathlib import Path

import numpy as np

from parefg.discretization.budget import check_problem_size
from parefg.errors import InputError
from parefg.petsc_options import step_solver_options
from parefg.run import create_output_dir, plan_output_dir, remove_empty_dirs, run_scene
from parefg.scene.loader import load_scene

RATE_KEYS = {"discretization.h": "h", "time.dt": "dt"}


def parse_axes(vary: list[str]) -> list[tuple[str, list[str]]]:
    """'section.key=v1,v2' strings -> [(key, [v1, v2])]; InputError on bad syntax."""
    axes = []
    for item in vary:
        key, sep, values = item.partition("=")
        if not sep or "." not in key or not values:
            raise InputError(f"--vary {item!r}: expected section.key=v1,v2,...")
        axes.append((key.strip(), [v.strip() for v in values.split(",") if v.strip()]))
    return axes


SWEEP_OUTPUT = "output.every=0"  # not the default time series: sweeps time the solver


def run_sweep(
    comm,
    scene_source: str,
    vary: list[str],
    sets: list[str],
    out: str | None,
    max_memory: float | None = None,
) -> list:
    """Run every case of the grid; return the rows.  Collective.

    Every case is validated and its size checked against ``max_memory`` (GB per machine;
    default: its available memory) before any case runs.  Rank 0 then writes sweep.csv and
    error_vs_time.png and prints the rate table.
    """
    rows, out_dir = run_cases(comm, scene_source, vary, sets, out, max_memory)
    if comm.rank == 0:
        write_csv(out_dir / "sweep.csv", rows)
        _plot(out_dir / "error_vs_time.png", rows)
        print(rate_table(rows, [key for key, _ in parse_axes(vary)]))
        print(f"sweep: {out_dir}/sweep.csv, error_vs_time.png")
    return rows


def run_cases(
    comm,
    scene_source: str,
    vary: list[str],
    sets: list[str],
    out: str | None,
    max_memory: float | None = None,
    progress: bool = True,
) -> tuple[list[dict], Path]:
    """Validate every case of the grid, then run them into OUT/caseNNN.  Collective.

    Returns the rows (one dict per case, in the order of the grid) and the output directory.
    With ``progress``, rank 0 prints one line per finished case.
    """
    axes = parse_axes(vary)
    cases = list(itertools.product(*[values for _, values in axes]))
    # validate every case before running any (bad input: exit 2, nothing run)
    # the timed cases write their final step only (a --set output.every=N still wins)
    sets = [SWEEP_OUTPUT, *sets]
    command_line = step_solver_options()
    scenes = [
        load_scene(scene_source, [*sets, *_overrides(axes, case)], command_line) for case in cases
    ]
    for scene in scenes:
        check_problem_size(comm, scene, max_memory)
    out_dir = plan_output_dir(comm, f"sweep-{scenes[0].name}", out)
    created = create_output_dir(comm, out_dir, out)
    try:
        rows = _run_cases(comm, axes, cases, scenes, out_dir, max_memory, progress)
    except InputError:
        # bad input found by the first case (a PETSc option, the mesh): leave nothing behind
        if comm.rank == 0:
            remove_empty_dirs(created)
        raise
    return rows, out_dir


def _run_cases(comm, axes, cases, scenes, out_dir: Path, max_memory, progress) -> list[dict]:
    """Run the validated cases one after the other into out_dir/caseNNN.  Collective."""
    rows = []
    for i, (case, scene) in enumerate(zip(cases, scenes, strict=True)):
        case_dir = str(out_dir / f"case{i:03d}")
        summary = run_scene(comm, scene, out=case_dir, quiet=True, max_memory=max_memory)
        row = _row(axes, case, scene, summary)
        rows.append(row)
        if comm.rank == 0 and progress:
            print(f"  case {i + 1}/{len(cases)}: " + _format_row(row), flush=True)
    return rows


def _overrides(axes, case) -> list[str]:
    return [f"{key}={value}" for (key, _), value in zip(axes, case, strict=True)]


def _row(axes, case, scene, summary) -> dict:
    errors = summary.get("errors", {})
    row = {key: value for (key, _), value in zip(axes, case, strict=True)}
    row.update(
        h=scene.discretization.h,
        dt=scene.time.dt,
        degree=scene.discretization.degree,
        n_dofs=summary["n_dofs"],
        l2_rel=errors.get("l2_rel", np.nan),
        h1_rel=errors.get("h1_rel", np.nan),
        time=summary["timings"]["total"],
        solve=summary["timings"]["solve"],
        newton=summary["newton_iterations"],
        factorizations=summary["factorizations"],
    )
    return row


def _format_row(row: dict) -> str:
    return (
        f"h {row['h']:<8.4g} dt {row['dt']:<8.4g} m {row['degree']}  dofs {row['n_dofs']:>7}  "
        f"L2 {row['l2_rel']:.3e}  H1 {row['h1_rel']:.3e}  time {row['time']:.2f} s"
    )


def write_csv(path: Path, rows: list[dict]) -> None:
    """Rows (dicts with the same keys) as a CSV file with a header line."""
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def fitted_rate(x, errors) -> float:
    """Observed order of convergence: the least-squares slope of log(errors) against log(x).

    The one rate fit of parefg (the sweep's table, scripts/verify/convergence_tables.py,
    the verification tests).  Every point counts: a zero, negative or non-finite error
    gives nan, so a failed case cannot hide in a fit (callers that mean to skip missing
    errors drop them first).  nan with fewer than two distinct x.
    """
    x, errors = np.asarray(x, float), np.asarray(errors, float)
    if x.size < 2 or np.ptp(x) == 0 or not np.all(np.isfinite(errors) & (errors > 0)):
        return float("nan")
    return float(np.polyfit(np.log(x), np.log(errors), 1)[0])


def _rate_of_known(x, errors) -> float:
    """fitted_rate over the cases that have an error (scenes without [exact] have nan)."""
    x, errors = np.asarray(x, float), np.asarray(errors, float)
    known = np.isfinite(errors) & (errors > 0)
    return fitted_rate(x[known], errors[known])


def rate_table(rows: list[dict], varied: list[str]) -> str:
    """Markdown table: one line per case, then the rates fitted along h and dt."""
    lines = ["| m | h | dt | DOFs | L2 rel | H1 rel | time [s] | Newton |", "|---" * 8 + "|"]
    lines += [
        f"| {r['degree']} | {r['h']:.4g} | {r['dt']:.4g} | {r['n_dofs']} | {r['l2_rel']:.3e} | "
        f"{r['h1_rel']:.3e} | {r['time']:.2f} | {r['newton']} |"
        for r in rows
    ]
    for key, column in RATE_KEYS.items():
        if key not in varied:
            continue
        others = [k for k in varied if k != key]
        groups: dict[tuple, list[dict]] = {}
        for r in rows:
            groups.setdefault(tuple(r[k] for k in others), []).append(r)
        for group_key, group in groups.items():
            x = [r[column] for r in group]
            label = ", ".join(f"{k}={v}" for k, v in zip(others, group_key, strict=True)) or "all"
            l2_rate = _rate_of_known(x, [r["l2_rel"] for r in group])
            h1_rate = _rate_of_known(x, [r["h1_rel"] for r in group])
            lines.append(f"\nrate in {column} ({label}): L2 {l2_rate:.2f}, H1 {h1_rate:.2f}")
    return "\n".join(lines)


def _plot(path: Path, rows: list[dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    for degree in sorted({r["degree"] for r in rows}):
        group = sorted((r for r in rows if r["degree"] == degree), key=lambda r: r["time"])
        times = np.array([r["time"] for r in group])
        errors = np.array([r["h1_rel"] for r in group])
        (points,) = ax.loglog(times, errors, "o", alpha=0.6, label=f"m = {degree}")
        # the Pareto front: the smallest error reached within each run time
        front = np.minimum.accumulate(errors)
        ax.step(times, front, where="post", color=points.get_color())
        for r in group:
            ax.annotate(
                f"h={r['h']:.3g}\ndt={r['dt']:.3g}",
                (r["time"], r["h1_rel"]),
                fontsize=6,
                textcoords="offset points",
                xytext=(3, 3),
            )
    ax.set_xlabel("wall time [s]")
    ax.set_ylabel("relative H1 error at T")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
