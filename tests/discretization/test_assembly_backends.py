"""The numpy and numba kernels of the assembly build the same matrices.

Small problems assemble with :mod:`parefg.discretization.assembly_numpy`, large ones with
the numba kernels of :mod:`parefg.discretization.assembly_kernels`
(:mod:`parefg.discretization.backends`).  On the same shape values both must give the same
node lists, pairs and CSR patterns (identical) and the same Gram values to round-off
(1e-13 of the largest entry, as test_assembly.py asks of either against scipy); whole
discretizations built with either backend must have the same owned rows of M and K,
serially and under mpirun -n 2.  (Which modules a build imports: test_aot.py.)
"""

import numpy as np
import pytest
import scipy.sparse as sp
from mpi4py import MPI

from parefg.discretization import aot, assembly_numpy, backends
from parefg.discretization.assembly import Coupling
from parefg.discretization.mls import MLS
from parefg.discretization.operators import build_discretization
from parefg.scene.loader import load_scene

TOLERANCE = 1e-13

pytestmark = pytest.mark.skipif(not backends.numba_installed(), reason="numba is not installed")


def assert_close(new, reference):
    scale = np.abs(reference).max()
    assert scale > 0
    assert np.abs(new - reference).max() <= TOLERANCE * scale


# Small (289 nodes, m = 1 and 2) and medium (1089 nodes, m = 2) squares.
CASES = [(1, 1 / 16), (2, 1 / 16), (2, 1 / 32)]


@pytest.fixture(scope="module", params=CASES, ids=["small-m1", "small-m2", "medium-m2"])
def shape_case(request):
    """MLS values (numba) at the domain points of a square discretization."""
    degree, h = request.param
    scene = load_scene("square", [f"discretization.degree={degree}", f"discretization.h={h}"])
    disc = build_discretization(MPI.COMM_WORLD, scene)
    cloud, settings = disc.cloud, scene.discretization
    mls = MLS(cloud.coords, settings.support * cloud.spacing, degree, settings.weight,
              backend="numba")  # fmt: skip
    return disc, mls.evaluate(disc.domain.points, gradients=True)


def couplings(monkeypatch, shape, n_nodes, cell):
    """The Coupling of the same points with each backend: {backend: Coupling}."""
    result = {}
    for backend in backends.NAMES:
        monkeypatch.setenv(backends.ENVIRONMENT, backend)
        result[backend] = Coupling.of(shape, n_nodes, cell)
    return result


