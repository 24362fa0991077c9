"""MLS shape functions: consistency to round-off, analytic gradients, neighbour search, errors.

Exactness tests use the reproducing property of MLS of degree m: for every
monomial f = x^a y^b with a + b <= m,

    sum_I phi_I(x) f(x_I) = f(x)   and   sum_I grad phi_I(x) f(x_I) = grad f(x),

so the expected values are the monomials themselves, never outputs of the code.
Under mpirun each rank evaluates its share of the points and the errors are
combined with one allreduce (MAX), so every rank asserts the same numbers.
"""

import re

import numpy as np
import pytest
from mpi4py import MPI

from parefg.discretization import mls as mls_module
from parefg.discretization import mls_kernels
from parefg.discretization.mls import BACKENDS, MLS, MLSError, basis_exponents, n_basis
from parefg.discretization.weights import WEIGHTS, get_weight
from parefg.errors import InputError
from parefg.scene.schema import DEFAULT_SUPPORT

H = 0.1
# Dilation s per degree m that gives every point enough well-placed neighbours.
SUPPORT = {1: 2.0, 2: 2.6, 3: 3.3}
TOLERANCE = 1e-10


def grid_nodes(h=H):
    """Regular grid of the unit square with spacing h, (n, 2)."""
    ticks = np.linspace(0.0, 1.0, round(1.0 / h) + 1)
    x, y = np.meshgrid(ticks, ticks, indexing="ij")
    return np.column_stack([x.ravel(), y.ravel()])


def jittered_nodes(h=H, seed=1):
    """Grid with interior nodes moved by up to 30% of h in each direction, (n, 2)."""
    nodes = grid_nodes(h)
    interior = np.all((nodes > h / 2) & (nodes < 1 - h / 2), axis=1)
    rng = np.random.default_rng(seed)
    nodes[interior] += 0.3 * h * rng.uniform(-1.0, 1.0, (interior.sum(), 2))
    return nodes


def square_points(seed=2):
    """Random interior points plus corners, edge points and points hugging the corners."""
    rng = np.random.default_rng(seed)
    corners = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=float)
    t = rng.uniform(0.0, 1.0, 20)
    zero, one = np.zeros_like(t), np.ones_like(t)
    edges = np.concatenate(
        [np.column_stack(pair) for pair in ((t, zero), (t, one), (zero, t), (one, t))]
    )
    near_corners = np.abs(corners - rng.uniform(0.0, 1e-3, (4, 2)))
    return np.concatenate([rng.uniform(0.0, 1.0, (300, 2)), corners, edges, near_corners])


def my_share(points, comm=MPI.COMM_WORLD):
    """The points this rank evaluates."""
    return points[comm.rank :: comm.size]


def reproduction_errors(shape, nodes, points, degree):
    """Largest scale-aware errors of sum phi_I f(x_I) and sum grad phi_I f(x_I), over all ranks.

    Values are compared relative to max|f| on the domain (1 on domains inside
    the unit square that touch (1, 1)), gradients relative to max|grad f| (a or b).
    """
    value_error, gradient_error = 0.0, 0.0
    neighbour_coords = nodes[shape.neighbours]  # (n, n_max, 2)
    for a, b in basis_exponents(degree):
        at_nodes = neighbour_coords[..., 0] ** a * neighbour_coords[..., 1] ** b
        exact = points[:, 0] ** a * points[:, 1] ** b
        exact_dx = a * points[:, 0] ** max(a - 1, 0) * points[:, 1] ** b
        exact_dy = b * points[:, 0] ** a * points[:, 1] ** max(b - 1, 0)
        value = np.sum(shape.phi * at_nodes, axis=1)
        gradient = np.einsum("nkd,nk->nd", shape.dphi, at_nodes)
        value_error = max(value_error, np.max(np.abs(value - exact), initial=0.0))
        gradient_scale = max(a, b, 1)
        gradient_error = max(
            gradient_error,
            np.max(np.abs(gradient[:, 0] - exact_dx), initial=0.0) / gradient_scale,
            np.max(np.abs(gradient[:, 1] - exact_dy), initial=0.0) / gradient_scale,
        )
    comm = MPI.COMM_WORLD
    return comm.allreduce(value_error, op=MPI.MAX), comm.allreduce(gradient_error, op=MPI.MAX)


