"""The grouped (numba) assembly equals the straightforward scipy formulation.

The reference below is the previous implementation, kept verbatim in spirit: scalar
point-to-node matrices from COO, Gram matrices as sparse products S^T W S, stiffness
blocks combined with Kronecker products.  The assembled M, K, D (owned rows) and the
point operators must equal it to 1e-13 relative to the largest entry, serially and
under mpirun (the reference sums every rank's dense contribution with an allreduce).
"""

import numpy as np
import pytest
import scipy.sparse as sp
from held_nodes import global_mls
from mpi4py import MPI

from parefg.discretization.assembly import Coupling
from parefg.discretization.operators import _mass_slots, build_discretization
from parefg.parallel import owned_rows
from parefg.scene.loader import load_scene

TOLERANCE = 1e-13


# -- the reference: the straightforward formulation ----------------------------------


def reference_scalar(shape, n_nodes, derivative=None):
    """(n_points, n_nodes): row q holds phi_I(x_q) or d phi_I / d x_derivative, from COO."""
    n_points, n_max = shape.neighbours.shape
    rows = np.repeat(np.arange(n_points), n_max).reshape(n_points, n_max)[shape.mask]
    values = shape.phi if derivative is None else shape.dphi[:, :, derivative]
    return sp.csr_matrix(
        (values[shape.mask], (rows, shape.neighbours[shape.mask])), shape=(n_points, n_nodes)
    )


def reference_gram(left, weights, right):
    return (left.T @ sp.diags(weights) @ right).tocsr()


def reference_interleave(scalar):
    return sp.kron(scalar, sp.identity(2), format="csr")


def reference_stiffness(grads, weights, lam, mu):
    """K[2I+a, 2J+b] = int lam d_a phi_I d_b phi_J + mu (delta_ab grad.grad + d_b phi_I d_a phi_J).

    Summed block by block with Kronecker products, as the previous implementation did.
    """
    s = [[reference_gram(grads[a], weights, grads[b]) for b in range(2)] for a in range(2)]
    laplace = s[0][0] + s[1][1]
    total = sp.csr_matrix((2 * grads[0].shape[1],) * 2)
    for a in range(2):
        for b in range(2):
            block = lam * s[a][b] + mu * s[b][a] + (mu * laplace if a == b else 0)
            unit = sp.csr_matrix(([1.0], ([a], [b])), shape=(2, 2))
            total = total + sp.kron(block, unit, format="csr")
    return total


def reference_gradients(shape, n_nodes):
    """(4 n_points x 2 n_nodes): row 4q + 2c + d = d phi_I / d x_d on DOF 2I + c."""
    q, k = np.nonzero(shape.mask)
    node = shape.neighbours[q, k]
    rows, cols, data = [], [], []
    for c in range(2):
        for d in range(2):
            rows.append(4 * q + 2 * c + d)
            cols.append(2 * node + c)
            data.append(shape.dphi[q, k, d])
    return sp.csr_matrix(
        (np.concatenate(data), (np.concatenate(rows), np.concatenate(cols))),
        shape=(4 * len(shape.mask), 2 * n_nodes),
    )


# -- helpers -------------------------------------------------------------------------


def global_dense(comm, local):
    """Sum of every rank's (global-row) contribution as a dense array.  Collective."""
    return comm.allreduce(local.toarray())


def owned_dense(disc, matrix):
    start, stop = disc.node_range
    return global_dense(disc.comm, matrix)[2 * start : 2 * stop]


def petsc_local_rows(matrix):
    """This rank's rows of a PETSc AIJ matrix as a dense array (global columns)."""
    indptr, indices, data = matrix.getValuesCSR()
    n_rows = matrix.getLocalSize()[0]
    return sp.csr_matrix((data, indices, indptr), shape=(n_rows, matrix.getSize()[1])).toarray()


def assert_equal_matrices(new, reference):
    scale = np.abs(reference).max()
    assert scale > 0
    assert np.abs(new - reference).max() <= TOLERANCE * scale


