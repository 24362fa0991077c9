"""The Z made part by part: each rank makes its own piece of the five transfinite patches
(SPEC 5; issue 13: no rank meshes, partitions or holds the whole cloud).

gmsh meshes the Z (:func:`~parefg.geometry.shapes._build_z`) as five conforming
transfinite patches (:data:`~parefg.geometry.shapes.Z_PATCHES`), each a lattice of
n x m cells between its four corners: node (i, j) of a patch lies at the bilinear blend
of the corners at (i / n, j / m); the cells are the lattice's quadrilaterals, or each
split along one diagonal (:data:`RISING_DIAGONAL`; the short one of the parallelogram's);
the patches share the nodes of their common sides.  So nodes, cells, spacing and
boundary are functions of (patch, i, j) alone: every rank computes the same numbering
and partition from O(p) numbers, without communication, then builds its own part
(:func:`patch_part`) in the layout :func:`~parefg.geometry.distribute.partition_on_root`
sends a rank: its own nodes, its cells' corners and the boundary's nodes, every segment
and the cell next to it.

Numbering.  A node shared by several patches belongs to the first of them in
:data:`NUMBERING`; each patch then numbers an index rectangle, its lattice without the
sides glued to an earlier patch (:data:`GLUED`).  The nodes are numbered band by band
(:data:`BANDS`: the bottom strip, the parallelogram, the top strip), row by row, each
row left to right: ``original_index``, the same for any rank count (result.h5's node
order).  Below :data:`PATCH_PARTS_FROM` parts the partition cuts that numbering into
runs of equal work, horizontal bands (a node weighs its patch's nodes per area,
:func:`patch_weights`: the parallelogram's are denser); from there on each patch gets
whole parts in proportion to its nodes and numbers them in serpentine order of square
tiles (row by row within a tile), so the run a rank owns is a compact piece of one patch.
A cell belongs to the part of its lower-left corner, or, where an earlier patch numbers
that node, of the nearest corner its own patch numbers.

The coordinates are gmsh's up to round-off (~1e-12: gmsh blends the same corners); the
cells are gmsh's (each triangle from the same corner), cells and segments in another
order.  A jittered cloud is meshed on rank 0.  Nothing here is collective.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from parefg.geometry.cells import CellType
from parefg.geometry.cloud import BoundaryCells, NodeCloud
from parefg.geometry.partition import Partition
from parefg.geometry.shapes import (
    Z_BOUNDARY,
    Z_EDGE_NAMES,
    Z_EDGE_OF_CURVE,
    Z_PATCH_POINTS,
    Z_PATCHES,
    transfinite_cells,
)

# The order in which the patches number their nodes: bottom-left, bottom-right, the
# parallelogram, top-right, top-left (each shares a side with the one before).
NUMBERING = (0, 1, 2, 4, 3)
# The numbering's bands, bottom to top: the bottom strip (two patches side by side, their
# rows level), the parallelogram, the top strip; each band row by row, a row left to right.
BANDS = ((0, 1), (2,), (3, 4))
# The glued sides, (patch, side) -> (a patch earlier in NUMBERING, side): the nodes of the
# first side are those of the second, at the same index along it.  Side 0 is j = 0, 1 is
# i = n, 2 is j = m, 3 is i = 0 (i, j: a patch's own lattice indices); the two sides of a
# pair run the same way.
GLUED = {(1, 3): (0, 1), (2, 0): (0, 2), (4, 0): (2, 2), (3, 1): (4, 3)}
# Whether the triangles of each patch split its cells along the diagonal from the lower-left
# to the upper-right corner (True) or from the lower-right to the upper-left (False), in
# the patch's own indices: gmsh's choice for the arrangements of _build_z (the top-right
# patch's first curve is the parallelogram's, reversed, so its "Left" is the other one).
RISING_DIAGONAL = (False, False, False, False, True)
# Where gmsh starts each of a cell's two triangles (first the one with the bottom side):
# at the corner listed first below (0), or at the next (1).  The order matters: a
# triangle's quadrature points depend on it.
TRIANGLE_START = ((0, 0), (0, 0), (1, 0), (0, 0), (1, 1))
# The lattice edges at a node, (di, dj): along the axes, then the falling diagonal's two,
# then the rising one's (a patch's triangles have one of the diagonals, RISING_DIAGONAL).
EDGE_OFFSETS = ((1, 0), (-1, 0), (0, 1), (0, -1), (1, -1), (-1, 1), (1, 1), (-1, -1))
# From this many parts on, no part crosses a patch boundary: each patch gets whole parts
# (:func:`_shares`), the largest part at most 9 % (and one node) above the mean (every p
# from 40 to 1000 at 8e3 to 8e5 nodes; 23 % at p = 20, hence not earlier); fewer parts
# are runs of the numbering: horizontal bands, which grow thin as parts grow many.
PATCH_PARTS_FROM = 8 * len(Z_PATCHES)


@dataclass(frozen=True)
class Lattice:
    """The Z's patches at one h, and a partition of their nodes (module docstring).

    Arrays are indexed by patch.  ``numbered[p]`` = (i0, i1, j0, j1): patch p numbers the
    nodes i0 <= i < i1, j0 <= j < j1, band after band (:data:`BANDS`) from
    ``band_offsets``.  The partition's order is that numbering where ``tiles`` is None,
    else patch after patch (:data:`NUMBERING`) from ``patch_offsets``, each in serpentine
    order of ``tiles[p]``-wide square tiles (0: row by row).
    """

    corners: np.ndarray  # (n_patches, 4, 2), counter-clockwise, corner k starts side k
    n_cells: np.ndarray  # (n_patches, 2) int64: n (sides 0, 2) and m (sides 1, 3)
    numbered: np.ndarray  # (n_patches, 4) int64
    band_offsets: np.ndarray  # (n_bands,) int64
    patch_offsets: np.ndarray  # (n_patches,) int64
    cell_offsets: np.ndarray  # (n_patches,) int64: first number of each patch's cells
    tiles: np.ndarray | None  # (n_patches,) int64
    node_ranges: np.ndarray  # (n_parts + 1,) int64
    cells: str

    @property
    def n_nodes(self) -> int:
        return int(self.node_ranges[-1])

    # -- nodes ---------------------------------------------------------------------------
    def coords(self, patch: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        """(n, 2) positions of the nodes (patch, i, j): the bilinear blend of the corners."""
        s = (i / self.n_cells[patch, 0])[:, None]
        t = (j / self.n_cells[patch, 1])[:, None]
        c = self.corners[patch]  # (n, 4, 2)
        return (
            (1 - s) * (1 - t) * c[:, 0]
            + s * (1 - t) * c[:, 1]
            + s * t * c[:, 2]
            + ((1 - s) * t * c[:, 3])
        )

    def canonical(self, patch, i, j) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(patch, i, j) of the patch that numbers each node (:data:`GLUED`), as copies."""
        patch, i, j = (np.array(a, dtype=np.int64) for a in (patch, i, j))
        for _ in range(len(GLUED)):  # each gluing leads to an earlier patch
            moved = False
            for (source, side), (target, target_side) in GLUED.items():
                on = (patch == source) & _on_side(self.n_cells[source], i, j, side)
                if on.any():
                    along = _along(side, i[on], j[on])
                    i[on], j[on] = _at(self.n_cells[target], target_side, along)
                    patch[on] = target
                    moved = True
            if not moved:
                break
        return patch, i, j

    def row_number(self, patch, i, j) -> np.ndarray:
        """(n,) the number of the nodes (patch, i, j) its patch numbers: band after band,
        row by row, each row left to right (``original_index``)."""
        number = np.empty(len(patch), dtype=np.int64)
        i0, i1, j0, j1 = self.numbered.T
        for band, members in enumerate(BANDS):
            for k, q in enumerate(members):
                mine = patch == q
                row = j[mine]
                # the band's rows below, and this row's nodes in the patches to the left
                below = sum(
                    (i1[m] - i0[m]) * np.clip(row - j0[m], 0, j1[m] - j0[m]) for m in members
                )
                left = sum((i1[m] - i0[m]) * ((row >= j0[m]) & (row < j1[m])) for m in members[:k])
                number[mine] = self.band_offsets[band] + below + left + (i[mine] - i0[q])
        return number

    def global_ids(self, patch, i, j) -> np.ndarray:
        """(n,) partition numbers of the nodes (patch, i, j) its patch numbers."""
        if self.tiles is None:
            return self.row_number(patch, i, j)
        i0, i1, j0, j1 = self.numbered[patch].T
        tiled = _tile_index(i - i0, j - j0, i1 - i0, j1 - j0, self.tiles[patch])
        return self.patch_offsets[patch] + tiled

    def nodes_numbered(self, start: int, stop: int):
        """(patch, i, j) of the nodes numbered start .. stop - 1 in the partition's order,
        in that order."""
        found = [(np.empty(0, dtype=np.int64),) * 3]
        if self.tiles is None:
            for band, members in enumerate(BANDS):
                found.append(self._band_nodes(band, members, start, stop))
        else:
            for p in NUMBERING:
                count = int(_count(self.numbered[p]))
                offset = int(self.patch_offsets[p])
                first, last = max(start, offset), min(stop, offset + count)
                if first >= last:
                    continue
                i0, i1, j0, j1 = (int(v) for v in self.numbered[p])
                local = np.arange(first - offset, last - offset, dtype=np.int64)
                u, v = _tile_position(local, i1 - i0, j1 - j0, int(self.tiles[p]))
                found.append((np.full(len(local), p, dtype=np.int64), u + i0, v + j0))
        return tuple(np.concatenate(a) for a in zip(*found, strict=True))

    def _band_nodes(self, band: int, members, start: int, stop: int):
        """(patch, i, j) of the band's nodes numbered start .. stop - 1."""
        i0, i1, j0, j1 = self.numbered.T
        rows = np.arange(max(j1[m] for m in members), dtype=np.int64)
        widths = [(i1[m] - i0[m]) * ((rows >= j0[m]) & (rows < j1[m])) for m in members]
        row_starts = self.band_offsets[band] + np.concatenate([[0], np.cumsum(sum(widths))])
        first, last = max(start, int(row_starts[0])), min(stop, int(row_starts[-1]))
        number = np.arange(first, max(first, last), dtype=np.int64)
        row = np.searchsorted(row_starts, number, side="right") - 1
        along = number - row_starts[row]  # position in the row, left to right
        patch = np.full(len(number), -1, dtype=np.int64)
        i = np.zeros(len(number), dtype=np.int64)
        for m, width in zip(members, widths, strict=True):
            here = (patch < 0) & (along < width[row])
            patch[here], i[here] = m, i0[m] + along[here]
            along = along - np.where(patch < 0, width[row], 0)
        return patch, i, row

    def part_of(self, ids: np.ndarray) -> np.ndarray:
        return np.searchsorted(self.node_ranges, ids, side="right") - 1

    # -- cells ---------------------------------------------------------------------------
    def anchor(self, patch, ci, cj) -> tuple[np.ndarray, np.ndarray]:
        """(i, j) of the node whose part owns cell (ci, cj) of ``patch``: its lower-left
        corner moved into the patch's numbered rectangle (a corner of the cell)."""
        i0, _, j0, _ = self.numbered[patch].T
        return np.maximum(ci, i0), np.maximum(cj, j0)

    def cells_at(self, patch, i, j):
        """(patch, ci, cj) of the cells anchored at the nodes (patch, i, j)."""
        i0, _, j0, _ = self.numbered[patch].T
        n, m = self.n_cells[patch].T
        found = []
        for di in (0, -1):
            for dj in (0, -1):
                ci, cj = i + di, j + dj
                # the cell itself, or the one the numbered rectangle's first line cuts off
                ok = (ci >= 0) & (ci < n) & (cj >= 0) & (cj < m)
                ok &= ((di == 0) | (i == i0)) & ((dj == 0) | (j == j0))
                found.append((patch[ok], ci[ok], cj[ok]))
        return tuple(np.concatenate(parts) for parts in zip(*found, strict=True))

    def cell_number(self, patch, ci, cj) -> np.ndarray:
        """(n,) number of the quadrilateral cells in the whole mesh."""
        return self.cell_offsets[patch] + cj * self.n_cells[patch, 0] + ci


