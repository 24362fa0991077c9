"""Benchmark: memory per DOF of a run, by phase and by what holds it (steady and peak).

Each case (scene square, degree m, spacing h) runs in a fresh process: after a warm-up
(imports, numba compilation) it builds the discretization, the Simulation and runs a few
time steps (CG + GAMG, so no factorization), then evaluates the error norms (the domain
gradients).  It records

* per phase (cloud = mesh and partition, shape = neighbours and MLS, assembly, simulation,
  time loop, errors): the resident set retained at the phase's end and the peak resident
  set within it (Linux VmHWM, reset per phase through /proc/self/clear_refs), both above
  the warm-up baseline;
* the bytes held after the time loop, by holder: the node cloud and partition, MLS shape
  arrays, point operators (PETSc), the DOF matrices (M, K, G_D, A_const, the Jacobian;
  PETSc), scipy matrices, the contact law, the rest of the Simulation (vectors).  PETSc's
  own MatInfo.memory is 0 in this build, so a PETSc matrix counts 12 bytes per allocated
  nonzero plus 16 per row (values, 32-bit column indices, row pointers).

Prints KB per DOF and writes results/bench_memory_per_dof.csv.

    nice .venv/bin/python scripts/bench/bench_memory_per_dof.py [--degree 1,2] [--h 0.0125,0.00625]
"""

import gc
import json
import subprocess
import sys
import time
import types
from pathlib import Path

import benchlib

PHASES = ("cloud", "shape", "assembly", "other", "simulation", "time_loop", "errors")
HOLDERS = ("cloud", "shape", "operators", "matrices", "scipy", "contact", "loop_vectors")
SOLVER = ["-ksp_type", "cg", "-pc_type", "gamg", "-mass_ksp_type", "cg", "-mass_pc_type", "jacobi"]


def _status_kib(key: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1])
    raise KeyError(key)


def reset_peak() -> None:
    """Reset VmHWM to the current resident set (Linux >= 4.0)."""
    Path("/proc/self/clear_refs").write_text("5")


class Recorder:
    """Per phase: the resident set it adds (summed over its calls) and the peak within it.

    Bytes above the baseline (the resident set when the recorder starts).  The resident
    set rarely shrinks when memory is freed (the allocator keeps it), so "retained" is an
    upper bound; :func:`holders` counts what is actually held.
    """

    def __init__(self):
        gc.collect()
        self.baseline = self._last = _status_kib("VmRSS") * 1024
        self.rows: dict[str, dict[str, float]] = {}
        reset_peak()

    def end(self, name: str) -> None:
        """Close phase ``name`` (it began where the previous phase ended)."""
        peak = _status_kib("VmHWM") * 1024 - self.baseline
        gc.collect()
        now = _status_kib("VmRSS") * 1024
        row = self.rows.setdefault(name, {"retained": 0.0, "peak": 0.0})
        row["retained"] += now - self._last
        row["peak"] = max(row["peak"], peak)
        self._last = now
        reset_peak()

    def total(self) -> float:
        return self._last - self.baseline


def _mat_bytes(mat) -> float:
    from petsc4py import PETSc

    info = mat.getInfo(PETSc.Mat.InfoType.LOCAL)
    return 12 * info["nz_allocated"] + 16 * mat.getLocalSize()[0]