@pytest.mark.parametrize("weight", sorted(WEIGHTS))
@pytest.mark.parametrize("degree", [1, 2, 3])
@pytest.mark.parametrize("cloud", ["grid", "jittered"])
def test_reproduces_polynomials_on_unit_square(cloud, degree, weight):
    nodes = grid_nodes() if cloud == "grid" else jittered_nodes()
    points = my_share(square_points())
    shape = MLS(nodes, SUPPORT[degree] * H, degree, weight).evaluate(points)
    value_error, gradient_error = reproduction_errors(shape, nodes, points, degree)
    assert value_error < TOLERANCE
    assert gradient_error < TOLERANCE


@pytest.fixture(scope="module")
def geometry_clouds():
    """Square and Z node clouds from parefg.geometry.gmsh_mesh (collective: built on every rank)."""
    geometry = pytest.importorskip("parefg.geometry.gmsh_mesh")
    return {
        shape: geometry.build_node_cloud(MPI.COMM_WORLD, {"shape": shape}, H)
        for shape in ("square", "z")
    }


@pytest.mark.parametrize("weight", sorted(WEIGHTS))
@pytest.mark.parametrize("degree", [1, 2, 3])
@pytest.mark.parametrize("domain", ["square", "z"])
def test_reproduces_polynomials_on_gmsh_clouds(geometry_clouds, domain, degree, weight):
    from parefg.discretization.quadrature import cell_quadrature, segment_quadrature

    cloud = geometry_clouds[domain]
    # Cell and boundary Gauss points and the nodes: everywhere the solver evaluates MLS.
    cells = cell_quadrature(cloud.coords, cloud.quads, cloud.triangles, 3)
    boundary = segment_quadrature(cloud.coords, cloud.segments, 3)
    points = my_share(np.concatenate([cells.points, boundary.points, cloud.coords]))
    # The supports of a run: the Z's strip cells are 0.1 x 0.083 at h = 0.1 (c_I = 0.092),
    # so s = 3.3 reaches only 3 node columns at x = 1 and the cubic basis is singular there.
    radius = DEFAULT_SUPPORT[degree] * cloud.spacing
    shape = MLS(cloud.coords, radius, degree, weight).evaluate(points)
    value_error, gradient_error = reproduction_errors(shape, cloud.coords, points, degree)
    assert value_error < TOLERANCE
    assert gradient_error < TOLERANCE


def dense_phi(shape, n_nodes, values=None):
    """``values`` (default phi) on the padded lists as a dense (n_points, n_nodes) matrix."""
    values = shape.phi if values is None else values
    dense = np.zeros((len(shape.phi), n_nodes))
    rows = np.broadcast_to(np.arange(len(shape.phi))[:, None], shape.neighbours.shape)
    np.add.at(dense, (rows[shape.mask], shape.neighbours[shape.mask]), values[shape.mask])
    return dense


@pytest.mark.parametrize("weight", sorted(WEIGHTS))
@pytest.mark.parametrize("degree", [1, 2, 3])
def test_gradients_match_finite_differences(degree, weight):
    nodes = jittered_nodes()
    mls = MLS(nodes, SUPPORT[degree] * H, degree, weight)
    points = my_share(np.random.default_rng(3).uniform(0.05, 0.95, (60, 2)))
    analytic = np.zeros((len(points), len(nodes), 2))
    shape = mls.evaluate(points)
    for d in range(2):
        analytic[..., d] = dense_phi(shape, len(nodes), shape.dphi[..., d])
    step = 1e-6
    error = 0.0
    for d in range(2):
        shift = np.zeros(2)
        shift[d] = step
        forward = dense_phi(mls.evaluate(points + shift, gradients=False), len(nodes))
        backward = dense_phi(mls.evaluate(points - shift, gradients=False), len(nodes))
        central = (forward - backward) / (2 * step)
        error = max(error, np.max(np.abs(central - analytic[..., d]), initial=0.0))
    # Gradients are O(1/h) = 10; central differences with this step agree to ~1e-8.
    assert MPI.COMM_WORLD.allreduce(error, op=MPI.MAX) < 1e-7


