"""The coarse trace space of Nitsche's Dirichlet method (parefg.discretization.coarse_trace).

Groups follow the boundary's straight runs and never cross a corner; the projection is
the weighted L2 projection onto polynomials of degree (segments of the group - 1) in arc
length: it keeps those polynomials, is idempotent and self-adjoint in the quadrature
weights, and removes what is orthogonal to them.  Not collective (plain arrays).
"""

import numpy as np
import pytest

from parefg.discretization.coarse_trace import (
    CHUNK_SEGMENTS,
    HAT_SEGMENTS,
    group_largest,
    hat_projection,
    projection,
    trace_groups,
)
from parefg.discretization.quadrature import segment_quadrature


def _polygon(vertices: np.ndarray, per_edge: list[int]):
    """Coordinates and counter-clockwise segments of a closed polygon, per_edge[i] segments
    on edge i, numbered from a shuffled start so that the walk does not rely on order."""
    points = []
    for i, n in enumerate(per_edge):
        a, b = vertices[i], vertices[(i + 1) % len(vertices)]
        points += [a + (b - a) * t for t in np.arange(n) / n]
    coords = np.array(points)
    n = len(coords)
    segments = np.stack([np.arange(n), (np.arange(n) + 1) % n], axis=1)
    order = np.random.default_rng(3).permutation(n)
    return coords, segments[order]


SQUARE = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])


def test_groups_split_straight_runs_and_never_cross_a_corner():
    per_edge = [8, 5, 2, 13]
    coords, segments = _polygon(SQUARE, per_edge)
    group, offset = trace_groups(coords, segments, np.arange(len(segments)))
    direction = coords[segments[:, 1]] - coords[segments[:, 0]]
    direction /= np.linalg.norm(direction, axis=1)[:, None]
    sizes = []
    for g in np.unique(group):
        members = np.flatnonzero(group == g)
        np.testing.assert_allclose(
            direction[members], direction[members[:1]].repeat(len(members), 0)
        )
        sizes.append(len(members))
        # offsets run 0, |s_1|, |s_1| + |s_2|, ... along the chain
        lengths = np.linalg.norm(
            coords[segments[members, 1]] - coords[segments[members, 0]], axis=1
        )
        np.testing.assert_allclose(
            np.sort(offset[members]), np.concatenate([[0], np.cumsum(lengths)[:-1]])
        )
    expected = [max(1, round(n / CHUNK_SEGMENTS)) for n in per_edge]
    assert len(sizes) == sum(expected)
    assert sorted(sizes) == sorted(
        len(c)
        for n, k in zip(per_edge, expected, strict=True)
        for c in np.array_split(np.arange(n), k)
    )


def test_a_slight_bend_is_no_corner_and_an_open_chain_starts_at_its_end():
    """Ten segments along a polyline turning by 10 degrees: one run, split in groups of
    consecutive segments (an open chain is walked from its first segment)."""
    angles = np.radians(10.0) * np.arange(11)
    coords = np.cumsum(np.stack([np.cos(angles), np.sin(angles)], 1), axis=0)
    segments = np.stack([np.arange(10), np.arange(1, 11)], 1)[::-1]  # listed backwards
    group, _ = trace_groups(coords, segments, np.arange(10))
    chain = group[::-1]  # in walking order
    assert len(np.unique(group)) == round(10 / CHUNK_SEGMENTS)
    assert np.all(np.diff(chain) >= 0)  # groups are contiguous along the chain


def _projected_square(build, per_edge: list[int], order: int, per_group: int):
    """P of ``build`` (projection, hat_projection) on the square's boundary, checked to be a
    W-self-adjoint projection.  Returns (P dense, group per segment, group, offset,
    quadrature, arc length in the group per point)."""
    coords, segments = _polygon(SQUARE, per_edge)
    ids = np.arange(len(segments))
    group, offset = trace_groups(coords, segments, ids, per_group)
    quadrature = segment_quadrature(coords, segments, order, segment_ids=ids)
    point_group, point_offset = np.repeat(group, order), np.repeat(offset, order)
    p = build(quadrature, coords, segments, point_group, point_offset).toarray()
    w = np.diag(quadrature.weights)
    np.testing.assert_allclose(p @ p, p, atol=1e-10)
    np.testing.assert_allclose(w @ p, (w @ p).T, atol=1e-12)
    start = coords[segments[quadrature.cell, 0]]
    arc = point_offset + np.linalg.norm(quadrature.points - start, axis=1)
    return p, group, point_group, point_offset, quadrature, arc


@pytest.mark.parametrize("order", [2, 3, 5])
def test_projection_keeps_the_coarse_polynomials_and_is_a_weighted_projection(order):
    p, group, point_group, _, quadrature, arc = _projected_square(
        projection, [9, 4, 3, 6], order, CHUNK_SEGMENTS
    )
    # a polynomial of the group's degree in arc length (each group its own) is kept
    field = np.zeros(len(arc))
    for g in np.unique(group):
        members = point_group == g
        degree = len(np.unique(quadrature.cell[members])) - 1
        field[members] = np.polyval(np.arange(1.0, degree + 2), arc[members])
    np.testing.assert_allclose(p @ field, field, atol=1e-10 * np.abs(field).max())
    # rank: one coefficient per segment (9 + 4 + 3 + 6)
    assert np.linalg.matrix_rank(p) == 22
    # a field oscillating point by point within each segment is mostly removed
    oscillation = np.tile([1.0, -1.0], len(arc))[: len(arc)] if order % 2 == 0 else None
    if oscillation is not None:
        assert np.linalg.norm(p @ oscillation) < 0.5 * np.linalg.norm(oscillation)


@pytest.mark.parametrize("order", [2, 3])
def test_hat_projection_keeps_continuous_piecewise_linear_fields_and_is_local(order):
    """The contact law's space: hats on each group's vertices (groups of HAT_SEGMENTS)."""
    p, group, point_group, point_offset, _, arc = _projected_square(
        hat_projection, [17, 4, 3, 9], order, HAT_SEGMENTS
    )
    # one coefficient per vertex of a group: segments (17 + 4 + 3 + 9) + groups
    assert np.linalg.matrix_rank(p) == 33 + len(np.unique(group))
    # a continuous piecewise-linear field of arc length (a kink at every vertex) is kept
    field = np.zeros(len(arc))
    for g in np.unique(group):
        members = point_group == g
        # random values at the segments' first vertices and past the last point
        knots = np.append(np.unique(point_offset[members]), arc[members].max() + 1e-12)
        values = np.random.default_rng(int(g)).normal(size=len(knots))
        field[members] = np.interp(arc[members], knots, values)
    np.testing.assert_allclose(p @ field, field, atol=1e-10 * np.abs(field).max())
    # local: a group's points see only their group
    assert np.all(p[np.not_equal.outer(point_group, point_group)] == 0.0)
    # a field oscillating point by point within each segment is mostly removed
    if order == 2:
        oscillation = np.tile([1.0, -1.0], len(arc) // 2)
        assert np.linalg.norm(p @ oscillation) < 0.5 * np.linalg.norm(oscillation)


def test_group_largest_gives_each_group_its_largest_and_keeps_ungrouped_points():
    values = np.array([1.0, 5.0, 2.0, 7.0, 3.0, 4.0])
    group = np.array([0, 0, -1, 1, 1, -1])
    np.testing.assert_array_equal(group_largest(values, group), [5.0, 5.0, 2.0, 7.0, 7.0, 4.0])
    ungrouped = np.full(3, -1)  # a contact with penalty parts only: nothing changes
    np.testing.assert_array_equal(group_largest(values[:3], ungrouped), values[:3])
