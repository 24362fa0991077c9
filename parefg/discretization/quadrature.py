"""Gauss quadrature on background cells and boundary segments (SPEC 3).

The "order" n of a rule is the number of Gauss points per direction:

- quadrilaterals: n x n tensor Gauss-Legendre through the bilinear map, exact for
  integrands of degree 2n - 1 in each reference variable: total degree 2n - 1 on
  parallelograms, 2n - 2 on general quadrilaterals (the Jacobian of a bilinear
  map adds one degree in each reference variable);
- triangles: the collapsed (Duffy) square with Gauss-Jacobi(alpha = 1) points in
  the collapsed direction, n^2 points exact for total degree 2n - 1;
- segments: n-point Gauss-Legendre, exact for degree 2n - 1.

Rules are built for all cells at once; the points of one cell are contiguous.
"""

from dataclasses import dataclass

import numpy as np
from scipy.special import roots_jacobi, roots_legendre

from parefg.errors import InputError


@dataclass
class Quadrature:
    """Quadrature points and weights of a set of cells or boundary segments.

    Attributes
    ----------
    points : ndarray, shape (n_qp, 2)
    weights : ndarray, shape (n_qp,)
        Gauss weights times the Jacobian determinant of the cell map.
    cell : ndarray of int64, shape (n_qp,)
        Index of the cell (quads first, then triangles numbered n_quads + j) or of
        the segment the point belongs to.
    normals : ndarray, shape (n_qp, 2), or None
        Outward unit normals for boundary rules, None for cell rules.
    """

    points: np.ndarray
    weights: np.ndarray
    cell: np.ndarray
    normals: np.ndarray | None


def _check_order(order):
    if not isinstance(order, int | np.integer) or order < 1:
        raise InputError(f"discretization.quadrature: must be an integer >= 1, got {order!r}")


def gauss_legendre_unit(order: int) -> tuple[np.ndarray, np.ndarray]:
    """n-point Gauss-Legendre rule on [0, 1]: points (n,), weights (n,) summing to 1."""
    points, weights = roots_legendre(order)
    return (points + 1.0) / 2.0, weights / 2.0


def reference_quad_rule(order: int) -> tuple[np.ndarray, np.ndarray]:
    """n x n tensor Gauss-Legendre rule on [-1, 1]^2: points (n^2, 2), weights (n^2,)."""
    points, weights = roots_legendre(order)
    xi, eta = np.meshgrid(points, points, indexing="ij")
    return np.column_stack([xi.ravel(), eta.ravel()]), np.outer(weights, weights).ravel()


def reference_triangle_rule(order: int) -> tuple[np.ndarray, np.ndarray]:
    """Collapsed Gauss rule on the triangle (0,0), (1,0), (0,1): points (n^2, 2), weights (n^2,).

    With x = u, y = v (1 - u) the integral becomes int_0^1 int_0^1 f (1 - u) dv du;
    the factor (1 - u) is the Gauss-Jacobi(1, 0) weight, so n points in u and n
    Gauss-Legendre points in v integrate total degree 2n - 1 exactly.
    """
    t, jacobi_weights = roots_jacobi(order, 1.0, 0.0)
    # int_0^1 g(u) (1 - u) du = 1/4 int_{-1}^{1} g((1 + t)/2) (1 - t) dt
    u, u_weights = (1.0 + t) / 2.0, jacobi_weights / 4.0
    v, v_weights = gauss_legendre_unit(order)
    uu, vv = np.meshgrid(u, v, indexing="ij")
    points = np.column_stack([uu.ravel(), (vv * (1.0 - uu)).ravel()])
    return points, np.outer(u_weights, v_weights).ravel()


def _quad_cells(coords, quads, order, ids):
    """Points (n_cells * n^2, 2) and weights of the bilinear map of each quadrilateral."""
    reference, reference_weights = reference_quad_rule(order)  # (n^2, 2), (n^2,)
    xi, eta = reference[:, 0], reference[:, 1]
    # Bilinear shape functions and their derivatives at the Gauss points, (n^2, 4) each.
    shape = 0.25 * np.column_stack([(1 - xi) * (1 - eta), (1 + xi) * (1 - eta),
                                    (1 + xi) * (1 + eta), (1 - xi) * (1 + eta)])  # fmt: skip
    dshape_dxi = 0.25 * np.column_stack([-(1 - eta), 1 - eta, 1 + eta, -(1 + eta)])
    dshape_deta = 0.25 * np.column_stack([-(1 - xi), -(1 + xi), 1 + xi, 1 - xi])
    corners = coords[quads[ids]]  # (n_cells, 4, 2)
    # one (n^2, 4) @ (4, 2) product per cell (matmul: 20x einsum's time at 1e6 points, and
    # each cell's bits independent of the others in the call)
    points = shape @ corners  # (n_cells, n^2, 2)
    dx_dxi = dshape_dxi @ corners  # (n_cells, n^2, 2)
    dx_deta = dshape_deta @ corners
    jacobian = dx_dxi[..., 0] * dx_deta[..., 1] - dx_dxi[..., 1] * dx_deta[..., 0]
    weights = reference_weights * np.abs(jacobian)  # (n_cells, n^2)
    return points.reshape(-1, 2), weights.ravel()


