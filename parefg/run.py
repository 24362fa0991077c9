"""Run a scene end to end: discretize, step, write results and summary.json (SPEC 7, 8)."""

from __future__ import annotations

import json
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from mpi4py import MPI

from parefg import __version__
from parefg.discretization.budget import check_problem_size
from parefg.discretization.operators import build_discretization
from parefg.errors import InputError, Interrupted, SolverError
from parefg.io.checkpoint import read_checkpoint
from parefg.io.monitors import Progress, StopRequest
from parefg.io.observers import CheckpointObserver, ResultsObserver
from parefg.io.output import ResultWriter
from parefg.parallel import call_on_root
from parefg.petsc_options import (
    petsc_configuration,
    scene_options,
    step_solver_options,
    unused_options_warning,
)
from parefg.profiling import factorization_stats, peak_rss_kib, phase, start_logging
from parefg.scene.loader import load_scene
from parefg.timestepping.loop import Callback, Observer, time_loop
from parefg.timestepping.simulation import Simulation


def plan_output_dir(comm, scene_name: str, requested: str | None) -> Path:
    """The run's output directory, checked but not created (nothing is written).  Collective.

    Without --out: runs/<scene>, or runs/<scene>-2, -3, ... if taken.  Refuses
    (InputError on every rank) an existing non-empty directory, a path that is not a
    directory, a dangling symbolic link, a name the file system cannot hold, and a path
    under a file; what only mkdir can tell (/proc, a read-only file system) is
    refused by :func:`create_output_dir`.
    """
    return call_on_root(comm, _planned_output_dir, scene_name, requested)


def _planned_output_dir(scene_name: str, requested: str | None) -> Path:
    """:func:`plan_output_dir` on one rank: the path, or InputError saying why not."""
    if requested is not None:
        path = Path(requested)
    else:
        base = Path("runs") / scene_name
        path, n = base, 1
        while path.exists() or path.is_symlink():
            n += 1
            path = base.with_name(f"{base.name}-{n}")
    message = _unusable_output(path, requested)
    if message:
        raise InputError(message)
    return path


def create_output_dir(comm, path: Path, requested: str | None) -> list[Path]:
    """Create ``path`` and its missing parents; returns the directories created.  Collective.

    On failure the directories this call created are removed again and InputError is
    raised on every rank.
    """
    return call_on_root(comm, _created_output_dir, path, requested)


def _created_output_dir(path: Path, requested: str | None) -> list[Path]:
    """:func:`create_output_dir` on one rank."""
    missing = [p for p in (path, *path.parents) if not (p.exists() or p.is_symlink())]
    created: list[Path] = []
    try:
        for directory in reversed(missing):
            directory.mkdir()
            created.append(directory)
    except OSError as error:
        remove_empty_dirs(created)
        reason = _os_reason(error)
        raise InputError(f"{_output_label(path, requested)}: cannot create it ({reason})") from None
    return created


def remove_empty_dirs(created: list[Path]) -> None:
    """Remove the directories a run created (innermost first) as long as they are empty."""
    for directory in reversed(created):
        try:
            directory.rmdir()
        except OSError:
            return  # not empty (or gone): keep it and everything above it


def _output_label(path: Path, requested: str | None) -> str:
    text = str(path)
    if len(text) > 80:
        text = f"{text[:50]}...{text[-20:]} ({len(text)} characters)"
    return f"--out {text}" if requested is not None else f"output directory {text}"


def _os_reason(error: OSError) -> str:
    return error.strerror or str(error)


def _unusable_output(path: Path, requested: str | None) -> str | None:
    """Why ``path`` cannot become the output directory (checked without writing), or None."""
    label = _output_label(path, requested)
    try:
        if path.is_symlink() and not path.exists():
            return f"{label}: is a dangling symbolic link; choose another --out"
        if path.exists():
            if not path.is_dir():
                return f"{label}: exists and is not a directory; choose another --out"
            if any(path.iterdir()):
                return f"output directory {path} exists and is not empty; choose another --out"
            return None
        return _uncreatable(path, label)
    except OSError as error:  # a name too long for the file system, a loop of links, ...
        return f"{label}: cannot create it ({_os_reason(error)})"


def _uncreatable(path: Path, label: str) -> str | None:
    """For a path that does not exist: why mkdir would fail, as far as it is known now."""
    ancestor = next(p for p in path.absolute().parents if p.exists())
    if not ancestor.is_dir():
        return f"{label}: cannot create it ({ancestor} is not a directory)"
    name_max = os.pathconf(ancestor, "PC_NAME_MAX")
    path_max = os.pathconf(ancestor, "PC_PATH_MAX")
    longest = max(len(os.fsencode(part)) for part in path.parts)
    if longest > name_max:
        return f"{label}: cannot create it (a name of {longest} bytes; the limit is {name_max})"
    if len(os.fsencode(path.absolute())) >= path_max:
        return f"{label}: cannot create it (longer than the path limit of {path_max} bytes)"
    if os.statvfs(ancestor).f_flag & os.ST_RDONLY:
        return f"{label}: cannot create it ({ancestor} is on a read-only file system)"
    if not os.access(ancestor, os.W_OK | os.X_OK):
        return f"{label}: cannot create it ({ancestor} is not writable)"
    return None