def lattice(h: float, cells: str, min_cells: int, n_parts: int) -> Lattice | None:
    """The Z's lattice at h and its partition into ``n_parts``; None where some part
    would be empty."""
    corners = np.array(Z_PATCH_POINTS, dtype=float)[np.array(Z_PATCHES)]  # (5, 4, 2)
    n_cells = np.array(
        [
            [
                transfinite_cells(math.dist(*c[0:2]), h, min_cells),
                transfinite_cells(math.dist(*c[1:3]), h, min_cells),
            ]
            for c in corners
        ],
        dtype=np.int64,
    )
    numbered = np.column_stack([np.zeros(5), n_cells[:, 0] + 1, np.zeros(5), n_cells[:, 1] + 1])
    numbered = numbered.astype(np.int64)
    for patch, side in GLUED:  # a glued side is numbered by the earlier patch
        column = {0: 2, 1: 1, 2: 3, 3: 0}[side]
        numbered[patch, column] += 1 if side in (0, 3) else -1
    counts = _count(numbered)
    order = np.array(NUMBERING)
    band_counts = np.array([counts[list(members)].sum() for members in BANDS])
    band_offsets = np.concatenate([[0], np.cumsum(band_counts)[:-1]]).astype(np.int64)
    patch_offsets = _offsets(counts, NUMBERING)
    cell_offsets = _offsets(n_cells[:, 0] * n_cells[:, 1], NUMBERING)
    n_nodes = int(counts.sum())
    if n_parts > n_nodes:
        return None
    tiles = None
    if n_parts < PATCH_PARTS_FROM:
        weights = patch_weights(corners, n_cells)
        band_weights = np.array(
            [np.dot(counts[list(m)], weights[list(m)]) / counts[list(m)].sum() for m in BANDS]
        )
        node_ranges = _weighted_runs(band_counts, band_weights, n_parts)
    else:
        # by node counts (weighting them by work left a 10.7 % part at p = 44 against 8.6 %
        # unweighted); each share <= its count: n_parts <= n_nodes
        shares = _shares(counts[order], n_parts)
        ranges = [
            patch_offsets[p] + _even(int(counts[p]), int(k))[:-1]
            for p, k in zip(order, shares, strict=True)
        ]
        node_ranges = np.concatenate([*ranges, [n_nodes]]).astype(np.int64)
        tiles = np.zeros(5, dtype=np.int64)
        for p, k in zip(order, shares, strict=True):
            if k > 1:  # square tiles of about one part each
                tiles[p] = max(1, round(math.sqrt(counts[p] / k)))
    return Lattice(
        corners, n_cells, numbered, band_offsets, patch_offsets, cell_offsets, tiles,
        node_ranges, cells,
    )  # fmt: skip