@pytest.fixture(scope="module", params=[1, 2], ids=["m1", "m2"])
def case(request):
    """A discretization of the square (h = 1/16) and MLS evaluated at its points."""
    scene = load_scene(
        "square", [f"discretization.degree={request.param}", "discretization.h=0.0625"]
    )
    disc = build_discretization(MPI.COMM_WORLD, scene)
    # the held nodes, global numbers in the lists: the references index global nodes
    return scene, disc, global_mls(disc, scene.discretization)


# -- tests ---------------------------------------------------------------------------


def test_mass_and_stiffness_equal_reference(case):
    scene, disc, mls = case
    shape = mls.evaluate(disc.domain.points, gradients=True)
    n, weights = disc.n_nodes, disc.domain.weights
    phi = reference_scalar(shape, n)
    grads = [reference_scalar(shape, n, d) for d in range(2)]
    mass = reference_interleave(reference_gram(phi, scene.material.rho * weights, phi))
    stiffness = reference_stiffness(grads, weights, scene.material.lam, scene.material.mu)
    assert_equal_matrices(disc.owned["mass"].toarray(), owned_dense(disc, mass))
    assert_equal_matrices(disc.owned["stiffness"].toarray(), owned_dense(disc, stiffness))
    assert_equal_matrices(petsc_local_rows(disc.stiffness), owned_dense(disc, stiffness))


def test_stiffness_pattern_is_the_pairs_sharing_a_point(case):
    """Entry (I, J) is stored exactly when phi_I and phi_J are both nonzero at some point."""
    _, disc, mls = case
    shape = mls.evaluate(disc.domain.points, gradients=False)
    incidence = reference_scalar(shape, disc.n_nodes)
    incidence.data[:] = 1.0
    expected = owned_dense(disc, sp.kron(incidence.T @ incidence, np.ones((2, 2)))) > 0
    stored = disc.owned["stiffness"].copy()
    stored.data[:] = 1.0
    np.testing.assert_array_equal(stored.toarray() > 0, expected)


def reference_nitsche(shape, points, beta, n_nodes, lam, mu, projection=None):
    """D = int beta phi_I phi_J - C - C^T, C[2I+a, 2J+b] = int phi_I (sigma(phi_J e_b) n)_a.

    (sigma(phi_J e_b) n)_a = lam n_a d_b phi_J + mu (delta_ab d_n phi_J + n_b d_a phi_J), so
    C = lam S_ab + mu S_ba + mu delta_ab (S_00 + S_11) with S_ab = int phi_I n_a d_b phi_J.
    With the coarse trace's ``projection`` P (points x points), phi and its derivatives
    are projected first: the normal is constant on a group, so P (n_a d_b phi) =
    n_a P (d_b phi).
    """
    phi = reference_scalar(shape, n_nodes)
    grads = [reference_scalar(shape, n_nodes, d) for d in range(2)]
    if projection is not None:
        phi, grads = projection @ phi, [projection @ g for g in grads]
    weights, normals = points.weights, points.normals
    s = [
        [reference_gram(phi, weights * normals[:, a], grads[b]) for b in range(2)] for a in range(2)
    ]
    trace = s[0][0] + s[1][1]
    cross = sp.csr_matrix((2 * n_nodes,) * 2)
    for a in range(2):
        for b in range(2):
            block = lam * s[a][b] + mu * s[b][a] + (mu * trace if a == b else 0)
            unit = sp.csr_matrix(([1.0], ([a], [b])), shape=(2, 2))
            cross = cross + sp.kron(block, unit, format="csr")
    return reference_interleave(reference_gram(phi, weights * beta, phi)) - cross - cross.T


