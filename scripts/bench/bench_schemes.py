"""Time schemes: generalized-alpha against Newmark, and the consistent start (issue 11, item 2).

Three tables (printed, and written as CSV to --out):

1. at_rest.csv -- time-independent exact solutions with u0 != 0 (clamped; pressed on the
   obstacle) at alpha = 1e2 and 1e4 E/h: the largest kinetic energy over the run relative
   to the elastic energy, max |a| (nodal parameters), and the H1 error against that of the
   static solution (the discrete equilibrium).
2. rates.csv -- L2 error at T = 1 of the square and z scenes (sliding contact) against
   dt = 0.1, 0.05, 0.025 for Newmark and generalized-alpha, with the fitted rate.
3. impact.csv -- the impact scene: E_end / E_0 (stored energy + dissipation) per scheme at
   alpha_contact = 1e3 and the default 1e4 E/h.

Usage: ``python scripts/bench/bench_schemes.py [--out DIR] [--quick]``.  Serial; minutes.
"""

from pathlib import Path

import numpy as np
from benchlib import parser, write_csv
from mpi4py import MPI

from parefg.run import prepare
from parefg.scene.library import AT_REST, AT_REST_ON_OBSTACLE
from parefg.timestepping.simulation import Simulation

COMM = MPI.COMM_WORLD
GA = "time.scheme=generalized-alpha"
SCHEMES = {
    "newmark 1/2": ["time.beta=0.5"],
    "newmark 1/4": ["time.beta=0.25"],
    "gen-alpha 1": [GA, "time.rho_inf=1"],
    "gen-alpha 0.8": [GA, "time.rho_inf=0.8"],
    "gen-alpha 0.5": [GA, "time.rho_inf=0.5"],
    "gen-alpha 0": [GA, "time.rho_inf=0"],
}
AT_REST_CASES = {"clamped": AT_REST, "on-obstacle": AT_REST_ON_OBSTACLE}


def run(source: str, overrides) -> tuple[Simulation, object, float]:
    """Run to T; return the simulation, the final state and max |a| over the run."""
    sim = prepare(COMM, source, overrides)
    state = sim.start()
    largest = state.a.norm(3)
    for n in range(1, sim.scene.time.n_steps + 1):
        state = sim.step(state, n)
        largest = max(largest, state.a.norm(3))
    return sim, state, largest


def at_rest_table(directory: str) -> list[dict]:
    rows = []
    for case, text in AT_REST_CASES.items():
        path = f"{directory}/at_rest_{case}.toml"
        Path(path).write_text(text)
        for factor in (1e2, 1e4):
            penalty = f"penalty.alpha={factor / 0.125}"
            static, final, _ = run(path, ['time.scheme="static"', penalty])
            reference = static.errors(final.u, 0.5)["h1_rel"]
            for name in ("newmark 1/2", "newmark 1/4", "gen-alpha 0.8", "gen-alpha 0"):
                sim, state, largest = run(path, [*SCHEMES[name], penalty])
                kinetic = max(row["kinetic_energy"] for row in sim.history)
                elastic = sim.history[-1]["elastic_energy"]
                rows.append(
                    {
                        "case": case,
                        "alpha_h_over_E": factor,
                        "scheme": name,
                        "max_kinetic_over_elastic": kinetic / elastic,
                        "max_abs_a": largest,
                        "h1": sim.errors(state.u, 0.5)["h1_rel"],
                        "h1_static": reference,
                    }
                )
    return rows


def rates_table(quick: bool) -> list[dict]:
    rows = []
    steps = [0.1, 0.05, 0.025]
    names = ["newmark 1/2", "gen-alpha 0.8"] if quick else list(SCHEMES)
    for scene in ("square", "z"):
        for name in names:
            l2 = []
            for dt in steps:
                sim, state, _ = run(scene, [*SCHEMES[name], f"time.dt={dt}"])
                l2.append(sim.errors(state.u, 1.0)["l2_rel"])
            rate = float(np.polyfit(np.log(steps), np.log(l2), 1)[0])
            rows.append(
                {
                    "scene": scene,
                    "scheme": name,
                    **{f"l2_dt{dt}": e for dt, e in zip(steps, l2, strict=True)},
                    "rate": rate,
                }
            )
    return rows


def impact_table(quick: bool) -> list[dict]:
    rows = []
    names = ["newmark 1/2", "gen-alpha 0.8"] if quick else list(SCHEMES)
    for alpha in (1e3, 1e5):
        for name in names:
            pinned = ["boundary.bottom.method=penalty", f"penalty.alpha_contact={alpha}"]
            sim, _, largest = run("impact", [*SCHEMES[name], *pinned])
            first, last = sim.history[0], sim.history[-1]
            stored = ("kinetic_energy", "elastic_energy", "penalty_energy", "dissipated_energy")
            ratio = sum(last[k] for k in stored) / sum(first[k] for k in stored)
            rows.append(
                {
                    "alpha_contact": alpha,
                    "scheme": name,
                    "E_end_over_E0": ratio,
                    "max_abs_a": largest,
                }
            )
    return rows


def show(title: str, rows: list[dict]) -> None:
    print(f"\n{title}")
    keys = list(rows[0])
    print(" | ".join(keys))
    for row in rows:
        cells = [f"{v:.3g}" if isinstance(v, float) else str(v) for v in row.values()]
        print(" | ".join(cells))


def main() -> None:
    options = parser(__doc__, 1)
    options.add_argument("--quick", action="store_true", help="two schemes only")
    args = options.parse_args()
    Path(args.out).mkdir(parents=True, exist_ok=True)
    for title, name, rows in (
        ("time-independent u0 != 0", "at_rest.csv", at_rest_table(args.out)),
        ("L2 error at T = 1 (m = 2, h = 1/16)", "rates.csv", rates_table(args.quick)),
        ("impact energy", "impact.csv", impact_table(args.quick)),
    ):
        show(title, rows)
        write_csv(args.out, name, rows)


if __name__ == "__main__":
    main()
