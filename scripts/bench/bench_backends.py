"""Crossover of the numpy and numba kernels: where numba's start-up pays for itself.

For the square scene (default degree m = 2, and --degree) at several h, one process builds
the discretization (``build_discretization``) with ``PAREFG_KERNELS=numpy`` and with
``PAREFG_KERNELS=numba`` in turn, --repeats times each after one warm-up build per backend
(so numba's kernels are loaded: the warm cost), and takes the median of the phases the
backend computes (neighbours + mls + assembly).  Separately, numba's one-off cost in a
fresh process (importing numba and loading the cached kernels a run uses) is the median
difference of two fresh processes that build the smallest case, numba against numpy, minus
their warm difference.  A fresh run prefers numba where

    warm numpy - warm numba > one-off numba cost,

and a warm process (benchmarks that build many times) where warm numpy > warm numba.
Prints a table and writes results/bench_backends_m<degree>.csv.

    .venv/bin/python scripts/bench/bench_backends.py [--repeats 3] [--degree 2]
"""

import os
import statistics
import subprocess
import sys
import time

import benchlib
from mpi4py import MPI

from parefg.discretization.operators import build_discretization
from parefg.scene.loader import load_scene

SPACINGS = [1 / 12, 1 / 16, 1 / 20, 1 / 24, 1 / 28, 1 / 32]
PHASES = ("neighbours", "mls", "assembly")
FRESH = """
import os, time
from mpi4py import MPI
from parefg.discretization.operators import build_discretization
from parefg.scene.loader import load_scene
scene = load_scene("square", ["discretization.h={h}", "discretization.degree={degree}"])
tic = time.perf_counter()
build_discretization(MPI.COMM_WORLD, scene)
print(time.perf_counter() - tic)
"""


def kernel_time(scene, backend):
    """neighbours + mls + assembly of one build with the given kernels, and the node count."""
    os.environ["PAREFG_KERNELS"] = backend
    disc = build_discretization(MPI.COMM_WORLD, scene)
    return sum(disc.timings[phase] for phase in PHASES), disc.n_nodes


def fresh_build(h, degree, backend, repeats):
    """Median build time (s) in a fresh process per repeat (imports outside the timing)."""
    env = dict(os.environ, PAREFG_KERNELS=backend)
    code = FRESH.format(h=h, degree=degree)
    times = []
    for _ in range(repeats):
        out = subprocess.run(
            [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
        )
        times.append(float(out.stdout.split()[-1]))
    return statistics.median(times)


def main():
    parser = benchlib.parser(__doc__, repeats=3)
    parser.add_argument("--degree", type=int, default=2)
    args = parser.parse_args()
    rows = []
    for h in SPACINGS:
        scene = load_scene(
            "square", [f"discretization.h={h}", f"discretization.degree={args.degree}"]
        )
        for backend in ("numpy", "numba"):
            kernel_time(scene, backend)  # warm-up: numba's kernels loaded
        samples = {"numpy": [], "numba": []}
        for _ in range(args.repeats):  # interleaved, against drifting load
            for backend in samples:
                seconds, n_nodes = kernel_time(scene, backend)
                samples[backend].append(seconds)
        warm = {backend: statistics.median(values) for backend, values in samples.items()}
        rows.append(
            {"h": h, "n_nodes": n_nodes, "numpy_s": warm["numpy"], "numba_s": warm["numba"]}
        )
        print(f"h={h:.4f} nodes={n_nodes} numpy={warm['numpy']:.3f}s numba={warm['numba']:.3f}s")
    h0 = SPACINGS[0]
    fresh = {b: fresh_build(h0, args.degree, b, 2 * args.repeats + 1) for b in ("numpy", "numba")}
    one_off = (fresh["numba"] - fresh["numpy"]) - (rows[0]["numba_s"] - rows[0]["numpy_s"])
    print(f"fresh build h={h0:g}: numpy {fresh['numpy']:.3f}s, numba {fresh['numba']:.3f}s")
    print(f"numba one-off cost in a fresh process: {one_off:.3f}s")
    print("\n| h | nodes | numpy warm (s) | numba warm (s) | numpy - numba (s) | a run prefers |")
    print("|---|---|---|---|---|---|")
    for row in rows:
        gain = row["numpy_s"] - row["numba_s"]
        row["one_off_s"] = one_off
        row["fresh_prefers"] = "numba" if gain > one_off else "numpy"
        print(
            f"| {row['h']:.4f} | {row['n_nodes']} | {row['numpy_s']:.3f} | {row['numba_s']:.3f}"
            f" | {gain:+.3f} | {row['fresh_prefers']} |"
        )
    print(benchlib.write_csv(args.out, f"bench_backends_m{args.degree}.csv", rows))
    return 0


if __name__ == "__main__":
    start = time.perf_counter()
    status = main()
    print(f"({time.perf_counter() - start:.0f} s)")
    sys.exit(status)