@pytest.mark.parametrize("group", [64, 1], ids=["cells", "points"])
def test_backends_give_the_same_pattern_and_gram_values(shape_case, monkeypatch, group):
    disc, shape = shape_case
    n_points = len(shape.mask)
    cell = np.repeat(np.arange(n_points // group + 1), group)[:n_points]
    by = couplings(monkeypatch, shape, disc.n_nodes, cell)
    for name in ("indptr", "indices", "node_start", "nodes", "pair_start", "pair_local",
                 "pair_position"):  # fmt: skip
        np.testing.assert_array_equal(getattr(by["numpy"], name), getattr(by["numba"], name))
        assert getattr(by["numpy"], name).dtype == getattr(by["numba"], name).dtype, name
    weights = disc.domain.weights
    for left in (shape.phi[:, :, None], shape.dphi):
        grams = {}
        for backend, coupling in by.items():
            monkeypatch.setenv(backends.ENVIRONMENT, backend)
            grams[backend] = coupling.gram(left, left, weights)
        assert_close(grams["numpy"], grams["numba"])
        blocks = np.repeat(np.repeat(grams["numba"][:, :1, :1], 2, axis=1), 2, axis=2)
        blocks = blocks * np.array([[1.0, 2.0], [3.0, 4.0]])  # distinct entries per block
        for diagonal_only in (False, True):
            matrices = {}
            for backend, coupling in by.items():
                monkeypatch.setenv(backends.ENVIRONMENT, backend)
                matrices[backend] = coupling.interleaved(blocks, diagonal_only)
            for attribute in ("indptr", "indices", "data"):  # a copy: identical
                np.testing.assert_array_equal(
                    getattr(matrices["numpy"], attribute), getattr(matrices["numba"], attribute)
                )


def test_numpy_gram_of_blocks_one_after_the_other_equals_all_at_once(shape_case, monkeypatch):
    """Into ``data`` that already holds earlier groups' sums, the numpy kernel adds in group
    order as the numba kernel does: two halves of the groups give the bits of all at once."""
    disc, shape = shape_case
    monkeypatch.setenv(backends.ENVIRONMENT, "numpy")
    n_points = len(shape.mask)
    cell = np.repeat(np.arange(n_points // 64 + 1), 64)[:n_points]
    whole = Coupling.of(shape, disc.n_nodes, cell)
    dphi, weights = np.ascontiguousarray(shape.dphi), disc.domain.weights
    at_once = whole.gram(dphi, dphi, weights)
    data = np.zeros_like(at_once)
    n_groups = len(whole.group_start) - 1
    for groups in (slice(0, n_groups // 2 + 1), slice(n_groups // 2, n_groups + 1)):
        group_start = whole.group_start[groups]
        first, last = int(group_start[0]), int(group_start[-1])
        node_start, pair_start = whole.node_start[groups], whole.pair_start[groups]
        pairs = slice(int(pair_start[0]), int(pair_start[-1]))
        assembly_numpy.gram_groups(
            dphi[first:last], dphi[first:last], weights[first:last],
            shape.neighbours[first:last], shape.mask[first:last], group_start - first,
            node_start - node_start[0], whole.nodes[node_start[0] : node_start[-1]],
            pair_start - pair_start[0], whole.pair_local[pairs], whole.pair_position[pairs],
            data, None,
        )  # fmt: skip
    np.testing.assert_array_equal(data, at_once)


def owned_rows(matrix):
    """This rank's rows of a PETSc AIJ matrix as scipy CSR (global columns)."""
    indptr, indices, data = matrix.getValuesCSR()
    shape = (matrix.getLocalSize()[0], matrix.getSize()[1])
    return sp.csr_matrix((data, indices, indptr), shape=shape)


@pytest.mark.parametrize("degree,h", [(2, 1 / 16), (2, 1 / 24)], ids=["small", "medium"])
def test_discretizations_of_both_backends_have_the_same_owned_rows(monkeypatch, degree, h):
    """M, K and D of whole builds (MLS, search and assembly by either backend) agree:
    patterns identical, values to round-off; serially and under mpirun -n 2.

    D by the penalty method: Nitsche's beta is a generalized eigenvalue of each segment
    (trace_inverse.py) whose problem has the rigid motions as near null space, so it
    amplifies the shape functions' round-off to ~1e-10 relative, whatever assembled it.
    """
    scene = load_scene(
        "square",
        [f"discretization.degree={degree}", f"discretization.h={h}", "boundary.top.method=penalty"],
    )
    built = {}
    for backend in backends.NAMES:
        monkeypatch.setenv(backends.ENVIRONMENT, backend)
        built[backend] = build_discretization(MPI.COMM_WORLD, scene)
    for name in ("mass", "stiffness", "dirichlet"):
        new, reference = (owned_rows(getattr(built[b], name)) for b in ("numpy", "numba"))
        np.testing.assert_array_equal(new.indptr, reference.indptr)
        np.testing.assert_array_equal(new.indices, reference.indices)
        scale = MPI.COMM_WORLD.allreduce(np.abs(reference.data).max(), op=MPI.MAX)
        difference = MPI.COMM_WORLD.allreduce(np.abs(new.data - reference.data).max(), op=MPI.MAX)
        assert difference <= TOLERANCE * scale, name


def test_backend_is_chosen_by_the_global_node_count(monkeypatch):
    # Without the kernels compiled ahead of time (with them: numba at every size).
    monkeypatch.setenv(aot.ENVIRONMENT, "")
    monkeypatch.delenv(backends.ENVIRONMENT, raising=False)
    assert backends.choose(backends.NUMBA_MIN_NODES - 1) == "numpy"
    assert backends.choose(backends.NUMBA_MIN_NODES) == "numba"
    assert backends.choose(backends.NUMBA_MIN_NODES, compiled=False) == "numpy"
    monkeypatch.setenv(backends.ENVIRONMENT, "numba")
    assert backends.choose(10) == "numba"
    monkeypatch.setenv(backends.ENVIRONMENT, "fortran")
    with pytest.raises(Exception, match=backends.ENVIRONMENT):
        backends.choose(10)