def naive_shape_functions(nodes, radius, degree, weight, x):
    """phi_I(x) for one point by the textbook formula in the unshifted basis p(x) = [x^a y^b]."""
    exponents = basis_exponents(degree)
    r = np.linalg.norm(nodes - x, axis=1) / radius
    w = get_weight(weight).value(r)
    basis_nodes = nodes[:, None, 0] ** exponents[:, 0] * nodes[:, None, 1] ** exponents[:, 1]
    basis_x = x[0] ** exponents[:, 0] * x[1] ** exponents[:, 1]
    moment = (basis_nodes * w[:, None]).T @ basis_nodes
    return w * (basis_nodes @ np.linalg.solve(moment, basis_x))


@pytest.mark.parametrize("degree", [1, 2, 3])
def test_values_match_textbook_formula(degree):
    nodes = jittered_nodes()
    radius = SUPPORT[degree] * H * np.linspace(1.0, 1.2, len(nodes))  # nonuniform supports
    points = my_share(square_points()[::10])
    dense = dense_phi(MLS(nodes, radius, degree, "quartic").evaluate(points), len(nodes))
    expected = np.array(
        [naive_shape_functions(nodes, radius, degree, "quartic", x) for x in points]
    )
    error = np.max(np.abs(dense - expected), initial=0.0)
    assert MPI.COMM_WORLD.allreduce(error, op=MPI.MAX) < 1e-8


@pytest.mark.parametrize("backend", BACKENDS)
def test_neighbours_are_exactly_the_covering_nodes(backend):
    # A dense cluster of nodes near (0.9, 0.9) and one query point inside it that the
    # padding-width sample misses: the search must widen its lists, not drop nodes.
    rng = np.random.default_rng(4)
    nodes = np.concatenate([grid_nodes(), 0.9 + 0.02 * rng.uniform(-1, 1, (200, 2))])
    radius = 0.25 * rng.uniform(0.5, 1.0, len(nodes))
    points = np.concatenate([rng.uniform(0.0, 0.5, (1000, 2)), [[0.9, 0.9]]])[[1000, *range(1000)]]
    shape = MLS(nodes, radius, 1, backend=backend).evaluate(points, gradients=False)
    covering = (
        np.linalg.norm(points[:, None, :] - nodes[None, :, :], axis=2) < radius
    )  # brute force
    found = np.zeros_like(covering)
    rows = np.broadcast_to(np.arange(len(points))[:, None], shape.mask.shape)
    found[rows[shape.mask], shape.neighbours[shape.mask]] = True
    assert np.array_equal(found, covering)
    assert shape.mask.sum() == covering.sum()  # no node listed twice
    assert np.all((shape.neighbours >= 0) & (shape.neighbours < len(nodes)))
    assert np.all(shape.phi[~shape.mask] == 0.0)


def test_condition_estimate_bounds_the_two_norm_condition():
    degree, nodes = 2, jittered_nodes()
    points = square_points()[::25]
    shape = MLS(nodes, SUPPORT[degree] * H, degree).evaluate(points, gradients=False)
    exponents = basis_exponents(degree)
    for x, condition in zip(points, shape.condition, strict=True):
        distance = np.linalg.norm(nodes - x, axis=1)
        covering = distance < SUPPORT[degree] * H
        xi = (nodes[covering] - x) / (SUPPORT[degree] * H)  # scaled by the largest radius R
        basis = xi[:, None, 0] ** exponents[:, 0] * xi[:, None, 1] ** exponents[:, 1]
        w = get_weight("cubic").value(distance[covering] / (SUPPORT[degree] * H))
        two_norm = np.linalg.cond((basis * w[:, None]).T @ basis)
        assert two_norm * (1 - 1e-8) <= condition <= n_basis(degree) * two_norm


def test_chunks_and_gradient_switch_do_not_change_values(monkeypatch):
    nodes, points = jittered_nodes(), square_points()
    mls = MLS(nodes, SUPPORT[2] * H, 2)
    whole = mls.evaluate(points)
    monkeypatch.setattr(mls_module, "CHUNK_POINTS", 7)
    chunked = mls.evaluate(points)
    without_gradients = mls.evaluate(points, gradients=False)
    assert without_gradients.dphi is None
    np.testing.assert_array_equal(chunked.phi, whole.phi)
    np.testing.assert_array_equal(chunked.dphi, whole.dphi)
    np.testing.assert_array_equal(without_gradients.phi, whole.phi)


