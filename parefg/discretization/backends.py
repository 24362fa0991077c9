"""Which kernels compute MLS and the assembly: numba's, compiled ahead of time where
``make setup`` installed them, else numpy for small problems and numba's JIT for large ones.

Both backends give the same neighbour lists, CSR patterns and values to round-off
(tests/discretization/test_mls.py, test_assembly_backends.py).  numba's kernels are faster
per point.  Compiled ahead of time (:mod:`.aot`) they load in a millisecond, so they are
the default at every size.  Without that module a process that uses them first pays
importing numba (~0.17 s) and loading its cached machine code (~0.3 s for the kernels of
a run): on a small problem that is most of the run.  The default is then chosen by the
global node count, which every rank knows, so that all ranks (and 1 rank against 2) use
the same kernels: numba from :data:`NUMBA_MIN_NODES` nodes on (where it is installed and
knows the weight), numpy below.  The threshold is the crossover of whole runs measured by
scripts/bench/bench_backends.py.  (Ranks of one installation agree on whether the
compiled module is there; ranks that did not would differ by round-off only.)

The environment variable ``PAREFG_KERNELS`` (``numba`` or ``numpy``) overrides the
choice, e.g. to compare the backends on one scene.  numba is imported only by the
modules of its kernels, and those only when a kernel runs by the JIT.
"""

import functools
import importlib.util
import os

from parefg.discretization import aot
from parefg.errors import InputError

# Nodes from which numba's kernels win a whole run, one-off costs included.  Measured by
# scripts/bench/bench_backends.py (square, m = 2, medians of 3): warm numpy - warm numba
# (search + MLS + assembly) is 0.24 s at 289 nodes and 0.38 s at 441, numba's one-off cost
# in a fresh process 0.35 s: the crossover is at ~400 nodes.
NUMBA_MIN_NODES = 400
ENVIRONMENT = "PAREFG_KERNELS"
NAMES = ("numba", "numpy")


@functools.cache
def numba_installed() -> bool:
    """Whether numba can be imported (without importing it)."""
    return importlib.util.find_spec("numba") is not None


def forced() -> str | None:
    """The backend named by ``PAREFG_KERNELS``, or None."""
    name = os.environ.get(ENVIRONMENT, "").strip().lower()
    if not name:
        return None
    if name not in NAMES:
        raise InputError(f"{ENVIRONMENT} must be one of {NAMES}, got {name!r}")
    if name == "numba" and not numba_installed():
        raise InputError(f"{ENVIRONMENT}=numba, but numba is not installed")
    return name


def choose(n_nodes: int, compiled: bool = True) -> str:
    """The backend for a problem of ``n_nodes`` (global) nodes.

    ``compiled``: whether numba has a kernel for the problem (MLS: a weight with a code).
    """
    name = forced()
    if name is not None:
        return name if compiled else "numpy"
    if compiled and (aot.available() or (numba_installed() and n_nodes >= NUMBA_MIN_NODES)):
        return "numba"
    return "numpy"


def describe() -> str:
    """One line for ``parefg info``: which kernels a run uses (as :func:`choose` does)."""
    name = forced()
    if name == "numpy":
        return f"numpy ({ENVIRONMENT}=numpy)"
    if aot.available():
        source = f"numba's, compiled ahead of time ({aot.directory()})"
        return source + (f" ({ENVIRONMENT}=numba)" if name else ", at every size")
    if not numba_installed():
        return "numpy (numba is not installed)"
    source = "numba's JIT (nothing compiled ahead of time for this source: make setup)"
    return source + (
        f" ({ENVIRONMENT}=numba)" if name else f" from {NUMBA_MIN_NODES} nodes, numpy below"
    )
