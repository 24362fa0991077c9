"""A rectangle meshed part by part (parefg.geometry.grid_parts): gmsh's grid, split into
rectangles of nodes, each part holding only its own nodes, its cells' and the boundary's,
and a run on it giving the answer of the cloud meshed and partitioned on rank 0."""

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from parts_runs import assert_answers_as_on_root

from parefg.geometry import grid_parts
from parefg.geometry.cloud import boundary_cells
from parefg.geometry.gmsh_mesh import mesh_domain
from parefg.scene.loader import load_scene

RECTANGLE = {"shape": "rectangle", "origin": [0.3, -1.1], "size": [2.0, 0.7]}
GRIDS = {  # name -> (domain, h, cells): 17 x 17 nodes; 8 x 16 with triangles; 16 x 6; 3 x 3
    "square-quad": ({"shape": "square"}, 1 / 16, "quad"),
    "square-tri": ({"shape": "square"}, 1 / 7, "tri"),
    "rectangle-quad": (RECTANGLE, 0.13, "quad"),
    "rectangle-tri": (RECTANGLE, 0.13, "tri"),
    "square-coarse": ({"shape": "square"}, 1 / 2, "quad"),
}


def grid_of(name: str) -> grid_parts.Grid:
    domain, h, cells = GRIDS[name]
    scene = SimpleNamespace(
        domain=domain, discretization=SimpleNamespace(h=h, jitter=0.0, cells=cells)
    )
    grid = grid_parts.scene_grid(scene)
    assert grid is not None
    return grid


def whole_grid(grid: grid_parts.Grid):
    """The grid as one part: every node, numbered by lattice index."""
    blocks = grid_parts.grid_blocks(grid, 1)
    assert blocks is not None
    return grid_parts.grid_part(grid, blocks, 0)[0]


def canonical(cells: np.ndarray) -> list[tuple]:
    """Cells as sorted tuples of corner numbers, each rotated to start at its lowest."""
    return sorted(tuple(np.roll(row, -int(np.argmin(row)))) for row in cells)


@pytest.mark.parametrize("name", ["square-quad", "square-tri", "rectangle-quad", "rectangle-tri"])
def test_one_part_is_the_grid_gmsh_makes(name):
    domain, h, cells = GRIDS[name]
    meshed = mesh_domain(domain, h, cells)
    mine = whole_grid(grid_of(name))
    # the same nodes, to the bit (gmsh's are snapped to the lattice)
    number = {tuple(xy): n for n, xy in enumerate(meshed.coords)}
    assert len(number) == meshed.n_nodes == mine.n_nodes
    gmsh_of = np.array([number[tuple(xy)] for xy in mine.coords])  # (n,) mine -> gmsh's
    np.testing.assert_array_equal(meshed.coords[gmsh_of], mine.coords)
    np.testing.assert_allclose(mine.spacing, meshed.spacing[gmsh_of], rtol=1e-14, atol=0)
    # the same counter-clockwise cells, boundary segments (directed) and parts
    assert canonical(gmsh_of[mine.quads]) == canonical(meshed.quads)
    assert canonical(gmsh_of[mine.triangles]) == canonical(meshed.triangles)
    assert mine.part_names == meshed.part_names
    mine_segments = sorted(zip(map(tuple, gmsh_of[mine.segments]), mine.segment_part, strict=True))
    assert mine_segments == sorted(
        zip(map(tuple, meshed.segments), meshed.segment_part, strict=True)
    )
    # each segment's cell is the one that bounds it in gmsh's mesh
    meshed_cells = boundary_cells(meshed)
    by_segment = {
        tuple(s): set(c[c >= 0]) for s, c in zip(meshed.segments, meshed_cells.corners, strict=True)
    }
    for segment, corners in zip(gmsh_of[mine.segments], mine.segment_cells.corners, strict=True):
        assert set(gmsh_of[corners[corners >= 0]]) == by_segment[tuple(segment)]
    assert len(np.unique(mine.segment_cells.cell)) == len(np.unique(meshed_cells.cell))


