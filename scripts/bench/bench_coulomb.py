"""Coulomb friction: the fixed point on Tresca bounds against semismooth Newton (1 rank).

Prints (and writes to ``--csv``) one row per case: Newton iterations, outer (bound)
iterations, factorizations, the largest count per step, the solve time and the errors,
for

* ``fp``: parefg's solver (timestepping/coulomb.py: convex Tresca steps with frozen bounds
  g^(k) = mu_f p(u^(k)), iterated until the Coulomb residual meets the step tolerance);
* ``ssn``: a prototype semismooth Newton on the nonsymmetric Coulomb system
  F(u) = A u - b + B_nu^T W p + B_tau^T W clip(alpha_T z, -mu_f p, mu_f p), with the
  generalized Jacobian (slipping points add mu_f alpha_C sign(z) B_tau^T W B_nu), scipy's
  sparse LU and backtracking on |F| (no energy exists for the exact line search), to the
  same step tolerance.

Scenes: the sliding block and the manufactured solution of parefg.scene.library (those of
tests/mechanics/test_coulomb.py), and a
sweep of the friction coefficient on the block (where the fixed point stops contracting).

    python scripts/bench/bench_coulomb.py [--csv coulomb.csv] [--quick]
"""

import argparse
import csv
import pathlib
import tempfile
import time

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from mpi4py import MPI

from parefg.errors import SolverError
from parefg.mechanics.contact_frame import _scipy_from_petsc
from parefg.run import prepare
from parefg.scene.library import COULOMB_MMS, COULOMB_SLIDE
from parefg.timestepping.simulation import Simulation

COMM = MPI.COMM_SELF


class SemismoothNewton:
    """Prototype step solver with the interface of ContactStepSolver (1 rank only)."""

    def __init__(self, sim: Simulation, max_it: int = 100):
        self.law, self.max_it = sim.law, max_it
        self.a_const = _scipy_from_petsc(sim.a_const).tocsc()
        self.factorizations = self.jacobian_builds = 0
        self.outer_iterations = 1
        self.tolerance = self.residual_norm = float("nan")

    def _residual(self, u, b):
        law = self.law
        un, ut = law.normal_op @ u, law.tangent_op @ u
        pressure = law.pressure(un)
        law.bound = np.where(law.coulomb, law.coefficient * pressure, law.bound)
        z = law.alpha_t * (ut - law.slip)
        friction = np.clip(z, -law.bound, law.bound)
        w = law.weights
        r = self.a_const @ u - b + law.normal_op.T @ (w * pressure)
        return r + law.tangent_op.T @ (w * friction), un, z

    def _jacobian(self, un, z):
        law, w = self.law, self.law.weights
        closed = un > law.gap
        stick = np.abs(z) < law.bound
        slip_coupling = w * np.sign(z) * law.coefficient * law.alpha_c * (closed & ~stick)
        jac = self.a_const + law.normal_op.T @ sp.diags(w * law.alpha_c * closed) @ law.normal_op
        jac = jac + law.tangent_op.T @ sp.diags(w * law.alpha_t * stick) @ law.tangent_op
        return (jac + law.tangent_op.T @ sp.diags(slip_coupling) @ law.normal_op).tocsc()

    def solve(self, b_vec, u_vec, t):
        b, u = b_vec.getArray().copy(), u_vec.getArray().copy()
        self.tolerance = 1e-10 * max(np.linalg.norm(b), np.linalg.norm(self.a_const @ u))
        r, un, z = self._residual(u, b)
        norm, it = np.linalg.norm(r), 0
        while norm > self.tolerance:
            if it >= self.max_it or not np.isfinite(norm):
                raise SolverError(f"semismooth Newton failed at t = {t:.6g}: |F| = {norm:.3g}")
            direction = -spla.spsolve(self._jacobian(un, z), r)
            self.factorizations += 1
            step = 1.0
            for _ in range(30):  # backtracking on |F|
                trial = self._residual(u + step * direction, b)
                if np.linalg.norm(trial[0]) <= (1 - 1e-4 * step) * norm:
                    break
                step *= 0.5
            u = u + step * direction
            r, un, z = trial
            norm, it = np.linalg.norm(r), it + 1
        u_vec.setArray(u)
        self.residual_norm = norm
        return it, it


def run(source: str, overrides: list[str], solver: str) -> dict:
    sim = prepare(COMM, source, overrides)
    scene = sim.scene
    if solver == "ssn":
        sim.solver = SemismoothNewton(sim)
    state, start, status = sim.start(), time.perf_counter(), "ok"
    try:
        for n in range(1, scene.time.n_steps + 1):
            state = sim.step(state, n)
    except SolverError as error:
        status = f"failed at step {n}: {str(error)[:80]}"
    errors = sim.errors(state.u, scene.time.T) if scene.exact and status == "ok" else {}
    return {
        "newton": sim.newton_iterations,
        "outer": sim.coulomb_iterations if solver == "fp" else "-",
        "factorizations": sim.solver.factorizations,
        "max_newton_per_step": sim.max_newton_per_step,
        "max_outer_per_step": sim.max_coulomb_per_step if solver == "fp" else "-",
        "solve_s": round(time.perf_counter() - start, 2),
        "h1_rel": f"{errors['h1_rel']:.4e}" if errors else "-",
        "status": status,
    }


def cases(quick: bool) -> list[tuple[str, str, list[str]]]:
    block = ["time.T=0.8"] if quick else []
    stiff = ["time.T=0.5", "discretization.h=0.0625", "time.dt=0.01"]
    stiff += ["boundary.bottom.method=penalty", "penalty.alpha_contact=1.6e8"]
    rows = [
        ("mms h=1/16", "mms", ["discretization.h=0.0625"]),
        ("slide (through the stop)", "slide", block),
        ("slide, alpha_C = 1e4 E/h, h = 1/16", "slide", stiff),
    ]
    for mu in (0.1, 0.5, 1.0, 2.0):
        rows.append(
            (f"slide mu_f = {mu}", "slide", [*block, f"boundary.bottom.friction_coefficient={mu}"])
        )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--csv", default=None)
    parser.add_argument("--quick", action="store_true", help="shorter block runs")
    args = parser.parse_args()
    directory = pathlib.Path(tempfile.mkdtemp(prefix="bench_coulomb_"))
    sources = {"mms": directory / "mms.toml", "slide": directory / "slide.toml"}
    sources["mms"].write_text(COULOMB_MMS)
    sources["slide"].write_text(COULOMB_SLIDE)
    table = []
    for label, key, overrides in cases(args.quick):
        for solver in ("fp", "ssn"):
            row = {"case": label, "solver": solver, **run(str(sources[key]), overrides, solver)}
            table.append(row)
            print(" | ".join(str(v) for v in row.values()), flush=True)
    if args.csv:
        with open(args.csv, "w", newline="") as file:
            writer = csv.DictWriter(file, fieldnames=list(table[0]))
            writer.writeheader()
            writer.writerows(table)


if __name__ == "__main__":
    main()
