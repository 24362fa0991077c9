"""Benchmark: parefg against GetFEM on the square scene, time to accuracy measured side by side.

Both codes solve the same continuous problem (SPEC 6 "square": plane-strain elasticity,
manufactured solution, penalty contact at y = 0 with gap 0, return-mapping Tresca friction
with the derived bound, Newmark beta = gamma = 1/2, T = 1), read from the same
``load_scene("square", overrides)``; GetFEM's model is scripts/bench/getfem_square.py
(P2 triangles by default, its Newton and MUMPS).  Before timing, the GetFEM data strings
are checked against parefg's derived data at random points (to round-off).

Each case is a point (h, dt) of a grid per code; the relative H1-seminorm error at T
against the median wall time of ``--repeats`` runs (repeats interleaved over all cases of
both codes, so that a noisy machine loads both alike).  Timed: parefg's ``run_scene``
(mesh, MLS, assembly, time loop, final output, errors; scene loading excluded) and
GetFEM's mesh, FEM, model, initial state, time loop and error integrals (the data
derivation excluded); imports excluded on both sides, one process, one BLAS thread
(OMP_NUM_THREADS=1 unless set).  For each target (1e-3, 1e-4, 1e-5) the cheapest measured
case at or below it, per code, and the ratio parefg / GetFEM.  The GetFEM model is
verified first: its errors along the grid's diagonal (h and dt halved together), along h
at the smallest dt and along dt at the finest h, with fitted rates; a diagonal rate below
RATE_FLOOR of the expected one (FEM degree for H1) makes the script exit 1.

    .venv/bin/python scripts/bench/getfem_side_by_side.py [--repeats 3] [--quick]
        [--out results/getfem_side_by_side]
    .venv/bin/python scripts/bench/getfem_side_by_side.py --tables-from DIR/side_by_side.csv

Writes side_by_side.csv (every case), targets.csv and time_vs_error.png (both codes, with
each code's front) into --out; prints the convergence tables, every case, the targets
table and the cheapest case per discretization.  --tables-from redoes the tables and
the figure of an earlier run without running anything.
Needs Debian's python3-getfem (optional): without it, one line and exit 0.
"""

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")  # before numpy, PETSc, MUMPS load their BLAS

import argparse  # noqa: E402
import csv  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

TARGETS = (1e-3, 1e-4, 1e-5)
RATE_FLOOR = 0.8  # the diagonal rate must reach 0.8 x the expected order
# (code, degree) -> (1/h values, dt values): full products; parefg's degree is the MLS m
GRIDS = {
    ("GetFEM", 1): ((8, 16, 32), (0.05, 0.025, 0.0125)),  # verification only: H1 ~ h
    ("GetFEM", 2): ((4, 8, 16, 32), (0.05, 0.025, 0.0125, 0.00625)),
    ("GetFEM", 3): ((4, 8, 16), (0.025, 0.0125, 0.00625, 0.003125)),
    ("parefg", 2): ((8, 16, 24, 32), (0.05, 0.025, 0.0125, 0.00625)),
    ("parefg", 3): ((8, 16, 24), (0.025, 0.0125, 0.00625, 0.003125)),
}
# (code, degree) -> (1/h, dt) points between the grids' h, near the targets, for both codes
# alike: the time to reach a target is that of the cheapest case at or below it, so a coarse
# h grid overstates it.  Not part of the convergence tables (not halvings).
BETWEEN = {
    ("GetFEM", 2): ((12, 0.025), (12, 0.0125), (24, 0.0125), (24, 0.00625)),
    ("GetFEM", 3): ((6, 0.025), (6, 0.0125), (10, 0.003125), (12, 0.00625), (12, 0.003125)),
    ("parefg", 2): ((4, 0.025), (6, 0.025), (12, 0.0125), (12, 0.00625)),
    ("parefg", 3): (
        (4, 0.025),
        (6, 0.025),
        (6, 0.0125),
        (12, 0.00625),
        (12, 0.003125),
        (14, 0.003125),
    ),
}
QUICK_GRIDS = {  # for development: seconds, not minutes
    ("GetFEM", 1): ((4, 8, 16), (0.1, 0.05, 0.025)),
    ("GetFEM", 2): ((4, 8, 16), (0.1, 0.05, 0.025)),
    ("parefg", 2): ((8, 16), (0.05, 0.025)),
}
FINAL_STEP_ONLY = "output.every=0"  # no time series (as `parefg sweep`): both write nothing else


def overrides(code: str, degree: int, n: int, dt: float) -> list[str]:
    """The scene overrides of one case: h = 1/n, dt, and parefg's MLS degree."""
    extra = [f"discretization.degree={degree}"] if code == "parefg" else []
    return [f"discretization.h={1.0 / n!r}", f"time.dt={dt!r}", FINAL_STEP_ONLY, *extra]