def patched(scene) -> bool:
    """Whether runs make ``scene``'s domain here, part by part (the unjittered Z)."""
    return scene.domain["shape"] == "z" and scene.discretization.jitter == 0


def mesh_by_patches(comm, scene) -> tuple[NodeCloud, Partition] | None:
    """This rank's part of the Z and the partition (as
    :func:`~parefg.geometry.distribute.partition_on_root` returns them); None, on every
    rank alike, where the domain is not the Z, is jittered, or has fewer nodes than
    parts.  Not collective: every rank decides the same."""
    if not patched(scene):
        return None
    discretization = scene.discretization
    grid = lattice(discretization.h, discretization.cells, discretization.degree, comm.size)
    return None if grid is None else patch_part(grid, comm.rank)


def patch_part(grid: Lattice, rank: int) -> tuple[NodeCloud, Partition]:
    """Part ``rank`` of the Z's cloud and the partition (module docstring).

    The cloud holds the part's own nodes, its cells' corners and the boundary's nodes
    (the segments' ends and their cells' corners), ascending by global number; its cells
    are the part's; the segments, their parts and cells are the whole boundary's.
    ``node_ids`` is None for one part (it holds every node).
    """
    n_parts = len(grid.node_ranges) - 1
    start, stop = int(grid.node_ranges[rank]), int(grid.node_ranges[rank + 1])
    own = grid.nodes_numbered(start, stop)
    cell_patch, ci, cj = grid.cells_at(*own)
    corners = _corners(cell_patch, ci, cj)  # 4 x (patch, i, j), counter-clockwise
    boundary = _boundary(grid)
    seg_patch, (seg_ci, seg_cj), which = boundary["patch"], boundary["cell"], boundary["which"]
    seg_corners = _corners(seg_patch, seg_ci, seg_cj)
    # every node held, canonical: own, the cells' corners, the segments' ends and cells
    pieces = [own, *corners, boundary["start"], boundary["end"], *seg_corners]
    patch, i, j = (np.concatenate(a) for a in zip(*pieces, strict=True))
    patch, i, j = grid.canonical(patch, i, j)
    node_ids, first = np.unique(grid.global_ids(patch, i, j), return_index=True)
    patch, i, j = patch[first], i[first], j[first]

    def at(p, a, b) -> np.ndarray:  # held positions of nodes given in any patch
        return np.searchsorted(node_ids, grid.global_ids(*grid.canonical(p, a, b)))

    ll, lr, ur, ul = (at(*c) for c in corners)
    if grid.cells == CellType.QUAD:
        quads, triangles = np.column_stack([ll, lr, ur, ul]), np.empty((0, 3), dtype=np.int64)
    else:
        triangles = _triangles(cell_patch, ll, lr, ur, ul).reshape(-1, 3)
        quads = np.empty((0, 4), dtype=np.int64)
    s_ll, s_lr, s_ur, s_ul = (at(*c) for c in seg_corners)
    quad_number = grid.cell_number(seg_patch, seg_ci, seg_cj)
    if grid.cells == CellType.QUAD:
        cell = quad_number
        cell_corners = np.column_stack([s_ll, s_lr, s_ur, s_ul])
    else:
        cell = 2 * quad_number + which
        triangle = _triangles(seg_patch, s_ll, s_lr, s_ur, s_ul)[np.arange(len(which)), which]
        cell_corners = np.column_stack([triangle, np.full(len(which), -1, dtype=np.int64)])
    anchor = grid.global_ids(*grid.canonical(seg_patch, *grid.anchor(seg_patch, seg_ci, seg_cj)))
    cloud = NodeCloud(
        coords=grid.coords(patch, i, j),
        spacing=_spacing(grid, patch, i, j),
        quads=quads,
        triangles=triangles,
        segments=np.column_stack([at(*boundary["start"]), at(*boundary["end"])]),
        segment_part=boundary["part"],
        part_names=boundary["names"],
        original_index=grid.row_number(patch, i, j),
        segment_cells=BoundaryCells(cell=cell, corners=cell_corners),
        node_ids=None if n_parts == 1 else node_ids,
    )
    partition = Partition(
        n_parts=n_parts,
        node_ranges=grid.node_ranges,
        quad_owner=None,
        triangle_owner=None,
        segment_owner=grid.part_of(anchor),
    )
    return cloud, partition


