"""Benchmark: meshing time by phase and peak memory, 1e4 ... 1e6+ nodes.

Each case (domain, cells, target node count) runs in a fresh process, which meshes the
domain as parefg.geometry.gmsh_mesh.mesh_domain does (same options, same builders) and
times its phases: "build" (gmsh geometry), "generate" (parefg.geometry.gmsh_mesh.generate:
gmsh.model.mesh.generate(2), on a coarser mesh with uniform refinements for large
unstructured clouds, the count in the "refinements" column) and
"extract" (the NodeCloud: cells, spacing, boundary segments), wall and CPU time (the CPU
time of this process is the steadier number on a shared machine), with its peak RSS.
h is chosen from the target count (square: (1/h + 1)^2 nodes; others: the budget's
unstructured density).  A case that exceeds --timeout seconds is reported as such, and so
is one whose process dies (gmsh's Mesh.Algorithm 8 crashes in Debian's gmsh 4.8).

Each case also reports the cells' quality: the smallest interior angle of any cell and the
1st percentile of the cells' smallest angles (degrees; 60 / 90 for ideal triangles / quads).

A case is DOMAIN:CELLS or DOMAIN:CELLS:ALGORITHM.  "square" and "z" are structured
(transfinite); "zpoly" is the same Z outline as a generic polygon and "plate" a .geo file,
both meshed unstructured with parefg's gmsh options, or with Mesh.Algorithm = ALGORITHM
(5 Delaunay, 6 Frontal-Delaunay, 8 Frontal-Delaunay for quads) when given, then on the
whole cloud without refinements; ``--algorithms
5,6,8`` expands every unstructured case without one over those algorithms.

Prints a markdown table and writes results/bench_meshing.csv.

    nice .venv/bin/python scripts/bench/bench_meshing.py [--nodes 1e4,1e5,1e6] [--timeout 120]
    nice .venv/bin/python scripts/bench/bench_meshing.py --cases zpoly:tri,zpoly:quad,\\
        plate:tri,plate:quad --algorithms 5,6,8 --nodes 1e4,1e5,1e6
"""

import json
import math
import subprocess
import sys
import time

import benchlib
import numpy as np

from parefg.geometry.cells import UNSTRUCTURED_DENSITY

PLATE = {
    "shape": "geo",
    "file": "meshes/plate_with_hole.geo",
    "parts": ["bottom", "top", "sides", "hole"],
}
Z_POLYGON = {
    "shape": "polygon",
    "vertices": [[0, 0], [1, 0], [1, 0.25], [0.4, 0.25], [1, 0.75], [1, 1], [0, 1], [0, 0.75],
                 [0.6, 0.75], [0, 0.25]],
    "edge_names": ["bottom", "sides", "sides", "sides", "sides", "top", "sides", "sides", "sides",
                   "sides"],
}  # fmt: skip
DOMAINS = {"square": {"shape": "square"}, "z": {"shape": "z"}, "zpoly": Z_POLYGON, "plate": PLATE}
AREA = {"square": 1.0, "z": 0.7, "zpoly": 0.7, "plate": 2.0 - math.pi / 16}
STRUCTURED = ("square", "z")
CASES = ("square:quad", "z:tri", "z:quad", "zpoly:tri", "zpoly:quad", "plate:tri", "plate:quad")


def spacing_for(domain: str, nodes: float) -> float:
    """Target h giving about ``nodes`` nodes on the domain."""
    if domain == "square":
        return 1.0 / (math.sqrt(nodes) - 1)
    return math.sqrt(UNSTRUCTURED_DENSITY * AREA[domain] / nodes)


def smallest_angles(coords, cells) -> np.ndarray:
    """(n_cells,) the smallest interior angle of each cell, in degrees."""
    corners = coords[cells]  # (n_cells, n_corners, 2)
    before = np.roll(corners, 1, axis=1) - corners
    after = np.roll(corners, -1, axis=1) - corners
    cosine = np.sum(before * after, axis=2) / (
        np.linalg.norm(before, axis=2) * np.linalg.norm(after, axis=2)
    )
    return np.degrees(np.arccos(np.clip(cosine, -1, 1))).min(axis=1)


def quality(cloud) -> dict:
    """Smallest cell angle and the 1st percentile of the cells' smallest angles."""
    angles = np.concatenate(
        [smallest_angles(cloud.coords, c) for c in (cloud.quads, cloud.triangles) if len(c)]
    )
    return {"min_angle": round(float(angles.min()), 1),
            "p01_angle": round(float(np.percentile(angles, 1)), 1)}  # fmt: skip


