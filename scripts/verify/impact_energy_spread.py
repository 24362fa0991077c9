"""How much the generalized-alpha impact's energy band depends on the last bits.

Runs the impact scene (generalized-alpha, rho_inf 0.8, alpha_contact 1e7, as in
tests/verification/test_impact_energy.py) with the initial velocity perturbed by ``eps``
relative, and prints per run min and max of E / E_0, the min over the first rebound
(t <= 0.2) and the first step where E / E_0 leaves the unperturbed run by 1e-12 and by
1e-3; then mean, std and range of the min.  Writes CSV.  Runs on any number of ranks
(the rank count is a perturbation of its own: another summation order).

    python scripts/verify/impact_energy_spread.py --csv spread.csv
    mpirun -n 2 python scripts/verify/impact_energy_spread.py --eps=0,1e-15,-1e-15
"""

import argparse
import csv

import numpy as np
from mpi4py import MPI

from parefg.discretization.operators import build_discretization
from parefg.scene.loader import load_scene
from parefg.timestepping.loop import time_loop
from parefg.timestepping.simulation import Simulation

COLUMNS = ("kinetic_energy", "elastic_energy", "penalty_energy", "dissipated_energy")
EPS = (
    0.0,
    1e-15,
    -1e-15,
    2e-15,
    3e-15,
    -3e-15,
    5e-15,
    -5e-15,
    1e-14,
    -1e-14,
    3e-14,
    -3e-14,
    1e-13,
    -1e-13,
)


def energy_ratio(comm, eps: float) -> tuple[np.ndarray, float]:
    """E / E_0 per step of the impact run with v_0 scaled by (1 + eps, 1 - eps); and dt."""
    vx, vy = 0.5 * (1 + eps), -1.0 * (1 - eps)
    overrides = ["time.scheme=generalized-alpha", "boundary.bottom.method=penalty"]
    overrides += ["penalty.alpha_contact=1e7"]
    scene = load_scene("impact", [*overrides, f"initial.v=[{vx!r}, {vy!r}]"])
    sim = Simulation(comm, scene, build_discretization(comm, scene))
    state = sim.start()
    state = time_loop(sim, state, 1)
    energy = np.array([sum(r[c] for c in COLUMNS) - r["external_work"] for r in sim.history])
    return energy / energy[0], scene.time.dt


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--eps", default=",".join(map(str, EPS)), help="comma-separated")
    parser.add_argument("--csv", default="impact_energy_spread.csv")
    args = parser.parse_args()
    comm = MPI.COMM_WORLD
    reference, dt = energy_ratio(comm, 0.0)
    rows = []
    for eps in [float(text) for text in args.eps.split(",")]:
        ratio = reference if eps == 0.0 else energy_ratio(comm, eps)[0]
        gap = np.abs(ratio - reference)
        first = [int(np.argmax(gap > tol)) if (gap > tol).any() else -1 for tol in (1e-12, 1e-3)]
        early = ratio[: round(0.2 / dt) + 1].min()
        rows.append((comm.size, eps, ratio.min(), ratio.max(), early, *first))
    if comm.rank != 0:
        return
    header = ("ranks", "eps", "min", "max", "min_t<=0.2", "step_1e-12", "step_1e-3")
    print("| " + " | ".join(header) + " |")
    for row in rows:
        print(
            f"| {row[0]} | {row[1]:+.0e} | {row[2]:.6f} | {row[3]:.6f} | {row[4]:.6f} "
            f"| {row[5]} | {row[6]} |"
        )
    mins = np.array([row[2] for row in rows])
    print(
        f"min E/E_0: mean {mins.mean():.5f}, std {mins.std():.5f}, "
        f"range {mins.min():.5f} .. {mins.max():.5f}"
    )
    with open(args.csv, "w", newline="") as out:
        writer = csv.writer(out)
        writer.writerow(header)
        writer.writerows(rows)


if __name__ == "__main__":
    main()
