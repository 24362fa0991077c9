"""The stability stress matrix: parefg runs at the edges of its parameter ranges (issue 6).

Each row is one ``parefg run`` subprocess (1 rank) that is reported as converged, failed
(exit 1) or rejected (exit 2; "rejected (expected)" where bad input is the point of the row),
with: the largest Newton iteration count of a step, the energy drift, the relative L2 / H1
errors at T (scenes with an exact solution), the min / max condition number of the MLS
moment matrices and the wall time.  The energy drift is

    max_n |B_n - B_0| / max_n (kinetic + elastic + penalty + dissipated)_n,
    B = kinetic + elastic + penalty + dissipated - external work,

read from result.h5 /history: B is conserved exactly by the continuous problem, so the
drift measures what the time scheme and the penalty switches gain or lose, relative to the
largest energy the run held.

Rows: penalty alpha 1e0 .. 1e14 E/h; time step 1e-4 .. 0.5; a long run of 100 periods of
the lowest mode of a clamped rectangle (beta = 1/4, no contact; the period is measured
from the kinetic-energy minima of a short run); jittered clouds 0 .. 40 % of h (m = 1, 2);
the plate with a hole and the clustered cloud (meshes/); a too-small support; m = 3;
nu -> 1/2; very soft and very stiff material; repeated frictional impacts (contact
closings and openings counted from active_contact_points).

Usage: ``.venv/bin/python scripts/bench/stress.py [--out results] [--keep]``; prints a markdown
table and writes OUT/stress.csv.  About 3 minutes on 2 cores.
"""

from __future__ import annotations

import argparse
import csv
import json
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

REPO = Path(__file__).resolve().parents[2]
PAREFG = str(Path(sys.executable).with_name("parefg"))
ENERGY_COLUMNS = ("kinetic_energy", "elastic_energy", "penalty_energy", "dissipated_energy")
EXACT_U = ["(1 - cos(t)) * (1 + x) * exp(y)", "-(1 - cos(t)) * y * exp(x)"]  # SPEC 6
# The SPEC 6 manufactured solution on the plate with a hole: contact at y = 0 (u_2 = 0
# there), clamped top, every other part loaded by the exact traction.
PLATE_SCENE = f"""
[domain]
shape = "geo"
file = "{REPO / "meshes" / "plate_with_hole.geo"}"
parts = ["bottom", "top", "sides", "hole"]
[discretization]
h = 0.1
degree = 1
[time]
T = 1.0
dt = 0.05
[boundary.bottom]
type = "contact"
[boundary.top]
type = "dirichlet"
[boundary.sides]
type = "neumann"
[boundary.hole]
type = "neumann"
[exact]
u = {json.dumps(EXACT_U)}
"""
# A clamped 1 x 0.25 rectangle (a short cantilever), started with a velocity of the shape of
# its first bending mode; no contact, so every step is one linear solve.
CANTILEVER_SCENE = """
[domain]
shape = "rectangle"
size = [1.0, 0.25]
[discretization]
h = 0.125
degree = 1
[time]
beta = 0.25
T = {T!r}
dt = {dt!r}
[boundary.left]
type = "dirichlet"
[initial]
v = [0, "0.1 * x * x"]
"""
CLUSTERED = [
    'domain.shape="geo"',
    f'domain.file="{REPO / "meshes" / "clustered.geo"}"',
    'domain.parts=["bottom", "right", "top", "left"]',
]


@dataclass
class Row:
    """One run of the matrix and what it reported."""

    group: str
    case: str
    scene: str
    overrides: list[str]
    expect_rejection: bool = False
    status: str = ""
    max_newton: int | None = None
    drift: float | None = None
    l2_rel: float | None = None
    h1_rel: float | None = None
    cond_min: float | None = None
    cond_max: float | None = None
    seconds: float = 0.0
    note: str = ""
    history: dict = field(default_factory=dict, repr=False)


def run_row(row: Row, out: Path) -> Row:
    """Run ``parefg run`` for one row in a fresh directory under ``out`` and read its output."""
    directory = out / f"{row.group}-{row.case}".replace(" ", "_").replace("/", "_")
    shutil.rmtree(directory, ignore_errors=True)
    command = [PAREFG, "run", row.scene, "--out", str(directory), "--quiet"]
    command += [arg for text in row.overrides for arg in ("--set", text)]
    start = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True, timeout=600)
    row.seconds = time.perf_counter() - start
    message = (done.stderr.strip().splitlines() or [""])[-1]
    if done.returncode == 2:
        row.status = "rejected (expected)" if row.expect_rejection else "rejected"
        row.note = message
        return row
    row.status = "converged" if done.returncode == 0 else f"failed (exit {done.returncode})"
    if done.returncode != 0:
        row.note = message
    if (directory / "summary.json").is_file():
        _read_summary(row, json.loads((directory / "summary.json").read_text()))
    if (directory / "result.h5").is_file():
        _read_history(row, directory / "result.h5")
    return row


