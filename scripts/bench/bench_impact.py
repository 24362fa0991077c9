"""Benchmark: an elastic bar thrown at a rigid wall, against its closed-form impact.

A block L = 1 high, 0.4 wide (plane strain, nu = 0, frictionless: exactly the 1D bar),
E = rho = 1 (c = sqrt(E / rho) = 1), moves down at uniform v0 = 0.1 across the gap
s = 0.05 to the obstacle.  The rigid-wall solution (St-Venant): the bottom stops at
touch-down t0 = s / v0, a compression wave runs up and back, and the whole bar leaves the
wall at t0 + 2 L / c with its velocity reversed; meanwhile the contact pressure is
rho c v0; the energy is conserved.  Each case runs the built-in impact scene with those
overrides at h = 0.1, degree 1, for every alpha_contact (in E / h) x dt x beta (1/4, 1/2)
x [time] contact_force (discrete_gradient, and endpoint: the penalty force at the end
of the step, the scheme before).  Columns:

    E_end/E_0       (kinetic + elastic + penalty + dissipated - work) at T over t = 0
    v_rebound/exact mean velocity at T (momentum / mass) over +v0
    duration/exact  (last - first step with a closed point + dt) over 2 L / c
    p_mean/exact    time mean over the contact of the step's mean pressure (impulse / dt,
                    averaged over Gamma_C) over rho c v0
    p_peak/exact    its peak over rho c v0 (the touch-down of a stiff penalty rings)

A penalty below ~1e3 E / h is too soft to be a rigid wall (the bar sinks into it: longer
contact, lower pressure); that is the penalty model, not the time integration.

    .venv/bin/python scripts/bench/bench_impact.py [--out results/impact] [--quick]

writes impact.csv and impact_energy.png (energy history of several alpha) in --out.
"""

import argparse
import csv
import sys
from pathlib import Path

import numpy as np
import petsc4py

import parefg  # noqa: F401  (PETSC_DIR)

petsc4py.init(sys.argv[:1])
from mpi4py import MPI  # noqa: E402

from parefg.discretization.operators import build_discretization  # noqa: E402
from parefg.mechanics.discrete_gradient import dg_pressure  # noqa: E402
from parefg.scene.loader import load_scene  # noqa: E402
from parefg.timestepping.simulation import Simulation  # noqa: E402

LENGTH, WIDTH, V0, GAP, H = 1.0, 0.4, 0.1, 0.05, 0.1
T_END = GAP / V0 + 2 * LENGTH + 0.5  # half a time unit of flight after the rebound
EXACT = {"v": V0, "duration": 2 * LENGTH, "pressure": V0}  # c = 1, rho c v0 = v0
ALPHAS = (1e0, 1e3, 1e6, 1e9, 1e12)  # alpha_contact in E / h
DTS = (0.05, 0.02)
BETAS = (0.25, 0.5)
METHODS = ("discrete_gradient", "endpoint")
ENERGY = ("kinetic_energy", "elastic_energy", "penalty_energy", "dissipated_energy")


def bar_scene(alpha: float, dt: float, beta: float, method: str):
    """The impact scene turned into the nu = 0 frictionless bar (see the module docstring)."""
    return load_scene(
        "impact",
        [
            f"domain.size=[{WIDTH}, {LENGTH}]",
            f"discretization.h={H}",
            "material.nu=0.0",
            "boundary.bottom.friction=0.0",
            f"boundary.bottom.gap={GAP}",
            f"initial.v=[0.0, {-V0}]",
            f"time.T={T_END}",
            f"time.dt={dt}",
            f"time.beta={beta}",
            f"time.contact_force={method}",
            "boundary.bottom.method=penalty",  # the alpha sweep: contact defaults to Nitsche
            f"penalty.alpha_contact={alpha / H}",
        ],
    )


