"""Environment defaults set before MPI or PETSc start: petsc4py's PETSc, Open MPI's transport.

Debian's petsc4py finds its PETSc build through PETSC_DIR unless the
``petsc-dev`` alternative is installed; point it at Debian's PETSc 3.18 build
when the user has not chosen one.

Open MPI chooses its point-to-point layer (the "pml") at MPI_Init by opening every
component it may use and keeping the best.  With Debian's configuration (``pml = ^ucx``)
it always ends with ``ob1`` on one machine, but opening the others (``cm`` and its
network layers) costs ~0.25 s of every process, a third of a small run.  Where all ranks
are on one machine, so that ob1's shared-memory transport is what Open MPI would pick
anyway, ask for ob1 directly; a process started without mpirun (a singleton) also skips
starting Open MPI's helper daemon, which it needs only to spawn processes (parefg never
does).  Any OMPI_MCA_* value the user set wins; on several machines nothing is changed,
so a cluster keeps its fast network layer.  Other MPI libraries ignore these variables.

Such isolated singletons all name their session directory jf.0 under the same base
(/tmp/ompi.HOST.UID), so two processes starting at once could race to create it ("A call
to mkdir was unable to create the desired directory ... File exists": seen when a test
run and another parefg process started together).  A singleton made isolated here gets a
session-directory base of its own, removed when the process ends.
"""

import atexit
import os
import shutil
import tempfile

DEBIAN_PETSC_DIR = "/usr/lib/petscdir/petsc3.18/x86_64-linux-gnu-real"

if "PETSC_DIR" not in os.environ and os.path.isdir(DEBIAN_PETSC_DIR):
    os.environ["PETSC_DIR"] = DEBIAN_PETSC_DIR


def one_machine_transport(environ) -> dict[str, str]:
    """The Open MPI settings to add to ``environ`` (nothing the user has set, nothing
    when mpirun spread the ranks over several machines)."""
    world = environ.get("OMPI_COMM_WORLD_SIZE")
    singleton = world is None
    if not singleton and environ.get("OMPI_COMM_WORLD_LOCAL_SIZE") != world:
        return {}
    wanted = {"OMPI_MCA_pml": "ob1"}
    if singleton:
        wanted["OMPI_MCA_ess_singleton_isolated"] = "1"
    return {key: value for key, value in wanted.items() if key not in environ}


def private_session_base() -> dict[str, str]:
    """A new session-directory base for this process's Open MPI (removed at exit); {} when
    none can be made (Open MPI then uses its default)."""
    try:
        base = tempfile.mkdtemp(prefix="parefg-ompi-")
    except OSError:
        return {}
    atexit.register(shutil.rmtree, base, ignore_errors=True)
    return {"OMPI_MCA_orte_tmpdir_base": base}


_settings = one_machine_transport(os.environ)
if "OMPI_MCA_ess_singleton_isolated" in _settings and "OMPI_MCA_orte_tmpdir_base" not in os.environ:
    _settings.update(private_session_base())
os.environ.update(_settings)