def test_no_points_gives_empty_arrays():
    shape = MLS(grid_nodes(), 0.2, 1).evaluate(np.zeros((0, 2)))
    assert shape.phi.shape[0] == 0 and shape.dphi.shape[0] == 0 and shape.condition.shape == (0,)


def test_n_basis_counts_pascal_terms():
    assert [n_basis(m) for m in (1, 2, 3)] == [3, 6, 10]
    assert basis_exponents(2).tolist() == [[0, 0], [1, 0], [0, 1], [2, 0], [1, 1], [0, 2]]


@pytest.mark.parametrize("backend", BACKENDS)
def test_too_small_support_names_point_and_neighbour_count(backend):
    # Support 0.75 h on a grid: a cell centre sees only the 4 corners of its cell.
    mls = MLS(grid_nodes(), 0.75 * H, 2, support_factor=0.75, backend=backend)
    with pytest.raises(MLSError) as raised:
        mls.evaluate(np.array([[0.45, 0.45], [0.55, 0.55]]))
    message = str(raised.value)
    assert "\n" not in message
    assert "(0.45, 0.45)" in message
    assert "4 neighbours for 6 basis functions (degree 2)" in message
    assert "increase discretization.support (now 0.75)" in message
    assert isinstance(raised.value, InputError)


@pytest.mark.parametrize("backend", BACKENDS)
def test_point_outside_every_support_is_an_error(backend):
    with pytest.raises(MLSError, match=re.escape("(3, 3): 0 neighbours for 3 basis functions")):
        MLS(grid_nodes(), 2 * H, 1, backend=backend).evaluate(np.array([[0.5, 0.5], [3.0, 3.0]]))


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("slope", [0.5, 0.0])
def test_collinear_neighbours_are_an_error(slope, backend):
    # Plenty of nodes, all on one line: A is singular for every degree >= 1 (for slope 0
    # exactly singular, which breaks the LU factorization itself).
    t = np.linspace(0.0, 1.0, 30)
    nodes = np.column_stack([t, slope * t])
    points = np.array([[0.5, 0.5 * slope], [0.25, 0.25 * slope]])
    point = re.escape(f"at point (0.5, {0.5 * slope:g})")
    with pytest.raises(MLSError, match=point + r": \d+ neighbours for 3 basis functions"):
        MLS(nodes, 0.3, 1, backend=backend).evaluate(points)


def test_bad_degree_and_weight_are_input_errors():
    with pytest.raises(InputError, match="degree"):
        MLS(grid_nodes(), 0.2, 4)
    with pytest.raises(InputError, match='"cubic", "quartic", "gaussian"'):
        get_weight("cosine")


@pytest.mark.parametrize("name", sorted(WEIGHTS))
def test_weights_are_compact_decreasing_and_differentiated(name):
    weight = get_weight(name)
    r = np.linspace(0.0, 1.5, 3001)
    value, slope = weight.value(r), weight.derivative(r)
    assert value[0] > 0 and np.all(value[r >= 1.0] == 0.0) and np.all(slope[r >= 1.0] == 0.0)
    assert np.all(np.diff(value[r <= 1.0]) < 0)
    interior = (r > 0.01) & (r < 0.99) & (np.abs(r - 0.5) > 0.01)
    step = 1e-6
    central = (weight.value(r + step) - weight.value(r - step)) / (2 * step)
    np.testing.assert_allclose(slope[interior], central[interior], atol=1e-7)
    assert abs(weight.value(np.array([1.0 - 1e-9]))[0]) < 1e-6  # continuous at r = 1


def test_weight_formulas():
    cubic, quartic = get_weight("cubic"), get_weight("quartic")
    cubic_expected = [2 / 3, 2 / 3 - 0.25 + 0.0625, 1 / 6, 1 / 48]
    np.testing.assert_allclose(
        cubic.value(np.array([0, 0.25, 0.5, 0.75])), cubic_expected, rtol=1e-14
    )
    np.testing.assert_allclose(quartic.value(np.array([0.0, 0.5])), [1.0, 0.3125], rtol=1e-14)
    gaussian = get_weight("gaussian")
    floor = np.exp(-1 / 0.16)
    expected = (np.exp(-0.25 / 0.16) - floor) / (1 - floor)
    np.testing.assert_allclose(gaussian.value(np.array([0.0, 0.5])), [1.0, expected], rtol=1e-14)


# ----------------------------------------------------------------------------- compiled backend