def cases(grids: dict, between: dict | None = None) -> list[dict]:
    """Every (code, degree, h, dt) of the grids, in order, then the ``between`` points."""
    grid = [
        {"code": code, "degree": degree, "n": n, "h": 1.0 / n, "dt": dt, "between": 0}
        for (code, degree), (ns, dts) in grids.items()
        for n in ns
        for dt in dts
    ]
    extra = [
        {"code": code, "degree": degree, "n": n, "h": 1.0 / n, "dt": dt, "between": 1}
        for (code, degree), points in (between or {}).items()
        for n, dt in points
    ]
    return grid + extra


class Runner:
    """Runs one case of either code and returns (seconds, result row); imports done once."""

    def __init__(self, getfem_square):
        # One warm process runs every case: numba's one-off start-up (import, cached
        # kernels) is paid once, after which its kernels beat numpy's at every size
        # (scripts/bench/bench_backends.py), so the small cases use them too.
        os.environ.setdefault("PAREFG_KERNELS", "numba")
        import petsc4py

        import parefg  # noqa: F401  (PETSC_DIR)

        petsc4py.init(sys.argv[:1])
        from mpi4py import MPI

        from parefg.run import run_scene
        from parefg.scene.loader import load_scene

        self.comm, self.run_scene, self.load_scene = MPI.COMM_WORLD, run_scene, load_scene
        self.gs = getfem_square
        self.data = None

    def getfem(self, case: dict) -> tuple[float, dict]:
        scene = self.load_scene("square", overrides("GetFEM", *_key(case)))
        if self.data is None:  # the data do not depend on h or dt
            self.data = self.gs.derive_data(scene)
            mismatch = self.gs.data_mismatch(scene, self.data)
            print(f"GetFEM data against parefg's derived data: max rel. difference {mismatch:.1e}")
            if not mismatch < 1e-12:
                raise SystemExit("getfem_side_by_side: the GetFEM data differ from parefg's")
        result = self.gs.solve(scene, self.data, case["degree"])
        return result["seconds"], result

    def parefg(self, case: dict) -> tuple[float, dict]:
        scene = self.load_scene("square", overrides("parefg", *_key(case)))
        with tempfile.TemporaryDirectory() as tmp:
            tic = time.perf_counter()
            summary = self.run_scene(self.comm, scene, out=str(Path(tmp) / "run"), quiet=True)
            seconds = time.perf_counter() - tic
        errors = summary["errors"]
        return seconds, {"dofs": summary["n_dofs"], "steps": summary["n_steps"],
                         "newton": summary["newton_iterations"], **errors}  # fmt: skip

    def run(self, case: dict) -> tuple[float, dict]:
        return (self.getfem if case["code"] == "GetFEM" else self.parefg)(case)


def _key(case: dict) -> tuple[int, int, float]:
    return case["degree"], case["n"], case["dt"]


def measure(runner: Runner, grid: list[dict], repeats: int) -> list[dict]:
    """Median seconds of ``repeats`` runs per case, repeats interleaved over all cases."""
    times: list[list[float]] = [[] for _ in grid]
    results: list[dict] = [{} for _ in grid]
    for repeat in range(repeats):
        for i, case in enumerate(grid):
            seconds, results[i] = runner.run(case)
            times[i].append(seconds)
            if repeat == 0:
                h1 = results[i]["h1_rel"]
                print(f"  {label(case)}: H1 {h1:.2e}, {seconds:.2f} s", flush=True)
    kept = ("dofs", "steps", "newton", "l2_rel", "h1_rel")
    return [
        {
            **case,
            **{k: results[i][k] for k in kept},
            "median_s": statistics.median(times[i]),
            "min_s": min(times[i]),
            "max_s": max(times[i]),
        }  # fmt: skip
        for i, case in enumerate(grid)
    ]


def label(case: dict) -> str:
    kind = f"P{case['degree']}" if case["code"] == "GetFEM" else f"m = {case['degree']}"
    return f"{case['code']} {kind}, h = 1/{case['n']}, dt = {case['dt']:g}"


def fitted_rate(x, errors) -> float:
    """Slope of log(error) against log(x), least squares; nan with fewer than 2 points."""
    x, errors = np.asarray(x, float), np.asarray(errors, float)
    if len(x) < 2:
        return float("nan")
    with warnings.catch_warnings():  # a flat series (error floor) is a result, not a fault
        warnings.simplefilter("ignore")  # numpy 1.24: RankWarning has no stable home
        return float(np.polyfit(np.log(x), np.log(errors), 1)[0])