# --------------------------------------------------------------------------- helpers


def _count(numbered: np.ndarray) -> np.ndarray:
    """Nodes of index rectangles (..., 4) = (i0, i1, j0, j1)."""
    return (numbered[..., 1] - numbered[..., 0]) * (numbered[..., 3] - numbered[..., 2])


def patch_weights(corners: np.ndarray, n_cells: np.ndarray) -> np.ndarray:
    """(n_patches,) the work of a node of each patch against the sparsest patch's: its
    lattice's nodes per area (a node's neighbours and matrix entries grow with it; the
    parallelogram's skewed lattice has ~1.56 times the strips' at the same spacing)."""
    sides = corners[:, [1, 3]] - corners[:, [0]]  # (n_patches, 2, 2): the two edge vectors
    area = np.abs(sides[:, 0, 0] * sides[:, 1, 1] - sides[:, 0, 1] * sides[:, 1, 0])
    density = n_cells[:, 0] * n_cells[:, 1] / area
    return density / density.min()


def _weighted_runs(counts: np.ndarray, weights: np.ndarray, n_parts: int) -> np.ndarray:
    """(n_parts + 1,) ranges of a numbering of ``counts`` nodes per band, each node of
    band b weighing weights[b], into runs of equal weight (to a node); equal runs if
    rounding would leave a run empty."""
    ends = np.concatenate([[0], np.cumsum(counts * weights)])  # weight at each band start
    targets = np.arange(1, n_parts) * ends[-1] / n_parts
    band = np.clip(np.searchsorted(ends, targets, side="right") - 1, 0, len(counts) - 1)
    starts = np.concatenate([[0], np.cumsum(counts)])
    cuts = np.rint(starts[band] + (targets - ends[band]) / weights[band]).astype(np.int64)
    ranges = np.concatenate([[0], cuts, [starts[-1]]]).astype(np.int64)
    return ranges if np.all(np.diff(ranges) > 0) else _even(int(starts[-1]), n_parts)


