"""The trace-inverse constant of the MLS space on each boundary segment (Nitsche's beta).

Symmetric Nitsche is coercive when its stabilization beta exceeds twice the constant C_e
of the discrete trace-inverse inequality

    || sigma(v) n ||^2_{L2(e)}  <=  C_e  a_{omega_e}(v, v)    for every v in V_h,

where e is a boundary segment and omega_e the background cell it bounds: then
a(v, v) - 2 int sigma(v) n . v + beta ||v||^2 >= a(v, v) / 2 + (beta - 2 C_e) ||v||^2
on each segment (Griebel & Schweitzer 2003 for partition-of-unity methods; Embar, Dolbow &
Harari 2010 for splines).  C_e is the largest eigenvalue of the generalized problem
A x = C B x with A = int_e (sigma n)^T (sigma n) and B = a restricted to omega_e, both on
the coefficients of the nodes whose supports meet omega_e.  It scales as E / h.

B is singular on the rigid motions (which A annihilates too, as the MLS basis reproduces
linear fields) and numerically near-singular on the MLS functions that are almost rigid
on the small cell; the eigenproblem is solved on the range of B above a relative
threshold, with B integrated by a finer Gauss rule than the run's so that the cell's
strain samples outnumber the local coefficients.  Not collective: each rank estimates
its own segments, from data every rank holds (the nodes, and the cell of every segment:
``NodeCloud.segment_cells``), so the estimate of a segment does not depend on the
partition.
"""

from __future__ import annotations

import numpy as np

from parefg.discretization.mls import MLS, ShapeValues
from parefg.discretization.quadrature import cell_quadrature, segment_quadrature
from parefg.geometry.cloud import BoundaryCells, NodeCloud, boundary_cells

#: Gauss points per direction of the cell rule of B, above the run's (and at least this)
ESTIMATE_QUADRATURE = 8
#: eigenvalues of B below this fraction of its largest are its (numerical) null space
RANGE_THRESHOLD = 1e-10


def segment_cells(cloud: NodeCloud) -> BoundaryCells:
    """The cell of every segment: kept by a distributed cloud, else found in its cells."""
    return cloud.segment_cells if cloud.segment_cells is not None else boundary_cells(cloud)


def _strain_rows(dphi: np.ndarray) -> np.ndarray:
    """Voigt strain (eps_xx, eps_yy, 2 eps_xy) per point on interleaved local DOFs.

    ``dphi`` (n_points, n_nodes, 2) -> (n_points, 3, 2 n_nodes).
    """
    n_points, n_nodes, _ = dphi.shape
    rows = np.zeros((n_points, 3, n_nodes, 2))
    rows[:, 0, :, 0] = dphi[:, :, 0]
    rows[:, 1, :, 1] = dphi[:, :, 1]
    rows[:, 2, :, 0] = dphi[:, :, 1]
    rows[:, 2, :, 1] = dphi[:, :, 0]
    return rows.reshape(n_points, 3, 2 * n_nodes)


def _elasticity(lam: float, mu: float) -> np.ndarray:
    """Plane-strain D with sigma_voigt = D eps_voigt, (3, 3)."""
    return np.array([[lam + 2 * mu, lam, 0.0], [lam, lam + 2 * mu, 0.0], [0.0, 0.0, mu]])


def _traction_rows(strain: np.ndarray, normals: np.ndarray, lam: float, mu: float) -> np.ndarray:
    """sigma(v) n per point: (n_points, 3, n_dofs) strains -> (n_points, 2, n_dofs)."""
    stress = _elasticity(lam, mu) @ strain  # (n_points, 3, n_dofs): xx, yy, xy
    nx, ny = normals[:, 0, None], normals[:, 1, None]
    return np.stack(
        [stress[:, 0] * nx + stress[:, 2] * ny, stress[:, 2] * nx + stress[:, 1] * ny], 1
    )


def _local_gradients(shape: ShapeValues, rows: slice, columns: np.ndarray) -> np.ndarray:
    """dphi at the points ``rows`` of ``shape`` on the local node list ``columns``.

    Returns (n_points, len(columns), 2); ``columns`` (sorted) holds every node of the rows.
    """
    assert shape.dphi is not None  # evaluated with gradients
    mask, neighbours, dphi = shape.mask[rows], shape.neighbours[rows], shape.dphi[rows]
    local = np.searchsorted(columns, neighbours)
    out = np.zeros((len(mask), len(columns), 2))
    points = np.broadcast_to(np.arange(len(mask))[:, None], mask.shape)
    out[points[mask], local[mask]] = dphi[mask]  # a point lists each node once
    return out


