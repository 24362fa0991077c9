"""PETSc options as input: the scene's [solver] table, bad values, options nobody used.

PETSc is parefg's solver configuration language (SPEC 4): options come from the command
line (handed to ``petsc4py.init``) and from the scene's ``[solver]`` table.  This module

* puts the scene's options into the global database for the duration of one run, under
  the command line's (a command-line option of the same name wins), and takes them out
  afterwards, so a second run in the same process does not inherit them;
* turns a ``PETSc.Error`` raised while the solvers are configured (an unknown
  ``-ksp_type``, ``-pc_factor_mat_solver_type nope``) into an :class:`InputError` that
  names the option;
* lists the options no PETSc object (and no parefg code) ever queried -- typically a
  misspelling such as ``-ksp_tpye`` -- through PETSc's own bookkeeping
  (``PetscOptionsLeftGet``, which petsc4py 3.18 does not wrap; reached with ctypes).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import itertools
from contextlib import contextmanager

from petsc4py import PETSc

from parefg.errors import InputError, SolverError
from parefg.parallel import default_options, raise_everywhere, wait_for_all

#: PC types that solve exactly (to round-off) under KSP preonly, and that keep a factor in memory
EXACT_FACTORIZATIONS = ("lu", "cholesky")

# Options PETSc reads only in PetscFinalize, after any check a run can make.
_READ_AT_FINALIZE = {
    "options_left",
    "options_view",
    "malloc_dump",
    "malloc_view",
    "memory_view",
    "objects_dump",
}
# PETSc error codes that are the numerics failing, not the configuration being wrong.
_SOLVER_FAILURES = {71: "zero pivot in LU", 77: "not converged", 81: "zero pivot in Cholesky"}
_OUT_OF_MEMORY = 55
# seconds a rank that failed waits for the others to leave the block before it aborts the
# job: a rank stuck in a collective the failed rank left would otherwise wait forever
AGREEMENT_TIMEOUT = 60.0


def scene_options(solver_options: dict[str, str]):
    """Insert the scene's [solver] options for the duration of the block.

    Options already in the database (the command line's) are left alone, so the command
    line wins; exactly the inserted names are deleted on exit, whatever happens.
    Yields the names inserted.  Not collective (every rank does the same).
    """
    return default_options("", solver_options)


@functools.cache  # the process's libpetsc does not change; reading the maps costs ~20 ms
def _library():
    """libpetsc as petsc4py loaded it (found in the process's mappings), or None."""
    loaded = []
    try:
        with open("/proc/self/maps") as maps:
            loaded = [line.split()[-1] for line in maps if "/libpetsc" in line]
    except OSError:
        pass
    # find_library runs ldconfig or gcc (0.05-0.2 s measured): only when the maps do not do
    fallbacks = (ctypes.util.find_library(name) for name in ("petsc_real", "petsc"))
    for name in itertools.chain(dict.fromkeys(loaded), fallbacks):
        if name is None:
            continue
        try:
            library = ctypes.CDLL(name)
        except OSError:
            continue
        if hasattr(library, "PetscOptionsLeftGet"):
            return library
    return None


def _left_on_this_rank() -> set[str] | None:
    """Names of the options in the global database never queried here; None if unknown."""
    library = _library()
    if library is None:
        return None
    int_type = ctypes.c_int64 if PETSc.IntType().itemsize == 8 else ctypes.c_int32
    count = int_type()
    names = ctypes.POINTER(ctypes.c_char_p)()
    values = ctypes.POINTER(ctypes.c_char_p)()
    arguments = (None, ctypes.byref(count), ctypes.byref(names), ctypes.byref(values))
    if library.PetscOptionsLeftGet(*arguments) != 0:
        return None
    left = {names[i].decode() for i in range(count.value)}
    library.PetscOptionsLeftRestore(*arguments)
    return left - _READ_AT_FINALIZE


def unused_options(comm) -> list[str] | None:
    """Options no rank used (sorted, without '-'); None where PETSc cannot tell.  Collective."""
    local = _left_on_this_rank()
    everywhere = comm.allgather(local)
    if any(left is None for left in everywhere):
        return None
    return sorted(set.intersection(*everywhere))


def unused_options_warning(comm, scene_names: list[str]) -> str | None:
    """The one-line warning about options nobody used, or None.  Collective.

    ``scene_names`` are the options that came from the scene's [solver] table; they are
    named ``solver.NAME``, the others ``-NAME``.
    """
    unused = unused_options(comm)
    if not unused:
        return None
    shown = [f"solver.{name}" if name in scene_names else f"-{name}" for name in unused]
    return (
        "parefg: warning: PETSc option(s) never used (misspelled, or not for this scene?): "
        + ", ".join(shown)
    )


def _options_named_in(text: str, scene: dict[str, str]) -> list[str]:
    """Database options whose value is a word of ``text`` (PETSc's message names the value).

    An option with the value the scene's [solver] table gave it is shown as ``solver.NAME``.
    """
    words = set(text.replace(",", " ").replace(".", " ").split())
    found = []
    for name, value in PETSc.Options().getAll().items():
        if isinstance(value, str) and value in words:
            from_scene = scene.get(name) == value
            found.append(f"solver.{name} = {value!r}" if from_scene else f"-{name} {value}")
    return found


def describe_petsc_error(error: PETSc.Error, what: str, scene: dict[str, str]) -> str:
    """One line: what PETSc refused, naming the option whose value it could not use."""
    lines = [line.strip() for line in getattr(error, "_traceback_", []) if line.strip()]
    detail = lines[-1] if lines else f"PETSc error code {error.ierr}"
    named = _options_named_in(detail, scene)
    culprit = f"PETSc option {' / '.join(named)}: " if named else "PETSc options: "
    return f"{culprit}rejected while setting up {what} ({detail})"


def step_solver_options() -> dict[str, str]:
    """The step solver's -ksp_type, -pc_type, -sub_pc_type and -mat_type in PETSc's
    options database (the command line, PETSC_OPTIONS), which choose the discretization's
    symmetric-solver defaults (parefg.scene.schema.wants_symmetric).  Not collective."""
    given = PETSc.Options().getAll()
    names = ("ksp_type", "pc_type", "sub_pc_type", "mat_type")
    return {name: str(given[name]) for name in names if name in given}


@contextmanager
def petsc_configuration(comm, what: str, scene: dict[str, str]):
    """Run a block that configures PETSc objects; a PETSc error becomes InputError.  Collective.

    ``what`` says what is set up; ``scene`` is the scene's [solver] table (to name an
    option as the scene spelled it).

    Every rank leaves the block (:func:`~parefg.parallel.wait_for_all`), then the ranks
    agree (:func:`~parefg.parallel.raise_everywhere`): if any rank failed, every rank
    raises the first failing rank's message, so no rank is left behind.  An
    out-of-memory error is re-raised as it is; a zero pivot or non-convergence is a
    :class:`SolverError`.
    """
    error: Exception | None = None
    try:
        yield
    except PETSc.Error as failure:
        if failure.ierr == _OUT_OF_MEMORY:
            raise
        kind = SolverError if failure.ierr in _SOLVER_FAILURES else InputError
        error = kind(describe_petsc_error(failure, what, scene))
    wait_for_all(comm, patience=None if error is None else AGREEMENT_TIMEOUT, abort_code=2)
    raise_everywhere(comm, error)