def prepare(
    comm, source: str, overrides: Sequence[str] = (), keep_history: bool = True
) -> Simulation:
    """Load and discretize a scene and set up its Simulation, to step in-process.  Collective.

    ``source`` and ``overrides`` are those of :func:`~parefg.scene.loader.load_scene`; the
    scene and its discretization are ``sim.scene`` and ``sim.disc``.  The problem size is
    checked against the machine first (InputError on every rank).  Nothing is written and
    no step is taken: ``state = sim.start()``, then ``state = sim.step(state, n)`` for
    n = 1 .. ``sim.scene.time.n_steps``.  ``keep_history`` False keeps only the last row of
    ``sim.history`` (long runs).  The solvers read the scene's [solver] options as in a
    run (:func:`build_simulation`).  :func:`run_scene` is the whole run with its output.
    """
    scene = load_scene(source, list(overrides), step_solver_options())
    return build_simulation(comm, scene, build_discretization(comm, scene), keep_history)


def build_simulation(comm, scene, disc, keep_history: bool = True) -> Simulation:
    """The Simulation of ``scene`` on ``disc``, its step solvers configured.  Collective.

    The scene's [solver] options apply (under the command line's) while the solvers read
    them; a PETSc error meanwhile (an unknown -ksp_type) is an InputError on every rank.
    The one place a Simulation is made: :func:`prepare` (in-process) and
    :func:`run_scene` (the whole run) both call it.
    """
    with (
        scene_options(scene.solver.options),
        petsc_configuration(comm, "the solvers", scene.solver.options),
    ):
        return Simulation(comm, scene, disc, keep_history=keep_history)


def run_scene(
    comm,
    scene,
    out: str | None = None,
    quiet: bool = False,
    fail_at_step: int | None = None,
    checkpoint_every: int = 0,
    restart: str | None = None,
    max_memory: float | None = None,
    observers=(),
) -> dict:
    """Run ``scene`` on ``comm``; write result.h5/.xdmf and summary.json.  Collective.

    ``checkpoint_every`` > 0 writes DIR/checkpoint.h5 every that many steps; ``restart``
    continues from such a file (its step + 1 onwards) instead of the initial state.
    ``max_memory`` (GB per machine; default: its available memory) bounds the estimated
    size of the run: a scene beyond it is refused before anything is created.
    Each of ``observers`` is called as ``observer(n, sim, state)`` after every step n, on
    every rank; the state's vectors are the run's: read them (``getArray(readonly=True)``),
    never write them.

    Outputs: with ``[output] every`` = N > 0, t = 0 (unless restarted), every N-th step
    and the final step; with 0 the final step only.  SIGINT / SIGTERM stop the run after
    the step every rank has finished (that step is written too): summary.json says
    "interrupted" and Interrupted (exit 128 + signal) is raised.

    The scene's [solver] options apply for this run only, under the command line's; at
    the end, rank 0 warns on stderr about PETSc options no object used.

    Everything that can be checked -- the problem size, the output path, the
    discretization, the solver options, the checkpoint -- is checked before the output
    directory is created, so bad input writes nothing.

    Returns the summary dict (the contents of summary.json).
    """
    options = dict(fail_at_step=fail_at_step, checkpoint_every=checkpoint_every)
    with StopRequest(comm) as stop, scene_options(scene.solver.options) as from_scene:
        summary = _run(comm, scene, out, quiet, stop, restart, observers, max_memory, **options)
        warning = unused_options_warning(comm, from_scene)
    if warning and comm.rank == 0:
        print(warning, file=sys.stderr, flush=True)
    return summary


def _run(
    comm, scene, out, quiet, stop, restart, observers, max_memory, fail_at_step, checkpoint_every
) -> dict:
    start = time.perf_counter()
    start_logging()
    factorized_before = factorization_stats()[0]  # PETSc's log counts since the process began
    budget = check_problem_size(comm, scene, max_memory)
    out_dir = plan_output_dir(comm, scene.name, out)
    say = (lambda *a: print(*a, flush=True)) if comm.rank == 0 and not quiet else (lambda *a: None)
    say(f"parefg {__version__}: scene {scene.name} on {comm.size} rank(s) -> {out_dir}")
    disc = build_discretization(comm, scene, budget)
    stop.reclaim()  # meshing (gmsh) may have replaced the SIGINT handler
    sim, state, first = _start(comm, scene, disc, restart)
    say(
        f"  {disc.n_nodes} nodes, {disc.n_dofs} DOFs,"
        f" {scene.time.n_steps} steps of {scene.time.dt:g}, degree {scene.discretization.degree},"
        f" {'contact' if sim.law else 'no contact'}"
    )
    writer = _open_writer(comm, sim, out_dir, out)
    results = ResultsObserver(writer)
    if restart is None:
        results.write_initial(sim, state)
    loop_observers: list[Observer] = [results]
    if checkpoint_every > 0:
        loop_observers.append(CheckpointObserver(out_dir / "checkpoint.h5", checkpoint_every))
    loop_observers += [Progress(comm, scene.time.n_steps, quiet, first)]
    loop_observers += [Callback(observer) for observer in observers]
    try:
        state = time_loop(sim, state, first, loop_observers, stop, fail_at_step)
    except SolverError as error:
        status = "interrupted" if isinstance(error, Interrupted) else "failed"
        summary = _summary(comm, scene, disc, sim, (start, factorized_before), status=status)
        _write_summary(comm, out_dir, summary)
        writer.close(_flat(summary))
        if isinstance(error, Interrupted):
            message = f"{error}; results so far in {out_dir}"
            raise Interrupted(message, error.exit_code - 128) from None
        raise
    with phase(sim.timings, "errors"):
        errors = sim.errors(state.u, scene.time.T)
    summary = _summary(comm, scene, disc, sim, (start, factorized_before), errors)
    writer.close(_flat(summary))
    summary["timings"]["total"] = time.perf_counter() - start
    _write_summary(comm, out_dir, summary)
    if comm.rank == 0 and not quiet:
        print_summary(summary, out_dir)
    return summary


