"""Run a scene end to end: discretize, step, write results and summary.json (SPEC 7, 8)."""

from __future__ import annotations

import json
import resource
import sys
import time
from pathlib import Path

import numpy as np
from mpi4py import MPI

from parefg import __version__
from parefg.checkpoint import read_checkpoint, write_checkpoint
from parefg.errors import InputError, SolverError
from parefg.operators import build_discretization
from parefg.output import ResultWriter
from parefg.profiling import factorization_stats, phase, start_logging
from parefg.simulation import Simulation


def choose_output_dir(comm, scene_name: str, requested: str | None) -> Path:
    """The run's output directory; never an existing non-empty one.  Collective.

    Without --out: runs/<scene>, or runs/<scene>-2, -3, ... if taken.
    """
    message, path = None, None
    if comm.rank == 0:
        if requested is not None:
            path = Path(requested)
            if path.exists() and (not path.is_dir() or any(path.iterdir())):
                message = f"output directory {path} exists and is not empty; choose another --out"
        else:
            base = Path("runs") / scene_name
            path, n = base, 1
            while path.exists():
                n += 1
                path = base.with_name(f"{base.name}-{n}")
        if message is None:
            path.mkdir(parents=True, exist_ok=True)
    message, path = comm.bcast((message, path), root=0)
    if message:
        raise InputError(message)
    return path