def run_bar(comm, alpha: float, dt: float, beta: float, method: str) -> dict:
    """One case: the table's ratios and the energy history.  Collective."""
    scene = bar_scene(alpha, dt, beta, method)
    disc = build_discretization(comm, scene)
    sim = Simulation(comm, scene, disc)
    state = sim.start()
    law, ones = sim.law, disc.create_vec()
    ones.setArray(np.tile([0.0, 1.0], ones.getLocalSize() // 2))  # e_y: MLS reproduces it
    mass_y = sim._quadratic(disc.mass, ones)
    area = comm.allreduce(float(law.weights.sum()))
    pressures, energies, closed = [], [_energy(sim.history[-1])], []
    for n in range(1, scene.time.n_steps + 1):
        state = sim.step(state, n)
        step_mean = _step_mean_pressure(law, law.kinematics(state.u)[0], method)
        pressures.append(comm.allreduce(float(np.dot(law.weights, step_mean))) / area)
        energies.append(_energy(sim.history[-1]))
        closed.append(sim.history[-1]["active_contact_points"] > 0)
    disc.mass.mult(state.v, sim._product)
    velocity = sim._product.dot(ones) / mass_y  # mean v_y at T (up: the rebound)
    steps = np.flatnonzero(closed)
    duration = (steps[-1] - steps[0] + 1) * dt if len(steps) else 0.0
    return {
        "alpha_E_per_h": alpha,
        "dt": dt,
        "beta": beta,
        "method": method,
        "E_end/E_0": energies[-1] / energies[0],
        "E_max/E_0": max(energies) / energies[0],
        "v_rebound/exact": velocity / EXACT["v"],
        "duration/exact": duration / EXACT["duration"],
        "p_mean/exact": np.sum(pressures) * dt / max(duration, dt) / V0,
        "p_peak/exact": max(pressures) / EXACT["pressure"],
        "history": np.array(energies) / energies[0],
    }


def _step_mean_pressure(law, un, method: str) -> np.ndarray:
    """The pressure the step applied on average, at the points: impulse / dt.

    (p(d_{n-1}) + C_n)/2 with C_n the step's force: the discrete gradient DG(d_{n-1}, d_n)
    or the endpoint's trapezoidal mean.  (The pressure alpha d_n^+ at the time levels is
    not the force the wall applies when the stiff penalty mode is not resolved in time.)
    """
    d0, d1, alpha = law.start_penetration, un - law.gap, law.alpha_c
    end = dg_pressure(d0, d1, alpha) if method == "discrete_gradient" else alpha * np.maximum(d1, 0)
    return 0.5 * (alpha * np.maximum(d0, 0.0) + end)


def _energy(row: dict) -> float:
    return sum(row[name] for name in ENERGY) - row["external_work"]


def plot(results: list[dict], path: Path) -> None:
    """Energy history E(t)/E_0 for every alpha at the finest dt, beta = 1/4 and 1/2."""
    finest = min(r["dt"] for r in results)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(11, 7), sharex=True)
    panels = [((i, b), (j, m)) for i, b in enumerate(BETAS) for j, m in enumerate(METHODS)]
    for (i, beta), (j, method) in panels:
        ax = axes[i, j]
        for r in results:
            if r["beta"] == beta and r["method"] == method and r["dt"] == finest:
                t = np.arange(len(r["history"])) * r["dt"]
                ax.plot(t, r["history"], label=f"alpha = {r['alpha_E_per_h']:.0e} E/h")
        ax.set_title(f"{method}, beta = {beta}, dt = {finest}")
        low, high = ax.get_ylim()
        ax.set_ylim(min(low, 0.95), max(high, 1.05))  # the [0.95, 1.05] band at least
        ax.set_ylabel("E(t) / E_0")
        ax.grid(True, which="both", alpha=0.3)
    axes[-1, 0].set_xlabel("t")
    axes[-1, 1].set_xlabel("t")
    axes[0, 0].legend(fontsize=8)
    fig.suptitle("nu = 0 bar at a rigid wall: discrete energy through the impact")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("results/impact"))
    parser.add_argument("--quick", action="store_true", help="dt = 0.05 only")
    args = parser.parse_args()
    comm = MPI.COMM_WORLD
    dts = DTS[:1] if args.quick else DTS
    results = [
        run_bar(comm, alpha, dt, beta, method)
        for method in METHODS
        for beta in BETAS
        for dt in dts
        for alpha in ALPHAS
    ]
    columns = [k for k in results[0] if k != "history"]
    if comm.rank != 0:
        return
    args.out.mkdir(parents=True, exist_ok=True)
    with open(args.out / "impact.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=columns)
        writer.writeheader()
        writer.writerows({k: r[k] for k in columns} for r in results)
    print(" | ".join(f"{c:>17s}" for c in columns))
    for r in results:
        cells = (f"{r[c]:>17.4g}" if isinstance(r[c], float) else f"{r[c]:>17}" for c in columns)
        print(" | ".join(cells))
    plot(results, args.out / "impact_energy.png")


if __name__ == "__main__":
    main()
