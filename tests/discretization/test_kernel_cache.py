"""The compiled kernels are cached on disk: a run pays numba's compilation once, not each time.

Every numba kernel of :mod:`parefg.discretization.mls_kernels` and
:mod:`parefg.discretization.assembly_kernels` is compiled with ``cache=True``, and a fresh
process that runs them (MLS search and evaluation, a Gram assembly) after a first one
finds them all in the cache: no compilation in the second process.  A kernel numba cannot
cache (a closure, an object-mode fallback, a global it re-reads) shows up here as a miss.
"""

import subprocess
import sys

import pytest
from conftest import mpi_env

from parefg.discretization import aot, assembly_kernels, backends, mls_kernels

try:
    import numba
    import numba.core.caching
    import numba.core.registry
except ImportError:  # pragma: no cover - numba is a Debian package of the environment
    numba = None

pytestmark = pytest.mark.skipif(numba is None, reason="numba is not installed")

# Uses the kernels as a run does (search, shape functions, coupling pattern, Gram,
# interleaving) and prints the compilations each kernel needed in this process.
PROBE = """
import numpy as np
from numba.core.registry import CPUDispatcher
from parefg.discretization import assembly_kernels, mls_kernels
from parefg.discretization.assembly import Coupling
from parefg.discretization.mls import MLS

grid = np.linspace(0.0, 1.0, 6)
nodes = np.array([(x, y) for x in grid for y in grid])
points = np.random.default_rng(0).random((50, 2))
mls = MLS(nodes, np.full(len(nodes), 0.5), 2)
shape = mls.evaluate(points)
coupling = Coupling.of(shape, len(nodes))
gram = coupling.gram(shape.dphi, shape.dphi, np.ones(len(points)))
coupling.interleaved(np.repeat(gram[:, :1, :1], 2, axis=1).repeat(2, axis=2))
for module in (mls_kernels, assembly_kernels):
    for name, kernel in vars(module).items():
        if isinstance(kernel, CPUDispatcher):
            print(module.__name__, name, sum(kernel.stats.cache_misses.values()))
"""


def _compilations() -> dict[str, int]:
    """Kernel -> compilations in a fresh process that uses the kernels as a run does."""
    # A problem this small takes the numpy kernels by default (backends.py): force numba.
    # And by the JIT: the kernels compiled ahead of time would not touch its cache.
    env = mpi_env() | {backends.ENVIRONMENT: "numba", aot.ENVIRONMENT: ""}
    result = subprocess.run(
        [sys.executable, "-c", PROBE], capture_output=True, text=True, env=env, timeout=300
    )
    assert result.returncode == 0, result.stderr
    rows = [line.split() for line in result.stdout.splitlines()]
    return {f"{module}.{name}": int(misses) for module, name, misses in rows}


def test_every_kernel_is_compiled_with_an_on_disk_cache():
    kernels = [
        (module.__name__, name)
        for module in (mls_kernels, assembly_kernels)
        for name, kernel in vars(module).items()
        if isinstance(kernel, numba.core.registry.CPUDispatcher)
    ]
    assert len(kernels) >= 10  # the search, the MLS helpers and the assembly kernels
    uncached = [
        f"{module}.{name}"
        for module, name in kernels
        if not isinstance(
            getattr(sys.modules[module], name)._cache, numba.core.caching.FunctionCache
        )
    ]
    assert uncached == []


@pytest.mark.serial_only
def test_a_second_process_compiles_nothing():
    _compilations()  # fills the cache if this tree has none yet (first run after an edit)
    second = _compilations()
    assert len(second) >= 10
    compiled = {name: count for name, count in second.items() if count}
    assert compiled == {}, f"compiled again in a fresh process: {compiled}"