def _offsets(counts: np.ndarray, order) -> np.ndarray:
    """(n_patches,) first number of each patch's nodes, patch after patch in ``order``."""
    offsets = np.zeros(len(counts), dtype=np.int64)
    offsets[list(order)] = np.concatenate([[0], np.cumsum(counts[list(order)])[:-1]])
    return offsets


def _even(count: int, n_parts: int) -> np.ndarray:
    """(n_parts + 1,) ranges of ``count`` items in parts differing by at most one."""
    sizes = np.full(n_parts, count // n_parts, dtype=np.int64)
    sizes[: count % n_parts] += 1
    return np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)


def _shares(counts: np.ndarray, n_parts: int) -> np.ndarray:
    """Parts per patch, at least one each, that make the largest part (a patch's nodes
    over its parts) smallest: each next part to the patch whose parts are largest (the
    highest-averages rule; ties to the earlier patch), from the floors of the node shares."""
    shares = np.maximum(1, np.floor(n_parts * counts / counts.sum())).astype(np.int64)
    while shares.sum() > n_parts:  # the floors of 1 can overshoot: take back the cheapest
        spare = np.flatnonzero(shares > 1)
        shares[spare[np.argmin(counts[spare] / (shares[spare] - 1))]] -= 1
    while shares.sum() < n_parts:
        shares[np.argmax(counts / shares)] += 1
    return shares