def reference_nitsche_contact(shape, points, n_nodes, lam, mu):
    """N = int T^T T / gamma of Nitsche contact: T[q, 2J+b] = sigma_nu(phi_J e_b)(x_q),
    which is lam d_b phi_J + 2 mu nu_b d_nu phi_J; on the coarse trace (the default) with
    the derivatives projected (P commutes with the normal on a straight part)."""
    grads = [reference_scalar(shape, n_nodes, d) for d in range(2)]
    if points.projection is not None:
        grads = [points.projection @ g for g in grads]
    normals = points.normals
    normal_derivative = sp.diags(normals[:, 0]) @ grads[0] + sp.diags(normals[:, 1]) @ grads[1]
    traction = sp.csr_matrix((len(normals), 2 * n_nodes))
    for b in range(2):
        block = lam * grads[b] + 2 * mu * sp.diags(normals[:, b]) @ normal_derivative
        unit = sp.csr_matrix(([1.0], ([0], [b])), shape=(1, 2))
        traction = traction + sp.kron(block, unit, format="csr")
    return reference_gram(traction, points.weights / points.gamma, traction)


def test_dirichlet_and_contact_pattern_equal_reference(case):
    """D of the defaults (Nitsche on the Dirichlet and the contact parts) and of the penalty
    (alpha_D G_D) equal the reference."""
    scene, disc, mls = case
    n, lam, mu = disc.n_nodes, scene.material.lam, scene.material.mu
    dirichlet = sp.csr_matrix((2 * n, 2 * n))
    for name, bc in scene.boundaries.items():
        if bc.kind == "dirichlet":
            assert bc.method == "nitsche"
            points, part = disc.boundary[name], disc.dirichlet_parts[name]
            shape = mls.evaluate(points.points, gradients=True)
            dirichlet += reference_nitsche(shape, points, part.beta, n, lam, mu, part.projection)
        if bc.kind == "contact":
            assert bc.method == "nitsche"
    shape = mls.evaluate(disc.contact.points, gradients=True)
    dirichlet -= reference_nitsche_contact(shape, disc.contact, n, lam, mu)
    assert_equal_matrices(disc.owned["dirichlet"].toarray(), owned_dense(disc, dirichlet))
    assert_equal_matrices(petsc_local_rows(disc.dirichlet), owned_dense(disc, dirichlet))

    penalty_scene = load_scene(
        "square", [f"discretization.degree={scene.discretization.degree}",
                   "discretization.h=0.0625", "boundary.top.method=penalty",
                   "boundary.bottom.method=penalty"]
    )  # fmt: skip
    penalty = build_discretization(MPI.COMM_WORLD, penalty_scene)
    points = penalty.boundary["top"]
    phi = reference_scalar(mls.evaluate(points.points, gradients=False), n)
    gram = reference_interleave(reference_gram(phi, points.weights, phi))
    reference = owned_dense(penalty, penalty_scene.penalty.alpha_dirichlet * gram)
    assert_equal_matrices(penalty.owned["dirichlet"].toarray(), reference)

    phi = reference_scalar(mls.evaluate(disc.contact.points, gradients=False), n)
    phi.data[:] = 1.0
    # the law reads u through the hat projection P (a point reaches its group's nodes) and
    # sigma_nu at the point itself
    reach = abs(disc.contact.projection) @ phi + phi
    coupling = sp.kron(reach.T @ reach, np.ones((2, 2)), format="csr")
    expected = owned_dense(disc, coupling) > 0
    pattern = disc.contact_pattern.copy()
    assert not np.any(pattern.data)  # the pattern carries zeros only
    pattern.data[:] = 1.0
    np.testing.assert_array_equal(pattern.toarray() > 0, expected)


def test_point_operators_equal_reference(case):
    """Values: the scalar operator S; gradients of a field: the reference gradient operator."""
    _, disc, mls = case
    n = disc.n_nodes
    u = disc.create_vec()
    coords = disc.owned_coords
    u.setArray(np.column_stack([np.sin(3 * coords[:, 0]), coords[:, 0] * coords[:, 1]]).ravel())
    whole = np.concatenate(disc.comm.allgather(u.getArray()))  # (2 n,) every rank's block
    for points in (disc.domain, disc.nodes):
        shape = mls.evaluate(points.points, gradients=True)
        assert_equal_matrices(petsc_local_rows(points.values), reference_scalar(shape, n).toarray())
        expected = (reference_gradients(shape, n) @ whole).reshape(-1, 2, 2)
        assert_equal_matrices(points.evaluate_gradient(u), expected)
        values = reference_interleave(reference_scalar(shape, n)) @ whole
        assert_equal_matrices(points.evaluate(u), values.reshape(-1, 2))


