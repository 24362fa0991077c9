"""The Z made part by part (parefg.geometry.patch_parts): the same cloud gmsh makes, and
parts that together are the whole of it, each holding only its piece and the boundary."""

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from parts_runs import assert_answers_as_on_root
from scipy.spatial import cKDTree

from parefg.geometry import patch_parts
from parefg.geometry.cloud import boundary_cells
from parefg.geometry.gmsh_mesh import mesh_domain
from parefg.scene.loader import load_scene

# (h, cells, m): 3 node rows across the strips at m = 1, 4 at m = 3; 948 nodes at 1/32
CASES = [(1 / 8, "quad", 1), (1 / 8, "tri", 3), (1 / 13, "tri", 1), (1 / 32, "quad", 2)]


def whole(h: float, cells: str, m: int):
    """The Z as one part: every node, numbered row by row patch after patch."""
    grid = patch_parts.lattice(h, cells, m, 1)
    assert grid is not None
    return patch_parts.patch_part(grid, 0)[0]


def rotated(rows) -> set[tuple]:
    """Cells (rows of keys) as tuples rotated to start at their least key: the same cell
    with any starting corner, counter-clockwise order kept."""
    out = set()
    for row in rows:
        row = [tuple(key) if np.ndim(key) else key for key in row]
        first = min(range(len(row)), key=row.__getitem__)
        out.add(tuple(row[first:] + row[:first]))
    return out


@pytest.mark.parametrize("h, cells, m", CASES)
def test_one_part_is_the_z_gmsh_makes(h, cells, m):
    meshed = mesh_domain({"shape": "z"}, h, cells, None, m)
    mine = whole(h, cells, m)
    assert mine.n_nodes == meshed.n_nodes and mine.node_ids is None
    # gmsh blends the corners with other round-off: each node matched to its nearest
    _, gmsh_of = cKDTree(meshed.coords).query(mine.coords)
    assert len(np.unique(gmsh_of)) == mine.n_nodes
    scale = np.abs(meshed.coords).max()
    np.testing.assert_allclose(mine.coords, meshed.coords[gmsh_of], rtol=0, atol=1e-10 * scale)
    np.testing.assert_allclose(mine.spacing, meshed.spacing[gmsh_of], rtol=1e-10)
    # the same cells (counter-clockwise; triangles from the same corner, which places
    # their quadrature points), segments (with their parts) and segment cells
    assert rotated(gmsh_of[mine.quads]) == rotated(meshed.quads)
    assert {tuple(t) for t in gmsh_of[mine.triangles]} == {tuple(t) for t in meshed.triangles}
    assert mine.part_names == meshed.part_names
    segments = {(*gmsh_of[s], p) for s, p in zip(mine.segments, mine.segment_part, strict=True)}
    assert segments == {(*s, p) for s, p in zip(meshed.segments, meshed.segment_part, strict=True)}
    reference = boundary_cells(meshed)

    def cell_of_segment(segments, corners, number=None) -> set:
        number = np.arange(len(meshed.coords)) if number is None else number
        triangle = corners[:, 3] < 0  # a triangle's corners as listed, a quad's rotated
        return {
            (number[s[0]], *(rotated([number[c]]) if q else [tuple(number[c[:3]])]))
            for s, c, q in zip(segments, corners, ~triangle, strict=True)
        }

    assert cell_of_segment(mine.segments, mine.segment_cells.corners, gmsh_of) == (
        cell_of_segment(meshed.segments, reference.corners)
    )
    # a segment's cell number names its cell: equal numbers, equal cells, and back
    named = {
        (number, *rotated([c[c >= 0]]))
        for number, c in zip(mine.segment_cells.cell, mine.segment_cells.corners, strict=True)
    }
    assert len(named) == len({n for n, _ in named}) == len({c for _, c in named})


def test_whole_parts_per_patch_stay_balanced():
    """From PATCH_PARTS_FROM parts on, the largest part is at most 9 % (and one node)
    above the mean (whole parts per patch): every p up to 400 at 7e4 nodes, some up to 1000
    at 8e5 (the worst measured: 8.6 % at p = 53)."""
    cases = [(1 / 300, p) for p in range(patch_parts.PATCH_PARTS_FROM, 401)]
    cases += [(1 / 1000, p) for p in (47, 53, 69, 333, 1000)]
    for h, n_parts in cases:
        grid = patch_parts.lattice(h, "quad", 1, n_parts)
        assert grid is not None and grid.tiles is not None
        sizes = np.diff(grid.node_ranges)
        assert sizes.min() > 0 and sizes.max() <= 1.09 * sizes.mean() + 1, n_parts


