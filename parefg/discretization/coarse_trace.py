"""The coarse trace space of Nitsche's boundary methods: one polynomial coefficient per segment.

Symmetric Nitsche with a large stabilization tends to the penalty's limit u_h = ubar at
every boundary Gauss point.  An MLS space has one node per segment along the boundary but
several Gauss points per segment, so that limit over-constrains the trace and the error
grows with beta (square, m = 2, h = 1/8: 94x from safety 1.1 to 2e4, README "Dirichlet
parameter").  The method here imposes the condition on a coarse space instead: the
boundary terms act on the L2 projection P of the trace and of the traction onto
polynomials of degree n_g - 1 on groups of n_g ~ CHUNK_SEGMENTS consecutive segments of
one straight run of the boundary::

    D = int beta P(u) . P(v) - int P(sigma(u) n) . P(v) - int P(u) . P(sigma(v) n)

One coefficient per segment and component is what the MLS trace can meet without taking
freedom from the interior, so the beta -> infinity limit (a Lagrange multiplier on the
coarse space, which Nitsche's form stabilizes: Stenberg 1995) stays accurate; degree
n_g - 1 >= 3 approximates the traction to O(h^4), so the projection costs no rate for
m <= 3.  Measured (static square, m = 2, h = 1/8 ... 1/32): the same errors as pointwise
Nitsche at safety 2, within 1.01x from safety 1.1 to 2e4.

beta is constant on a group (its segments' largest bound), which makes P and beta commute:
the load L = beta P V - P T reproduces the form's data terms.  Groups never cross a corner
of the boundary (where the traction jumps), a part or a rank: a group is owned by the rank
of its lowest segment.  Dirichlet and contact parts use it by default ("nitsche"; for
contact the law on P u, P sigma_nu and P s, and the body feels the traction P(p nu)).
Contact parts may take :func:`hat_projection` instead ("nitsche-hat").  Nothing here is
collective.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import scipy.sparse as sp

if TYPE_CHECKING:  # the scene schema reads dirichlet.py, which imports project_rows
    from parefg.discretization.quadrature import Quadrature

#: segments per group of the coarse trace (degree CHUNK_SEGMENTS - 1 on a full group)
CHUNK_SEGMENTS = 4
#: segments per group of the contact law's piecewise-linear space (:func:`hat_projection`):
#: each group adds one condition at its ends, and P couples the nodes of its group
HAT_SEGMENTS = 8
#: a turn of more than this between consecutive segments is a corner (30 degrees)
CORNER_COSINE = np.cos(np.radians(30.0))


def trace_groups(
    coords: np.ndarray,
    segments: np.ndarray,
    segment_ids: np.ndarray,
    per_group: int = CHUNK_SEGMENTS,
):
    """Group of each segment of ``segment_ids`` and its arc offset within the group.

    The segments are walked as chains (the end of one is the start of the next), cut at
    corners, and each straight run of n segments is split into max(1, round(n /
    per_group)) groups of near-equal size.  Returns (group, offset), both
    (len(segment_ids),): group numbers from 0, rank-independent for the same input;
    offset the arc length from the group's start to the segment's first node.
    """
    segment_ids = np.asarray(segment_ids, dtype=np.int64)
    group = np.full(len(segment_ids), -1, dtype=np.int64)
    offset = np.zeros(len(segment_ids))
    if len(segment_ids) == 0:
        return group, offset
    start, end = segments[segment_ids, 0], segments[segment_ids, 1]
    tangent = coords[end] - coords[start]
    length = np.hypot(tangent[:, 0], tangent[:, 1])
    tangent = tangent / length[:, None]
    following = {int(a): i for i, a in enumerate(start)}  # first node -> local segment
    preceding = {int(b): i for i, b in enumerate(end)}  # last node -> local segment
    previous = np.array([preceding.get(int(a), -1) for a in start], dtype=np.int64)
    turn = np.einsum("ij,ij->i", tangent[previous], tangent) < CORNER_COSINE
    # walks start where a chain begins, then at corners (a closed polygon's run is not
    # cut where its walk happens to start), then anywhere (a smooth closed loop)
    begins = previous < 0
    order = np.concatenate(
        [np.flatnonzero(begins), np.flatnonzero(~begins & turn), np.flatnonzero(~begins & ~turn)]
    )
    visited = np.zeros(len(segment_ids), dtype=bool)
    runs: list[list[int]] = []
    for first in order:
        if visited[first]:
            continue
        run: list[int] = []
        current: int | None = int(first)
        while current is not None and not visited[current]:
            visited[current] = True
            if run and tangent[run[-1]] @ tangent[current] < CORNER_COSINE:
                runs.append(run)
                run = []
            run.append(current)
            current = following.get(int(end[current]))
        runs.append(run)
    n_groups = 0
    for run in runs:
        for chunk in np.array_split(run, max(1, round(len(run) / per_group))):
            group[chunk] = n_groups
            offset[chunk] = np.concatenate([[0.0], np.cumsum(length[chunk])[:-1]])
            n_groups += 1
    return group, offset


def projection(
    quadrature: Quadrature,
    coords: np.ndarray,
    segments: np.ndarray,
    group: np.ndarray,
    offset: np.ndarray,
) -> sp.csr_matrix:
    """The weighted L2 projection onto the coarse space, (n_points x n_points).

    ``group``, ``offset``: of each point's segment (:func:`trace_groups`); the points of a
    group must all be in ``quadrature``; points of group -1 (a penalty part's) keep their
    values (identity rows).  Applies to each component of a point field.  The projection
    is W-self-adjoint: W P = P^T W with W the quadrature weights.
    """
    start = coords[segments[quadrature.cell, 0]]
    arc = offset + np.hypot(*(quadrature.points - start).T)  # along the group

    def legendre(points: np.ndarray) -> np.ndarray:
        """Legendre polynomials of degree < the group's segments, in [-1, 1] over its points."""
        n_segments = len(np.unique(quadrature.cell[points]))
        low, high = arc[points].min(), arc[points].max()
        scaled = (2 * arc[points] - low - high) / max(high - low, np.finfo(float).tiny)
        return np.polynomial.legendre.legvander(scaled, n_segments - 1)

    return _projection_by_group(quadrature.weights, group, legendre)


def _projection_by_group(weights: np.ndarray, group: np.ndarray, basis) -> sp.csr_matrix:
    """The W-orthogonal projection onto span ``basis(points)`` on each group's points.

    ``basis``: the point indices of one group -> their (points x functions) basis values.
    Points of group -1 keep their values.
    """
    alone = np.flatnonzero(group < 0)
    rows, columns, values = [alone], [alone], [np.ones(len(alone))]
    # the points of each group, in one sort (a rank without points of the part: empty P)
    by_group = np.argsort(group, kind="stable")
    starts = np.flatnonzero(np.diff(group[by_group])) + 1
    for points in np.split(by_group, starts):
        if len(points) == 0 or group[points[0]] < 0:
            continue
        root = np.sqrt(weights[points])
        orthonormal, _ = np.linalg.qr(root[:, None] * basis(points))  # in the weights
        block = (orthonormal / root[:, None]) @ (orthonormal * root[:, None]).T
        rows.append(np.repeat(points, len(points)))
        columns.append(np.tile(points, len(points)))
        values.append(block.ravel())
    n = len(weights)
    return sp.csr_matrix(
        (np.concatenate(values), (np.concatenate(rows), np.concatenate(columns))), shape=(n, n)
    )


def project_rows(projection: sp.csr_matrix, interleaved: sp.csr_matrix) -> sp.csr_matrix:
    """P applied to each component of an operator with rows 2q + c (values, tractions)."""
    return (sp.kron(projection, sp.identity(2), format="csr") @ interleaved).tocsr()


def group_largest(values: np.ndarray, group: np.ndarray) -> np.ndarray:
    """``values`` per point with each group's points given its largest (group -1 kept).

    beta or gamma constant on a group makes P commute with it.
    """
    grouped = group >= 0
    largest = np.zeros(group.max() + 1 if len(group) else 0)
    np.maximum.at(largest, group[grouped], values[grouped])
    out = np.array(values, dtype=float)
    out[grouped] = largest[group[grouped]]
    return out


def hat_projection(
    quadrature: Quadrature,
    coords: np.ndarray,
    segments: np.ndarray,
    group: np.ndarray,
    offset: np.ndarray,
) -> sp.csr_matrix:
    """The weighted L2 projection onto continuous piecewise-linear functions, (n_points)^2.

    On each group (:func:`trace_groups`, cut with :data:`HAT_SEGMENTS`) the hat functions of
    its n_s + 1 vertices span the space: one coefficient per segment, as the polynomial
    space of :func:`projection`, but each local to two segments, so that the edge of a
    contact zone is resolved at the segments' scale.  ``group``, ``offset``: of each
    point's segment; points of group -1 keep their values.  W-self-adjoint, as
    :func:`projection`.
    """
    start = coords[segments[quadrature.cell, 0]]
    length = np.hypot(*(coords[segments[quadrature.cell, 1]] - start).T)
    along = np.hypot(*(quadrature.points - start).T) / length  # (n_points,) in [0, 1]

    def hats(points: np.ndarray) -> np.ndarray:
        """The group's hats at its points: a point lies between vertices k and k + 1."""
        _, left = np.unique(offset[points], return_inverse=True)  # segments in arc order
        values = np.zeros((len(points), left.max() + 2))
        values[np.arange(len(points)), left] = 1 - along[points]
        values[np.arange(len(points)), left + 1] = along[points]
        return values

    return _projection_by_group(quadrature.weights, group, hats)