def test_grouping_does_not_change_the_gram_matrix(case):
    """Cell groups and one-point groups give the same pattern and values (round-off)."""
    _, disc, mls = case
    shape = mls.evaluate(disc.domain.points, gradients=True)
    cells = np.repeat(np.arange(len(shape.mask) // 5 + 1), 5)[: len(shape.mask)]
    by_group = Coupling.of(shape, disc.n_nodes, cells)
    by_point = Coupling.of(shape, disc.n_nodes)
    np.testing.assert_array_equal(by_group.indptr, by_point.indptr)
    np.testing.assert_array_equal(by_group.indices, by_point.indices)
    grouped = by_group.gram(shape.dphi, shape.dphi, disc.domain.weights)
    pointwise = by_point.gram(shape.dphi, shape.dphi, disc.domain.weights)
    assert np.abs(grouped - pointwise).max() <= TOLERANCE * np.abs(pointwise).max()


def test_owned_rows_matches_the_dense_sum_and_the_union_of_patterns(comm):
    """Random contributions (rows anywhere, duplicates, explicit zeros):
    the owned rows are the dense sum over ranks, their pattern the union of every rank's
    entries (zeros included), in canonical CSR."""
    n_rows, n_cols = 40, 30
    row_ranges = np.array(
        [0, *sorted(np.random.default_rng(0).integers(0, n_rows, comm.size - 1)), n_rows]
    )
    rng = np.random.default_rng(comm.rank + 7)
    n = 150
    rows, cols = rng.integers(0, n_rows, n), rng.integers(0, n_cols, n)
    data = np.where(rng.random(n) < 0.2, 0.0, rng.standard_normal(n))
    local = sp.coo_matrix((data, (rows, cols)), shape=(n_rows, n_cols))
    owned = owned_rows(comm, local, row_ranges)
    everything = comm.allgather((rows, cols, data))
    start, stop = row_ranges[comm.rank], row_ranges[comm.rank + 1]
    dense = np.zeros((n_rows, n_cols))
    pattern = np.zeros((n_rows, n_cols), dtype=bool)
    for r, c, d in everything:
        np.add.at(dense, (r, c), d)
        pattern[r, c] = True
    np.testing.assert_allclose(owned.toarray(), dense[start:stop], rtol=1e-14, atol=1e-14)
    found = np.zeros((stop - start, n_cols), dtype=bool)
    found[np.repeat(np.arange(stop - start), np.diff(owned.indptr)), owned.indices] = True
    np.testing.assert_array_equal(found, pattern[start:stop])
    assert owned.nnz == pattern[start:stop].sum()  # no duplicates
    for row in range(stop - start):
        columns = owned.indices[owned.indptr[row] : owned.indptr[row + 1]]
        assert np.all(np.diff(columns) > 0)  # sorted


@pytest.mark.parametrize("layout", ["own rows only", "all rows on rank 0", "int64 indices"])
def test_owned_rows_edge_cases(comm, layout):
    """Nothing received (every rank adds to its own rows only), ranks that own no row, and
    64-bit indices: the owned rows are still the sum, in canonical CSR with zeros kept."""
    n_rows = 12
    if layout == "all rows on rank 0":
        row_ranges = np.array([0] + [n_rows] * comm.size)
    else:
        row_ranges = np.linspace(0, n_rows, comm.size + 1).astype(np.int64)
    start, stop = row_ranges[comm.rank], row_ranges[comm.rank + 1]
    rows = np.arange(start, stop) if layout == "own rows only" else np.arange(n_rows)
    rows = np.concatenate([rows, rows])
    cols = np.concatenate([rows[: len(rows) // 2], np.zeros(len(rows) // 2, dtype=np.int64)])
    data = np.concatenate([np.full(len(rows) // 2, 1.0), np.zeros(len(rows) // 2)])
    local = sp.csr_matrix((data, (rows, cols)), shape=(n_rows, n_rows))
    if layout == "int64 indices":
        local.indices, local.indptr = local.indices.astype(np.int64), local.indptr.astype(np.int64)
    owned = owned_rows(comm, local, row_ranges)
    contributors = 1 if layout == "own rows only" else comm.size
    expected = np.zeros((stop - start, n_rows))
    expected[np.arange(stop - start), np.arange(start, stop)] = contributors
    np.testing.assert_array_equal(owned.toarray(), expected)
    assert owned.nnz == 2 * (stop - start) - (1 if start == 0 and stop > 0 else 0)
    assert owned.has_sorted_indices


def test_owned_rows_sums_contributions_and_keeps_zeros(comm):
    """Every rank adds rank + 1 on the diagonal and an explicit zero at (i, 0)."""
    n_rows = 6
    row_ranges = np.linspace(0, n_rows, comm.size + 1).astype(np.int64)
    rows = np.concatenate([np.arange(n_rows), np.arange(n_rows)])
    cols = np.concatenate([np.arange(n_rows), np.zeros(n_rows, dtype=np.int64)])
    data = np.concatenate([np.full(n_rows, comm.rank + 1.0), np.zeros(n_rows)])
    local = sp.csr_matrix((data, (rows, cols)), shape=(n_rows, n_rows))
    owned = owned_rows(comm, local, row_ranges)
    start, stop = row_ranges[comm.rank], row_ranges[comm.rank + 1]
    total = comm.size * (comm.size + 1) / 2
    expected = np.zeros((stop - start, n_rows))
    expected[np.arange(stop - start), np.arange(start, stop)] = total
    np.testing.assert_array_equal(owned.toarray(), expected)
    # one explicit zero in column 0 per row, except row 0 where it meets the diagonal
    assert owned.nnz == 2 * (stop - start) - (1 if start == 0 and stop > 0 else 0)


def _pattern(matrix: sp.spmatrix) -> sp.csr_matrix:
    """The stored entries of ``matrix`` (explicit zeros included) as ones."""
    ones = sp.csr_matrix(matrix, copy=True)
    ones.data[:] = 1.0
    return ones


@pytest.mark.parametrize("coefficient", [0.0, 800.0])
def test_combined_rows_are_the_sum_on_the_union_of_the_patterns(case, coefficient):
    """c M + K + D with the Gamma_C pattern reserved: the values of scipy's sum, to the
    bit (the same additions), every entry of every term and of the pattern stored (scipy's
    sum drops what cancels), M placed into K's entries by position (the fast path)."""
    _, disc, _ = case
    owned = disc.owned
    combined = disc.combined_rows(coefficient, reserve_contact=True)
    expected = (coefficient * owned["mass"] + owned["stiffness"]) + owned["dirichlet"]
    assert (combined != expected).nnz == 0  # exact
    covered = _pattern(combined)
    for term in (owned["mass"], owned["stiffness"], owned["dirichlet"], disc.contact_pattern):
        assert (_pattern(term) - _pattern(term).multiply(covered)).nnz == 0
    assert _mass_slots(owned["stiffness"], owned["mass"]) is not None
    without = disc.combined_rows(coefficient, reserve_contact=False)
    assert (without != expected).nnz == 0
    assert (_pattern(without) - _pattern(without).multiply(covered)).nnz == 0


def test_mass_slots_refuse_another_layout(case):
    """M not in K's interleaved layout (a row longer, or another column): no positions,
    so combined_rows takes scipy's sum instead."""
    _, disc, _ = case
    owned = disc.owned
    stiffness, mass = owned["stiffness"], owned["mass"]
    assert _mass_slots(stiffness, stiffness) is None  # rows as long as K's
    shifted = mass.copy()
    shifted.indices = shifted.indices.copy()
    shifted.indices[0] = (shifted.indices[0] + 1) % shifted.shape[1]
    assert _mass_slots(stiffness, shifted) is None