def _start(comm, scene, disc, restart: str | None):
    """The simulation and the level it starts from: t = 0, or a checkpoint.  Collective."""
    sim = build_simulation(comm, scene, disc, keep_history=False)  # rows go to the writer
    with petsc_configuration(comm, "the solvers", scene.solver.options):
        state, first = sim.start(), 1  # sets up the mass solve (-mass_ options) too
    if restart is not None:
        snapshot = read_checkpoint(comm, Path(restart), sim)
        state, first = sim.restore(snapshot), snapshot["step"] + 1
    return sim, state, first


def _open_writer(comm, sim, out_dir: Path, out: str | None) -> ResultWriter:
    """Create the output directory and the result writer (nothing is left if that fails)."""
    created = create_output_dir(comm, out_dir, out)
    try:
        with phase(sim.timings, "output"):
            return result_writer(comm, sim, out_dir)
    except BaseException:
        if comm.rank == 0:
            remove_empty_dirs(created)
        raise


def result_writer(comm, sim, out_dir: Path) -> ResultWriter:
    """The writer of ``sim``'s results (nodes, Gamma_C points, the effective scene) in the
    existing directory ``out_dir``.  Collective."""
    disc, contact = sim.disc, sim.disc.contact
    return ResultWriter(
        comm,
        out_dir,
        node_coords=disc.nodes.points,
        node_rows=disc.nodes.rows,
        n_nodes=disc.n_nodes,
        contact_coords=np.zeros((0, 2)) if contact is None else contact.points,
        contact_rows=np.zeros(0, dtype=np.int64) if contact is None else contact.rows,
        n_contact=disc.n_contact,
        metadata={"params": sim.scene.params, "version": __version__, "mpi_ranks": comm.size},
    )


def _summary(comm, scene, disc, sim, started, errors=None, status="ok") -> dict:
    """summary.json of a run; ``started`` = (perf_counter, factorization seconds) at its start."""
    start, factorized_before = started
    timings = {"total": time.perf_counter() - start, **disc.timings}
    timings["assembly"] = disc.timings["assembly"] + sim.timings["assembly"]
    timings.update(solve=sim.timings["solve"], output=sim.timings["output"])
    timings["errors"] = sim.timings.get("errors", 0.0)  # the error norms at T (exact scenes)
    # PETSc's factorization events (part of assembly and solve), slowest rank
    factorized = factorization_stats()[0] - factorized_before  # this run's, not the process's
    timings["factorization"] = comm.allreduce(factorized, op=MPI.MAX)
    summary = {
        "scene": scene.name,
        "params": scene.params,
        "mpi_ranks": comm.size,
        "n_nodes": disc.n_nodes,
        "n_dofs": disc.n_dofs,
        "n_steps": scene.time.n_steps,
        "steps_done": int(round(sim.history[-1]["time"] / scene.time.dt)),
        "timings": timings,
        "newton_iterations": sim.newton_iterations,
        "linear_iterations": sim.linear_iterations,
        "factorizations": sim.solver.factorizations,
        "max_newton_per_step": sim.max_newton_per_step,
        **sim.coulomb_summary(),  # outer iterations of the Coulomb fixed point, if any
        "peak_rss_mb": comm.allreduce(peak_rss_kib(), op=MPI.MAX) / 1024,  # largest rank
        "mls_condition": {"min": disc.condition_range[0], "max": disc.condition_range[1]},
        "version": __version__,
        "status": status,
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
    if "coulomb_iterations" in summary:
        lines.append(
            f"Coulomb fixed point: {summary['coulomb_iterations']} outer iterations "
            f"(at most {summary['max_coulomb_per_step']} per step)"
        )
    if "errors" in summary:
        e = summary["errors"]
        lines.append(f"errors at T: L2 {e['l2_rel']:.3e}   H1 {e['h1_rel']:.3e}  (relative)")
    lines.append("time [s]: " + "  ".join(f"{k} {v:.2f}" for k, v in t.items()))
    lines.append(f"results: {out_dir}/result.h5, result.xdmf, summary.json")
    print("\n".join(lines), file=file, flush=True)
