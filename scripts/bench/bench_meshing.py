"""Benchmark: meshing time by phase and peak memory, 1e4 ... 1e6+ nodes.

Each case (domain, cells, target node count) runs in a fresh process, which meshes the
domain as parefg.geometry.gmsh_mesh.mesh_domain does (same options, same builders) and
times its phases: "build" (gmsh geometry), "generate" (gmsh.model.mesh.generate(2)) and
"extract" (the NodeCloud: cells, spacing, boundary segments), with the process's peak
RSS.  h is chosen from the target count (square: (1/h + 1)^2 nodes; others: the budget's
unstructured density).  A case that exceeds --timeout seconds is reported as such.

Prints a markdown table and writes results/bench_meshing.csv.

    nice .venv/bin/python scripts/bench/bench_meshing.py [--nodes 1e4,1e5,1e6] [--timeout 120]
"""

import json
import math
import subprocess
import sys
import time

import benchlib

PLATE = {
    "shape": "geo",
    "file": "meshes/plate_with_hole.geo",
    "parts": ["bottom", "top", "sides", "hole"],
}
DOMAINS = {"square": {"shape": "square"}, "z": {"shape": "z"}, "plate": PLATE}
AREA = {"square": 1.0, "z": 0.7, "plate": 2.0 - math.pi / 16}
CASES = ("square:quad", "z:tri", "z:quad", "plate:tri", "plate:quad")


def spacing_for(domain: str, nodes: float) -> float:
    """Target h giving about ``nodes`` nodes on the domain."""
    if domain == "square":
        return 1.0 / (math.sqrt(nodes) - 1)
    return math.sqrt(1.16 * AREA[domain] / nodes)  # size_estimate.UNSTRUCTURED_DENSITY


def child(domain: str, h: float, cells: str) -> dict:
    """Mesh one case in this process; its phase times, counts and peak RSS."""
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
        built = SHAPES[table["shape"]].build(gmsh, table, h, cells)
        recombine = cells == "quad" and not built.structured
        gmsh_mesh._set_mesh_options(gmsh, h, cells, recombine=recombine)
        times["build"] = time.perf_counter() - start
        start = time.perf_counter()
        gmsh.model.mesh.generate(2)
        times["generate"] = time.perf_counter() - start
        start = time.perf_counter()
        cloud = gmsh_mesh._extract_cloud(gmsh, built, cells)
        times["extract"] = time.perf_counter() - start
        gmsh.finalize()
    return {
        "nodes": cloud.n_nodes,
        "quads": len(cloud.quads),
        "triangles": len(cloud.triangles),
        **{k: round(v, 3) for k, v in times.items()},
        "peak_rss_mb": round(peak_rss_kib() / 1024),
    }


def measure(case: str, nodes: float, timeout: float) -> dict:
    domain, cells = case.split(":")
    h = spacing_for(domain, nodes)
    row = {"domain": domain, "cells": cells, "target": int(nodes), "h": round(h, 6)}
    command = [sys.executable, __file__, "--child", json.dumps([domain, h, cells])]
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=timeout, check=True)
        row.update(json.loads(done.stdout.splitlines()[-1]))
    except subprocess.TimeoutExpired:
        row["status"] = f"> {timeout:g} s"
    return row


def main():
    if len(sys.argv) == 3 and sys.argv[1] == "--child":
        print(json.dumps(child(*json.loads(sys.argv[2]))))
        return
    parser = benchlib.parser(__doc__, repeats=1)
    parser.add_argument("--nodes", default="1e4,3e4,1e5,3e5,1e6")
    parser.add_argument("--cases", default=",".join(CASES))
    parser.add_argument("--timeout", type=float, default=120.0)
    args = parser.parse_args()
    print("| domain | cells | nodes | quads | triangles | generate [s] | extract [s] | RSS [MB] |")
    print("|---|---|---|---|---|---|---|---|")
    rows = []
    for case in args.cases.split(","):
        for nodes in (float(n) for n in args.nodes.split(",")):
            row = measure(case, nodes, args.timeout)
            rows.append(row)
            if "status" in row:
                print(f"| {row['domain']} | {row['cells']} | ~{row['target']} | {row['status']} |")
                break  # larger targets only take longer
            print(
                f"| {row['domain']} | {row['cells']} | {row['nodes']} | {row['quads']} | "
                f"{row['triangles']} | {row['generate']:.2f} | {row['extract']:.2f} | "
                f"{row['peak_rss_mb']} |",
                flush=True,
            )
    keys = list(dict.fromkeys(key for row in rows for key in row))  # timed-out rows lack some
    rows = [{key: row.get(key, "") for key in keys} for row in rows]
    print(f"wrote {benchlib.write_csv(args.out, 'bench_meshing.csv', rows)}")


if __name__ == "__main__":
    main()
