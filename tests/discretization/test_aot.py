"""The kernels compiled ahead of time (:mod:`parefg.discretization.aot`) are the JIT's.

``make setup`` compiles every signature the JIT compiled on its warm-up scenes into one
extension module.  Here: it is installed for this source; a build of any size loads it
without importing numba and never falls back to the JIT (without it, a build below the
node-count threshold runs numpy's kernels and imports no numba either); whole builds
through it are bit for bit those of numba's JIT, serially and under mpirun -n 2; a call
whose argument types it was not compiled for (another dtype, a strided view, a read-only
array) goes to the JIT, which gives the right answer; a damaged module directory is no
module; and the key a call is matched on is numba's own type of each argument.
"""

import subprocess
import sys

import numpy as np
import pytest
from conftest import mpi_env
from mpi4py import MPI

from parefg.discretization import aot, backends
from parefg.discretization.operators import build_discretization
from parefg.scene.loader import load_scene

pytestmark = pytest.mark.skipif(not backends.numba_installed(), reason="numba is not installed")


def test_the_compiled_module_of_this_source_is_installed():
    # `make setup` builds it; without it every run pays numba's import (~0.35 s).
    assert aot.available(), f"no compiled kernels in {aot.directory()}: run `make setup`"


def test_value_keys_are_numba_types():
    import numba

    matrix = np.arange(12.0).reshape(3, 4)
    read_only = matrix.copy()
    read_only.flags.writeable = False
    values = [
        matrix,
        np.asfortranarray(matrix),
        matrix[:, ::2],
        read_only,
        np.zeros(5, dtype=np.int32),
        np.zeros((2, 3), dtype=bool),
        np.zeros((0, 2)),
        3,
        2.5,
        True,
        np.int64(4),
        np.float64(1.0),
        np.bool_(False),
        (0.0, 0.0, 0.0),
        (matrix, np.zeros(3, dtype=np.int64), 1.0),
    ]
    for value in values:
        assert aot.value_key(value) == aot.type_key(numba.typeof(value)), value


# Scenes whose builds take every kernel: MLS of each degree, VCI (m = 3), Nitsche and
# penalty boundaries, the Z domain's unstructured cells.
BUILDS = [
    ("square", ["discretization.degree=1"]),
    ("square", ["discretization.degree=2", "discretization.h=0.0625"]),
    ("square", ["discretization.degree=3", "discretization.h=0.125"]),
    ("z", ["discretization.h=0.125"]),
]


def _matrices(disc) -> dict[str, np.ndarray]:
    arrays = {}
    for name in ("mass", "stiffness", "dirichlet"):
        indptr, indices, data = getattr(disc, name).getValuesCSR()
        arrays.update({f"{name}.indptr": indptr, f"{name}.indices": indices, name: data})
    return arrays


@pytest.mark.parametrize("scene,overrides", BUILDS, ids=[f"{s}-{o[0]}" for s, o in BUILDS])
def test_builds_through_the_compiled_module_are_the_jits_bit_for_bit(monkeypatch, scene, overrides):
    monkeypatch.setenv(backends.ENVIRONMENT, "numba")
    loaded = load_scene(scene, overrides)
    aot.misses.clear()
    compiled = _matrices(build_discretization(MPI.COMM_WORLD, loaded))
    assert aot.misses == {}  # every call ran compiled code
    monkeypatch.setenv(aot.ENVIRONMENT, "")  # no module: numba's JIT
    jit = _matrices(build_discretization(MPI.COMM_WORLD, loaded))
    assert sum(aot.misses.values()) > 0
    for name, array in jit.items():
        np.testing.assert_array_equal(compiled[name], array, err_msg=name)


def test_a_call_the_module_was_not_compiled_for_runs_by_the_jit():
    from parefg.discretization import assembly_kernels

    kernels = aot.kernels("assembly_kernels")
    rows = np.array([2, 0, 1, 0, 2, 2], dtype=np.int64)
    cols = np.array([1, 0, 2, 1, 1, 0], dtype=np.int64)
    expected = assembly_kernels.pairs_to_csr(rows, cols, 3)
    aot.misses.clear()
    as_compiled = kernels.pairs_to_csr(rows, cols, 3)
    assert aot.misses == {}
    strided = np.repeat(rows, 2)[::2]  # the same values, a view with a stride of 2
    read_only = cols.copy()
    read_only.flags.writeable = False
    for arguments in ((strided, cols, 3), (rows, read_only, 3), (rows.astype(np.int32), cols, 3)):
        found = kernels.pairs_to_csr(*arguments)
        for part, reference in zip(found, expected, strict=True):
            np.testing.assert_array_equal(part, reference)
    assert aot.misses == {"assembly_kernels.pairs_to_csr": 3}
    for part, reference in zip(as_compiled, expected, strict=True):
        np.testing.assert_array_equal(part, reference)


def test_no_module_for_another_source(tmp_path, monkeypatch):
    # A directory without this digest's module (another source, CPU or numpy): none is
    # loaded, and the backend falls back to the node-count rule.
    (tmp_path / ("0" * 24)).mkdir()
    monkeypatch.setenv(aot.ENVIRONMENT, str(tmp_path))
    monkeypatch.delenv(backends.ENVIRONMENT, raising=False)
    assert not aot.available()
    assert backends.choose(backends.NUMBA_MIN_NODES - 1) == "numpy"


@pytest.mark.parametrize(
    "table", ["not json", "[1, 2]", '{"mls_kernels.shape_functions": [[[], "missing"]]}']
)
def test_a_damaged_module_directory_is_no_module(tmp_path, monkeypatch, table):
    # A table that is not JSON, not a mapping, or names functions the module lacks (here
    # the installed module copied beside it): no traceback, the JIT runs every kernel.
    installed = aot.directory()
    assert installed is not None
    damaged = tmp_path / aot.digest()
    damaged.mkdir()
    for library in installed.glob(f"{aot.MODULE_NAME}.*"):
        (damaged / library.name).write_bytes(library.read_bytes())
    (damaged / aot.TABLE_NAME).write_text(table)
    monkeypatch.setenv(aot.ENVIRONMENT, str(tmp_path))
    assert not aot.available()


# A build of the square, then the numba modules it loaded.
BUILD = """
import sys
from mpi4py import MPI
from parefg.discretization import aot
from parefg.discretization.operators import build_discretization
from parefg.scene.loader import load_scene
disc = build_discretization(MPI.COMM_WORLD, load_scene("square", {overrides!r}))
assert (disc.n_nodes >= {limit}) == {large}, disc.n_nodes
assert aot.misses == {{}}, aot.misses
print(sorted(name for name in sys.modules if name.split(".")[0] in ("numba", "llvmlite")
             or name.endswith(("mls_kernels", "assembly_kernels"))))
"""


@pytest.mark.serial_only
@pytest.mark.parametrize(
    "large,module",
    [(True, None), (False, ""), (False, None)],
    ids=["large-compiled", "small-without-module", "small-compiled"],
)
def test_a_build_loads_no_numba(large, module):
    # With the compiled module at any size; without it below the node-count threshold,
    # where the numpy kernels run (above it the JIT does).
    env = {k: v for k, v in mpi_env().items() if k != backends.ENVIRONMENT}
    if module is not None:
        env[aot.ENVIRONMENT] = module
    overrides = ["discretization.h=0.03"] if large else []
    probe = BUILD.format(overrides=overrides, limit=backends.NUMBA_MIN_NODES, large=large)
    result = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, env=env, timeout=300
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.split("\n")[-2] == "[]"
