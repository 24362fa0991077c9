"""Fixed (per-run, not per-step) costs of small runs, phase by phase, in a warm process.

What ``run.run_scene`` spends besides the time steps on the small square runs of the
GetFEM comparison (scripts/bench/getfem_side_by_side.py): meshing, partition, MLS and
assembly of the domain, boundary and node operators, the Nitsche trace-inverse estimate,
the simulation set-up, output, the error norms and the summary.  Each case is run in a
process that already imported everything and ran it once (numba's kernels compiled, the
mesh cache warm), with ``output.every = 0`` as in the comparison.

Tables (medians of --repeats runs per case and worker, over --rounds workers per tree):

1. Phases of a one-step run (time.T = dt), in ms: exclusive wall time of the functions
   listed in PHASES (time inside a nested listed function counts for that one only);
   "other" is the rest of run_scene.
2. run_scene of the whole run (all steps) and of the one-step run, in s.

With ``--baseline PYTHON`` (e.g. /work/main/.venv/bin/python) the same worker runs with
that interpreter (its checkout's parefg), alternating with this tree's, and the tables
add the ratio this / baseline.  ``--clock cpu`` measures process CPU time instead of
wall time (robust to a loaded machine; the runs are single-threaded with
OMP_NUM_THREADS=1).  Writes results/bench_fixed_costs.csv.

    .venv/bin/python scripts/bench/bench_fixed_costs.py [--repeats 5] [--rounds 2] \
        [--baseline /work/main/.venv/bin/python] [--clock cpu]
"""

import argparse
import functools
import importlib
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

import benchlib

# (label, m, 1/h, dt): the GetFEM comparison's parefg runs, and a finer cloud
CASES = [("m=2 h=1/8", 2, 8, 0.025), ("m=3 h=1/8", 3, 8, 0.0125), ("m=2 h=1/16", 2, 16, 0.025)]

# (phase, module, attribute): functions timed exclusively (a missing one is skipped)
PHASES = [
    ("budget", "parefg.run", "check_problem_size"),
    ("output dir", "parefg.run", "plan_output_dir"),
    ("mesh", "parefg.discretization.operators", "mesh_on_root"),
    ("partition", "parefg.discretization.operators", "partition_on_root"),
    ("MLS set-up", "parefg.discretization.operators", "MLS"),
    ("domain M, K, S", "parefg.discretization.operators", "_Builder._domain"),
    ("boundaries", "parefg.discretization.boundary_operators", "BoundaryOperators._boundaries"),
    ("Nitsche beta", "parefg.discretization.boundary_operators", "nitsche_beta"),
    ("node points", "parefg.discretization.operators", "_Builder._node_points"),
    ("discretization rest", "parefg.discretization.operators", "_Builder.build"),
    ("simulation set-up", "parefg.run", "_start"),
    ("open writer", "parefg.run", "_open_writer"),
    ("write t=0", "parefg.io.observers", "ResultsObserver.write_initial"),
    ("time loop", "parefg.run", "time_loop"),
    ("errors", "parefg.timestepping.simulation", "Simulation.errors"),
    ("summary", "parefg.run", "_summary"),
    ("close writer", "parefg.io.output", "ResultWriter.close"),
    ("summary.json", "parefg.run", "_write_summary"),
]


CLOCKS = {"wall": time.perf_counter, "cpu": time.process_time}


class Phases:
    """Exclusive time per phase: a phase's time excludes the phases it calls."""

    def __init__(self, clock):
        self.clock = clock
        self.seconds: dict[str, float] = {}
        self.stack: list[list] = []  # [label, start, time in nested phases]

    def wrap(self, label: str, function):
        @functools.wraps(function)
        def timed(*args, **kwargs):
            self.stack.append([label, self.clock(), 0.0])
            try:
                return function(*args, **kwargs)
            finally:
                label_, start, nested = self.stack.pop()
                spent = self.clock() - start
                self.seconds[label_] = self.seconds.get(label_, 0.0) + spent - nested
                if self.stack:
                    self.stack[-1][2] += spent

        return timed

    def install(self) -> None:
        """Replace the functions of PHASES by timed ones (for the rest of the process)."""
        for label, module_name, attribute in PHASES:
            owner = importlib.import_module(module_name)
            *path, name = attribute.split(".")
            for part in path:
                owner = getattr(owner, part, None)
            if owner is not None and hasattr(owner, name):
                setattr(owner, name, self.wrap(label, getattr(owner, name)))


