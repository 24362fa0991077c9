"""The nodes a rank holds: its own, and the ghosts whose supports reach where it evaluates
MLS (issue 13: no rank holds arrays sized by the whole cloud).

A rank evaluates shape functions only in a box known before any MLS work
(:func:`evaluation_box`): its own nodes (output), its cells (their Gauss points lie in
the cells' corners' hull) and the boundary segments whose points it takes (its own, and
the other segments of each coarse-trace group it owns), with the cells next to them (the
trace-inverse estimate).  Every node whose support reaches that box is then held
(:func:`add_ghosts`): the owners select them, as the neighbour search will
(:func:`~parefg.discretization.neighbours.nodes_reaching_box`, the same numbers), and
send them.  So every neighbour list of a point in the box is complete; a point outside
it is a defect (:class:`~parefg.discretization.neighbours.RegionSearch` refuses it).
"""

from __future__ import annotations

import numpy as np

from parefg.discretization import coarse_trace
from parefg.discretization.neighbours import nodes_reaching_box
from parefg.geometry.cloud import BoundaryCells, NodeCloud
from parefg.geometry.partition import Partition
from parefg.parallel import alltoallv

# the box is widened by this fraction of its size (and of 1): a Gauss point computed
# from its cell's corners may round just outside their bounding box
BOX_MARGIN = 1e-9


def owned_positions(cloud: NodeCloud, node_ranges: np.ndarray, rank: int) -> slice:
    """Where this rank's own nodes (one contiguous run of global numbers) sit in the cloud
    it holds.  Not collective."""
    return cloud.run_of(int(node_ranges[rank]), int(node_ranges[rank + 1]))


def evaluated_segments(
    cloud: NodeCloud, segment_owner: np.ndarray, rank: int, grouping: dict[int, int]
) -> np.ndarray:
    """Every segment whose points this rank evaluates: its own, and each segment of a
    coarse-trace group whose lowest segment it owns (a group's points go to that rank:
    BoundaryOperators._boundary_quadrature).  ``grouping``: the segments per group of
    each grouped part (by part id).  Sorted ids.  Not collective."""
    mine = segment_owner == rank
    for part_id, per_group in grouping.items():
        on_part = np.flatnonzero(cloud.segment_part == part_id)
        if len(on_part) == 0:
            continue
        group, _ = coarse_trace.trace_groups(cloud.coords, cloud.segments, on_part, per_group)
        first = np.full(group.max() + 1, len(cloud.segments))
        np.minimum.at(first, group, on_part)
        mine[on_part] |= segment_owner[first[group]] == rank
    return np.flatnonzero(mine)


def evaluation_box(
    cloud: NodeCloud, partition: Partition, rank: int, grouping: dict[int, int]
) -> np.ndarray:
    """(2, 2) lower and upper corners of the box holding every point where this rank
    evaluates MLS (module docstring; ``grouping`` as for :func:`evaluated_segments`),
    widened by BOX_MARGIN.  Not collective."""
    segments = evaluated_segments(cloud, partition.segment_owner, rank, grouping)
    assert cloud.segment_cells is not None  # a distributed cloud
    corners = cloud.segment_cells.corners[segments]
    used = [
        cloud.quads.ravel(),
        cloud.triangles.ravel(),
        cloud.segments[segments].ravel(),
        corners[corners >= 0],
    ]
    points = [cloud.coords[owned_positions(cloud, partition.node_ranges, rank)]]
    points += [cloud.coords[nodes] for nodes in used]
    every = np.concatenate(points)
    lower, upper = every.min(axis=0), every.max(axis=0)
    margin = BOX_MARGIN * (np.max(upper - lower) + 1.0)
    return np.array([lower - margin, upper + margin])


def add_ghosts(
    comm, cloud: NodeCloud, node_ranges: np.ndarray, support: float, box: np.ndarray
) -> NodeCloud:
    """This rank's cloud with every node whose support (``support`` times its spacing)
    reaches ``box`` (this rank's :func:`evaluation_box`).  Collective.

    Each rank sends every other rank the nodes of its own whose supports reach that
    rank's box (one allgather of the boxes, one all-to-all of the nodes).  One rank:
    ``cloud`` itself.  The result has ``node_ids`` None when it holds every node.
    """
    if comm.size == 1:
        return cloud
    boxes = np.array(comm.allgather(np.asarray(box, dtype=float)))  # (p, 2, 2)
    owned = owned_positions(cloud, node_ranges, comm.rank)
    coords, spacing = cloud.coords[owned], cloud.spacing[owned]
    radius = support * spacing
    # the box this rank's supports cover: ranks whose boxes miss it get nothing
    reach = np.array(
        [(coords - radius[:, None]).min(axis=0), (coords + radius[:, None]).max(axis=0)]
    )
    sent = []
    for other, (lower, upper) in enumerate(boxes):
        misses = np.any(lower > reach[1]) or np.any(upper < reach[0])
        if other == comm.rank or misses or len(coords) == 0:
            sent.append(np.zeros(0, dtype=np.int64))
        else:
            sent.append(nodes_reaching_box(coords, radius, lower, upper))
    counts = np.array([len(s) for s in sent], dtype=np.int64)
    chosen = np.concatenate(sent)  # positions among this rank's own nodes
    ids = alltoallv(comm, (chosen + int(node_ranges[comm.rank])).astype(np.int64), counts)
    x = alltoallv(comm, np.ascontiguousarray(coords[chosen, 0]), counts)
    y = alltoallv(comm, np.ascontiguousarray(coords[chosen, 1]), counts)
    received_spacing = alltoallv(comm, spacing[chosen].astype(np.float64), counts)
    original = alltoallv(comm, cloud.original_index[owned][chosen].astype(np.int64), counts)
    held = cloud.global_ids()
    merged = np.union1d(held, ids)
    if len(merged) == len(held):  # every ghost was held already
        return cloud
    new_coords = np.empty((len(merged), 2))
    new_spacing, new_original = np.empty(len(merged)), np.empty(len(merged), dtype=np.int64)
    old_at, new_at = np.searchsorted(merged, held), np.searchsorted(merged, ids)
    new_coords[old_at], new_spacing[old_at] = cloud.coords, cloud.spacing
    new_original[old_at] = cloud.original_index
    new_coords[new_at, 0], new_coords[new_at, 1] = x, y
    new_spacing[new_at], new_original[new_at] = received_spacing, original
    complete = len(merged) == node_ranges[-1]
    node_ids = None if complete else merged

    def moved(nodes: np.ndarray) -> np.ndarray:  # held positions, before -> after (-1 kept)
        return np.where(nodes >= 0, old_at[nodes], -1)

    assert cloud.segment_cells is not None
    return NodeCloud(
        coords=new_coords,
        spacing=new_spacing,
        original_index=new_original,
        quads=moved(cloud.quads),
        triangles=moved(cloud.triangles),
        segments=moved(cloud.segments),
        segment_part=cloud.segment_part,
        part_names=cloud.part_names,
        segment_cells=BoundaryCells(
            cell=cloud.segment_cells.cell, corners=moved(cloud.segment_cells.corners)
        ),
        node_ids=node_ids,
    )