@pytest.mark.parametrize("name", ["square-quad", "rectangle-tri", "square-coarse"])
@pytest.mark.parametrize("n_parts", [2, 3, 4, 5, 7, 8])
def test_parts_together_are_the_whole_grid(name, n_parts):
    grid = grid_of(name)
    blocks = grid_parts.grid_blocks(grid, n_parts)
    if name == "square-coarse" and n_parts == 8:  # 3 x 3 nodes: no 8 rectangles of 1-2
        assert blocks is None
        return
    assert blocks is not None
    whole = whole_grid(grid)
    n_x, n_y = grid.n_cells
    owners, n_cells, segment_owner = [], 0, None
    for rank in range(n_parts):
        cloud, partition = grid_parts.grid_part(grid, blocks, rank)
        lattice = cloud.original_index
        # every array held agrees with the whole grid's at the same lattice node
        np.testing.assert_array_equal(cloud.coords, whole.coords[lattice])
        np.testing.assert_array_equal(cloud.spacing, whole.spacing[lattice])
        np.testing.assert_array_equal(lattice[cloud.segments], whole.segments)
        assert np.all(np.diff(cloud.node_ids) > 0)
        # the own nodes: one run of global numbers
        start, stop = partition.node_ranges[rank], partition.node_ranges[rank + 1]
        own = cloud.run_of(int(start), int(stop))
        np.testing.assert_array_equal(cloud.node_ids[own], np.arange(start, stop))
        owners.append(lattice[own])
        n_cells += len(cloud.quads) + len(cloud.triangles)
        # nothing held beyond the part, its cells' far line and the two outer rings
        i0, i1, j0, j1 = blocks.rects[rank]
        assert cloud.n_nodes <= (i1 - i0 + 1) * (j1 - j0 + 1) + 4 * (n_x + n_y + 2)
        # each segment runs along an edge of its cell, counter-clockwise; a part's own
        # segments' cells are among its cells
        own_cells = {tuple(sorted(c)) for c in (*cloud.quads, *cloud.triangles)}
        for s, ((a, b), corners) in enumerate(
            zip(cloud.segments, cloud.segment_cells.corners, strict=True)
        ):
            corners = list(corners[corners >= 0])
            assert corners[(corners.index(a) + 1) % len(corners)] == b
            assert partition.segment_owner[s] != rank or tuple(sorted(corners)) in own_cells
        assert segment_owner is None or np.array_equal(segment_owner, partition.segment_owner)
        segment_owner = partition.segment_owner
    # every node owned once, every cell once; parts within one grid line of each other
    np.testing.assert_array_equal(np.sort(np.concatenate(owners)), np.arange(grid.n_nodes))
    assert n_cells == len(whole.quads) + len(whole.triangles)
    sizes = np.diff(blocks.node_ranges)
    assert sizes.max() - sizes.min() <= max(n_x, n_y) + 1


@settings(max_examples=60, deadline=None, database=None)
@given(
    n_x=st.integers(1, 12),
    n_y=st.integers(1, 12),
    aspect=st.floats(0.1, 10.0),
    n_parts=st.integers(1, 9),
    cells=st.sampled_from(["quad", "tri"]),
)
def test_any_grid_splits_into_rectangles_that_own_everything_once(n_x, n_y, aspect, n_parts, cells):
    """Random grids and part counts: either no split (too few nodes for p rectangles), or
    parts that own every node, cell and segment exactly once and hold their cells' corners."""
    grid = grid_parts.Grid(np.zeros(2), np.array([1.0, aspect]), (n_x, n_y), cells)
    blocks = grid_parts.grid_blocks(grid, n_parts)
    if blocks is None:
        assert n_parts > 1
        return
    whole = whole_grid(grid)
    owned, n_cells, n_owned_segments = [], 0, 0
    for rank in range(n_parts):
        cloud, partition = grid_parts.grid_part(grid, blocks, rank)
        np.testing.assert_array_equal(cloud.coords, whole.coords[cloud.original_index])
        start, stop = partition.node_ranges[rank], partition.node_ranges[rank + 1]
        assert stop > start  # no empty part
        owned.append(cloud.original_index[cloud.run_of(int(start), int(stop))])
        n_cells += len(cloud.quads) + len(cloud.triangles)
        n_owned_segments += int(np.count_nonzero(partition.segment_owner == rank))
        own_cells = {tuple(sorted(c)) for c in (*cloud.quads, *cloud.triangles)}
        corners = cloud.segment_cells.corners[partition.segment_owner == rank]
        assert all(tuple(sorted(c[c >= 0])) in own_cells for c in corners)
    np.testing.assert_array_equal(np.sort(np.concatenate(owned)), np.arange(grid.n_nodes))
    assert n_cells == len(whole.quads) + len(whole.triangles)
    assert n_owned_segments == len(whole.segments) == 2 * (n_x + n_y)


def test_only_unjittered_rectangles_are_grids():
    def scene(domain, jitter=0.0):
        return SimpleNamespace(
            domain=domain, discretization=SimpleNamespace(h=0.1, jitter=jitter, cells="quad")
        )

    assert grid_parts.scene_grid(scene({"shape": "square"})) is not None
    assert grid_parts.scene_grid(scene({"shape": "square"}, jitter=0.1)) is None
    assert grid_parts.scene_grid(scene({"shape": "z"})) is None


@pytest.fixture
def run_dir(comm, tmp_path):
    """One directory shared by all ranks (rank 0's tmp_path)."""
    return Path(comm.bcast(str(tmp_path), root=0))


@pytest.mark.parametrize(
    "overrides",
    [
        ["time.dt=0.1"],
        ["time.dt=0.1", 'discretization.cells="tri"', "discretization.degree=1"],
        ["time.dt=0.1", 'domain.shape="rectangle"', "domain.size=[1.5, 1.0]"],
    ],
    ids=["square", "square-tri", "rectangle"],
)
def test_a_run_on_the_parts_answers_as_one_meshed_on_rank_0(comm, run_dir, monkeypatch, overrides):
    scene = load_scene("square", ["discretization.h=0.125", "time.T=0.5", *overrides])
    assert_answers_as_on_root(comm, scene, run_dir, monkeypatch, "mesh_by_parts", 0.05)