def _on_side(n_cells: np.ndarray, i, j, side: int) -> np.ndarray:
    n, m = n_cells
    return (j == 0, i == n, j == m, i == 0)[side]


def _along(side: int, i, j):
    """The index along a side: i on sides 0 and 2, j on 1 and 3."""
    return i if side in (0, 2) else j


def _at(n_cells: np.ndarray, side: int, along) -> tuple[np.ndarray, np.ndarray]:
    """(i, j) of the nodes ``along`` a side."""
    n, m = (int(v) for v in n_cells)
    fixed = np.full_like(along, (0, n, m, 0)[side])
    return (along, fixed) if side in (0, 2) else (fixed, along)


def _tile_index(u, v, width, height, tile) -> np.ndarray:
    """Position of (u, v) in a width x height rectangle numbered row by row (tile 0) or
    in serpentine order of tile x tile squares, row by row within each."""
    u, v = np.asarray(u), np.asarray(v)
    width, height, tile = (np.broadcast_to(a, u.shape) for a in (width, height, tile))
    rows_order = v * width + u
    t = np.maximum(tile, 1)
    tile_row, tile_column = v // t, u // t
    rows_here = np.minimum(t, height - tile_row * t)  # rows of this tile row
    tile_width = np.minimum(t, width - tile_column * t)
    before = np.where(
        tile_row % 2 == 0,
        tile_column * t,  # the tiles to the left, all full
        width - np.minimum(width, (tile_column + 1) * t),  # those to the right
    )
    inside = (v - tile_row * t) * tile_width + (u - tile_column * t)
    tiled = tile_row * t * width + before * rows_here + inside
    return np.where(tile > 0, tiled, rows_order)