def held_bytes(roots, seen: set, category: str, totals: dict) -> None:
    """Add the bytes reachable from ``roots`` (not yet ``seen``) to ``totals`` by holder.

    numpy arrays count their buffers (a view its base), PETSc matrices and vectors their
    storage; an array inside a ShapeValues counts as "shape", inside a scipy sparse matrix
    as "scipy", whatever root reaches it.  Modules, classes and function globals are not
    followed (closures are).
    """
    import numpy as np
    import scipy.sparse as sp
    from petsc4py import PETSc

    from parefg.discretization.mls import ShapeValues

    stack = [(root, category) for root in roots]
    while stack:
        obj, kind = stack.pop()
        if obj is None or id(obj) in seen or isinstance(obj, (type, types.ModuleType)):
            continue
        seen.add(id(obj))
        if isinstance(obj, np.ndarray):
            if isinstance(obj.base, np.ndarray):
                stack.append((obj.base, kind))
            else:
                totals[kind] = totals.get(kind, 0) + obj.nbytes
        elif isinstance(obj, PETSc.Mat):
            totals[kind] = totals.get(kind, 0) + _mat_bytes(obj)
        elif isinstance(obj, PETSc.Vec):
            totals["loop_vectors"] = totals.get("loop_vectors", 0) + 8 * obj.getLocalSize()
        elif isinstance(obj, PETSc.Object):
            continue  # solvers: their memory is the linear solver's
        elif isinstance(obj, types.FunctionType):
            stack += [(cell.cell_contents, kind) for cell in obj.__closure__ or ()]
        elif isinstance(obj, types.MethodType):
            stack.append((obj.__func__, kind))
        elif isinstance(obj, dict):
            stack += [(value, kind) for value in obj.values()]
        elif isinstance(obj, (list, tuple, set, frozenset)):
            stack += [(value, kind) for value in obj]
        elif hasattr(obj, "__dict__"):
            inner = "shape" if isinstance(obj, ShapeValues) else kind
            inner = "scipy" if sp.issparse(obj) else inner
            stack += [(value, inner) for value in vars(obj).values()]


def holders(disc, sim) -> dict[str, float]:
    """Bytes held by each part of the run after the time loop (see :func:`held_bytes`)."""
    seen: set = {id(sim.scene), id(disc.comm)}
    totals: dict[str, float] = {}
    point_sets = [disc.domain, disc.nodes, *disc.boundary.values(), disc.contact]
    matrices = [disc.mass, disc.stiffness, disc.dirichlet, sim.a_const]
    matrices.append(getattr(sim.solver, "jacobian", None))
    for category, roots in (
        ("cloud", [disc.cloud, disc.partition]),
        ("matrices", matrices),
        ("operators", point_sets),
        ("contact", [sim.law]),
        ("loop_vectors", [sim, disc]),
    ):
        held_bytes(roots, seen, category, totals)
    return totals


def run_case(degree: int, h: float, steps: int) -> dict:
    """One case in this process; returns its row (bytes, seconds)."""
    import petsc4py

    petsc4py.init([sys.argv[0], *SOLVER])
    import tracemalloc

    from mpi4py import MPI

    import parefg.discretization.operators as operators
    from parefg.discretization.operators import build_discretization
    from parefg.scene.loader import load_scene
    from parefg.timestepping.simulation import Simulation

    comm = MPI.COMM_WORLD
    T = steps * 0.05 / 4

    def scene_at(spacing):
        overrides = [f"discretization.h={spacing!r}", f"discretization.degree={degree}"]
        return load_scene("square", [*overrides, "time.dt=0.0125", f"time.T={T!r}"])

    warm = scene_at(0.25)  # imports, numba compilation, PETSc set-up
    warm_disc = build_discretization(comm, warm)
    warm_sim = Simulation(comm, warm, warm_disc)
    warm_sim.errors(warm_sim.step(warm_sim.start(), 1).u, warm.time.dt)
    del warm_disc, warm_sim
    scene = scene_at(h)
    tracemalloc.start()
    recorder = Recorder()
    original_phase = operators.phase
    names = {"mesh": "cloud", "neighbours": "shape", "mls": "shape", "assembly": "assembly"}

    class Phase:  # records memory at the end of each build phase
        def __init__(self, timings, name):
            self.inner, self.name = original_phase(timings, name), names[name]

        def __enter__(self):
            recorder.end("other")  # what ran between the phases
            return self.inner.__enter__()

        def __exit__(self, *exc):
            self.inner.__exit__(*exc)
            recorder.end(self.name)

    operators.phase = Phase
    tic = time.perf_counter()
    disc = build_discretization(comm, scene)
    operators.phase = original_phase
    seconds = {"build": time.perf_counter() - tic}
    tic = time.perf_counter()
    sim = Simulation(comm, scene, disc, keep_history=False)
    state = sim.start()
    recorder.end("simulation")
    seconds["simulation"] = time.perf_counter() - tic
    tic = time.perf_counter()
    for n in range(1, scene.time.n_steps + 1):
        state = sim.step(state, n)
    recorder.end("time_loop")
    seconds["time_loop"] = time.perf_counter() - tic
    steady = recorder.total()
    held = holders(disc, sim)
    tic = time.perf_counter()
    errors = sim.errors(state.u, scene.time.T)
    recorder.end("errors")
    seconds["errors"] = time.perf_counter() - tic
    traced_peak = tracemalloc.get_traced_memory()[1]
    row = {"degree": degree, "h": h, "dofs": disc.n_dofs, "steps": scene.time.n_steps}
    row["steady"] = steady
    row["peak"] = max(memory["peak"] for memory in recorder.rows.values())
    for name in PHASES:
        memory = recorder.rows.get(name, {"retained": 0.0, "peak": 0.0})
        row[f"{name}_retained"], row[f"{name}_peak"] = memory["retained"], memory["peak"]
    row.update({f"held_{name}": held.get(name, 0.0) for name in HOLDERS})
    row["numpy_peak"] = traced_peak
    row.update({f"time_{k}": v for k, v in {**disc.timings, **seconds}.items()})
    row["h1_rel"] = errors["h1_rel"] if errors else float("nan")
    return row