class Progress:
    """Rank-0 progress lines, about every 10 % of the run, with Newton counts and ETA."""

    def __init__(self, comm, n_steps: int, quiet: bool):
        self.show = comm.rank == 0 and not quiet
        self.n_steps, self.start = n_steps, time.perf_counter()
        self.every = max(1, n_steps // 10)

    def update(self, n: int, t: float, newton: int) -> None:
        if not self.show or (n % self.every and n != self.n_steps):
            return
        elapsed = time.perf_counter() - self.start
        eta = elapsed / n * (self.n_steps - n)
        print(
            f"  step {n:>5}/{self.n_steps}  t = {t:<10.4g} newton {newton:>2}  "
            f"elapsed {elapsed:7.2f} s  eta {eta:7.2f} s",
            flush=True,
        )


def _output_fields(sim: Simulation, state) -> tuple[dict, dict]:
    """u_h, velocity, acceleration, von Mises at the nodes; contact state at Gamma_C points."""
    nodes, scene = sim.disc.nodes, sim.scene
    grads = nodes.evaluate_gradient(state.u)  # (n_owned, 2, 2)
    strain = 0.5 * (grads + np.swapaxes(grads, 1, 2))
    trace = strain[:, 0, 0] + strain[:, 1, 1]
    sxx = scene.lam * trace + 2 * scene.mu * strain[:, 0, 0]
    syy = scene.lam * trace + 2 * scene.mu * strain[:, 1, 1]
    szz = scene.lam * trace  # plane strain
    sxy = 2 * scene.mu * strain[:, 0, 1]
    von_mises = np.sqrt(0.5 * ((sxx - syy) ** 2 + (syy - szz) ** 2 + (szz - sxx) ** 2) + 3 * sxy**2)
    node_fields = {
        "displacement": nodes.evaluate(state.u),
        "velocity": nodes.evaluate(state.v),
        "acceleration": nodes.evaluate(state.a),
        "von_mises": von_mises,
    }
    contact_fields = {}
    if sim.law is not None:
        law = sim.law
        un = law.kinematics(state.u)[0]
        contact_fields = {
            "gap": law.gap - un,
            "normal_pressure": law.pressure(un),
            "tangential_traction": law.step_friction,
            "status": law.step_status,
        }
    return node_fields, contact_fields


def _writer(comm, sim: Simulation, out_dir: Path, metadata: dict) -> ResultWriter:
    disc = sim.disc
    contact = disc.contact
    return ResultWriter(
        comm,
        out_dir,
        node_coords=disc.nodes.points,
        node_rows=disc.nodes.rows,
        n_nodes=disc.n_nodes,
        contact_coords=np.zeros((0, 2)) if contact is None else contact.points,
        contact_rows=np.zeros(0, dtype=np.int64) if contact is None else contact.rows,
        n_contact=disc.n_contact,
        metadata=metadata,
    )


def run_scene(
    comm,
    scene,
    out: str | None = None,
    quiet: bool = False,
    fail_at_step: int | None = None,
    checkpoint_every: int = 0,
    restart: str | None = None,
) -> dict:
    """Run ``scene`` on ``comm``; write result.h5/.xdmf and summary.json.  Collective.

    ``checkpoint_every`` > 0 writes DIR/checkpoint.h5 every that many steps; ``restart``
    continues from such a file (its step + 1 onwards) instead of the initial state.

    Returns the summary dict (the contents of summary.json).
    """
    start = time.perf_counter()
    start_logging()
    out_dir = choose_output_dir(comm, scene.name, out)
    say = (lambda *a: print(*a, flush=True)) if comm.rank == 0 and not quiet else (lambda *a: None)
    say(f"parefg {__version__}: scene {scene.name} on {comm.size} rank(s) -> {out_dir}")
    disc = build_discretization(comm, scene)
    sim = Simulation(comm, scene, disc, keep_history=False)  # rows go to the writer
    say(
        f"  {disc.n_nodes} nodes, {disc.n_dofs} DOFs, {scene.n_steps} steps of {scene.dt:g}, "
        f"degree {scene.degree}, {'contact' if sim.law else 'no contact'}"
    )
    metadata = {"params": scene.params, "version": __version__, "mpi_ranks": comm.size}
    with phase(sim.timings, "output"):
        writer = _writer(comm, sim, out_dir, metadata)

    state, first = sim.start(), 1
    if restart is not None:
        state, done, last_row = read_checkpoint(comm, Path(restart), sim)
        state, first = sim.resume(state, done, last_row), done + 1
    else:
        writer.append_history(sim.history[0])  # the t = 0 row
    progress = Progress(comm, scene.n_steps, quiet)
    try:
        for n in range(first, scene.n_steps + 1):
            if fail_at_step is not None and n == fail_at_step:
                raise SolverError(f"injected failure at step {n} (--fail-at-step)")
            state = sim.step(state, n)
            row = sim.history[-1]
            with phase(sim.timings, "output"):
                writer.append_history(row)
                if _is_output_step(n, scene):
                    node_fields, contact_fields = _output_fields(sim, state)
                    writer.write_step(n, row["time"], node_fields, contact_fields)
                if checkpoint_every > 0 and n % checkpoint_every == 0:
                    write_checkpoint(comm, out_dir / "checkpoint.h5", sim, state, n)
            progress.update(n, row["time"], row["newton_iterations"])
    except SolverError:
        summary = _summary(comm, scene, disc, sim, start, failed=True)
        _write_summary(comm, out_dir, summary)
        writer.close(_flat(summary))
        raise
    summary = _summary(comm, scene, disc, sim, start, errors=sim.errors(state.u, scene.T))
    writer.close(_flat(summary))
    summary["timings"]["total"] = time.perf_counter() - start
    _write_summary(comm, out_dir, summary)
    if comm.rank == 0 and not quiet:
        print_summary(summary, out_dir)
    return summary


def _is_output_step(n: int, scene) -> bool:
    every = scene.output_every
    return n == scene.n_steps or (every > 0 and n % every == 0)


def _summary(comm, scene, disc, sim, start, errors=None, failed=False) -> dict:
    timings = {"total": time.perf_counter() - start, **disc.timings}
    timings["assembly"] = disc.timings["assembly"] + sim.timings["assembly"]
    timings.update(solve=sim.timings["solve"], output=sim.timings["output"])
    # PETSc's factorization events (part of assembly and solve), slowest rank
    timings["factorization"] = comm.allreduce(factorization_stats()[0], op=MPI.MAX)
    summary = {
        "scene": scene.name,
        "params": scene.params,
        "mpi_ranks": comm.size,
        "n_nodes": disc.n_nodes,
        "n_dofs": disc.n_dofs,
        "n_steps": scene.n_steps,
        "steps_done": int(round(sim.history[-1]["time"] / scene.dt)),
        "timings": timings,
        "newton_iterations": sim.newton_iterations,
        "linear_iterations": sim.linear_iterations,
        "factorizations": sim.solver.factorizations,
        "max_newton_per_step": sim.max_newton_per_step,
        # peak resident memory of the largest rank (ru_maxrss is in KiB on Linux)
        "peak_rss_mb": comm.allreduce(
            resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, op=MPI.MAX
        )
        / 1024,
        "mls_condition": {"min": disc.condition_range[0], "max": disc.condition_range[1]},
        "version": __version__,
        "status": "failed" if failed else "ok",
    }
    if errors is not None:
        summary["errors"] = errors
    return summary


def _flat(summary: dict) -> dict:
    return {"summary_json": json.dumps(summary, default=float)}


def _write_summary(comm, out_dir: Path, summary: dict) -> None:
    if comm.rank == 0:
        (out_dir / "summary.json").write_text(json.dumps(summary, indent=2, default=float) + "\n")


def print_summary(summary: dict, out_dir: Path, file=sys.stdout) -> None:
    """The final table on rank 0."""
    t = summary["timings"]
    lines = [
        f"done: {summary['n_steps']} steps, {summary['newton_iterations']} Newton / "
        f"{summary['linear_iterations']} linear iterations, "
        f"{summary['factorizations']} factorization(s)"
    ]
    if "errors" in summary:
        e = summary["errors"]
        lines.append(f"errors at T: L2 {e['l2_rel']:.3e}   H1 {e['h1_rel']:.3e}  (relative)")
    lines.append("time [s]: " + "  ".join(f"{k} {v:.2f}" for k, v in t.items()))
    lines.append(f"results: {out_dir}/result.h5, result.xdmf, summary.json")
    print("\n".join(lines), file=file, flush=True)
