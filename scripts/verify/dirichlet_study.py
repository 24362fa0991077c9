"""Static manufactured solution: Dirichlet penalty vs Nitsche, quadrature, support (issue 12).

The scene of tests/verification/test_static_convergence.py (u_1 = sin(x) e^y / 2,
u_2 = cos(x + y) / 3, Dirichlet on top and left of the square, top and bottom of the Z,
Neumann elsewhere), one static step per case.  Each line of the grid is

    shape, degree, method, h, safety or alpha (x E/h), quadrature, support

and every combination given on the command line is run (``--h 0.125,0.0625``); the
rows go to a CSV, and the rates fitted in h (``parefg.sweep.fitted_rate``) of each group
are printed.  Collective (runs under mpirun -n P).

Usage::

    .venv/bin/python scripts/verify/dirichlet_study.py --shape square,z --degree 1,2,3 \\
        --method penalty,nitsche --h 0.125,0.0625,0.03125 --out results/dirichlet.csv
    .venv/bin/python scripts/verify/dirichlet_study.py --shape square --degree 2 \\
        --safety 2,20,200,2000,20000 --h 0.0625 --out results/safety.csv
"""

from __future__ import annotations

import argparse
import csv
import itertools
import tempfile
import time
from pathlib import Path

from mpi4py import MPI

from parefg.run import prepare
from parefg.sweep import fitted_rate

EXACT_U = '["sin(x) * exp(y) / 2", "cos(x + y) / 3"]'
BOUNDARIES = {
    "square": {"top": "dirichlet", "left": "dirichlet", "bottom": "neumann", "right": "neumann"},
    "z": {"top": "dirichlet", "bottom": "dirichlet", "sides": "neumann"},
}
# The unit square as a user polygon: the same problem on unstructured background cells.
BOUNDARIES["polygon"] = BOUNDARIES["square"]
POLYGON = (
    "vertices = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]\n"
    'edge_names = ["bottom", "right", "top", "left"]\n'
)


def scene_text(shape: str) -> str:
    boundary = "".join(
        f'[boundary.{name}]\ntype = "{kind}"\n\n' for name, kind in BOUNDARIES[shape].items()
    )
    return (
        f'[domain]\nshape = "{shape}"\n{POLYGON if shape == "polygon" else ""}\n'
        "[material]\nE = 1.0\nnu = 0.3\n\n"
        '[time]\nscheme = "static"\nT = 1.0\ndt = 1.0\n\n'
        f"{boundary}[exact]\nu = {EXACT_U}\n"
    )


def overrides(shape, degree, method, h, parameter, quadrature, support, integration) -> list[str]:
    """The --set strings of one case (parameter: Nitsche's safety or alpha_D h / E)."""
    sets = [f"discretization.h={h}", f"discretization.degree={degree}"]
    if integration is not None:
        sets.append(f'discretization.integration="{integration}"')
    for name, kind in BOUNDARIES[shape].items():
        if kind == "dirichlet":
            sets.append(f"boundary.{name}.method={method}")
            if method == "nitsche" and parameter is not None:
                sets.append(f"boundary.{name}.safety={parameter}")
    if method == "penalty" and parameter is not None:
        sets.append(f"penalty.alpha_dirichlet={parameter / h}")
    if quadrature is not None:
        sets.append(f"discretization.quadrature={quadrature}")
    if support is not None:
        sets.append(f"discretization.support={support}")
    return sets


def run_case(comm, path: str, sets: list[str]) -> dict:
    """Errors and wall time of one static solve (build + solve).  Collective."""
    comm.Barrier()
    tic = time.perf_counter()
    simulation = prepare(comm, path, sets)
    state = simulation.step(simulation.start(), 1)
    errors = simulation.errors(state.u, simulation.scene.time.T)
    elapsed = comm.allreduce(time.perf_counter() - tic, op=MPI.MAX)
    scene = simulation.scene
    return {
        "l2_rel": errors["l2_rel"],
        "h1_rel": errors["h1_rel"],
        "time": elapsed,
        "n_dofs": simulation.disc.n_dofs,
        "quadrature_used": scene.discretization.quadrature,
        "support_used": scene.discretization.support,
    }


def _values(text: str | None, convert) -> list:
    return [None] if text is None else [convert(v) for v in text.split(",")]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shape", default="square,z")
    parser.add_argument("--degree", default="1,2,3")
    parser.add_argument("--method", default="penalty,nitsche")
    parser.add_argument("--h", default="0.125,0.0625,0.03125")
    parser.add_argument("--safety", default=None, help="Nitsche safety (or alpha_D h/E)")
    parser.add_argument("--quadrature", default=None)
    parser.add_argument("--support", default=None)
    parser.add_argument("--integration", default=None, help="gauss, vci or both")
    parser.add_argument("--out", default="dirichlet_study.csv")
    args = parser.parse_args()
    comm = MPI.COMM_WORLD
    sizes = _values(args.h, float)
    grid = itertools.product(
        args.shape.split(","),
        _values(args.degree, int),
        args.method.split(","),
        _values(args.safety, float),
        _values(args.quadrature, int),
        _values(args.support, float),
        _values(args.integration, str),
    )
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for shape, degree, method, parameter, quadrature, support, integration in grid:
            path = str(Path(tmp) / f"{shape}.toml")
            Path(path).write_text(scene_text(shape))  # each rank's own temporary directory
            group = []
            for h in sizes:
                case = overrides(
                    shape, degree, method, h, parameter, quadrature, support, integration
                )
                row = {"shape": shape, "degree": degree, "method": method, "h": h}
                row["integration"] = integration or "default"
                row.update(parameter=parameter, **run_case(comm, path, case))
                group.append(row)
                if comm.rank == 0:
                    print(
                        " ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}"
                                 for k, v in row.items()),
                        flush=True,
                    )  # fmt: skip
            rows += group
            if comm.rank == 0 and len(sizes) > 1:
                l2 = fitted_rate(sizes, [r["l2_rel"] for r in group])
                h1 = fitted_rate(sizes, [r["h1_rel"] for r in group])
                label = f"{shape} m={degree} {method} {parameter} {integration}"
                print(f"  rates {label}: L2 {l2:.2f} H1 {h1:.2f}")
    if comm.rank == 0:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        with open(args.out, "w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
