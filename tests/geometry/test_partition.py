"""Recursive coordinate bisection: balance, contiguity, renumbering, compactness."""

from dataclasses import replace

import numpy as np
import pytest
from mpi4py import MPI

from parefg.errors import InputError
from parefg.geometry.cloud import boundary_cells
from parefg.geometry.gmsh_mesh import build_node_cloud
from parefg.geometry.partition import interface_fraction, partition_cloud

COMM = MPI.COMM_WORLD
PART_COUNTS = [1, 2, 3, 4]


@pytest.fixture(scope="module")
def square():
    """(0,1)^2 at h = 1/32: 33 x 33 nodes, 1024 quads."""
    return build_node_cloud(COMM, {"shape": "square"}, 1 / 32)


@pytest.fixture(scope="module")
def zcloud():
    """The unstructured Z domain, quads and possibly a few triangles."""
    return build_node_cloud(COMM, {"shape": "z"}, 0.05)


@pytest.fixture(scope="module", params=["square", "z"])
def cloud(request, square, zcloud):
    return {"square": square, "z": zcloud}[request.param]


@pytest.mark.parametrize("n_parts", PART_COUNTS)
def test_node_counts_balanced_and_ranges_contiguous(cloud, n_parts):
    _, partition = partition_cloud(cloud, n_parts)
    ranges = partition.node_ranges
    assert partition.n_parts == n_parts and ranges.shape == (n_parts + 1,)
    assert ranges[0] == 0 and ranges[-1] == cloud.n_nodes
    counts = np.diff(ranges)
    assert counts.max() - counts.min() <= 1
    assert counts.sum() == cloud.n_nodes
    np.testing.assert_array_equal(partition.node_owner(), np.repeat(np.arange(n_parts), counts))


@pytest.mark.parametrize("n_parts", PART_COUNTS)
def test_renumbering_preserves_geometry(cloud, n_parts):
    new, partition = partition_cloud(cloud, n_parts)
    # original_index maps new nodes to old ones, and is a permutation.
    np.testing.assert_array_equal(np.sort(new.original_index), np.arange(cloud.n_nodes))
    np.testing.assert_array_equal(new.coords, cloud.coords[new.original_index])
    np.testing.assert_array_equal(new.spacing, cloud.spacing[new.original_index])
    # Same cells and segments in the same order, only renumbered.
    for field in ("quads", "triangles", "segments"):
        old_cells, new_cells = getattr(cloud, field), getattr(new, field)
        assert new_cells.shape == old_cells.shape
        np.testing.assert_array_equal(new.coords[new_cells], cloud.coords[old_cells])
    np.testing.assert_array_equal(new.segment_part, cloud.segment_part)
    assert new.part_names == cloud.part_names
    # Within a part, nodes keep their previous relative order.
    for start, stop in zip(partition.node_ranges[:-1], partition.node_ranges[1:], strict=True):
        assert np.all(np.diff(new.original_index[start:stop]) > 0)


def test_original_index_composes(zcloud):
    once, _ = partition_cloud(zcloud, 3)
    twice, _ = partition_cloud(once, 2)
    np.testing.assert_array_equal(twice.coords, zcloud.coords[twice.original_index])


def test_one_part_is_the_identity(cloud):
    new, partition = partition_cloud(cloud, 1)
    for field in ("coords", "spacing", "quads", "triangles", "segments", "original_index"):
        np.testing.assert_array_equal(getattr(new, field), getattr(cloud, field))
    np.testing.assert_array_equal(partition.node_ranges, [0, cloud.n_nodes])
    for owner in (partition.quad_owner, partition.triangle_owner, partition.segment_owner):
        assert np.all(owner == 0)


def test_two_parts_of_the_square_are_compact(square):
    new, partition = partition_cloud(square, 2)
    # One straight cut crosses ~33 of the 2112 edges.
    assert interface_fraction(new, partition) < 0.1
    # The measure itself detects a scattered partition: with the nodes randomly
    # renumbered, the owner ranges scatter over the square and cut about half the edges.
    random_order = np.random.default_rng(0).permutation(new.n_nodes)
    scattered = replace(new, quads=random_order[new.quads])
    assert interface_fraction(scattered, partition) > 0.4


@pytest.mark.parametrize("n_parts", [2, 3, 4])
def test_cells_balanced_and_owned_next_to_their_nodes(square, n_parts):
    new, partition = partition_cloud(square, n_parts)
    counts = np.bincount(partition.quad_owner, minlength=n_parts)
    assert np.all(np.abs(counts - counts.mean()) <= 0.2 * counts.mean())
    # Same cuts for cells and nodes: every cell's owner owns at least one of its corners.
    corner_owner = partition.node_owner()[new.quads]  # (n_quads, 4)
    assert np.all(np.any(corner_owner == partition.quad_owner[:, None], axis=1))
    segment_corner_owner = partition.node_owner()[new.segments]
    assert np.all(np.any(segment_corner_owner == partition.segment_owner[:, None], axis=1))
    assert interface_fraction(new, partition) < 0.1