def _triangle_cells(coords, triangles, order, ids):
    """Points (n_cells * n^2, 2) and weights of the affine map of each triangle."""
    reference, reference_weights = reference_triangle_rule(order)  # (n^2, 2), (n^2,)
    corners = coords[triangles[ids]]  # (n_cells, 3, 2)
    edges = corners[:, 1:, :] - corners[:, :1, :]  # (n_cells, 2, 2): x1 - x0, x2 - x0
    points = corners[:, None, 0, :] + reference @ edges  # (n_cells, n^2, 2)
    twice_area = np.abs(edges[:, 0, 0] * edges[:, 1, 1] - edges[:, 0, 1] * edges[:, 1, 0])
    weights = reference_weights[None, :] * twice_area[:, None]  # (n_cells, n^2)
    return points.reshape(-1, 2), weights.ravel()


def _cells(connectivity, n_corners):
    """Connectivity as an int array (n_cells, n_corners), empty when None."""
    if connectivity is None:
        return np.zeros((0, n_corners), dtype=np.int64)
    return np.asarray(connectivity, dtype=np.int64).reshape(-1, n_corners)


def _selection(ids, n_cells):
    return np.arange(n_cells) if ids is None else np.asarray(ids, dtype=np.int64).ravel()


def cell_quadrature(
    coords, quads, triangles, order: int, quad_ids=None, triangle_ids=None
) -> Quadrature:
    """Gauss points of quadrilateral and triangular cells. Not collective.

    Parameters
    ----------
    coords : array_like, shape (n_vertices, 2)
    quads : array_like of int, shape (n_quads, 4), or None
        Corner indices, counter-clockwise.
    triangles : array_like of int, shape (n_triangles, 3), or None
    order : int
        Gauss points per direction n (n^2 points per cell).
    quad_ids, triangle_ids : array_like of int, optional
        Subsets of cells to integrate (default: all); e.g. this rank's cells.

    Returns
    -------
    Quadrature
        ``cell`` is the position in ``quads``, or n_quads + j for triangle j.
    """
    _check_order(order)
    coords = np.asarray(coords, dtype=float)
    quads, triangles = _cells(quads, 4), _cells(triangles, 3)
    quad_ids = _selection(quad_ids, len(quads))
    triangle_ids = _selection(triangle_ids, len(triangles))
    quad_points, quad_weights = _quad_cells(coords, quads, order, quad_ids)
    tri_points, tri_weights = _triangle_cells(coords, triangles, order, triangle_ids)
    per_cell = order * order
    cell = np.concatenate(
        [np.repeat(quad_ids, per_cell), np.repeat(len(quads) + triangle_ids, per_cell)]
    )
    return Quadrature(
        points=np.concatenate([quad_points, tri_points]),
        weights=np.concatenate([quad_weights, tri_weights]),
        cell=cell.astype(np.int64),
        normals=None,
    )


def segment_quadrature(coords, segments, order: int, segment_ids=None) -> Quadrature:
    """Gauss-Legendre points of straight boundary segments (a, b). Not collective.

    The domain lies to the left of a -> b, so the outward unit normal is
    (dy, -dx) / |b - a| with (dx, dy) = b - a.

    Parameters
    ----------
    coords : array_like, shape (n_vertices, 2)
    segments : array_like of int, shape (n_segments, 2)
    order : int
        Gauss points per segment.
    segment_ids : array_like of int, optional
        Subset of segments (default: all); ``cell`` holds these indices.
    """
    _check_order(order)
    coords = np.asarray(coords, dtype=float)
    segments = _cells(segments, 2)
    segment_ids = _selection(segment_ids, len(segments))
    t, reference_weights = gauss_legendre_unit(order)  # (n,), (n,)
    start = coords[segments[segment_ids, 0]]  # (n_seg, 2)
    tangent = coords[segments[segment_ids, 1]] - start  # (n_seg, 2): b - a
    length = np.hypot(tangent[:, 0], tangent[:, 1])  # (n_seg,)
    points = start[:, None, :] + t[None, :, None] * tangent[:, None, :]  # (n_seg, n, 2)
    normal = np.column_stack([tangent[:, 1], -tangent[:, 0]]) / length[:, None]  # (n_seg, 2)
    return Quadrature(
        points=points.reshape(-1, 2),
        weights=(reference_weights[None, :] * length[:, None]).ravel(),
        cell=np.repeat(segment_ids, order).astype(np.int64),
        normals=np.repeat(normal, order, axis=0),
    )