def run_once(m: int, n: int, dt: float, one_step: bool, phases: Phases) -> tuple[float, dict]:
    """Time of run_scene on the square scene, and the phases (ms) of that run."""
    from mpi4py import MPI

    from parefg.run import run_scene
    from parefg.scene.loader import load_scene

    overrides = [f"discretization.h={1.0 / n!r}", f"time.dt={dt!r}", "output.every=0"]
    overrides += [f"discretization.degree={m}"] + ([f"time.T={dt!r}"] if one_step else [])
    scene = load_scene("square", overrides)
    phases.seconds = {}
    with tempfile.TemporaryDirectory() as tmp:
        start = phases.clock()
        run_scene(MPI.COMM_WORLD, scene, out=tmp + "/run", quiet=True)
        wall = phases.clock() - start
    split = {label: 1000 * s for label, s in phases.seconds.items()}
    split["other"] = 1000 * wall - sum(split.values())
    return wall, split


def worker(repeats: int, clock: str) -> None:
    """Print one JSON line per measured run of every case (after a warming run each)."""
    phases = Phases(CLOCKS[clock])
    phases.install()
    for label, m, n, dt in CASES:
        for one_step in (True, False):
            run_once(m, n, dt, one_step, phases)  # warm: kernels, caches
            for _ in range(repeats):
                wall, split = run_once(m, n, dt, one_step, phases)
                sample = {"case": label, "one_step": one_step, "wall": wall, "phases": split}
                print(json.dumps(sample), flush=True)


def collect(trees: dict[str, str], repeats: int, rounds: int, clock: str) -> dict[str, list[dict]]:
    """The samples of every tree, from ``rounds`` alternating worker processes each."""
    samples: dict[str, list[dict]] = {tree: [] for tree in trees}
    env = dict(os.environ, OMP_NUM_THREADS="1")
    for _ in range(rounds):
        for tree, python in trees.items():
            command = [python, __file__, "--worker", "--repeats", str(repeats), "--clock", clock]
            done = subprocess.run(command, env=env, capture_output=True, text=True, check=True)
            samples[tree] += [json.loads(line) for line in done.stdout.splitlines() if line]
    return samples


def medians(samples: list[dict], case: str, one_step: bool) -> tuple[float, dict[str, float]]:
    chosen = [s for s in samples if s["case"] == case and s["one_step"] == one_step]
    labels = [label for label, *_ in PHASES] + ["other"]
    split = {
        label: statistics.median(s["phases"].get(label, 0.0) for s in chosen) for label in labels
    }
    return statistics.median(s["wall"] for s in chosen), split


def report(samples: dict[str, list[dict]]) -> list[dict]:
    """Print the two tables; return the CSV rows."""
    trees, rows = list(samples), []
    print("\n1. phases of a one-step run [ms] (medians)")
    labels = [label for label, *_ in PHASES] + ["other", "run_scene"]
    header = "".join(f"{label + ' ' + tree:>22}" for label, *_ in CASES for tree in trees)
    print(f"{'phase':<22}{header}")
    per = {(c, t): medians(samples[t], c, True) for c, *_ in CASES for t in trees}
    for phase in labels:
        cells = []
        for case, *_ in CASES:
            for tree in trees:
                wall, split = per[(case, tree)]
                value = 1000 * wall if phase == "run_scene" else split[phase]
                cells.append(f"{value:22.1f}")
                rows.append(
                    {
                        "table": "phases_ms",
                        "case": case,
                        "tree": tree,
                        "name": phase,
                        "value": value,
                    }
                )
        print(f"{phase:<22}{''.join(cells)}")
    print("\n2. run_scene [s] (medians)")
    print(
        f"{'case':<14}"
        + "".join(f"{'steps ' + t:>16}{'one step ' + t:>18}" for t in trees)
        + (f"{'ratio all':>11}{'ratio one':>11}" if len(trees) == 2 else "")
    )
    for case, *_ in CASES:
        line = f"{case:<14}"
        walls = {}
        for tree in trees:
            walls[tree] = (
                medians(samples[tree], case, False)[0],
                medians(samples[tree], case, True)[0],
            )
            line += f"{walls[tree][0]:16.3f}{walls[tree][1]:18.3f}"
            for kind, value in zip(("all_steps", "one_step"), walls[tree], strict=True):
                rows.append(
                    {
                        "table": "run_scene_s",
                        "case": case,
                        "tree": tree,
                        "name": kind,
                        "value": value,
                    }
                )
        if len(trees) == 2:
            a, b = (walls[t] for t in trees)
            line += f"{a[0] / b[0]:11.2f}{a[1] / b[1]:11.2f}"
        print(line)
    return rows


def main():
    parser = benchlib.parser(__doc__, repeats=5)
    parser.add_argument("--rounds", type=int, default=2, help="worker processes per tree")
    parser.add_argument("--baseline", help="interpreter of a baseline checkout")
    parser.add_argument("--clock", choices=sorted(CLOCKS), default="wall")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        worker(args.repeats, args.clock)
        return
    trees = {"this": sys.executable}
    if args.baseline:
        trees["baseline"] = args.baseline
    print(f"clock: {args.clock}")
    rows = report(collect(trees, args.repeats, args.rounds, args.clock))
    print("\nwrote", benchlib.write_csv(args.out, "bench_fixed_costs.csv", rows))


if __name__ == "__main__":
    main()