def main():
    parser = benchlib.parser(__doc__, repeats=1)
    parser.add_argument("--degree", default="1,2")
    parser.add_argument("--h", default="0.0125,0.00625")
    parser.add_argument("--steps", type=int, default=2)
    parser.add_argument("--case", nargs=2, help=argparse_suppress())
    args = parser.parse_args()
    if args.case:
        print(json.dumps(run_case(int(args.case[0]), float(args.case[1]), args.steps)))
        return
    rows = []
    for degree in (int(m) for m in args.degree.split(",")):
        for h in (float(v) for v in args.h.split(",")):
            command = [sys.executable, __file__, "--case", str(degree), repr(h)]
            command += ["--steps", str(args.steps)]
            done = subprocess.run(command, check=True, capture_output=True, text=True)
            rows.append(json.loads(done.stdout.strip().splitlines()[-1]))
            print(f"m = {degree}, h = {h}: {rows[-1]['dofs']} DOFs", flush=True)
    print_tables(rows)
    benchlib.write_csv(args.out, "bench_memory_per_dof.csv", rows)


def argparse_suppress():
    import argparse

    return argparse.SUPPRESS


def print_tables(rows) -> None:
    kb = [(r, 1e3 * r["dofs"]) for r in rows]
    print("\nKB/DOF by phase (resident set added / peak within it, above the warm-up baseline)\n")
    print("| m | DOFs | " + " | ".join(PHASES) + " | steady | peak |")
    print("|---|---|" + "---|" * (len(PHASES) + 2))
    for r, per in kb:
        cells = " | ".join(
            f"{r[p + '_retained'] / per:.1f} / {r[p + '_peak'] / per:.1f}" for p in PHASES
        )
        steady, peak = r["steady"] / per, r["peak"] / per
        print(f"| {r['degree']} | {r['dofs']} | {cells} | {steady:.1f} | {peak:.1f} |")
    print("\nKB/DOF held after the time loop, by holder\n")
    print("| m | DOFs | " + " | ".join(HOLDERS) + " | total |")
    print("|---|---|" + "---|" * (len(HOLDERS) + 1))
    for r, per in kb:
        values = [r[f"held_{h}"] / per for h in HOLDERS]
        cells = " | ".join(f"{v:.2f}" for v in values)
        print(f"| {r['degree']} | {r['dofs']} | {cells} | {sum(values):.2f} |")
    print("\nseconds by phase\n")
    keys = ("mesh", "neighbours", "mls", "assembly", "simulation", "time_loop", "errors")
    print("| m | DOFs | " + " | ".join(keys) + " |")
    print("|---|---|" + "---|" * len(keys))
    for r, _ in kb:
        print(
            f"| {r['degree']} | {r['dofs']} | "
            + " | ".join(f"{r['time_' + k]:.2f}" for k in keys)
            + " |"
        )


if __name__ == "__main__":
    main()
