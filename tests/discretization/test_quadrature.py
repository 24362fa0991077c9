"""Gauss rules on cells and segments: exactness degrees, areas, lengths, normals.

Expected integrals come from Green's theorem on the polygon edges, each edge
integrated with numpy's 30-point Gauss-Legendre rule (exact for the polynomial
integrands here), never from parefg.discretization.quadrature.
"""

import numpy as np
import pytest
from mpi4py import MPI

from parefg.discretization.quadrature import cell_quadrature, segment_quadrature
from parefg.errors import InputError

# A strongly distorted (non-parallelogram) quadrilateral, a parallelogram and a triangle, CCW.
QUAD = [(0, 0), (2, 0.3), (1.7, 1.5), (0.1, 1)]
PARALLELOGRAM = [(0, 0), (2, 0.5), (2.5, 2), (0.5, 1.5)]
TRIANGLE = [(0.2, 0.1), (1.5, 0.4), (0.5, 1.4)]


def exact_polygon_integral(vertices, a, b):
    """int_P x^a y^b dA = closed integral of x^(a+1) y^b / (a+1) dy (Green's theorem)."""
    nodes, weights = np.polynomial.legendre.leggauss(30)
    t, weights = (nodes + 1) / 2, weights / 2
    total = 0.0
    for (x0, y0), (x1, y1) in zip(vertices, vertices[1:] + vertices[:1], strict=True):
        x, y = x0 + t * (x1 - x0), y0 + t * (y1 - y0)
        total += np.sum(weights * x ** (a + 1) * y**b / (a + 1) * (y1 - y0))
    return total


def monomials(degree):
    return [(p - b, b) for p in range(degree + 1) for b in range(p + 1)]


def integrate(rule, a, b):
    return np.sum(rule.weights * rule.points[:, 0] ** a * rule.points[:, 1] ** b)


def relative_errors(rule, vertices, degree):
    """Largest relative error over the monomials of total degree <= degree."""
    errors = []
    for a, b in monomials(degree):
        exact = exact_polygon_integral(vertices, a, b)
        errors.append(abs(integrate(rule, a, b) - exact) / abs(exact))
    return max(errors)


def as_float(vertices):
    return np.array(vertices, dtype=float)


@pytest.mark.parametrize("order", [1, 2, 3, 4])
def test_quad_rule_exactness(order):
    # Through a bilinear map x^a y^b (total degree p) times the Jacobian has degree
    # p + 1 in each reference variable: exact for p <= 2n - 2 on a general quad,
    # and for p <= 2n - 1 on a parallelogram (constant Jacobian, affine map).
    distorted = cell_quadrature(as_float(QUAD), [[0, 1, 2, 3]], None, order)
    assert len(distorted.points) == order**2
    assert relative_errors(distorted, QUAD, 2 * order - 2) < 1e-13
    parallelogram = cell_quadrature(as_float(PARALLELOGRAM), [[0, 1, 2, 3]], None, order)
    assert relative_errors(parallelogram, PARALLELOGRAM, 2 * order - 1) < 1e-13
    assert relative_errors(parallelogram, PARALLELOGRAM, 2 * order) > 1e-8  # n is not too large


@pytest.mark.parametrize("order", [1, 2, 3, 4])
def test_triangle_rule_exactness(order):
    rule = cell_quadrature(as_float(TRIANGLE), None, [[0, 1, 2]], order)
    assert len(rule.points) == order**2
    assert relative_errors(rule, TRIANGLE, 2 * order - 1) < 1e-13
    assert relative_errors(rule, TRIANGLE, 2 * order) > 1e-8
    assert np.all(rule.weights > 0)


def shoelace(coords, cells):
    """Areas of polygons given by corner indices, (n_cells,)."""
    x, y = coords[cells, 0], coords[cells, 1]
    return 0.5 * np.abs(np.sum(x * np.roll(y, -1, axis=1) - np.roll(x, -1, axis=1) * y, axis=1))


def mixed_mesh():
    """Two distorted quads and two triangles sharing vertices."""
    coords = np.array([[0, 0], [1, 0.1], [2.2, 0], [0.1, 1], [1.1, 1.2], [2, 1], [1, 2]], float)
    quads = np.array([[0, 1, 4, 3], [1, 2, 5, 4]])
    triangles = np.array([[3, 4, 6], [4, 5, 6]])
    return coords, quads, triangles


