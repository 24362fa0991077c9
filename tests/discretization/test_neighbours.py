"""Neighbour search: the covering nodes of a point, nearest first, on graded clouds.

The reference is the definition, evaluated by brute force over every (point, node)
pair: the nodes I with |x - x_I| < d_I (the distance rounded as sqrt(dx^2 + dy^2)),
sorted by (distance, node), padded with the nearest node (node 0 where no node covers
the point).  Both backends must return exactly that, entry by entry.
"""

import numpy as np
import pytest

from parefg.discretization.mls import BACKENDS
from parefg.discretization.neighbours import (
    CLASS_RATIO,
    NeighbourSearch,
    RegionSearch,
    radius_classes,
)


def brute_force(points, nodes, radius):
    """(neighbours, mask) of the definition, from the full (n_points, n_nodes) distances."""
    dx = points[:, None, 0] - nodes[None, :, 0]
    dy = points[:, None, 1] - nodes[None, :, 1]
    distance = np.sqrt(dx * dx + dy * dy)  # (n_points, n_nodes)
    covered = distance < radius
    node = np.broadcast_to(np.arange(len(nodes)), distance.shape)
    order = np.lexsort((node, np.where(covered, distance, np.inf)), axis=1)
    n_max = max(int(covered.sum(axis=1).max()), 1)
    neighbours = order[:, :n_max]
    mask = np.take_along_axis(covered, neighbours, axis=1)
    nearest = np.where(mask[:, :1], neighbours[:, :1], 0)
    return np.where(mask, neighbours, nearest), mask


def graded_cloud(seed=3):
    """Nodes and radii over 5 decades, with exact ties and points no node covers.

    * random nodes whose radius grows from 2e-4 at x = 0 to 0.4 at x = 1;
    * a binary grid of spacing 1/8 on x >= 1/4 with radius exactly 1/8, and points on
      its nodes (neighbours at distance exactly d_I, which do not cover) and at its cell
      centres (four nodes at one distance);
    * nodes of x < 1/2 repeated at the same place with a radius a decade or two smaller
      or 3 times larger (equal distances across radius classes);
    * points near x = 0, between the tiny supports, that no node covers.
    """
    rng = np.random.default_rng(seed)
    random_nodes = rng.uniform(0.0, 1.0, (400, 2))
    random_radius = 2e-4 * (0.4 / 2e-4) ** random_nodes[:, 0]
    ticks = np.arange(7) / 8.0
    grid = np.column_stack([g.ravel() for g in np.meshgrid(0.25 + ticks, ticks, indexing="ij")])
    grid_radius = np.full(len(grid), 0.125)
    left = np.flatnonzero(random_nodes[:, 0] < 0.5)[:40]
    repeated = random_nodes[left]
    repeated_radius = random_radius[left] * rng.choice([0.01, 0.1, 3.0], len(left))
    nodes = np.concatenate([random_nodes, grid, repeated])
    radius = np.concatenate([random_radius, grid_radius, repeated_radius])
    centres = grid[:20] + 1.0 / 16.0
    points = np.concatenate(
        [
            rng.uniform(0.0, 1.0, (1500, 2)),
            grid,
            centres,
            nodes[:100],  # at nodes: distance 0 to one or more of them
            np.column_stack([rng.uniform(0.0, 0.02, 50), rng.uniform(0.1, 0.9, 50)]),
        ]
    )
    order = rng.permutation(len(nodes))  # node numbers unrelated to position or radius
    return np.ascontiguousarray(nodes[order]), radius[order], points


@pytest.mark.parametrize("backend", BACKENDS)
def test_lists_are_the_definition_on_a_graded_cloud(backend):
    nodes, radius, points = graded_cloud()
    expected = brute_force(points, nodes, radius)
    assert radius.max() / radius.min() > 10.0**4
    assert not expected[1][:, 0].all()  # some points lie outside every support
    found = NeighbourSearch(nodes, radius, backend).find(points)
    assert found[0].shape == expected[0].shape
    assert np.array_equal(found[1], expected[1])
    assert np.array_equal(found[0], expected[0])


def test_lists_are_the_definition_on_a_uniform_grid_with_ties():
    # One radius class; grid points and cell centres at exactly equal distances.
    ticks = np.arange(17) / 16.0
    nodes = np.column_stack([g.ravel() for g in np.meshgrid(ticks, ticks, indexing="ij")])
    radius = np.full(len(nodes), 3.2 / 16.0)
    points = np.concatenate([nodes, nodes[:-18] + 1.0 / 32.0])
    expected = brute_force(points, nodes, radius)
    for backend in BACKENDS:
        found = NeighbourSearch(nodes, radius, backend).find(points)
        assert np.array_equal(found[0], expected[0]) and np.array_equal(found[1], expected[1])