def convergence_tables(rows: list[dict]) -> tuple[str, bool]:
    """GetFEM's error tables (diagonal, along h, along dt) and whether the diagonal rate holds."""
    lines, ok = [], True
    for degree in sorted({r["degree"] for r in rows if r["code"] == "GetFEM"}):
        mine = [
            r
            for r in rows
            if r["code"] == "GetFEM" and r["degree"] == degree and not r.get("between")
        ]
        ns, dts = sorted({r["n"] for r in mine}), sorted({r["dt"] for r in mine}, reverse=True)
        at = {(r["n"], r["dt"]): r for r in mine}
        series = {
            "diagonal (h, dt halved together)": [
                at[p] for p in zip(ns, dts, strict=False) if p in at
            ],
            f"along h (dt = {dts[-1]:g})": [at[(n, dts[-1])] for n in ns],
            f"along dt (h = 1/{ns[-1]})": [at[(ns[-1], dt)] for dt in dts],
        }
        for name, picked in series.items():
            rate_h = fitted_rate([r["h"] for r in picked], [r["h1_rel"] for r in picked])
            rate_dt = fitted_rate([r["dt"] for r in picked], [r["h1_rel"] for r in picked])
            rate = rate_dt if name.startswith("along dt") else rate_h
            lines.append(f"\nGetFEM P{degree}, {name}: H1 rate {rate:.2f}")
            lines.append("| h | dt | DOFs | L2 rel | H1 rel |\n|---|---|---|---|---|")
            lines += [
                f"| 1/{r['n']} | {r['dt']:g} | {r['dofs']} | {r['l2_rel']:.3e} | "
                f"{r['h1_rel']:.3e} |"
                for r in picked
            ]
            if name.startswith("diagonal"):
                expected = min(degree, 2)  # H1: h^degree; Newmark gamma = 1/2: dt^2
                ok = ok and rate >= RATE_FLOOR * expected
    return "\n".join(lines), ok


def cheapest(rows: list[dict], code: str, target: float) -> dict | None:
    """The measured case of ``code`` with the smallest median time at or below ``target``."""
    hits = [r for r in rows if r["code"] == code and r["h1_rel"] <= target]
    return min(hits, key=lambda r: r["median_s"]) if hits else None


def target_rows(rows: list[dict]) -> list[dict]:
    """Per target: the cheapest case of each code and the ratio parefg / GetFEM."""
    table = []
    for target in TARGETS:
        best = {code: cheapest(rows, code, target) for code in ("GetFEM", "parefg")}
        ratio = float("nan")
        if best["GetFEM"] and best["parefg"]:
            ratio = best["parefg"]["median_s"] / best["GetFEM"]["median_s"]
        row = {"target_h1": target, "ratio_parefg_over_getfem": ratio}
        for code, r in best.items():
            row[f"{code}_case"] = label(r) if r else "not reached"
            row[f"{code}_s"] = r["median_s"] if r else float("nan")
            row[f"{code}_h1"] = r["h1_rel"] if r else float("nan")
        table.append(row)
    return table


def markdown(rows: list[dict], targets: list[dict]) -> str:
    header = (
        "| code | h | dt | DOFs | steps | Newton | L2 rel | H1 rel | median [s] | min..max [s] |"
    )
    lines = [header, "|---" * 10 + "|"]
    for r in rows:
        kind = f"P{r['degree']}" if r["code"] == "GetFEM" else f"m = {r['degree']}"
        lines.append(
            f"| {r['code']} {kind} | 1/{r['n']} | {r['dt']:g} | {r['dofs']} | {r['steps']} | "
            f"{r['newton']} | {r['l2_rel']:.2e} | {r['h1_rel']:.2e} | {r['median_s']:.3f} | "
            f"{r['min_s']:.2f}..{r['max_s']:.2f} |"
        )
    lines += ["", "| target H1 rel | GetFEM, cheapest case | parefg, cheapest case | ratio |",
              "|---|---|---|---|"]  # fmt: skip
    for t in targets:
        cells = [
            f"{t[f'{c}_s']:.3f} s ({t[f'{c}_case'].removeprefix(c + ' ')}, H1 {t[f'{c}_h1']:.2e})"
            if t[f"{c}_case"] != "not reached"
            else "not reached"
            for c in ("GetFEM", "parefg")
        ]
        ratio = t["ratio_parefg_over_getfem"]
        shown = f"{ratio:.2f}x" if np.isfinite(ratio) else "-"
        lines.append(f"| {t['target_h1']:g} | {cells[0]} | {cells[1]} | {shown} |")
    return "\n".join(lines)