def test_cell_areas_and_numbering():
    coords, quads, triangles = mixed_mesh()
    rule = cell_quadrature(coords, quads, triangles, 3)
    areas = np.concatenate([shoelace(coords, quads), shoelace(coords, triangles)])
    np.testing.assert_allclose(np.bincount(rule.cell, rule.weights), areas, rtol=1e-14)
    assert rule.normals is None and rule.cell.dtype == np.int64
    # A subset keeps the global numbering: triangles count after all quads.
    subset = cell_quadrature(coords, quads, triangles, 2, quad_ids=[1], triangle_ids=[1])
    assert np.unique(subset.cell).tolist() == [1, 3]
    np.testing.assert_allclose(
        np.bincount(subset.cell, subset.weights, minlength=4)[[1, 3]], areas[[1, 3]], rtol=1e-14
    )


def test_points_lie_in_their_cell():
    coords, quads, triangles = mixed_mesh()
    rule = cell_quadrature(coords, quads, triangles, 4)
    cells = [*quads, *triangles]
    for point, cell in zip(rule.points, rule.cell, strict=True):
        corners = coords[cells[cell]]
        edges = np.roll(corners, -1, axis=0) - corners
        to_point = point - corners
        # Inside a convex CCW polygon: to the left of every edge.
        assert np.all(edges[:, 0] * to_point[:, 1] - edges[:, 1] * to_point[:, 0] > 0)


def test_segments_lengths_points_and_outward_normals():
    # The boundary of the unit square, counter-clockwise, in 8 segments.
    coords = np.array([[0, 0], [0.5, 0], [1, 0], [1, 0.5], [1, 1], [0.5, 1], [0, 1], [0, 0.5]])
    segments = np.column_stack([np.arange(8), (np.arange(8) + 1) % 8])
    rule = segment_quadrature(coords, segments, 3)
    np.testing.assert_allclose(np.bincount(rule.cell, rule.weights), 0.5, rtol=1e-14)
    expected_normals = np.repeat([[0, -1], [0, -1], [1, 0], [1, 0], [0, 1], [0, 1], [-1, 0],
                                  [-1, 0]], 3, axis=0)  # fmt: skip
    np.testing.assert_allclose(rule.normals, expected_normals, atol=1e-15)
    # Divergence theorem: closed integral of x^5 n_x = int_square 5 x^4 = 1 (degree 5 = 2n - 1).
    np.testing.assert_allclose(
        np.sum(rule.weights * rule.points[:, 0] ** 5 * rule.normals[:, 0]), 1.0
    )
    subset = segment_quadrature(coords, segments, 2, segment_ids=[5, 2])
    assert subset.cell.tolist() == [5, 5, 2, 2]
    np.testing.assert_allclose(subset.points[:2, 1], 1.0)


def test_slanted_segment_normal_and_length():
    coords = np.array([[0.0, 0.0], [3.0, 4.0]])
    rule = segment_quadrature(coords, [[0, 1]], 1)
    np.testing.assert_allclose(rule.weights, [5.0])
    np.testing.assert_allclose(rule.normals, [[0.8, -0.6]])
    np.testing.assert_allclose(rule.points, [[1.5, 2.0]])


def test_bad_order_is_input_error():
    coords, quads, triangles = mixed_mesh()
    for order in (0, 2.5):
        with pytest.raises(InputError, match="discretization.quadrature"):
            cell_quadrature(coords, quads, triangles, order)


def test_z_domain_area_perimeter_and_divergence_theorem():
    geometry = pytest.importorskip("parefg.geometry.gmsh_mesh")
    cloud = geometry.build_node_cloud(MPI.COMM_WORLD, {"shape": "z"}, 0.1)
    z = [(0, 0), (1, 0), (1, 0.25), (0.4, 0.25), (1, 0.75), (1, 1), (0, 1), (0, 0.75), (0.6, 0.75),
         (0, 0.25)]  # fmt: skip
    corners = as_float(z)
    cells = cell_quadrature(cloud.coords, cloud.quads, cloud.triangles, 2)
    boundary = segment_quadrature(cloud.coords, cloud.segments, 2)
    np.testing.assert_allclose(cells.weights.sum(), exact_polygon_integral(z, 0, 0), rtol=1e-12)
    perimeter = np.sum(np.linalg.norm(np.roll(corners, -1, axis=0) - corners, axis=1))
    np.testing.assert_allclose(boundary.weights.sum(), perimeter, rtol=1e-12)
    # Closed integral of (x^2 y) n_x ds = int_Z 2 x y dA.
    flux = np.sum(boundary.weights * boundary.points[:, 0] ** 2 * boundary.points[:, 1]
                  * boundary.normals[:, 0])  # fmt: skip
    np.testing.assert_allclose(flux, 2 * exact_polygon_integral(z, 1, 1), rtol=1e-12)