def test_owners_cover_every_cell_of_an_unstructured_cloud(zcloud):
    new, partition = partition_cloud(zcloud, 3)
    for owner, cells in ((partition.quad_owner, new.quads),
                         (partition.triangle_owner, new.triangles),
                         (partition.segment_owner, new.segments)):  # fmt: skip
        assert owner.shape == (len(cells),) and owner.dtype == np.int64
        assert np.all((owner >= 0) & (owner < 3))
    assert set(partition.quad_owner) == {0, 1, 2}


def test_repeated_calls_agree(zcloud):
    first_cloud, first = partition_cloud(zcloud, 3)
    second_cloud, second = partition_cloud(zcloud, 3)
    np.testing.assert_array_equal(first_cloud.original_index, second_cloud.original_index)
    for field in ("node_ranges", "quad_owner", "triangle_owner", "segment_owner"):
        np.testing.assert_array_equal(getattr(first, field), getattr(second, field))


def test_every_rank_gets_the_same_partition(zcloud):
    new, partition = partition_cloud(zcloud, 2)
    signature = (new.original_index.tobytes(), partition.quad_owner.tobytes())
    assert all(other == signature for other in COMM.allgather(signature))


def test_more_parts_than_nodes_is_an_input_error(square):
    with pytest.raises(InputError, match="parts"):
        partition_cloud(square, square.n_nodes + 1)
    with pytest.raises(InputError, match="parts"):
        partition_cloud(square, 0)


@pytest.mark.parametrize("meshed_on", ["every rank", "rank 0"])
def test_partition_on_root_equals_partition_on_every_rank(zcloud, meshed_on):
    """Partition computed on rank 0 and Bcast as buffers == the per-rank computation, also
    when only rank 0 holds the cloud (the run's mesh_on_root: None elsewhere)."""
    from parefg.geometry.distribute import partition_on_root
    from parefg.geometry.gmsh_mesh import mesh_on_root

    comm = MPI.COMM_WORLD
    expected_cloud, expected = partition_cloud(zcloud, comm.size)
    given = zcloud
    if meshed_on == "rank 0":
        given = mesh_on_root(comm, {"shape": "z"}, 0.05)
        assert (given is None) == (comm.rank > 0)
    got_cloud, got = partition_on_root(comm, given)
    held = got_cloud.global_ids()  # this rank's nodes, its cells' and the boundary's
    for name in ("coords", "spacing", "original_index"):
        np.testing.assert_array_equal(getattr(got_cloud, name), getattr(expected_cloud, name)[held])
    for name in ("node_ranges", "segment_owner"):
        np.testing.assert_array_equal(getattr(got, name), getattr(expected, name))
    np.testing.assert_array_equal(held[got_cloud.segments], expected_cloud.segments)
    np.testing.assert_array_equal(got_cloud.segment_part, expected_cloud.segment_part)
    assert got_cloud.part_names == expected_cloud.part_names
    # each rank keeps its own cells, in the whole mesh's order, and every segment's cell
    assert got.quad_owner is None and got.triangle_owner is None
    np.testing.assert_array_equal(
        held[got_cloud.quads], expected_cloud.quads[expected.quad_owner == comm.rank]
    )
    np.testing.assert_array_equal(
        held[got_cloud.triangles], expected_cloud.triangles[expected.triangle_owner == comm.rank]
    )
    kept, whole = got_cloud.segment_cells, boundary_cells(expected_cloud)
    assert kept is not None
    np.testing.assert_array_equal(kept.cell, whole.cell)
    np.testing.assert_array_equal(
        np.where(kept.corners >= 0, held[kept.corners], -1), whole.corners
    )
    # no more than those nodes: on several ranks, fewer than the whole cloud
    start, stop = expected.node_ranges[comm.rank], expected.node_ranges[comm.rank + 1]
    boundary = np.union1d(expected_cloud.segments.ravel(), whole.corners[whole.corners >= 0])
    cells = [expected_cloud.quads[expected.quad_owner == comm.rank].ravel(),
             expected_cloud.triangles[expected.triangle_owner == comm.rank].ravel()]  # fmt: skip
    needed = np.union1d(np.arange(start, stop), np.union1d(np.concatenate(cells), boundary))
    np.testing.assert_array_equal(held, needed)
    assert (got_cloud.node_ids is None) == (comm.size == 1)


def test_broadcast_arrays_arrive_whole_in_chunks(monkeypatch):
    """Arrays longer than one Bcast's count go in chunks (MPI counts are 32-bit): with
    chunks of 7 elements, arrays of 0, 5, 7, 30 and 2 x 11 elements of three dtypes arrive
    bit for bit on every rank."""
    from parefg.geometry import distribute

    monkeypatch.setattr(distribute, "BCAST_CHUNK", 7)
    comm = MPI.COMM_WORLD
    sent = [
        np.zeros(0),
        np.arange(5, dtype=np.int64),
        np.linspace(0.0, 1.0, 7),
        np.arange(30, dtype=np.int8),
        np.sqrt(np.arange(22.0)).reshape(2, 11),
    ]
    got = distribute._bcast_arrays(comm, sent if comm.rank == 0 else None)
    for expected, array in zip(sent, got, strict=True):
        assert array.dtype == expected.dtype and array.shape == expected.shape
        np.testing.assert_array_equal(array, expected)