@pytest.mark.parametrize("weight", sorted(WEIGHTS))
@pytest.mark.parametrize("degree", [1, 2, 3])
def test_numba_and_numpy_backends_agree(degree, weight):
    # Same cloud, nonuniform supports: phi, dphi (as dense matrices, so list order does
    # not matter) and condition numbers agree to 1e-12 relative to their largest entry.
    nodes = jittered_nodes()
    radius = SUPPORT[degree] * H * np.linspace(1.0, 1.3, len(nodes))
    points = my_share(square_points())
    compiled, reference = (
        MLS(nodes, radius, degree, weight, backend=backend).evaluate(points)
        for backend in ("numba", "numpy")
    )
    errors = [np.max(np.abs(compiled.condition / reference.condition - 1.0), initial=0.0)]
    for component in (None, 0, 1):
        values = [
            dense_phi(s, len(nodes), s.phi if component is None else s.dphi[..., component])
            for s in (compiled, reference)
        ]
        errors.append(np.max(np.abs(values[0] - values[1]), initial=0.0) / np.abs(values[1]).max())
    assert max(MPI.COMM_WORLD.allreduce(e, op=MPI.MAX) for e in errors) < 1e-12


@pytest.mark.parametrize("degree", [1, 2, 3])
def test_numba_kernel_on_given_lists_matches_numpy_entrywise(degree):
    # On identical padded lists the two backends agree entry by entry, padding included.
    nodes = jittered_nodes()
    points = my_share(square_points())
    compiled = MLS(nodes, SUPPORT[degree] * H, degree, backend="numba")
    reference = MLS(nodes, SUPPORT[degree] * H, degree, backend="numpy")
    neighbours, mask = compiled.find_neighbours(points)
    phi, dphi, condition = reference._evaluate_chunk(points, neighbours, mask, True)
    shape = compiled.evaluate(points)
    assert np.array_equal(shape.neighbours, neighbours) and np.array_equal(shape.mask, mask)
    np.testing.assert_allclose(shape.phi, phi, rtol=0, atol=1e-12 * np.abs(phi).max(initial=1))
    np.testing.assert_allclose(shape.dphi, dphi, rtol=0, atol=1e-12 * np.abs(dphi).max(initial=1))
    # A^-1 (hence ||A^-1||_F) is only accurate to about kappa eps in either backend: m = 3
    # reaches kappa = 3e5 here, where 1e-12 is the round-off floor of the estimate itself.
    floor = np.maximum(1e-12, 4.0 * condition * np.finfo(float).eps)
    assert np.all(np.abs(shape.condition / condition - 1.0) <= floor)
    assert np.all(shape.phi[~mask] == 0.0) and np.all(shape.dphi[~mask] == 0.0)


@pytest.mark.parametrize("degree", [1, 2, 3])
def test_numba_kernel_results_do_not_depend_on_the_lane_group(degree):
    # The kernel evaluates LANES points at once. Each point's phi, dphi and condition must
    # be bit for bit those it gets alone, whatever shares its group: here a ragged last
    # group and a point whose Cholesky breaks down (too few neighbours) amid regular ones.
    nodes = jittered_nodes()
    mls = MLS(nodes, SUPPORT[degree] * H, degree, backend="numba")
    points = my_share(square_points())[: 3 * mls_kernels.LANES + 3].copy()
    points[mls_kernels.LANES + 2] = (-0.5 * SUPPORT[degree] * H, 0.5)  # outside the cloud
    neighbours, mask = mls.find_neighbours(points)
    mask[mls_kernels.LANES + 2, 1:] = False  # one neighbour: A is singular
    size = mls_module.basis_size(degree)
    arguments = (mls.nodes, mls.support_radius, mls.weight.code, size)
    together = mls_kernels.shape_functions(points, *arguments, neighbours, mask, True)
    alone = [
        mls_kernels.shape_functions(
            points[q : q + 1], *arguments, neighbours[q : q + 1], mask[q : q + 1], True
        )
        for q in range(len(points))
    ]
    for part, result in enumerate(together):
        assert np.array_equal(result, np.concatenate([a[part] for a in alone]))
    broken = mls_kernels.LANES + 2
    assert together[2][broken] == np.inf and np.all(together[0][broken] == 0.0)
    assert np.all(np.isfinite(together[2][np.arange(len(points)) != broken]))