def per_discretization(rows: list[dict]) -> str:
    """Markdown: per target, the cheapest case of each code and degree (P2 alone, m = 3 alone)."""
    kinds = sorted({(r["code"], r["degree"]) for r in rows})
    names = [f"{c} {'P' if c == 'GetFEM' else 'm = '}{d}" for c, d in kinds]
    lines = ["| target H1 rel | " + " | ".join(names) + " |", "|---" * (len(kinds) + 1) + "|"]
    for target in TARGETS:
        cells = []
        for code, degree in kinds:
            mine = [r for r in rows if r["code"] == code and r["degree"] == degree]
            best = cheapest(mine, code, target)
            cells.append(
                f"{best['median_s']:.2f} s (1/{best['n']}, {best['dt']:g})"
                if best
                else "not reached"
            )
        lines.append(f"| {target:g} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def write_csv(path: Path, rows: list[dict]) -> None:
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def plot(path: Path, rows: list[dict]) -> None:
    """H1 error against median time, one marker series per code and degree."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 5))
    styles = {"GetFEM": "s", "parefg": "o"}
    for code, degree in sorted({(r["code"], r["degree"]) for r in rows}):
        mine = [r for r in rows if r["code"] == code and r["degree"] == degree]
        kind = f"P{degree}" if code == "GetFEM" else f"m = {degree}"
        ax.loglog([r["median_s"] for r in mine], [r["h1_rel"] for r in mine], styles[code],
                  label=f"{code} {kind}", alpha=0.8)  # fmt: skip
    for code, color in (("GetFEM", "tab:orange"), ("parefg", "tab:red")):
        # the code's front: the smallest error reached within each time
        mine = sorted((r["median_s"], r["h1_rel"]) for r in rows if r["code"] == code)
        front = np.minimum.accumulate([e for _, e in mine])
        ax.step([t for t, _ in mine], front, where="post", color=color, lw=1, label=f"{code} front")
    for target in TARGETS:
        ax.axhline(target, color="grey", lw=0.5, ls="--")
    ax.set_xlabel("wall time, median [s] (1 process)")
    ax.set_ylabel("relative H1 error at T")
    ax.set_title("square scene: parefg and GetFEM, same machine, same run")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def read_rows(path: Path) -> list[dict]:
    """The rows of a side_by_side.csv, numbers as numbers."""
    with open(path, newline="") as handle:
        rows = list(csv.DictReader(handle))
    integers = ("degree", "n", "dofs", "steps", "newton", "between")
    return [
        {k: v if k == "code" else int(v) if k in integers else float(v) for k, v in row.items()}
        for row in rows
    ]


def report(rows: list[dict], out: Path) -> bool:
    """Print the tables, write the CSVs and the figure; True when GetFEM's rates hold."""
    tables, verified = convergence_tables(rows)
    targets = target_rows(rows)
    print(tables)
    print("\n" + markdown(rows, targets))
    print(
        "\nper discretization, cheapest case (h, dt) at each target:\n" + per_discretization(rows)
    )
    out.mkdir(parents=True, exist_ok=True)
    write_csv(out / "side_by_side.csv", rows)
    write_csv(out / "targets.csv", targets)
    plot(out / "time_vs_error.png", rows)
    print(f"\nwrote {out}/side_by_side.csv, targets.csv, time_vs_error.png")
    if not verified:
        print("getfem_side_by_side: GetFEM's diagonal H1 rate is below the expected order")
    return verified


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3, help="runs per median (default 3)")
    parser.add_argument("--out", default="results/getfem_side_by_side", help="output directory")
    parser.add_argument("--quick", action="store_true", help="a small grid, for development")
    parser.add_argument(
        "--tables-from", metavar="CSV", help="no runs: the tables and figure of a side_by_side.csv"
    )
    args = parser.parse_args(argv)
    if args.tables_from:
        return 0 if report(read_rows(Path(args.tables_from)), Path(args.out)) else 1
    try:
        import getfem
        import getfem_square
    except ImportError as exc:
        print(f"getfem_side_by_side: GetFEM is not available ({exc}); install python3-getfem")
        return 0
    getfem.util_trace_level(0)
    runner = Runner(getfem_square)
    grid = cases(QUICK_GRIDS) if args.quick else cases(GRIDS, BETWEEN)
    print("warm-up (first gmsh, PETSc, MUMPS use; not measured)")
    measure(runner, [grid[0], next(c for c in grid if c["code"] == "parefg")], 1)
    threads = os.environ["OMP_NUM_THREADS"]
    print(f"{len(grid)} cases, median of {args.repeats}, OMP_NUM_THREADS={threads}")
    rows = measure(runner, grid, args.repeats)
    return 0 if report(rows, Path(args.out)) else 1


if __name__ == "__main__":
    sys.exit(main())
