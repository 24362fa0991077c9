"""A rectangle meshed part by part: each rank makes its own piece of the structured grid
(SPEC 5; issue 13: no rank meshes, partitions or holds the whole cloud).

gmsh meshes a rectangle ("square", "rectangle") as a transfinite grid of n_x x n_y cells
whose nodes are snapped to the lattice origin + (i, j) step
(:func:`~parefg.geometry.shapes._build_box`, :func:`~parefg.geometry.gmsh_mesh._extract_cloud`):
its nodes, cells, spacing and boundary are functions of the indices (i, j) alone.  So
every rank computes the same partition of the index grid from O(p) numbers
(:func:`grid_blocks`, no communication) and builds its own part of the cloud
(:func:`grid_part`) in the layout :func:`~parefg.geometry.distribute.partition_on_root`
sends a rank: its own nodes, its cells' nodes and the boundary's, with every segment
and the cell next to it.  No array here is sized by the whole grid.

The partition is a recursive bisection of the index rectangle along its longer extent,
in whole grid lines, so every part is a rectangle of nodes (the parts' sizes differ by
at most half a grid line from the RCB's; a grid too small to split so falls back to
meshing on rank 0).  As with the RCB, a part owns the cells whose centres lie on its side
of the cuts (a cut runs between two node lines, so the cells across it go to the part
above it), and the boundary segments of its cells.  Within a part the nodes are numbered
row by row, and ``original_index`` is the lattice number j (n_x + 1) + i.

The coordinates are bit-identical to gmsh's snapped ones; the cells are gmsh's (quads
counter-clockwise from the lower-left corner; triangles split along the diagonal from
the lower-right to the upper-left corner, gmsh's "Left" arrangement), in another order.
A jittered cloud (``discretization.jitter`` > 0) is meshed on rank 0 (its random moves
follow gmsh's node order).  Nothing here is collective.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from parefg.geometry.cells import CellType
from parefg.geometry.cloud import BoundaryCells, NodeCloud
from parefg.geometry.partition import Cut, Partition, classify
from parefg.geometry.shapes import BOX_PART_NAMES, SHAPES, box_lattice


@dataclass(frozen=True)
class Grid:
    """The structured grid of a rectangle: nodes origin + (i, j) step, 0 <= i <= n_x,
    0 <= j <= n_y; ``cells`` a :class:`~parefg.geometry.cells.CellType`."""

    origin: np.ndarray  # (2,)
    step: np.ndarray  # (2,)
    n_cells: tuple[int, int]
    cells: str

    @property
    def n_nodes(self) -> int:
        return (self.n_cells[0] + 1) * (self.n_cells[1] + 1)

    def coords(self, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        """(n, 2) the nodes (i, j), as gmsh's snapped ones: origin + index * step."""
        return self.origin + np.column_stack([i, j]).astype(float) * self.step