def _read_summary(row: Row, summary: dict) -> None:
    row.max_newton = summary.get("max_newton_per_step")
    errors = summary.get("errors") or {}
    row.l2_rel, row.h1_rel = errors.get("l2_rel"), errors.get("h1_rel")
    condition = summary.get("mls_condition") or {}
    row.cond_min, row.cond_max = condition.get("min"), condition.get("max")


def _read_history(row: Row, path: Path) -> None:
    """The per-step table and the energy drift (module docstring) from result.h5."""
    with h5py.File(path, "r") as result:
        if "history" not in result:
            return
        row.history = {name: result["history"][name][()] for name in result["history"]}
    held = sum(row.history[name] for name in ENERGY_COLUMNS)  # (n_steps + 1,)
    balance = held - row.history["external_work"]
    if len(balance) > 1 and np.max(np.abs(held)) > 0:
        row.drift = float(np.max(np.abs(balance - balance[0])) / np.max(np.abs(held)))


# --------------------------------------------------------------------------- the matrix


def alpha_rows() -> list[Row]:
    """alpha_contact = alpha_friction = a E / h on square, h = 1/8, m = 1, T = 0.3."""
    h = 0.125
    fixed = [f"discretization.h={h}", "discretization.degree=1", "time.T=0.3"]
    return [
        Row("alpha", f"{a:.0e} E/h", "square",
            [*fixed, "boundary.bottom.method=penalty", f"penalty.alpha_contact={a / h!r}",
             f"penalty.alpha_friction={a / h!r}"])
        for a in (1e0, 1e2, 1e4, 1e6, 1e8, 1e10, 1e12, 1e14)
    ]  # fmt: skip


def dt_rows() -> list[Row]:
    """dt = 1e-4 .. 0.5 on square (h = 1/8, m = 1), T = max(10 dt, 0.05)."""
    rows = []
    for dt in (1e-4, 1e-3, 1e-2, 0.1, 0.5):
        T = max(10 * dt, 0.05)
        fixed = ["discretization.h=0.125", "discretization.degree=1"]
        rows.append(
            Row("dt", f"{dt:g} (T={T:g})", "square", [*fixed, f"time.T={T!r}", f"time.dt={dt!r}"])
        )
    return rows


def cloud_rows() -> list[Row]:
    """Jitter 0 .. 40 % (m = 1, 2; square, h = 1/16), plate with hole, clustered, tiny support."""
    rows = []
    for degree in (1, 2):
        for percent in (0, 10, 20, 30, 40):
            rows.append(Row("jitter", f"{percent}% m={degree}", "square", [
                "discretization.h=0.0625", f"discretization.degree={degree}",
                f"discretization.jitter={percent / 100}",
            ]))  # fmt: skip
    clustered = ["discretization.h=0.125", "discretization.degree=1", *CLUSTERED]
    rows += [
        Row("cloud", "plate with hole m=1", "PLATE", []),
        Row("cloud", "clustered h=1/8 m=1", "square", clustered),
        Row("cloud", "clustered 30% jitter", "square", [*clustered, "discretization.jitter=0.3"]),
        Row("cloud", "support 1.05 m=1", "square",
            ["discretization.h=0.125", "discretization.degree=1", "discretization.support=1.05"],
            expect_rejection=True),
    ]  # fmt: skip
    return rows


def material_rows() -> list[Row]:
    """m = 3; nu -> 1/2; very soft and very stiff (alpha follows E by default)."""
    fixed = ["discretization.h=0.125", "discretization.degree=1"]
    rows = [
        Row("degree", "m=3 h=1/8", "square", ["discretization.h=0.125", "discretization.degree=3"])
    ]
    rows += [Row("nu", f"{nu}", "square", [*fixed, f"material.nu={nu}"])
             for nu in (0.45, 0.49, 0.499)]  # fmt: skip
    rows += [Row("E", f"{E:g}", "square", [*fixed, f"material.E={E!r}"]) for E in (1e-3, 1e6)]
    return rows