def child(domain: str, h: float, cells: str, algorithm: int | None = None) -> dict:
    """Mesh one case in this process; its phase times, counts, cell quality and peak RSS."""
    import gmsh

    from parefg.geometry import gmsh_mesh
    from parefg.geometry.shapes import SHAPES
    from parefg.profiling import peak_rss_kib

    table = DOMAINS[domain]
    times = {}
    with gmsh_mesh._stdin_closed(), gmsh_mesh._private_home():
        gmsh_mesh._gmsh_initialize(gmsh)
        start = time.perf_counter()
        gmsh_mesh._set_mesh_options(gmsh, h, cells, recombine=False)
        built = SHAPES[table["shape"]].build(gmsh, table, h, cells)  # min_cells 1 (m = 1)
        recombine = cells == "quad" and not built.structured
        gmsh_mesh._set_mesh_options(gmsh, h, cells, recombine=recombine)
        if algorithm is not None:
            gmsh.option.setNumber("Mesh.Algorithm", algorithm)
        times["build"] = time.perf_counter() - start
        start, cpu = time.perf_counter(), time.process_time()
        if algorithm is None:
            refinements = gmsh_mesh.generate(gmsh, built, h)  # as parefg meshes
        else:  # the algorithm alone, on the whole cloud
            refinements = 0
            gmsh.model.mesh.generate(2)
        times["generate"] = time.perf_counter() - start
        times["generate_cpu"] = time.process_time() - cpu
        start, cpu = time.perf_counter(), time.process_time()
        cloud = gmsh_mesh._extract_cloud(gmsh, built, cells)
        times["extract"] = time.perf_counter() - start
        times["extract_cpu"] = time.process_time() - cpu
        gmsh.finalize()
    return {
        "nodes": cloud.n_nodes,
        "refinements": refinements,
        "quads": len(cloud.quads),
        "triangles": len(cloud.triangles),
        **{k: round(v, 3) for k, v in times.items()},
        **quality(cloud),
        "peak_rss_mb": round(peak_rss_kib() / 1024),
    }


def measure(case: str, nodes: float, timeout: float) -> dict:
    domain, cells, *algorithm = case.split(":")
    algorithm = int(algorithm[0]) if algorithm else None
    h = spacing_for(domain, nodes)
    row = {"domain": domain, "cells": cells, "algorithm": algorithm or "default",
           "target": int(nodes), "h": round(h, 6)}  # fmt: skip
    command = [sys.executable, __file__, "--child", json.dumps([domain, h, cells, algorithm])]
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=timeout)
        if done.returncode != 0:
            row["status"] = f"died (exit {done.returncode})"
        else:
            row.update(json.loads(done.stdout.splitlines()[-1]))
    except subprocess.TimeoutExpired:
        row["status"] = f"> {timeout:g} s"
    return row


def expand(cases: list[str], algorithms: list[str]) -> list[str]:
    """Each unstructured case without an algorithm, once per algorithm (if any are given)."""
    expanded = []
    for case in cases:
        domain, *rest = case.split(":")
        if algorithms and domain not in STRUCTURED and len(rest) == 1:
            expanded += [f"{case}:{algorithm}" for algorithm in algorithms]
        else:
            expanded.append(case)
    return expanded


def main():
    if len(sys.argv) == 3 and sys.argv[1] == "--child":
        print(json.dumps(child(*json.loads(sys.argv[2]))))
        return
    parser = benchlib.parser(__doc__, repeats=1)
    parser.add_argument("--nodes", default="1e4,3e4,1e5,3e5,1e6")
    parser.add_argument("--cases", default=",".join(CASES))
    parser.add_argument("--timeout", type=float, default=120.0)
    parser.add_argument("--algorithms", default="", help="e.g. 5,6,8 (see the docstring)")
    args = parser.parse_args()
    algorithms = [a for a in args.algorithms.split(",") if a]
    print(
        "| domain | cells | algorithm | nodes | quads | triangles | generate [s] "
        "| generate CPU [s] | extract CPU [s] | min angle | 1% angle | RSS [MB] | refinements |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    rows = []
    for case in expand(args.cases.split(","), algorithms):
        for nodes in (float(n) for n in args.nodes.split(",")):
            row = measure(case, nodes, args.timeout)
            rows.append(row)
            head = f"| {row['domain']} | {row['cells']} | {row['algorithm']} |"
            if "status" in row:
                print(f"{head} ~{row['target']} | {row['status']} |", flush=True)
                break  # larger targets only take longer
            print(
                f"{head} {row['nodes']} | {row['quads']} | {row['triangles']} | "
                f"{row['generate']:.2f} | {row['generate_cpu']:.2f} | {row['extract_cpu']:.2f} | "
                f"{row['min_angle']} | "
                f"{row['p01_angle']} | {row['peak_rss_mb']} | {row['refinements']} |",
                flush=True,
            )
    keys = list(dict.fromkeys(key for row in rows for key in row))  # timed-out rows lack some
    rows = [{key: row.get(key, "") for key in keys} for row in rows]
    print(f"wrote {benchlib.write_csv(args.out, 'bench_meshing.csv', rows)}")


if __name__ == "__main__":
    main()
