"""The node cloud: EFG nodes, background cells and tagged boundary segments (SPEC 5).

:class:`NodeCloud` is plain data.  As meshed it holds every cell; once distributed
(:func:`~parefg.geometry.distribute.partition_on_root`) a rank's copy holds only the cells
it owns, with the cell next to every boundary segment (:class:`BoundaryCells`).  The
helpers here compute what follows from its arrays alone (mesh edges, local node spacing,
cell areas and orientation, the cells of the boundary segments).  Nothing here is
collective, and nothing here knows gmsh: the clouds are made by
:mod:`parefg.geometry.gmsh_mesh` and perturbed by :mod:`parefg.geometry.jitter`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from parefg.errors import InputError

#: Spatial dimension of the node clouds (coordinates are (n, DIM) arrays).
DIM = 2


@dataclass
class NodeCloud:
    """EFG nodes, background cells and tagged boundary segments of one domain.

    Attributes
    ----------
    coords : (n_nodes, DIM) float
        Node positions x_I.
    spacing : (n_nodes,) float
        Local node spacing c_I: mean length of the mesh edges incident to node I.
    quads : (n_quads, 4) int64
        Quadrilateral cells, counter-clockwise (possibly empty); once distributed, only
        this rank's.
    triangles : (n_triangles, 3) int64
        Triangular cells, counter-clockwise (possibly empty); once distributed, only
        this rank's.
    segments : (n_segments, 2) int64
        Boundary segments (a, b) with the domain on their left, so the outward
        unit normal is (y_b - y_a, -(x_b - x_a)) / |x_b - x_a|.
    segment_part : (n_segments,) int64
        Index of each segment's boundary part in ``part_names``.
    part_names : list of str
        Boundary part names; ``"_free"`` collects segments of a user .geo that
        are on no listed part.
    original_index : (n_nodes,) int64
        Index of each node in the cloud as built: gmsh's order, or the numbering of a
        domain made part by part (a rectangle's lattice, the Z's bands:
        :mod:`~parefg.geometry.grid_parts`, :mod:`~parefg.geometry.patch_parts`); the
        same for any rank count.
    segment_cells : BoundaryCells or None
        The cell each segment bounds, set where the cells are distributed (every rank
        keeps it for every segment); None while the cloud holds all its cells.
    node_ids : (n_nodes,) int64 or None
        The global (partition) number of each node held, ascending, once distributed to
        a rank that holds only some nodes (its own, the ghosts its supports reach and
        the boundary's; :mod:`~parefg.geometry.distribute`): the cells and segments then
        refer to nodes by their position here.  None: the cloud holds every node,
        numbered 0 .. n_nodes - 1.
    """

    coords: np.ndarray
    spacing: np.ndarray
    quads: np.ndarray
    triangles: np.ndarray
    segments: np.ndarray
    segment_part: np.ndarray
    part_names: list[str]
    original_index: np.ndarray
    segment_cells: BoundaryCells | None = None
    node_ids: np.ndarray | None = None

    @property
    def n_nodes(self) -> int:
        """Number of nodes held (N where the cloud holds every node)."""
        return len(self.coords)

    def global_ids(self) -> np.ndarray:
        """(n_nodes,) the global number of each node held."""
        return np.arange(self.n_nodes) if self.node_ids is None else self.node_ids

    def run_of(self, start: int, stop: int) -> slice:
        """Where the nodes numbered start .. stop - 1 (all held, e.g. a rank's own) sit."""
        first = int(self.positions(np.array([start]))[0]) if stop > start else 0
        return slice(first, first + stop - start)

    def positions(self, global_ids: np.ndarray) -> np.ndarray:
        """Where the nodes numbered ``global_ids`` (all held) sit in the arrays here."""
        if self.node_ids is None:
            return np.asarray(global_ids, dtype=np.int64)
        return np.searchsorted(self.node_ids, global_ids)

    @property
    def dim(self) -> int:
        """Spatial dimension d of the coordinates."""
        return self.coords.shape[1]


@dataclass
class BoundaryCells:
    """The background cell each boundary segment bounds, in segment order.

    What a segment's trace-inverse estimate integrates over; O(boundary), so that every
    rank can keep it for every segment while it keeps only its own cells.

    Attributes
    ----------
    cell : (n_segments,) int64
        Index of the cell in the whole mesh (quads first, then triangles); -1 for a
        segment that bounds no cell.
    corners : (n_segments, 4) int64
        Its corners, counter-clockwise; a triangle's fourth corner is -1.
    """

    cell: np.ndarray
    corners: np.ndarray

    def of(self, segment_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(quads, triangles, is_triangle) of ``segment_ids``: the corners of their
        quadrilateral cells and of their triangular ones, each in segment order, and
        which segments' cells are triangles."""
        if np.any(self.cell[segment_ids] < 0):
            raise ValueError("a boundary segment bounds no cell of the cloud")
        corners = self.corners[segment_ids]  # (n, 4)
        is_triangle = corners[:, 3] < 0
        return corners[~is_triangle], corners[is_triangle, :3], is_triangle


def boundary_cells(cloud: NodeCloud) -> BoundaryCells:
    """The cell of every segment of a cloud that holds all its cells.

    A segment (a, b) has the domain on its left, as every counter-clockwise cell edge:
    it is the directed edge a -> b of exactly one cell.  A segment that bounds no cell
    gets cell -1 (its user, the trace-inverse estimate, refuses it).
    """
    n_quads, n_triangles = len(cloud.quads), len(cloud.triangles)
    edges = directed_edges(cloud.quads, cloud.triangles)  # quads' 4 edges first, then 3 each
    owner = np.concatenate(
        [np.repeat(np.arange(n_quads), 4), n_quads + np.repeat(np.arange(n_triangles), 3)]
    ).astype(np.int64)
    n = len(cloud.coords)
    keys = edges[:, 0] * n + edges[:, 1]
    order = np.argsort(keys)
    sorted_keys, sorted_owner = np.append(keys[order], -1), np.append(owner[order], -1)
    wanted = cloud.segments[:, 0] * n + cloud.segments[:, 1]
    position = np.searchsorted(sorted_keys[:-1], wanted)  # len(order): past the end
    found = sorted_keys[position] == wanted
    cell = np.where(found, sorted_owner[position], -1)
    corners = np.full((len(cell), 4), -1, dtype=np.int64)
    is_quad, is_triangle = found & (cell < n_quads), found & (cell >= n_quads)
    corners[is_quad] = cloud.quads[cell[is_quad]]
    corners[is_triangle, :3] = cloud.triangles[cell[is_triangle] - n_quads]
    return BoundaryCells(cell=cell, corners=corners)


def directed_edges(quads: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(n_cells_edges, 2) int64 edges (c_i, c_{i+1}) of every cell, in cell order."""
    blocks = [np.empty((0, 2), dtype=np.int64)]
    for cells in (quads, triangles):
        blocks.append(np.stack([cells, np.roll(cells, -1, axis=1)], axis=-1).reshape(-1, 2))
    return np.vstack(blocks).astype(np.int64)


def mesh_edges(quads: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(n_edges, 2) int64 unique undirected mesh edges (a < b), sorted."""
    directed = directed_edges(quads, triangles)
    # One int64 key a * n + b per edge: a 1D unique is ~20x faster than unique(axis=0),
    # which sorts rows as structured records (5 s of 12 for 1e6 nodes), same order.
    n = int(directed.max()) + 1 if len(directed) else 1
    keys = np.unique(directed.min(axis=1) * n + directed.max(axis=1))
    return np.stack([keys // n, keys % n], axis=1)


def signed_areas(coords: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """(n_cells,) shoelace areas 1/2 sum_i (x_i y_{i+1} - x_{i+1} y_i); > 0 when CCW."""
    corners = coords[cells]  # (n_cells, n_corners, 2)
    following = np.roll(corners, -1, axis=1)
    cross = corners[..., 0] * following[..., 1] - following[..., 0] * corners[..., 1]
    return 0.5 * cross.sum(axis=1)


def orient_counter_clockwise(coords: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Cells with clockwise ones reversed; InputError for a degenerate cell."""
    cells = np.array(cells, dtype=np.int64).reshape(-1, cells.shape[-1])
    areas = signed_areas(coords, cells)
    cells[areas < 0] = cells[areas < 0, ::-1]
    scale = np.ptp(coords, axis=0).max() if len(coords) else 1.0
    degenerate = np.abs(areas) <= 1e-14 * scale**2
    if np.any(degenerate):
        bad = int(np.flatnonzero(degenerate)[0])
        raise InputError(f"domain: degenerate mesh cell with corners {coords[cells[bad]].tolist()}")
    return cells


def node_spacing(coords: np.ndarray, quads: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(n_nodes,) c_I = mean length of the mesh edges incident to node I (any dimension)."""
    edges = mesh_edges(quads, triangles)
    lengths = np.linalg.norm(coords[edges[:, 1]] - coords[edges[:, 0]], axis=1)
    total = np.bincount(edges.ravel(), weights=np.repeat(lengths, 2), minlength=len(coords))
    count = np.bincount(edges.ravel(), minlength=len(coords))
    return total / count