def _tile_position(index: np.ndarray, width: int, height: int, tile: int):
    """(u, v) of positions ``index`` (the inverse of :func:`_tile_index`)."""
    if tile == 0:
        return index % width, index // width
    tile_row = index // (tile * width)
    rest = index - tile_row * tile * width
    rows_here = np.minimum(tile, height - tile_row * tile)
    n_columns = -(-width // tile)
    last_width = width - (n_columns - 1) * tile
    # even tile rows run left to right, full tiles first; odd ones start with the last
    # (narrower) tile
    even = tile_row % 2 == 0
    narrow_first = ~even & (rest < last_width * rows_here)
    shifted = np.where(even, rest, rest - last_width * rows_here)
    k = np.where(narrow_first, 0, shifted // (tile * rows_here))
    tile_column = np.where(even, k, np.where(narrow_first, n_columns - 1, n_columns - 2 - k))
    inside = np.where(narrow_first, rest, shifted - k * tile * rows_here)
    tile_width = np.minimum(tile, width - tile_column * tile)
    return tile_column * tile + inside % tile_width, tile_row * tile + inside // tile_width


def _corners(patch, ci, cj) -> list[tuple]:
    """(patch, i, j) of the lower-left, lower-right, upper-right and upper-left corners
    of cells (ci, cj)."""
    return [(patch, ci, cj), (patch, ci + 1, cj), (patch, ci + 1, cj + 1), (patch, ci, cj + 1)]


def _triangles(patch, ll, lr, ur, ul) -> np.ndarray:
    """(n, 2, 3) the two triangles of each cell of ``patch`` with these corners, as gmsh
    makes them (:data:`RISING_DIAGONAL`, :data:`TRIANGLE_START`), counter-clockwise."""
    rising = np.array(RISING_DIAGONAL)[patch][:, None, None]
    falling_pair = np.stack([np.column_stack([ll, lr, ul]), np.column_stack([ul, lr, ur])], 1)
    rising_pair = np.stack([np.column_stack([ll, lr, ur]), np.column_stack([ll, ur, ul])], 1)
    pair = np.where(rising, rising_pair, falling_pair)
    start = np.array(TRIANGLE_START)[patch][:, :, None]  # (n, 2, 1)
    return np.where(start == 1, np.roll(pair, -1, axis=2), pair)


def _boundary(grid: Lattice) -> dict:
    """The boundary segments counter-clockwise along the outline, then stably by part
    (as gmsh's cloud): their ends and cells as (patch, i, j), which triangle of the cell
    (0 or 1) bounds each, their parts and the part names (in order of appearance)."""
    names: list[str] = []
    blocks = []
    ends = zip(Z_BOUNDARY, Z_BOUNDARY[1:] + Z_BOUNDARY[:1], strict=True)
    for (a, b), edge in zip(ends, Z_EDGE_OF_CURVE, strict=True):
        patch, side = next(
            (p, k)
            for p, c in enumerate(Z_PATCHES)
            for k in range(4)
            if (c[k], c[(k + 1) % 4]) == (a, b)
        )
        name = Z_EDGE_NAMES[edge]
        if name not in names:
            names.append(name)
        n, m = (int(v) for v in grid.n_cells[patch])
        count = n if side in (0, 2) else m
        t = np.arange(count, dtype=np.int64)
        if side in (2, 3):  # counter-clockwise runs back along i or j
            t = t[::-1]
        one = np.ones_like(t)
        start, end, cell = {
            0: ((t, 0 * one), (t + 1, 0 * one), (t, 0 * one)),
            1: ((n * one, t), (n * one, t + 1), ((n - 1) * one, t)),
            2: ((t + 1, m * one), (t, m * one), (t, (m - 1) * one)),
            3: ((0 * one, t + 1), (0 * one, t), (0 * one, t)),
        }[side]
        # the first triangle has the bottom side, and the right one below a rising diagonal
        which = (0, 0 if RISING_DIAGONAL[patch] else 1, 1, 1 if RISING_DIAGONAL[patch] else 0)[side]
        blocks.append((patch * one, start, end, cell, which * one, names.index(name) * one))
    patch = np.concatenate([b[0] for b in blocks])
    part = np.concatenate([b[5] for b in blocks])
    order = np.argsort(part, kind="stable")

    def joined(k: int) -> tuple:
        return tuple(np.concatenate([b[k][c] for b in blocks])[order] for c in range(2))

    return {
        "patch": patch[order],
        "start": (patch[order], *joined(1)),
        "end": (patch[order], *joined(2)),
        "cell": joined(3),
        "which": np.concatenate([b[4] for b in blocks])[order],
        "part": part[order],
        "names": names,
    }


def _spacing(grid: Lattice, patch, i, j) -> np.ndarray:
    """(n,) c_I = mean length of the mesh edges at the nodes (patch, i, j), given as
    their numbering patch's (:func:`~parefg.geometry.cloud.node_spacing`): the lattice
    edges of every patch the node is in, each edge once, with the diagonals of the
    triangles.  A node inside its patch has its edges there (the few on the patches'
    sides go through :func:`_shared_spacing`, whose arrays are ~20 times larger)."""
    n, m = grid.n_cells[patch].T
    inside = (i > 0) & (i < n) & (j > 0) & (j < m)
    spacing = np.empty(len(patch))
    spacing[~inside] = _shared_spacing(grid, patch[~inside], i[~inside], j[~inside])
    p, a, b = patch[inside], i[inside], j[inside]
    here = grid.coords(p, a, b)
    total = np.zeros(len(p))
    rising = np.array(RISING_DIAGONAL)[p]
    for di, dj in EDGE_OFFSETS[: 4 if grid.cells == CellType.QUAD else 6]:
        # this patch's diagonal: (1, -1) and (-1, 1) fall, (1, 1) and (-1, -1) rise
        up = np.where(rising, -dj, dj) if di != 0 and dj != 0 else dj
        total += np.linalg.norm(grid.coords(p, a + di, b + up) - here, axis=1)
    spacing[inside] = total / (4 if grid.cells == CellType.QUAD else 6)
    return spacing


def _shared_spacing(grid: Lattice, patch, i, j) -> np.ndarray:
    """:func:`_spacing` of nodes on the patches' sides: their edges in every patch that
    has them (:func:`_aliases`), each edge once."""
    if len(patch) == 0:
        return np.zeros(0)
    node, p, a, b = _aliases(grid, patch, i, j)
    offsets = EDGE_OFFSETS[: 4 if grid.cells == CellType.QUAD else 8]
    n, m = grid.n_cells[p].T
    rising = np.array(RISING_DIAGONAL)[p]
    edge_nodes, others = [], []
    for di, dj in offsets:
        inside = (a + di >= 0) & (a + di <= n) & (b + dj >= 0) & (b + dj <= m)
        if di != 0 and dj != 0:  # a diagonal of this patch's triangles only
            inside &= rising == (di == dj)
        edge_nodes.append(node[inside])
        others.append(grid.canonical(p[inside], a[inside] + di, b[inside] + dj))
    node = np.concatenate(edge_nodes)
    other = tuple(np.concatenate(x) for x in zip(*others, strict=True))
    key = node * grid.n_nodes + grid.row_number(*other)
    _, first = np.unique(key, return_index=True)  # an edge of two patches counts once
    node = node[first]
    other = tuple(x[first] for x in other)
    here = grid.coords(patch[node], i[node], j[node])
    length = np.linalg.norm(grid.coords(*other) - here, axis=1)
    total = np.bincount(node, weights=length, minlength=len(patch))
    return total / np.bincount(node, minlength=len(patch))


def _aliases(grid: Lattice, patch, i, j):
    """(node, patch, i, j): every place of the nodes (patch, i, j) (given as their
    numbering patch's) in every patch that has them, ``node`` the position in the input."""
    found = [(np.arange(len(patch)), patch, i, j)]
    frontier = [found[0]]
    while frontier:  # glued sides lead back to ever later patches: this ends
        new = []
        for node, p, a, b in frontier:
            for (source, side), (target, target_side) in GLUED.items():
                on = (p == target) & _on_side(grid.n_cells[target], a, b, target_side)
                if on.any():
                    ia, jb = _at(grid.n_cells[source], side, _along(target_side, a[on], b[on]))
                    new.append((node[on], np.full(len(ia), source, dtype=np.int64), ia, jb))
        found += new
        frontier = new
    return tuple(np.concatenate(x) for x in zip(*found, strict=True))
