"""The ``parefg`` command (SPEC 8): run, sweep, scenes, info.

PETSc options (-snes_monitor, -ksp_type, -log_view, ...) may appear anywhere on the
command line; they are handed to PETSc before petsc4py is imported.  An uncaught
exception on any rank aborts every rank (no hang under mpirun).
"""

from __future__ import annotations

import argparse
import gc
import os
import sys

from parefg import __version__
from parefg.errors import InputError, SolverError


def _is_value(arg: str) -> bool:
    """A PETSc option value: anything not starting with '-', or a (negative) number."""
    try:
        float(arg)
        return True
    except ValueError:
        return not arg.startswith("-")


def _split_petsc_options(argv: list[str]) -> tuple[list[str], list[str]]:
    """Separate PETSc options (``-name [value]``) from parefg's own arguments."""
    ours, petsc = [], []
    i = 0
    while i < len(argv):
        arg = argv[i]
        if arg.startswith("-") and not arg.startswith("--") and len(arg) > 2 and not _is_value(arg):
            petsc.append(arg)
            if i + 1 < len(argv) and _is_value(argv[i + 1]):
                petsc.append(argv[i + 1])
                i += 1
        else:
            ours.append(arg)
        i += 1
    return ours, petsc


class _Parser(argparse.ArgumentParser):
    """argparse with parefg's error contract: one line on stderr (rank 0 only), exit 2.

    It runs before MPI is initialized, so the rank comes from the launcher's environment.
    """

    def error(self, message: str):
        rank = os.environ.get("OMPI_COMM_WORLD_RANK", os.environ.get("PMI_RANK", "0"))
        if rank == "0":
            command = self.prog.removeprefix("parefg").strip()
            where = f"{command}: " if command else ""
            print(f"parefg: error: {where}{message} (see {self.prog} --help)", file=sys.stderr)
        sys.exit(2)


def _count(text: str) -> int:
    """A non-negative integer argument (argparse type)."""
    value = int(text)
    if value < 0:
        raise ValueError(text)
    return value


_count.__name__ = "non-negative integer"  # argparse names the type in its message


FINISH_PATIENCE = 10.0  # seconds the ranks of a failed run wait for each other at the end
MAX_MEMORY_HELP = (
    "memory a run may use on each machine, in GB (default: 80%% of its available memory); "
    "a scene estimated to need more is refused before meshing"
)


def _parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="parefg",
        description="PETSc-parallel EFG solver for dynamic contact with friction. "
        "PETSc options (-snes_monitor, -ksp_type, ...) are accepted anywhere.",
    )
    parser.add_argument("--version", action="version", version=f"parefg {__version__}")
    sub = parser.add_subparsers(dest="command")
    run = sub.add_parser("run", help="run a scene")
    run.add_argument("scene", help="built-in scene name or path to a TOML file")
    run.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="SECTION.KEY=VALUE",
        help="override a scene value (repeatable)",
    )
    run.add_argument("--out", help="output directory (must not exist or be empty)")
    run.add_argument("--quiet", action="store_true", help="no progress output")
    run.add_argument("--fail-at-step", type=_count, help="testing: fail on purpose at this step")
    run.add_argument(
        "--checkpoint-every",
        type=_count,
        default=0,
        metavar="N",
        help="write DIR/checkpoint.h5 (u, v, a, slip, step) every N steps",
    )
    run.add_argument("--restart", metavar="FILE", help="continue from a checkpoint file")
    run.add_argument("--max-memory", type=float, metavar="GB", help=MAX_MEMORY_HELP)
    run.add_argument(
        "--solver",
        metavar="METHOD",
        help='linear solver method: "direct" (default) or "iterative" (CG + GAMG); '
        "overrides the scene's solver.method, -ksp_/-pc_ options still apply",
    )
    sweep = sub.add_parser("sweep", help="run a grid of cases; error-vs-time table, CSV and PNG")
    sweep.add_argument("scene")
    sweep.add_argument("--vary", action="append", required=True, metavar="SECTION.KEY=V1,V2,...")
    sweep.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE")
    sweep.add_argument("--out", help="output directory for the sweep")
    sweep.add_argument("--max-memory", type=float, metavar="GB", help=MAX_MEMORY_HELP)
    sub.add_parser("scenes", help="list the built-in scenes")
    sub.add_parser("info", help="versions, MPI and PETSc configuration")
    return parser


def _install_abort_hook() -> None:
    """An uncaught exception on one rank aborts all ranks instead of leaving them waiting."""
    from mpi4py import MPI

    default_hook = sys.excepthook

    def hook(kind, value, traceback):
        default_hook(kind, value, traceback)
        sys.stderr.flush()
        if MPI.COMM_WORLD.size > 1:
            MPI.COMM_WORLD.Abort(1)

    sys.excepthook = hook


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    ours, petsc_options = _split_petsc_options(argv)
    args = _parser().parse_args(ours)
    import petsc4py

    petsc4py.init([sys.argv[0], *petsc_options])
    from mpi4py import MPI

    from parefg.parallel import wait_for_all

    _install_abort_hook()
    comm = MPI.COMM_WORLD
    try:
        return _dispatch(comm, args)
    except (InputError, SolverError) as error:
        if comm.rank == 0:
            print(f"parefg: error: {error}", file=sys.stderr, flush=True)
        # every rank reaches the same error; one that does not within FINISH_PATIENCE
        # seconds is stuck in a collective, and the job is aborted
        wait_for_all(comm, patience=FINISH_PATIENCE, abort_code=error.exit_code)
        return error.exit_code


def _dispatch(comm, args) -> int:
    from parefg import commands

    if args.command is None:  # `mpirun -n 2 parefg`: the default scene at modest resolution
        args = _parser().parse_args(["run", "square"])
    return getattr(commands, args.command)(comm, args)


def program() -> None:
    """The ``parefg`` program: :func:`main` on the command line, then exit with its code.

    Before exiting, every object is frozen out of the garbage collector: at interpreter
    shutdown Python otherwise runs full collections over every object still alive (the
    modules of numpy, scipy, h5py, PETSc and the run's own), ~0.23 s of a 0.8 s default run
    measured.  Nothing the run wrote depends on them: its HDF5 files are closed, the XDMF
    index is written by unbuffered descriptors, summary.json is closed, and the exit
    handlers (MPI's and PETSc's finalization, the temporary directories) still run.  Only
    here, where the process ends: a caller of :func:`main` keeps its collector.
    """
    code = main()
    gc.freeze()
    sys.exit(code)


if __name__ == "__main__":
    program()