def test_lists_are_the_definition_on_two_interleaved_radius_classes():
    # Every third grid node with a 2.5 times larger support: two classes over one region,
    # each of which covers most points (merged lists with ties between the classes).
    ticks = np.arange(17) / 16.0
    nodes = np.column_stack([g.ravel() for g in np.meshgrid(ticks, ticks, indexing="ij")])
    radius = np.where(np.arange(len(nodes)) % 3 == 0, 0.5, 0.2)
    points = np.concatenate([np.random.default_rng(5).uniform(0.0, 1.0, (500, 2)), nodes])
    assert len(radius_classes(radius)[1]) == 2
    expected = brute_force(points, nodes, radius)
    for backend in BACKENDS:
        found = NeighbourSearch(nodes, radius, backend).find(points)
        assert np.array_equal(found[0], expected[0]) and np.array_equal(found[1], expected[1])


@pytest.mark.parametrize("backend", BACKENDS)
def test_region_search_gives_the_lists_of_the_whole_cloud(backend):
    """A search among the nodes that reach a box (a rank's part) lists, for points in the
    box, exactly the nodes of the definition over the whole cloud, numbered as in it; it
    holds fewer nodes; points outside the box grow it (rebuilt once) and get theirs."""
    nodes, radius, points = graded_cloud()
    search = RegionSearch(nodes, radius, backend, [[0.5, 0.0], [0.75, 0.5]])
    assert len(search.members) < 0.6 * len(nodes)
    inside = points[np.all((points >= [0.5, 0.0]) & (points <= [0.75, 0.5]), axis=1)]
    for chunk in (inside, points):  # then every point: the box grows to the whole square
        expected = brute_force(chunk, nodes, radius)
        found = search.find(chunk)
        assert np.array_equal(found[1], expected[1]) and np.array_equal(found[0], expected[0])
    assert search.rebuilds == 1 and search.members is None  # every node


def test_radius_classes_span_less_than_the_ratio_and_reach_their_radii():
    _, radius, _ = graded_cloud()
    classes, reach = radius_classes(radius)
    assert np.array_equal(np.unique(classes), np.arange(len(reach)))
    assert len(reach) >= 10  # 3.5 decades in factors of 2
    for c in range(len(reach)):
        members = radius[classes == c]
        assert members.max() / members.min() < CLASS_RATIO * (1 + 1e-12)
        assert np.all(members < reach[c]) and reach[c] < members.max() * (1 + 1e-12)
    uniform = radius_classes(np.linspace(1.0, 1.9, 50))
    assert np.array_equal(uniform[0], np.zeros(50)) and len(uniform[1]) == 1


def test_a_rank_searches_only_the_nodes_near_its_part():
    """In a run, each rank holds and searches only the nodes that reach its own part (on
    2 ranks, at h = 1/32, at most 75 % of the cloud's; on 1, all), and every evaluation of
    the run (the build, steps, output fields, error norms) falls in the box it started
    with (on several ranks a point outside it is an error: its nodes may not be held)."""
    from mpi4py import MPI

    from parefg.io.observers import output_fields
    from parefg.run import prepare

    comm = MPI.COMM_WORLD
    sim = prepare(comm, "z", ["discretization.h=0.03125", "time.T=0.1"])
    state = sim.start()
    for step in (1, 2):
        state = sim.step(state, step)
    output_fields(sim, state)
    sim.errors(state.u, 2 * sim.scheme.dt)
    search = sim.disc.domain.gradients.mls.search
    assert isinstance(search, RegionSearch) and search.rebuilds == 0
    if comm.size == 1:
        assert search.members is None  # every node
    else:
        assert len(search.members) <= 0.75 * sim.disc.n_nodes, len(search.members)
        assert len(sim.disc.cloud.coords) <= 0.85 * sim.disc.n_nodes  # own, ghosts, boundary
        assert not search.complete


def test_a_search_of_some_nodes_refuses_points_outside_its_box():
    """Holding only the nodes that reach its box (a rank's own and ghost nodes), a search
    cannot grow: a point outside the box is a RuntimeError, not a list missing nodes;
    points inside get the lists of the whole cloud."""
    nodes, radius, _ = graded_cloud()
    box = np.array([[0.2, 0.2], [0.6, 0.7]])
    held = np.flatnonzero(
        np.hypot(*(nodes - np.clip(nodes, *box)).T) <= radius * 1.01
    )  # what add_ghosts holds (and a little more)
    search = RegionSearch(nodes[held], radius[held], "numpy", box, complete=False)
    inside = np.random.default_rng(5).uniform(box[0], box[1], size=(50, 2))
    found, mask = search.find(inside)
    expected, expected_mask = brute_force(inside, nodes, radius)
    np.testing.assert_array_equal(
        np.where(mask, held[found], -1), np.where(expected_mask, expected, -1)
    )
    with pytest.raises(RuntimeError, match="outside the box"):
        search.find(np.array([[0.5, 0.5], [0.9, 0.5]]))
