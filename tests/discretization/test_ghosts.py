"""The nodes a rank holds (parefg.discretization.ghosts): its own, and every node whose
support reaches where it evaluates MLS, with nothing sized by the whole cloud.

Checked against the whole cloud, partitioned on every rank as rank 0 partitions it.
"""

import numpy as np
import pytest
from mpi4py import MPI

from parefg.discretization.ghosts import add_ghosts, evaluation_box
from parefg.discretization.neighbours import nodes_reaching_box
from parefg.discretization.operators import build_discretization
from parefg.geometry.distribute import partition_on_root
from parefg.geometry.gmsh_mesh import build_node_cloud
from parefg.geometry.partition import partition_cloud
from parefg.scene.loader import load_scene

COMM = MPI.COMM_WORLD


@pytest.mark.parametrize("shape, cells", [("square", "quad"), ("z", "tri")])
def test_a_rank_holds_every_node_that_reaches_its_box_and_their_data(shape, cells):
    """Held = own nodes, cells', boundary's and every node whose support reaches the
    rank's evaluation box, with their coordinates, spacings and original indices; the
    cells and segments name the same nodes as in the whole cloud."""
    support, h = 2.4, 1 / 32
    whole = build_node_cloud(COMM, {"shape": shape}, h, cells)
    expected, partition = partition_cloud(whole, COMM.size)
    cloud, _ = partition_on_root(COMM, whole)
    box = evaluation_box(cloud, partition, COMM.rank, {})
    before = cloud.global_ids()
    cloud = add_ghosts(COMM, cloud, partition.node_ranges, support, box)
    held = cloud.global_ids()
    reaching = nodes_reaching_box(expected.coords, support * expected.spacing, *box)
    assert np.all(np.isin(reaching, held)) and np.all(np.isin(before, held))
    np.testing.assert_array_equal(held, np.union1d(before, reaching))
    for name in ("coords", "spacing", "original_index"):
        np.testing.assert_array_equal(getattr(cloud, name), getattr(expected, name)[held])
    np.testing.assert_array_equal(held[cloud.segments], expected.segments)
    own = [expected.quads[partition.quad_owner == COMM.rank],
           expected.triangles[partition.triangle_owner == COMM.rank]]  # fmt: skip
    np.testing.assert_array_equal(held[cloud.quads], own[0])
    np.testing.assert_array_equal(held[cloud.triangles], own[1])
    if COMM.size == 1:
        assert cloud.node_ids is None
    elif COMM.size == 2:
        assert len(held) < 0.85 * expected.n_nodes


def test_the_run_holds_no_array_sized_by_the_whole_cloud():
    """On several ranks a discretization's node arrays (and its MLS's) hold only the
    rank's nodes; its owned nodes sit where owned_coords says."""
    scene = load_scene("square", ["discretization.h=0.03125"])
    disc = build_discretization(COMM, scene)
    start, stop = disc.node_range
    mls = disc.domain.gradients.mls
    assert len(mls.nodes) == len(disc.cloud.coords)
    held = disc.cloud.global_ids()
    np.testing.assert_array_equal(
        disc.owned_coords, disc.cloud.coords[np.searchsorted(held, np.arange(start, stop))]
    )
    if COMM.size > 1:
        assert len(disc.cloud.coords) < 0.8 * disc.n_nodes
        assert disc.cloud.node_ids is not None and len(disc.cloud.node_ids) == len(held)