@pytest.mark.parametrize("h, cells, m", CASES[:3])
@pytest.mark.parametrize("n_parts", [2, 3, 4, 5, 8, 13, 20, 40, 53])
def test_parts_together_are_the_whole_z(h, cells, m, n_parts):
    grid = patch_parts.lattice(h, cells, m, n_parts)
    assert grid is not None
    one = whole(h, cells, m)
    every = [tuple(c) for c in (*one.quads, *one.triangles)]
    owned, held_cells, segment_owner = [], [], None
    for rank in range(n_parts):
        cloud, partition = patch_parts.patch_part(grid, rank)
        row = cloud.original_index  # the whole Z's number of each node held
        # every array held agrees with the whole Z's at the same node, to the bit
        np.testing.assert_array_equal(cloud.coords, one.coords[row])
        np.testing.assert_array_equal(cloud.spacing, one.spacing[row])
        np.testing.assert_array_equal(row[cloud.segments], one.segments)
        np.testing.assert_array_equal(cloud.segment_part, one.segment_part)
        np.testing.assert_array_equal(cloud.segment_cells.cell, one.segment_cells.cell)
        corners = cloud.segment_cells.corners
        np.testing.assert_array_equal(
            np.where(corners >= 0, row[corners], -1), one.segment_cells.corners
        )
        assert np.all(np.diff(cloud.node_ids) > 0)
        start, stop = partition.node_ranges[rank], partition.node_ranges[rank + 1]
        assert stop > start
        own = cloud.run_of(int(start), int(stop))
        np.testing.assert_array_equal(cloud.node_ids[own], np.arange(start, stop))
        owned.append(row[own])
        mine = {tuple(row[c]) for c in (*cloud.quads, *cloud.triangles)}
        held_cells += [tuple(row[c]) for c in (*cloud.quads, *cloud.triangles)]
        # the part's own segments' cells are among its cells
        for s in np.flatnonzero(partition.segment_owner == rank):
            c = corners[s][corners[s] >= 0]
            assert tuple(row[c]) in mine or any(
                tuple(np.roll(row[c], k)) in mine for k in range(len(c))
            )
        # held: the own nodes, a line of cells' corners around them and the boundary
        boundary = [one.segments.ravel(), *(c[c >= 0] for c in one.segment_cells.corners)]
        n_boundary = len(np.unique(np.concatenate(boundary)))
        assert cloud.n_nodes <= (stop - start) + n_boundary + 4 * np.sqrt(stop - start) + 8
        assert segment_owner is None or np.array_equal(segment_owner, partition.segment_owner)
        segment_owner = partition.segment_owner
    # every node owned once, every cell made once
    np.testing.assert_array_equal(np.sort(np.concatenate(owned)), np.arange(one.n_nodes))
    assert sorted(held_cells) == sorted(every)
    # the work of each part (a node weighs its patch's nodes per area): below
    # PATCH_PARTS_FROM runs of the numbering equal to about a node's weight (or equal runs
    # where rounding would empty one); from there on whole parts per patch, by node count
    # (a coarse Z: parts of a few nodes, rounding weighs more)
    sizes, work = np.diff(grid.node_ranges), _work(grid)
    if n_parts < patch_parts.PATCH_PARTS_FROM:
        weights = patch_parts.patch_weights(grid.corners, grid.n_cells)
        assert work.max() - work.min() <= 2 * weights.max() or sizes.max() - sizes.min() <= 1
    else:
        assert sizes.max() <= 1.5 * sizes.mean()


def _work(grid) -> np.ndarray:
    """(n_parts,) the summed weights of each part's nodes."""
    weights = patch_parts.patch_weights(grid.corners, grid.n_cells)
    work = []
    for start, stop in zip(grid.node_ranges[:-1], grid.node_ranges[1:], strict=True):
        patch, _, _ = grid.nodes_numbered(int(start), int(stop))
        work.append(weights[patch].sum())
    return np.array(work)


def test_only_unjittered_z_is_made_by_patches():
    def scene(shape, jitter=0.0):
        discretization = SimpleNamespace(h=0.1, jitter=jitter, cells="quad", degree=2)
        return SimpleNamespace(domain={"shape": shape}, discretization=discretization)

    comm = SimpleNamespace(size=2, rank=1)
    assert patch_parts.mesh_by_patches(comm, scene("z")) is not None
    assert patch_parts.mesh_by_patches(comm, scene("z", jitter=0.1)) is None
    assert patch_parts.mesh_by_patches(comm, scene("square")) is None


@pytest.fixture
def run_dir(comm, tmp_path):
    """One directory shared by all ranks (rank 0's tmp_path)."""
    return Path(comm.bcast(str(tmp_path), root=0))


@pytest.mark.parametrize(
    "overrides",
    [[], ['discretization.cells="tri"', "discretization.degree=1"]],
    ids=["z", "z-tri"],
)
def test_a_run_on_the_patches_answers_as_one_meshed_on_rank_0(
    comm, run_dir, monkeypatch, overrides
):
    scene = load_scene("z", ["discretization.h=0.125", "time.T=0.5", "time.dt=0.1", *overrides])
    assert_answers_as_on_root(comm, scene, run_dir, monkeypatch, "mesh_by_patches", 0.1)