@pytest.mark.parametrize("name", sorted(WEIGHTS))
def test_compiled_weights_match_the_registry(name):
    r = np.linspace(0.0, 1.2, 1201)
    compiled = np.array(
        [mls_kernels.weight_and_slope(mls_kernels.WEIGHT_CODES[name], x) for x in r]
    )
    weight = get_weight(name)
    # Terms of the polynomials reach 24 (quartic slope), so cancellation near r = 1 leaves
    # a few ulps of 24, about 1e-14, as the floor of any two evaluation orders.
    np.testing.assert_allclose(compiled[:, 0], weight.value(r), rtol=1e-14, atol=1e-14)
    np.testing.assert_allclose(compiled[:, 1], weight.derivative(r), rtol=1e-14, atol=1e-14)


def test_both_backends_report_the_same_first_bad_point(monkeypatch):
    # Chunk 1 (points 0-6) holds an ill-conditioned point, chunk 2 a point with too few
    # neighbours: the chunked numpy path reports the former, and so must numba.
    monkeypatch.setattr(mls_module, "CHUNK_POINTS", 7)
    t = np.linspace(0.0, 1.0, 30)
    nodes = np.concatenate([grid_nodes(), np.column_stack([t, 3.0 + 0.5 * t])])
    points = np.full((20, 2), 0.5)
    points[3], points[10] = (0.5, 3.25), (9.0, 9.0)
    messages = []
    for backend in BACKENDS:
        with pytest.raises(MLSError) as raised:
            MLS(nodes, 0.3, 1, backend=backend).evaluate(points)
        messages.append(str(raised.value))
    assert "(0.5, 3.25)" in messages[0] and messages[0] == messages[1]


@pytest.mark.parametrize("estimate", [4e16, 3.5e17, np.inf, np.nan])
def test_numerically_singular_estimates_are_reported_as_singular(estimate):
    # An exactly singular A yields, depending on the SIMD path and the factorization, a
    # breakdown (inf) or a round-off estimate >= 1/eps: one verdict, one message for all.
    mls = MLS(grid_nodes(), 0.3, 1)
    with pytest.raises(MLSError) as raised:
        mls._check_conditioning(np.array([[0.5, 0.5]]), np.ones((1, 9), bool), np.array([estimate]))
    assert str(raised.value).startswith("MLS moment matrix singular at point (0.5, 0.5): 9 ")


def test_badly_conditioned_message_quotes_the_estimate_to_its_accuracy():
    mls = MLS(grid_nodes(), 0.3, 1)
    with pytest.raises(MLSError, match=re.escape("badly conditioned (condition number 3e+13 > ")):
        mls._check_conditioning(np.array([[0.5, 0.5]]), np.ones((1, 9), bool), np.array([3.1e13]))


def test_lu_breakdown_in_a_chunk_does_not_change_the_other_points_estimates():
    # One exactly singular matrix makes LU raise for the whole stack; the eigenvalue fallback
    # must still give the badly conditioned (kappa = 1e13) neighbour its finite estimate.
    moments = np.array([np.diag([1.0, 0.0]), np.diag([1.0, 1e-13]), np.eye(2)])
    _, condition = MLS._invert(moments)
    _, alone = MLS._invert(moments[1:])
    assert condition[0] == np.inf
    np.testing.assert_allclose(condition[1:], alone, rtol=1e-12)
    assert 1e12 < condition[1] < 1e14


def test_unknown_backend_is_an_input_error():
    with pytest.raises(InputError, match="backend"):
        MLS(grid_nodes(), 0.2, 1, backend="fortran")


def test_a_huge_support_is_advised_down_not_up():
    """With every node a neighbour, a dilation of 1e6 scales the basis to ~1e-6: A(x) is
    singular with plenty of neighbours, and the fix is a smaller support, not a larger one."""
    nodes = grid_nodes()
    spacing = np.full(len(nodes), 0.1)
    with pytest.raises(MLSError, match=re.escape("decrease discretization.support (now 1e+06)")):
        MLS(nodes, 1e6 * spacing, 2, support_factor=1e6).evaluate(nodes[:5])
    with pytest.raises(MLSError, match="increase discretization.support"):
        MLS(nodes, 0.5 * spacing, 2, support_factor=0.5).evaluate(nodes[:5] + 0.05)