def impact_row() -> Row:
    """Repeated frictional impacts: the impact scene for T = 3 with beta = 1/4."""
    return Row("impact", "T=3 beta=1/4", "impact", ["time.T=3.0", "time.beta=0.25"])


def contact_changes(active: np.ndarray) -> tuple[int, int]:
    """(closings, openings): steps where the number of active points leaves / returns to 0."""
    touching = np.asarray(active) > 0  # (n_steps + 1,)
    return int(np.sum(~touching[:-1] & touching[1:])), int(np.sum(touching[:-1] & ~touching[1:]))


def kinetic_minima_period(history: dict) -> float:
    """Lowest period from the spacing of kinetic-energy minima (two per period).

    Each interior local minimum is refined by the vertex of the parabola through it and its
    neighbours; the period is twice the median spacing.
    """
    t, kinetic = history["time"], history["kinetic_energy"]  # (n_steps + 1,)
    inner = np.flatnonzero((kinetic[1:-1] < kinetic[:-2]) & (kinetic[1:-1] <= kinetic[2:])) + 1
    left, mid, right = kinetic[inner - 1], kinetic[inner], kinetic[inner + 1]
    shift = 0.5 * (left - right) / (left - 2 * mid + right)  # in steps, |shift| <= 1/2
    minima = t[inner] + shift * (t[1] - t[0])
    if len(minima) < 2:
        raise RuntimeError(f"period estimate: {len(minima)} kinetic-energy minima in the short run")
    return float(2 * np.median(np.diff(minima)))


def long_run_rows(scenes: Path, out: Path) -> list[Row]:
    """Estimate the cantilever's lowest period, then run 100 periods with 20 steps each."""
    short = scenes / "cantilever_short.toml"
    short.write_text(CANTILEVER_SCENE.format(T=80.0, dt=0.25))
    probe = run_row(Row("long", "period probe", str(short), []), out)
    period = kinetic_minima_period(probe.history)
    probe.note = f"lowest period P = {period:.4g}"
    dt = period / 20
    long = scenes / "cantilever_long.toml"
    long.write_text(CANTILEVER_SCENE.format(T=2000 * dt, dt=dt))
    row = run_row(Row("long", "100 periods beta=1/4", str(long), []), out)
    kinetic = row.history.get("kinetic_energy")
    if kinetic is not None:
        held = sum(row.history[name] for name in ENERGY_COLUMNS)
        row.note = f"P = {period:.4g}, 2000 steps; energy max/min = {held.max() / held.min():.6f}"
    return [probe, row]


# --------------------------------------------------------------------------- report

COLUMNS = ("group", "case", "status", "max_newton", "drift", "l2_rel", "h1_rel", "cond_min",
           "cond_max", "seconds", "note")  # fmt: skip


def cell(value) -> str:
    """A table cell: floats in 3 significant digits, None as '-'."""
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:.3g}"
    return str(value)


def markdown(rows: list[Row]) -> str:
    lines = ["| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    lines += ["| " + " | ".join(cell(getattr(r, c)) for c in COLUMNS) + " |" for r in rows]
    return "\n".join(lines)


def write_csv(rows: list[Row], path: Path) -> None:
    with path.open("w", newline="") as stream:
        writer = csv.writer(stream)
        writer.writerow(COLUMNS)
        writer.writerows([[getattr(r, c) for c in COLUMNS] for r in rows])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=REPO / "results")
    parser.add_argument("--keep", action="store_true", help="keep the run directories")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix="parefg-stress-", dir=args.out))
    (work / "plate.toml").write_text(PLATE_SCENE)
    matrix = alpha_rows() + dt_rows() + cloud_rows() + material_rows() + [impact_row()]
    rows = []
    for row in matrix:
        row.scene = str(work / "plate.toml") if row.scene == "PLATE" else row.scene
        rows.append(run_row(row, work))
        print(f"{row.group:7s} {row.case:24s} {row.status:20s} {row.seconds:6.1f} s", flush=True)
    impact = rows[-1]
    if "active_contact_points" in impact.history:
        closings, openings = contact_changes(impact.history["active_contact_points"])
        impact.note = f"{closings} closings, {openings} openings"
    rows += long_run_rows(work, work)
    print(markdown(rows))
    write_csv(rows, args.out / "stress.csv")
    if not args.keep:
        shutil.rmtree(work)
    return 0


if __name__ == "__main__":
    sys.exit(main())
