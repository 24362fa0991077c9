"""MLS throughput: quadrature points per second per core, numba and numpy backends.

Square node cloud at h = 1/64, default supports s = 2.0 / 3.2 / 4.0 for m = 1 / 2 / 3
and Gauss rules of 5x5 (m = 1, 2) or 7x7 (m = 3) points per cell; each timing is the
median of 5 repeats of the neighbour search plus ``MLS.evaluate`` with gradients (one
warm-up call first, so numba compilation is not timed).  ``kernel`` is ``MLS.evaluate``
on precomputed neighbour lists (values + gradients, search excluded) in thread CPU time,
which a loaded machine disturbs less than wall time; ``kernel points/s`` is the figure
the MLS speed target is stated in.  Prints a markdown table and writes
results/bench_mls.csv.

Usage: .venv/bin/python scripts/bench/bench_mls.py [--repeats N] [--h H]
"""

import time

import benchlib
import numpy as np
from mpi4py import MPI

from parefg.discretization.mls import MLS
from parefg.discretization.quadrature import cell_quadrature
from parefg.geometry.gmsh_mesh import build_node_cloud

# (degree m, support dilation s, Gauss points per direction)
CASES = [(1, 2.0, 5), (2, 3.2, 5), (3, 4.0, 7)]
COLUMNS = [
    "degree",
    "backend",
    "n_points",
    "n_max",
    "search_s",
    "evaluate_s",
    "points_per_s",
    "kernel_cpu_s",
    "kernel_points_per_s",
]


def median_time(function, repeats, clock=time.perf_counter):
    """Median time of ``repeats`` calls of function() on ``clock`` (wall time by default)."""
    times = []
    for _ in range(repeats):
        tic = clock()
        function()
        times.append(clock() - tic)
    return float(np.median(times))


def bench_case(cloud, degree, support, order, backend, repeats):
    """One table row: search time, total evaluate time and points/s for one backend."""
    points = cell_quadrature(cloud.coords, cloud.quads, cloud.triangles, order).points
    mls = MLS(cloud.coords, support * cloud.spacing, degree, backend=backend)
    shape = mls.evaluate(points)  # warm-up (and numba compilation or cache load)
    search = median_time(lambda: mls.find_neighbours(points), repeats)
    total = median_time(lambda: mls.evaluate(points), repeats)
    neighbours = mls.find_neighbours(points)
    kernel = median_time(
        lambda: mls.evaluate(points, neighbours=neighbours), repeats, clock=time.thread_time
    )
    return {
        "degree": degree,
        "backend": backend,
        "n_points": len(points),
        "n_max": shape.neighbours.shape[1],
        "search_s": search,
        "evaluate_s": total,
        "points_per_s": len(points) / total,
        "kernel_cpu_s": kernel,
        "kernel_points_per_s": len(points) / kernel,
    }


def main():
    parser = benchlib.parser(__doc__, repeats=5)
    parser.add_argument("--h", type=float, default=1 / 64)
    args = parser.parse_args()
    cloud = build_node_cloud(MPI.COMM_SELF, {"shape": "square"}, args.h)
    rows = [
        bench_case(cloud, degree, support, order, backend, args.repeats)
        for degree, support, order in CASES
        for backend in ("numba", "numpy")
    ]
    print(
        f"MLS with gradients, square h = {args.h:g}, {len(cloud.coords)} nodes, "
        f"median of {args.repeats}, 1 core\n"
    )
    print(
        "| m | backend | points | n_max | search (s) | evaluate (s) | points/s | us/point "
        "| kernel CPU (s) | kernel points/s |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for row in rows:
        print(
            f"| {row['degree']} | {row['backend']} | {row['n_points']} | {row['n_max']} | "
            f"{row['search_s']:.3f} | {row['evaluate_s']:.3f} | {row['points_per_s']:.3g} | "
            f"{1e6 / row['points_per_s']:.2f} | {row['kernel_cpu_s']:.3f} | "
            f"{row['kernel_points_per_s']:.3g} |"
        )
    benchlib.write_csv(args.out, "bench_mls.csv", [{c: row[c] for c in COLUMNS} for row in rows])


if __name__ == "__main__":
    main()
