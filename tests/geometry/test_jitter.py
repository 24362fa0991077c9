"""Jittered node clouds (``[discretization] jitter`` and ``seed``).

Expected values come from the definition: boundary nodes stay, interior offsets are at
most jitter * h per direction and uniform (mean |offset| = jitter h / 2), the domain's
area is that of the unit square, cells stay unfolded (every corner cross product > 0).
"""

import hashlib

import numpy as np
import pytest
from mpi4py import MPI

from parefg.errors import InputError
from parefg.geometry.cloud import NodeCloud, node_spacing
from parefg.geometry.gmsh_mesh import build_node_cloud
from parefg.geometry.jitter import jitter_cloud
from parefg.scene.loader import load_scene

COMM = MPI.COMM_WORLD
SQUARE = {"shape": "square"}


def corner_cross(coords, cells):
    """(n_cells, n_corners) cross products of the two edges leaving each corner."""
    corners = coords[cells]
    forward = np.roll(corners, -1, axis=1) - corners
    backward = np.roll(corners, 1, axis=1) - corners
    return forward[..., 0] * backward[..., 1] - forward[..., 1] * backward[..., 0]


def boundary_mask(cloud):
    mask = np.zeros(cloud.n_nodes, dtype=bool)
    mask[cloud.segments.ravel()] = True
    return mask


@pytest.fixture(scope="module")
def grids():
    """{h: (plain cloud, cloud jittered by 20 %)} on the unit square."""
    return {
        h: (build_node_cloud(COMM, SQUARE, h), build_node_cloud(COMM, SQUARE, h, jitter=0.2))
        for h in (1 / 8, 1 / 16)
    }


def test_jitter_is_deterministic_and_seeded():
    first = build_node_cloud(COMM, SQUARE, 1 / 8, jitter=0.3, seed=7)
    again = build_node_cloud(COMM, SQUARE, 1 / 8, jitter=0.3, seed=7)
    other = build_node_cloud(COMM, SQUARE, 1 / 8, jitter=0.3, seed=8)
    np.testing.assert_array_equal(first.coords, again.coords)
    np.testing.assert_array_equal(first.spacing, again.spacing)
    assert np.abs(first.coords - other.coords).max() > 0.01


def test_every_rank_gets_the_same_jittered_cloud():
    cloud = build_node_cloud(COMM, SQUARE, 1 / 16, jitter=0.4)
    digest = hashlib.sha256(cloud.coords.tobytes() + cloud.spacing.tobytes()).hexdigest()
    assert len(set(COMM.allgather(digest))) == 1


@pytest.mark.parametrize("h", [1 / 8, 1 / 16])
def test_boundary_fixed_interior_moved_by_at_most_jitter_h(grids, h):
    plain, jittered = grids[h]
    offset = jittered.coords - plain.coords  # (n_nodes, 2)
    on_boundary = boundary_mask(plain)
    assert np.all(offset[on_boundary] == 0)
    interior = np.abs(offset[~on_boundary])
    assert np.all(interior.max(axis=1) > 0)
    # h-dependent magnitude: bounded by 0.2 h, uniform, so max near 0.2 h and mean near 0.1 h.
    assert interior.max() <= 0.2 * h * (1 + 1e-12)
    assert interior.max() >= 0.18 * h
    assert 0.085 * h <= interior.mean() <= 0.115 * h
    # Connectivity and parts are those of the plain grid.
    np.testing.assert_array_equal(jittered.quads, plain.quads)
    np.testing.assert_array_equal(jittered.segments, plain.segments)


def test_area_preserved_cells_unfolded_spacing_recomputed():
    plain = build_node_cloud(COMM, SQUARE, 1 / 16)
    cloud = build_node_cloud(COMM, SQUARE, 1 / 16, jitter=0.45, seed=3)
    assert np.all(corner_cross(cloud.coords, cloud.quads) > 0)
    corners = cloud.coords[cloud.quads]
    x, y = corners[..., 0], corners[..., 1]
    areas = 0.5 * np.sum(x * np.roll(y, -1, axis=1) - np.roll(x, -1, axis=1) * y, axis=1)
    assert abs(areas.sum() - 1.0) < 1e-13
    # Spacing is the mean incident edge length of the moved nodes, not the grid's h.
    edges = {tuple(sorted(e)) for q in cloud.quads for e in zip(q, np.roll(q, -1), strict=True)}
    node = int(np.flatnonzero(~boundary_mask(cloud))[0])
    incident = [
        np.linalg.norm(cloud.coords[a] - cloud.coords[b]) for a, b in edges if node in (a, b)
    ]
    assert cloud.spacing[node] == pytest.approx(np.mean(incident), rel=1e-12)
    assert np.abs(cloud.spacing - plain.spacing).max() > 0.01 / 16


def test_folded_cloud_is_an_input_error_naming_the_jitter():
    """A 3 x 3 grid whose centre node sits at (0.1, 0.1): the cell at the origin is a dart."""
    grid = np.array([[x, y] for y in (0.0, 1.0, 2.0) for x in (0.0, 1.0, 2.0)])
    grid[4] = (0.1, 0.1)
    quads = np.array([[0, 1, 4, 3], [1, 2, 5, 4], [3, 4, 7, 6], [4, 5, 8, 7]])
    ring = [0, 1, 2, 5, 8, 7, 6, 3]
    segments = np.array(list(zip(ring, ring[1:] + ring[:1], strict=True)))
    empty_triangles = np.empty((0, 3), dtype=np.int64)
    cloud = NodeCloud(
        coords=grid,
        spacing=node_spacing(grid, quads, empty_triangles),
        quads=quads,
        triangles=empty_triangles,
        segments=segments,
        segment_part=np.zeros(8, dtype=np.int64),
        part_names=["all"],
        original_index=np.arange(9),
    )
    with pytest.raises(InputError, match=r"discretization\.jitter = 0\.1 .*folds"):
        jitter_cloud(cloud, 0.1)


def test_scene_jitter_key():
    scene = load_scene("square", ["discretization.jitter=0.3", "discretization.seed=5"])
    assert (scene.discretization.jitter, scene.discretization.seed) == (0.3, 5)
    assert scene.domain == {"shape": "square"}
    plain = load_scene("square")
    assert (plain.discretization.jitter, plain.discretization.seed, plain.domain) == (
        0.0,
        0,
        {"shape": "square"},
    )
    assert "jitter" not in plain.params["discretization"]
    for bad in ("0.5", "-0.1", '"a"'):
        with pytest.raises(InputError, match=r"discretization\.jitter"):
            load_scene("square", [f"discretization.jitter={bad}"])
    with pytest.raises(InputError, match=r"discretization\.seed"):
        load_scene("square", ["discretization.seed=1.5"])