def trace_inverse_constants(
    mls: MLS,
    cloud: NodeCloud,
    segment_ids: np.ndarray,
    order: int,
    lam: float,
    mu: float,
    edge_values: tuple[np.ndarray, ShapeValues] | None = None,
) -> np.ndarray:
    """C_e of each segment in ``segment_ids`` (see the module docstring), (n_segments,).

    ``order``: Gauss points per segment (the run's); the cell rule of B has
    max(order + 3, ESTIMATE_QUADRATURE) points per direction.  ``edge_values`` = (points,
    shape with gradients) the caller has evaluated on the segments; used if those are
    the segments' Gauss points, else MLS is evaluated there.
    """
    segment_ids = np.asarray(segment_ids, dtype=np.int64)
    if len(segment_ids) == 0:  # a rank without segments of the part
        return np.zeros(0)
    quads, triangles, is_triangle = segment_cells(cloud).of(segment_ids)
    cell_order = max(order + 3, ESTIMATE_QUADRATURE)
    cell_rule = cell_quadrature(cloud.coords, quads, triangles, cell_order)
    # the rule lists quads first: the position of each segment's cell in it
    by_cell = np.argsort(is_triangle, kind="stable")
    position = np.empty(len(segment_ids), dtype=np.int64)
    position[by_cell] = np.arange(len(segment_ids))
    edge_rule = segment_quadrature(cloud.coords, cloud.segments, order, segment_ids=segment_ids)
    assert edge_rule.normals is not None
    cell_shape = mls.evaluate(cell_rule.points, gradients=True)
    if edge_values is not None and np.array_equal(edge_values[0], edge_rule.points):
        edge_shape = edge_values[1]
    else:
        edge_shape = mls.evaluate(edge_rule.points, gradients=True)
    elasticity = _elasticity(lam, mu)
    per_cell, constants = cell_order**2, np.empty(len(segment_ids))
    for i in range(len(segment_ids)):  # one small dense eigenproblem per segment
        cell_rows = slice(position[i] * per_cell, (position[i] + 1) * per_cell)
        edge_rows = slice(i * order, (i + 1) * order)
        nodes = np.unique(
            np.concatenate(
                [cell_shape.neighbours[cell_rows].ravel(), edge_shape.neighbours[edge_rows].ravel()]
            )
        )
        strain = _strain_rows(_local_gradients(cell_shape, cell_rows, nodes))  # (q, 3, n)
        stress = elasticity @ (cell_rule.weights[cell_rows, None, None] * strain)  # (q, 3, n)
        stiffness = strain.reshape(-1, len(nodes) * 2).T @ stress.reshape(-1, len(nodes) * 2)
        edge_strain = _strain_rows(_local_gradients(edge_shape, edge_rows, nodes))
        traction = _traction_rows(edge_strain, edge_rule.normals[edge_rows], lam, mu)
        # A = R^T R with R the traction rows scaled by the square roots of the (positive)
        # Gauss weights: 2 x order rows, far fewer than the 2 n coefficients
        root_weights = np.sqrt(edge_rule.weights[edge_rows])[:, None, None]
        rows = (root_weights * traction).reshape(-1, len(nodes) * 2)  # (2 q, 2 n)
        constants[i] = _largest_generalized(rows, stiffness)
    return constants


def nitsche_beta(
    mls: MLS,
    cloud: NodeCloud,
    nitsche_segments: np.ndarray,
    segment_ids: np.ndarray,
    order: int,
    lam: float,
    mu: float,
    edge_values: tuple[np.ndarray, ShapeValues] | None = None,
) -> np.ndarray:
    """The coercivity bound 2 C_e n_c of each segment in ``segment_ids``, (n_segments,).

    n_c counts the segments of ``nitsche_segments`` (every Nitsche segment of the cloud)
    that bound the same cell: a corner cell with two Nitsche edges shares its energy
    a_{omega_e} between their two estimates.  ``edge_values``: as for
    :func:`trace_inverse_constants`.
    """
    if len(segment_ids) == 0:
        return np.zeros(0)
    cells = segment_cells(cloud).cell
    shared, count_of = np.unique(cells[nitsche_segments], return_counts=True)
    count = count_of[np.searchsorted(shared, cells[np.asarray(segment_ids, dtype=np.int64)])]
    constants = trace_inverse_constants(mls, cloud, segment_ids, order, lam, mu, edge_values)
    return 2.0 * count * constants


def _largest_generalized(rows: np.ndarray, b: np.ndarray) -> float:
    """Largest C of A x = C B x on the range of the symmetric semidefinite B, A = R^T R.

    With B = V diag(lambda) V^T on its range, the problem is that of the symmetric
    Lambda^-1/2 V^T A V Lambda^-1/2 = P^T P, P = R V Lambda^-1/2, whose largest eigenvalue
    is that of the small P P^T (R has few rows: A has low rank).
    """
    values, vectors = np.linalg.eigh(b)
    keep = values > RANGE_THRESHOLD * values[-1]
    projected = rows @ (vectors[:, keep] / np.sqrt(values[keep]))  # (n_rows, n_kept)
    return float(np.linalg.eigvalsh(projected @ projected.T)[-1])
