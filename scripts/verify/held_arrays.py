"""The largest arrays each rank holds after a run's first step (issue 13: none O(N)).

Run under ``mpirun -n p``: builds the square scene (or ``--scene z``; m = 1, CG + GAMG) with h
chosen for
about ``--dofs-per-rank`` DOFs per rank, takes one step, then walks everything the
Simulation references (attributes, lists, dicts, tuples, scipy matrices; PETSc objects
are opaque and counted by PETSc's own distributed storage) and reports, per rank, the
nodes held against the global count and the largest numpy arrays with where they sit.
At fixed N/p the largest array must stay flat as p grows; an array sized by the whole
cloud would grow with p.

    mpirun -n 4 --oversubscribe .venv/bin/python scripts/verify/held_arrays.py \
        [--dofs-per-rank 25000] [--top 3] [--scene square|z]
"""

import argparse
import math

import numpy as np
import scipy.sparse as sp
from mpi4py import MPI


def arrays_of(root, limit_depth=12):
    """{id: (nbytes, length, path)} of every numpy array reachable from ``root``."""
    found, seen = {}, set()
    stack = [(root, "sim", 0)]
    while stack:
        obj, path, depth = stack.pop()
        if id(obj) in seen or depth > limit_depth:
            continue
        seen.add(id(obj))
        if isinstance(obj, np.ndarray):
            base = obj
            while isinstance(base.base, np.ndarray):
                base = base.base
            if id(base) not in found or found[id(base)][0] < base.nbytes:
                found[id(base)] = (base.nbytes, len(obj) if obj.ndim else 1, path)
            continue
        if sp.issparse(obj):
            for name in ("data", "indices", "indptr", "row", "col"):
                if hasattr(obj, name):
                    stack.append((getattr(obj, name), f"{path}.{name}", depth + 1))
            continue
        if isinstance(obj, dict):
            children = [(v, f"{path}[{k!r}]") for k, v in obj.items()]
        elif isinstance(obj, (list, tuple)):
            children = [(v, f"{path}[{i}]") for i, v in enumerate(obj)]
        elif hasattr(obj, "__dict__") and type(obj).__module__.startswith("parefg"):
            children = [(v, f"{path}.{k}") for k, v in vars(obj).items()]
        elif callable(obj) and getattr(obj, "__closure__", None):
            children = [(c.cell_contents, f"{path}<closure>") for c in obj.__closure__
                        if c.cell_contents is not None]  # fmt: skip
        else:
            continue
        stack.extend((child, name, depth + 1) for child, name in children)
    return found


def main() -> None:
    cli = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    cli.add_argument("--dofs-per-rank", type=int, default=25000)
    cli.add_argument("--degree", type=int, default=1)
    cli.add_argument("--top", type=int, default=3)
    cli.add_argument("--scene", choices=("square", "z"), default="square")
    args = cli.parse_args()
    from parefg.run import prepare  # after argparse: --help imports nothing heavy

    comm = MPI.COMM_WORLD
    dofs = args.dofs_per_rank * comm.size
    if args.scene == "square":  # (n + 1)^2 nodes
        n = max(2, round(math.sqrt(dofs / 2.0)) - 1)
    else:  # the Z: about 0.7 n^2 nodes
        n = max(8, round(math.sqrt(dofs / 1.4)))
    sim = prepare(
        comm,
        args.scene,
        [
            f"discretization.h={1.0 / n}",
            f"discretization.degree={args.degree}",
            "time.T=0.025",
            "time.dt=0.025",
            "solver.method='iterative'",
        ],  # fmt: skip
    )
    state = sim.start()
    state = sim.step(state, 1)
    found = sorted(arrays_of(sim).values(), reverse=True)  # by bytes
    longest = max(found, key=lambda item: item[1])
    disc = sim.disc
    lines = [
        f"rank {comm.rank}: {disc.n_nodes} nodes, {disc.node_range[1] - disc.node_range[0]} own, "
        f"{len(disc.cloud.coords)} held; largest arrays:"
    ]
    lines += [
        f"    {nbytes / 1e6:8.2f} MB, length {length:8d}  {path}"
        for nbytes, length, path in found[: args.top]
    ]
    lines.append(f"    longest: length {longest[1]} ({longest[0] / 1e6:.2f} MB)  {longest[2]}")
    report = comm.gather("\n".join(lines), root=0)
    largest = comm.allreduce(longest[1], op=MPI.MAX)
    if comm.rank == 0:
        print(f"p = {comm.size}, h = 1/{n}, N = {disc.n_nodes} nodes ({2 * disc.n_nodes} DOFs)")
        print("\n".join(report))
        print(f"longest array on any rank: length {largest} = {largest / disc.n_nodes:.3f} N")


if __name__ == "__main__":
    main()
