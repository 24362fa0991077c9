"""Hertz line contact of a half-disk on a rigid plane: parefg against the closed form.

The scene of :mod:`parefg.scene.hertz` (R = 1, E = 1, nu = 0.3, one static step pushing
the clamped top down by delta, frictionless penalty contact).  For each (h, alpha factor,
delta) of the grid given on the command line it solves in-process and prints the
contact resultant P (and its equilibrium checks), the Hertz half-width a and peak
pressure p0 of that P, and the measured ones with their relative errors:

* ``a_mom``: 2 sqrt(int p x^2 / int p), the half-width of an elliptic pressure with the
  measured second moment;
* ``a_fit``, ``p0_fit``: least-squares fit of p0 sqrt(1 - x^2/a^2) to the point pressures;
* ``p_max``: the largest point pressure; ``a_edge``: the outermost closed point.

The errors are given twice: against Hertz's closed form, and against Hertz's solution of
the condition parefg imposes (u . nu <= s with the body's normal nu, not the plane's:
to first order in p0 / E, :func:`parefg.scene.hertz.normal_projection_half_width`),
which differ by -1.8 % in a at nu = 0.3, a / R = 0.1.

Rows go to a CSV.  Collective (runs under mpirun -n P).

Usage::

    .venv/bin/python scripts/verify/hertz_study.py --h 0.2,0.1,0.05 --alpha 10 \\
        --delta 0.015 --out results/hertz.csv
    .venv/bin/python scripts/verify/hertz_study.py --h 0.1 --alpha 1,10,100,penalty,nitsche
    .venv/bin/python scripts/verify/hertz_study.py --h 0.1 --alpha penalty --chord-gap
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import itertools
import tempfile
import time
from pathlib import Path

from mpi4py import MPI

from parefg.discretization.budget import check_problem_size
from parefg.discretization.dirichlet import CONTACT_METHODS
from parefg.discretization.operators import build_discretization
from parefg.run import build_simulation
from parefg.scene.hertz import ARC_GAP, CHORD_GAP, hertz_scene, measure
from parefg.scene.loader import load_scene


def solve(
    comm,
    h: float,
    contact: float | str,
    delta: float,
    degree: int,
    nu: float,
    gap: str,
    max_memory: float,
) -> dict:
    """One static Hertz solve and its measures.  Collective."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "hertz.toml"
        if comm.rank == 0:
            path.write_text(hertz_scene(h, delta, contact, degree, nu, gap))
        comm.Barrier()
        start = time.perf_counter()
        scene = load_scene(str(path), [])
        # An explicit budget: with the machine's, the floor gmsh clamps the .geo's sizes to
        # (Budget.size_floor: the bounding box filled at the finest size) follows the memory
        # available at run time and the ranks per machine, and the mesh with it: 0.0047 at
        # 22 GB available, 0.0055 at ~17 GB, around h/10 at h = 0.05 (measured: one run of
        # that h got 3280 nodes instead of 3774 while other jobs held memory); 0.0105 at 4 GB.
        budget = check_problem_size(comm, scene, max_memory)
        sim = build_simulation(comm, scene, build_discretization(comm, scene, budget))
        state = sim.step(sim.start(), 1)
        result = dataclasses.asdict(measure(sim, state.u))
        comm.Barrier()  # every rank has read the scene before rank 0 removes it
    result.update(
        h=h,
        alpha_factor=contact,
        alpha_contact=sim.scene.penalty.alpha_contact,
        delta=delta,
        degree=degree,
        nu=nu,
        n_nodes=sim.disc.n_nodes,
        size_floor=budget.size_floor(2.0, 6.0),
        seconds=time.perf_counter() - start,
    )
    return result


def relative(value: float, reference: float) -> float:
    return value / reference - 1.0


def print_table(rows: list[dict]) -> None:
    header = (
        f"{'nu':>4} {'h':>6} {'alpha':>7} {'delta':>6} {'nodes':>6} {'P':>10} {'dP_stress':>9} "
        f"{'Px/P':>8} {'a_H':>7} {'a_mom':>8} {'a_fit':>8} {'a_edge':>8} {'p0_H':>7} "
        f"{'p0_fit':>8} {'p_max':>8} | {'a_mom':>7} {'a_fit':>7} {'p0_fit':>7} {'s':>5}"
    )
    print(header)
    for r in rows:
        print(
            f"{r['nu']:4.2f} {r['h']:6.3f} {str(r['alpha_factor']):>7} {r['delta']:6.3f} "
            f"{r['n_nodes']:6d} "
            f"{r['load']:10.4e} {relative(r['load_stress'], r['load']):+9.2e} "
            f"{r['load_x'] / r['load']:+8.1e} {r['a_hertz']:7.4f} "
            f"{relative(r['a_moment'], r['a_hertz']):+8.2%} "
            f"{relative(r['a_fit'], r['a_hertz']):+8.2%} "
            f"{relative(r['a_edge'], r['a_hertz']):+8.2%} {r['p0_hertz']:7.4f} "
            f"{relative(r['p0_fit'], r['p0_hertz']):+8.2%} "
            f"{relative(r['p_max'], r['p0_hertz']):+8.2%} | "
            f"{relative(r['a_moment'], r['a_normal']):+7.2%} "
            f"{relative(r['a_fit'], r['a_normal']):+7.2%} "
            f"{relative(r['p0_fit'], r['p0_normal']):+7.2%} {r['seconds']:5.1f}"
        )
    print(
        "errors relative to Hertz's closed form at the measured P; after |: relative to "
        "Hertz with the body's normal\n(parefg.scene.hertz.normal_projection_half_width); "
        "dP_stress: stress resultant / P - 1; Px: horizontal resultant"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--h", default="0.2,0.1,0.05", help="scene spacings (contact: h/10)")
    parser.add_argument(
        "--alpha",
        default="10",
        help="penalty alpha_contact x E / (h/10), 'penalty' (its default 1e4 E/h) or 'nitsche'",
    )
    parser.add_argument("--delta", default="0.015", help="top displacements")
    parser.add_argument("--degree", default="2")
    parser.add_argument("--nu", default="0.3", help="Poisson ratios")
    parser.add_argument(
        "--chord-gap",
        action="store_true",
        help="measure the gap from the boundary segments' chords instead of the arc",
    )
    parser.add_argument(
        "--max-memory",
        type=float,
        default=64.0,
        help="GB the budget assumes (sets the mesh-size floor, not the memory used: "
        "0.8 GB at h = 0.05)",
    )
    parser.add_argument("--out", default=None, help="CSV file")
    args = parser.parse_args()
    comm = MPI.COMM_WORLD
    gap = CHORD_GAP if args.chord_gap else ARC_GAP
    grid = itertools.product(
        [float(v) for v in args.nu.split(",")],
        [float(v) for v in args.degree.split(",")],
        [float(v) for v in args.delta.split(",")],
        [v if v in CONTACT_METHODS else float(v) for v in args.alpha.split(",")],
        [float(v) for v in args.h.split(",")],
    )
    rows = [
        solve(comm, h, alpha, delta, int(degree), nu, gap, args.max_memory)
        for nu, degree, delta, alpha, h in grid
    ]
    if comm.rank != 0:
        return
    print_table(rows)
    if args.out:
        out = Path(args.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        with out.open("w", newline="") as stream:
            writer = csv.DictWriter(stream, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
        print(f"wrote {out}")


if __name__ == "__main__":
    main()
