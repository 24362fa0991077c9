"""Partition a node cloud into compact, balanced subdomains, one per rank (SPEC 5).

Recursive coordinate bisection (RCB): a set of points meant for p parts is cut
perpendicular to its longer extent so that the two sides get node counts in the
ratio floor(p/2) : p - floor(p/2); the sides are cut again until every set is
one part.  Every part then holds floor(N/p) or ceil(N/p) nodes.  Nodes are
renumbered so that part r owns the contiguous block node_ranges[r]:node_ranges[r+1],
which makes the global DOF numbering of part r contiguous too (block size 2).

Cells and boundary segments go to the part of their centroid under the same
cuts, so cell ownership is as compact as node ownership.  Their order is kept:
cell and segment indices are global and the same on every rank.

Everything here is a pure, deterministic function of its input (no MPI): every
rank calls it with the same cloud and gets the same partition.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from parefg.errors import InputError
from parefg.geometry.cloud import NodeCloud, mesh_edges


@dataclass
class Partition:
    """Which rank owns which nodes, cells and boundary segments.

    Attributes
    ----------
    n_parts : int
        Number of parts (ranks).
    node_ranges : (n_parts + 1,) int64
        Part r owns the renumbered nodes node_ranges[r]:node_ranges[r + 1].
    quad_owner : (n_quads,) int64, or None
        Part owning each quadrilateral cell; None once distributed (each rank then holds
        its own cells, :func:`~parefg.geometry.distribute.partition_on_root`).
    triangle_owner : (n_triangles,) int64, or None
        Part owning each triangular cell; None once distributed.
    segment_owner : (n_segments,) int64
        Part owning each boundary segment.
    """

    n_parts: int
    node_ranges: np.ndarray
    quad_owner: np.ndarray | None
    triangle_owner: np.ndarray | None
    segment_owner: np.ndarray

    def node_owner(self) -> np.ndarray:
        """(n_nodes,) int64 part owning each (renumbered) node."""
        counts = np.diff(self.node_ranges)
        return np.repeat(np.arange(self.n_parts, dtype=np.int64), counts)


@dataclass
class Cut:
    """A bisection: points with coordinate ``axis`` below ``value`` go to ``below``.

    ``below`` and ``above`` are sub-cuts or, at the leaves, part numbers.
    """

    axis: int
    value: float
    below: Cut | int
    above: Cut | int


def partition_cloud(cloud: NodeCloud, n_parts: int) -> tuple[NodeCloud, Partition]:
    """Split ``cloud`` into ``n_parts`` compact parts and renumber its nodes part by part.

    Not collective (pure and deterministic).

    Returns
    -------
    cloud : NodeCloud
        The same geometry with nodes renumbered so that each part's nodes are
        contiguous (within a part, in increasing previous index);
        ``original_index`` is composed with the previous one, so
        ``new.coords == gmsh_coords[new.original_index]``.  Cells and segments
        keep their order; only their node indices change.
    partition : Partition
    """
    if not (isinstance(n_parts, int | np.integer) and 1 <= n_parts <= cloud.n_nodes):
        raise InputError(
            f"partition: cannot split {cloud.n_nodes} nodes into {n_parts!r} parts "
            "(need 1 <= parts <= nodes)"
        )
    # (n_nodes,) part of each node, filled leaf by leaf while cutting.
    node_part = np.empty(cloud.n_nodes, dtype=np.int64)
    cuts = _bisect(cloud.coords, np.arange(cloud.n_nodes), 0, n_parts, node_part)
    # New node order: by part, stable, so each part keeps increasing old order.
    old_of_new = np.argsort(node_part, kind="stable")
    new_of_old = np.empty_like(old_of_new)
    new_of_old[old_of_new] = np.arange(cloud.n_nodes)
    renumbered = replace(
        cloud,
        coords=cloud.coords[old_of_new],
        spacing=cloud.spacing[old_of_new],
        quads=new_of_old[cloud.quads],
        triangles=new_of_old[cloud.triangles],
        segments=new_of_old[cloud.segments],
        original_index=cloud.original_index[old_of_new],
        part_names=list(cloud.part_names),
    )
    node_counts = np.bincount(node_part, minlength=n_parts)
    partition = Partition(
        n_parts=int(n_parts),
        node_ranges=np.concatenate([[0], np.cumsum(node_counts)]).astype(np.int64),
        quad_owner=classify(cuts, _centroids(cloud.coords, cloud.quads)),
        triangle_owner=classify(cuts, _centroids(cloud.coords, cloud.triangles)),
        segment_owner=classify(cuts, _centroids(cloud.coords, cloud.segments)),
    )
    return renumbered, partition


def interface_fraction(cloud: NodeCloud, partition: Partition) -> float:
    """Fraction of mesh edges whose two nodes belong to different parts (0 = no interface)."""
    edges = mesh_edges(cloud.quads, cloud.triangles)  # (n_edges, 2)
    if len(edges) == 0:
        return 0.0
    owner = partition.node_owner()
    return float(np.mean(owner[edges[:, 0]] != owner[edges[:, 1]]))


def bisection_parts(points: np.ndarray, n_parts: int) -> np.ndarray:
    """(n_points,) int64 part of each point under the recursive coordinate bisection of
    :func:`partition_cloud` (the same cuts, ties and part sizes).  Not collective."""
    part = np.empty(len(points), dtype=np.int64)
    _bisect(points, np.arange(len(points)), 0, n_parts, part)
    return part


def _bisect(coords, members, first_part: int, n_parts: int, node_part) -> Cut | int:
    """Cut tree of the nodes ``members`` into parts first_part .. first_part + n_parts - 1.

    Writes each member's part into ``node_part``.  The lower side of a cut gets
    the first floor(n_parts / 2) parts and exactly their share of the nodes,
    floor(n/p) per part plus one for each of the first n mod p parts.
    """
    if n_parts == 1:
        node_part[members] = first_part
        return first_part
    points = coords[members]  # (n_members, d)
    axis = int(np.argmax(np.ptp(points, axis=0)))  # the longest extent
    # Sort along the axis; ties (grid lines) broken by the other coordinates, then index,
    # so a split grid line stays compact and the order is deterministic.
    others = [points[:, other] for other in range(points.shape[1]) if other != axis]
    order = np.lexsort((members, *others[::-1], points[:, axis]))
    n_below_parts = n_parts // 2
    n_members = len(members)
    n_below = n_below_parts * (n_members // n_parts) + min(n_below_parts, n_members % n_parts)
    along = points[order, axis]
    value = 0.5 * (along[n_below - 1] + along[n_below])
    below = _bisect(coords, members[order[:n_below]], first_part, n_below_parts, node_part)
    above = _bisect(
        coords, members[order[n_below:]], first_part + n_below_parts, n_parts - n_below_parts,
        node_part,
    )  # fmt: skip
    return Cut(axis, float(value), below, above)


def classify(cuts: Cut | int, points: np.ndarray) -> np.ndarray:
    """(n_points,) int64 part of each point under the cut tree (coordinate < value: below)."""
    part = np.empty(len(points), dtype=np.int64)
    pending = [(cuts, np.arange(len(points)))]  # (subtree, rows of points that reach it)
    while pending:
        subtree, rows = pending.pop()
        if isinstance(subtree, int):
            part[rows] = subtree
            continue
        is_below = points[rows, subtree.axis] < subtree.value
        pending += [(subtree.below, rows[is_below]), (subtree.above, rows[~is_below])]
    return part


def _centroids(coords: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """(n_cells, d) vertex averages of cells (or segments)."""
    return coords[cells].mean(axis=1) if len(cells) else np.empty((0, coords.shape[1]))