@dataclass(frozen=True)
class Blocks:
    """The partition of a grid's nodes into rectangles of indices, one per part.

    ``rects[r]`` = (i0, i1, j0, j1): part r owns i0 <= i < i1, j0 <= j < j1, numbered
    node_ranges[r] + (j - j0) (i1 - i0) + (i - i0); ``cuts`` classifies indices.
    """

    rects: np.ndarray  # (p, 4) int64
    node_ranges: np.ndarray  # (p + 1,) int64
    cuts: Cut | int

    def part_of(self, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        """(n,) the part owning each node (i, j)."""
        return classify(self.cuts, np.column_stack([i, j]).astype(float))

    def cell_part_of(self, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        """(n,) the part owning each cell with lower-left corner (i, j): its centre's."""
        return classify(self.cuts, np.column_stack([i + 0.5, j + 0.5]))

    def global_ids(self, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        """(n,) int64 global numbers of the nodes (i, j)."""
        part = self.part_of(i, j)
        i0, i1, j0, _ = self.rects[part].T
        return self.node_ranges[part] + (j - j0) * (i1 - i0) + (i - i0)


def scene_grid(scene) -> Grid | None:
    """The grid of ``scene``'s domain, or None where it is not meshed as one here (not a
    rectangle, or jittered).  Not collective."""
    shape = SHAPES[scene.domain["shape"]]
    if shape.box is None or scene.discretization.jitter > 0:
        return None
    origin, step, n_cells = box_lattice(*shape.box(scene.domain), scene.discretization.h)
    return Grid(origin, step, n_cells, scene.discretization.cells)


def mesh_by_parts(comm, scene) -> tuple[NodeCloud, Partition] | None:
    """This rank's part of ``scene``'s grid and the partition, as
    :func:`~parefg.geometry.distribute.partition_on_root` returns them; None (on every
    rank alike) where the domain is not a grid (:func:`scene_grid`) or the grid cannot be
    split into ``comm.size`` rectangles.  Not collective: every rank decides the same."""
    grid = scene_grid(scene)
    blocks = None if grid is None else grid_blocks(grid, comm.size)
    if grid is None or blocks is None:
        return None
    return grid_part(grid, blocks, comm.rank)


# --------------------------------------------------------------------------- partition


def grid_blocks(grid: Grid, n_parts: int) -> Blocks | None:
    """The recursive bisection of the grid's nodes into ``n_parts`` rectangles (module
    docstring), or None when a rectangle cannot be cut into its parts' share."""
    n_i, n_j = grid.n_cells[0] + 1, grid.n_cells[1] + 1
    rects = np.zeros((n_parts, 4), dtype=np.int64)
    cuts = _split(grid.step, (0, n_i, 0, n_j), 0, n_parts, rects)
    if cuts is None:
        return None
    counts = (rects[:, 1] - rects[:, 0]) * (rects[:, 3] - rects[:, 2])
    node_ranges = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    return Blocks(rects, node_ranges, cuts)


def _split(step, rect, first_part: int, n_parts: int, rects: np.ndarray) -> Cut | int | None:
    """Cut tree of the index rectangle ``rect`` into parts first_part .. + n_parts - 1
    (written into ``rects``); None if some rectangle cannot be cut.

    As :func:`~parefg.geometry.partition._bisect`: the longer extent is cut, the lower
    side gets the first floor(p / 2) parts and as near their node share as whole lines
    come (each side at least one node per part); the other axis if that one cannot.
    """
    if n_parts == 1:
        rects[first_part] = rect
        return first_part
    i0, i1, j0, j1 = rect
    lines = (i1 - i0, j1 - j0)
    extents = ((lines[0] - 1) * step[0], (lines[1] - 1) * step[1])
    n_below_parts = n_parts // 2
    n_nodes = lines[0] * lines[1]
    share = n_below_parts * (n_nodes // n_parts) + min(n_below_parts, n_nodes % n_parts)
    for axis in (0, 1) if extents[0] >= extents[1] else (1, 0):
        across = lines[1 - axis]
        low = math.ceil(n_below_parts / across)
        high = lines[axis] - math.ceil((n_parts - n_below_parts) / across)
        if low > high:
            continue
        below_lines = min(max(round(share / across), low), high)
        start = (i0, j0)[axis]
        below_rect = (i0, i0 + below_lines, j0, j1) if axis == 0 else (i0, i1, j0, j0 + below_lines)
        above_rect = (i0 + below_lines, i1, j0, j1) if axis == 0 else (i0, i1, j0 + below_lines, j1)
        below = _split(step, below_rect, first_part, n_below_parts, rects)
        above = _split(step, above_rect, first_part + n_below_parts, n_parts - n_below_parts, rects)
        if below is None or above is None:
            return None
        return Cut(axis, start + below_lines - 0.5, below, above)
    return None


# --------------------------------------------------------------------------- one part


def grid_part(grid: Grid, blocks: Blocks, rank: int) -> tuple[NodeCloud, Partition]:
    """Part ``rank`` of the grid's cloud, and the partition (module docstring).

    The cloud holds the part's own nodes, its cells' corners and the boundary's nodes
    (the segments' ends and their cells' corners: the two outer node rings), ascending by
    global number; its cells are the part's; segments, their parts and cells are the
    whole boundary's.  ``node_ids`` is None for one part (it holds every node).
    """
    n_x, n_y = grid.n_cells
    i0, i1, j0, j1 = (int(v) for v in blocks.rects[rank])
    # (n_cells_here,) lower-left corners of this part's cells (centres at index + 1/2 on
    # its side of the cuts at line - 1/2), row by row
    cell_rows = range(max(j0 - 1, 0), min(j1 - 1, n_y))
    cell_columns = range(max(i0 - 1, 0), min(i1 - 1, n_x))
    cell_j, cell_i = _rows(cell_rows, cell_columns)
    seg_start, seg_end, seg_cell, segment_part = _boundary(n_x, n_y)
    # every node held: the block with its cells' corners, and the two outer rings
    near_j, near_i = _rows(range(cell_rows.start, j1), range(cell_columns.start, i1))
    ring = _outer_rings(n_x, n_y)
    all_i = np.concatenate([near_i, ring[0]])
    all_j = np.concatenate([near_j, ring[1]])
    node_ids, first = np.unique(blocks.global_ids(all_i, all_j), return_index=True)
    held_i, held_j = all_i[first], all_j[first]

    def at(i: np.ndarray, j: np.ndarray) -> np.ndarray:  # held positions of nodes (i, j)
        return np.searchsorted(node_ids, blocks.global_ids(i, j))

    quads, triangles = _cells(grid.cells, cell_i, cell_j, at)
    cell, corners = _segment_cells(grid, seg_cell, at)
    cloud = NodeCloud(
        coords=grid.coords(held_i, held_j),
        spacing=_spacing(grid, held_i, held_j),
        quads=quads,
        triangles=triangles,
        segments=np.column_stack([at(*seg_start), at(*seg_end)]),
        segment_part=segment_part,
        part_names=list(BOX_PART_NAMES),
        original_index=held_j * (n_x + 1) + held_i,
        segment_cells=BoundaryCells(cell=cell, corners=corners),
        node_ids=None if len(blocks.rects) == 1 else node_ids,
    )
    partition = Partition(
        n_parts=len(blocks.rects),
        node_ranges=blocks.node_ranges,
        quad_owner=None,
        triangle_owner=None,
        segment_owner=blocks.cell_part_of(*seg_cell),
    )
    return cloud, partition


def _rows(j_range: range, i_range: range) -> tuple[np.ndarray, np.ndarray]:
    """(j, i) of every index pair, row by row (j outer): both (n,) int64."""
    j, i = np.meshgrid(
        np.arange(j_range.start, j_range.stop),
        np.arange(i_range.start, i_range.stop),
        indexing="ij",
    )
    return j.ravel().astype(np.int64), i.ravel().astype(np.int64)


def _outer_rings(n_x: int, n_y: int) -> tuple[np.ndarray, np.ndarray]:
    """(i, j) of the nodes in the two outermost rows and columns (with repeats)."""
    rows = sorted({0, min(1, n_y), max(n_y - 1, 0), n_y})
    columns = sorted({0, min(1, n_x), max(n_x - 1, 0), n_x})
    every_i, every_j = np.arange(n_x + 1), np.arange(n_y + 1)
    i = [every_i for _ in rows] + [np.full(n_y + 1, c) for c in columns]
    j = [np.full(n_x + 1, r) for r in rows] + [every_j for _ in columns]
    return np.concatenate(i).astype(np.int64), np.concatenate(j).astype(np.int64)


def _boundary(n_x: int, n_y: int):
    """The boundary segments counter-clockwise, part by part (bottom, right, top, left,
    :data:`~parefg.geometry.shapes.BOX_PART_NAMES`): (i, j) of their starts and ends, of
    their cells' lower-left corners, and their parts (n_segments,)."""
    along_x, along_y = np.arange(n_x), np.arange(n_y)
    zeros_x, zeros_y = np.zeros(n_x, dtype=np.int64), np.zeros(n_y, dtype=np.int64)
    top_i, left_j = along_x[::-1], along_y[::-1]
    start_i = np.concatenate([along_x, zeros_y + n_x, top_i + 1, zeros_y])
    start_j = np.concatenate([zeros_x, along_y, zeros_x + n_y, left_j + 1])
    end_i = np.concatenate([along_x + 1, zeros_y + n_x, top_i, zeros_y])
    end_j = np.concatenate([zeros_x, along_y + 1, zeros_x + n_y, left_j])
    cell_i = np.concatenate([along_x, zeros_y + n_x - 1, top_i, zeros_y])
    cell_j = np.concatenate([zeros_x, along_y, zeros_x + n_y - 1, left_j])
    part = np.repeat(np.arange(4, dtype=np.int64), [n_x, n_y, n_x, n_y])
    return (start_i, start_j), (end_i, end_j), (cell_i, cell_j), part


def _corners(i: np.ndarray, j: np.ndarray) -> tuple:
    """(i, j) of the lower-left, lower-right, upper-right and upper-left corners."""
    return (i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1)


def _cells(cells: str, i: np.ndarray, j: np.ndarray, at) -> tuple[np.ndarray, np.ndarray]:
    """(quads (n, 4), triangles (2 n, 3)) of the cells with lower-left corners (i, j), as
    held positions: counter-clockwise; a quad as two triangles (lower-left, lower-right,
    upper-left) and (upper-left, lower-right, upper-right) when ``cells`` is "tri"."""
    lower_left, lower_right, upper_right, upper_left = (at(*c) for c in _corners(i, j))
    if cells == CellType.QUAD:
        quads = np.column_stack([lower_left, lower_right, upper_right, upper_left])
        return quads, np.empty((0, 3), dtype=np.int64)
    first = np.column_stack([lower_left, lower_right, upper_left])
    second = np.column_stack([upper_left, lower_right, upper_right])
    return np.empty((0, 4), dtype=np.int64), np.stack([first, second], axis=1).reshape(-1, 3)


def _segment_cells(grid: Grid, seg_cell, at) -> tuple[np.ndarray, np.ndarray]:
    """(cell (n_segments,), corners (n_segments, 4)) of :class:`BoundaryCells`: the
    grid cell (quads j n_x + i; triangles 2 (j n_x + i) + which) bounding each segment
    of :func:`_boundary`, its corners as held positions (-1 fourth for a triangle)."""
    (n_x, n_y), (i, j) = grid.n_cells, seg_cell
    quad_number = j * n_x + i
    lower_left, lower_right, upper_right, upper_left = (at(*c) for c in _corners(i, j))
    if grid.cells == CellType.QUAD:
        return quad_number, np.column_stack([lower_left, lower_right, upper_right, upper_left])
    # bottom and left segments bound the first triangle, right and top the second
    second = np.repeat(np.array([0, 1, 1, 0], dtype=np.int64), [n_x, n_y, n_x, n_y])
    none = np.full(len(i), -1, dtype=np.int64)
    corners = np.where(
        second[:, None] == 1,
        np.column_stack([upper_left, lower_right, upper_right, none]),
        np.column_stack([lower_left, lower_right, upper_left, none]),
    )
    return 2 * quad_number + second, corners


def _spacing(grid: Grid, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """(n,) c_I = mean length of the grid edges at nodes (i, j)
    (:func:`~parefg.geometry.cloud.node_spacing`): the four axis neighbours, and for
    triangles the two along the diagonals."""
    n_x, n_y = grid.n_cells
    offsets = [(1, 0), (-1, 0), (0, 1), (0, -1)]
    if grid.cells != CellType.QUAD:
        offsets += [(1, -1), (-1, 1)]
    here = grid.coords(i, j)
    total, count = np.zeros(len(i)), np.zeros(len(i))
    for di, dj in offsets:
        inside = (i + di >= 0) & (i + di <= n_x) & (j + dj >= 0) & (j + dj <= n_y)
        length = np.linalg.norm(grid.coords(i + di, j + dj) - here, axis=1)
        total += np.where(inside, length, 0.0)
        count += inside
    return total / count
