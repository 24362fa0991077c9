"""gmsh meshing: a domain built, meshed and turned into a :class:`NodeCloud` (SPEC 5).

Rank 0 builds the domain with the gmsh Python API (the builder of its
:class:`~parefg.geometry.shapes.Shape`), meshes it at target spacing h and turns the
mesh into a :class:`~parefg.geometry.cloud.NodeCloud`: the EFG nodes (the mesh
vertices), the background integration cells (quadrilaterals and/or triangles,
counter-clockwise) and the boundary segments tagged with the boundary part they belong
to; optionally its interior nodes are jittered (:mod:`parefg.geometry.jitter`).
:func:`mesh_on_root` keeps the cloud on rank 0 (the run partitions it there);
:func:`build_node_cloud` broadcasts it, so every rank holds the same arrays.  A run on a
rectangle or the Z does not mesh here: each rank makes its own part of the transfinite
grid or patches gmsh would make (:mod:`parefg.geometry.grid_parts`,
:mod:`parefg.geometry.patch_parts`).

gmsh runs in a sealed session: stdin reads /dev/null, HOME is a private temporary
directory and no user configuration is read.
"""

from __future__ import annotations

import contextlib
import inspect
import math
import os
import tempfile

import numpy as np

from parefg.errors import InputError
from parefg.geometry import mesh_cache
from parefg.geometry.cells import CELL_TYPES, UNSTRUCTURED_DENSITY, CellType
from parefg.geometry.cloud import (
    DIM,
    NodeCloud,
    directed_edges,
    node_spacing,
    orient_counter_clockwise,
)
from parefg.geometry.jitter import jitter_cloud
from parefg.geometry.shapes import SHAPES, GmshDomain
from parefg.parallel import run_on_root

# gmsh element type codes of first-order cells.
GMSH_TRIANGLE, GMSH_QUAD = 2, 3
# Boundary segments on no listed part (traction-free, kept for output).
FREE_PART = "_free"
# gmsh's unstructured algorithms mesh at most about this many nodes; a finer cloud is a
# coarser mesh split uniformly (:func:`generate`).
DIRECT_NODES = 20_000
# a split curve may have this many times the segments of its mesh at h (_scaling_refinements)
CURVE_SCALING_SLACK = 1.25


def mesh_on_root(
    comm,
    domain: dict,
    h: float,
    cells: str = CellType.QUAD,
    jitter: float = 0.0,
    seed: int = 0,
    budget=None,
    min_cells: int = 1,
) -> NodeCloud | None:
    """Mesh a domain with gmsh on rank 0: the node cloud there, None on the other ranks.

    Collective.  Any failure on rank 0 (bad geometry, unreadable .geo, unknown
    physical name, empty part) is raised as :class:`InputError` on every rank
    (:func:`~parefg.parallel.run_on_root`), so no rank is left waiting.  The run
    partitions the cloud on rank 0 and sends each rank its arrays once
    (:func:`~parefg.geometry.distribute.partition_on_root`): no pickle of the whole cloud.

    Parameters
    ----------
    comm : mpi4py communicator
    domain : dict
        The scene's ``[domain]`` table: ``shape`` = "square" | "rectangle" |
        "z" | "polygon" | "geo" and that shape's parameters.
    h : float
        Target node spacing (> 0).
    cells : a :class:`~parefg.geometry.cells.CellType`
        Background cell type; "quad" may leave a few triangles on unstructured
        meshes.
    jitter, seed : float, int
        The scene's ``discretization.jitter`` and ``.seed``: interior nodes move
        by at most jitter c_I (:func:`parefg.geometry.jitter.jitter_cloud`); 0 keeps the mesh nodes.
    budget : parefg.discretization.budget.Budget, optional
        Refuses a .geo domain too large for the machine before gmsh meshes it.
    min_cells : int
        At least that many cells along each curve of a domain meshed as transfinite
        patches ("z"; the MLS degree m, see :class:`~parefg.geometry.shapes.Shape`).
    """
    return run_on_root(comm, _jittered_mesh, domain, h, cells, jitter, seed, budget, min_cells)


def build_node_cloud(comm, *args, **kwargs) -> NodeCloud:
    """:func:`mesh_on_root` (the same arguments), its cloud broadcast to every rank.

    Collective.  For callers that want the whole cloud everywhere (tests, benchmarks).
    """
    return comm.bcast(mesh_on_root(comm, *args, **kwargs), root=0)


def _jittered_mesh(
    domain: dict, h: float, cells: str, jitter: float, seed: int, budget, min_cells: int
):
    """:func:`mesh_on_root`'s task: the meshed (or cached), jittered cloud."""
    in_memory = mesh_cache.memory_key(domain, h, cells, min_cells)
    cloud = mesh_cache.recall(in_memory)
    if cloud is None:
        key = mesh_cache.mesh_key(domain, h, cells, min_cells)
        cloud = mesh_cache.load(key)
        if cloud is None:
            cloud = mesh_domain(domain, h, cells, budget, min_cells)
            mesh_cache.store(key, cloud)
        mesh_cache.remember(in_memory, cloud)
    return jitter_cloud(cloud, jitter, seed)


@contextlib.contextmanager
def _stdin_closed():
    """File descriptor 0 reads /dev/null inside the block (gmsh's C stdio reads fd 0).

    Defence in depth: whatever gmsh (or a .geo resetting General.NoPopup) asks, it reads
    end-of-file and takes its default instead of waiting on a pipe or a terminal.
    """
    saved = os.dup(0) if _fd_open(0) else None
    null = os.open(os.devnull, os.O_RDONLY)  # is 0 itself when fd 0 was closed
    try:
        if null != 0:
            os.dup2(null, 0)
        yield
    finally:
        if saved is None:  # fd 0 was closed: close it again
            os.close(0)
        else:
            os.dup2(saved, 0)
            os.close(saved)
        if null != 0:
            os.close(null)


@contextlib.contextmanager
def _private_home():
    """HOME is a private temporary directory inside the block, then restored.

    gmsh's FLTK layer writes ~/.fltk/fltk.org/fltk.prefs at every gmsh.initialize, even
    without a GUI: a run must not write outside its output directory, so it writes into
    a directory that is removed afterwards.
    """
    saved = os.environ.get("HOME")
    with tempfile.TemporaryDirectory(prefix="parefg-gmsh-home-") as home:
        os.environ["HOME"] = home
        try:
            yield
        finally:
            if saved is None:
                del os.environ["HOME"]
            else:
                os.environ["HOME"] = saved


def _fd_open(fd: int) -> bool:
    try:
        os.fstat(fd)
    except OSError:
        return False
    return True


@_stdin_closed()
@_private_home()
def mesh_domain(
    domain: dict, h: float, cells: str = CellType.QUAD, budget=None, min_cells: int = 1
) -> NodeCloud:
    """Build, mesh and extract one domain in this process (not collective).

    gmsh never reads stdin here (:func:`_gmsh_initialize`, :func:`_stdin_closed`).  With a
    ``budget`` (:class:`~parefg.discretization.budget.Budget`), a .geo domain whose surfaces'
    bounding boxes (an upper bound of its area) need more than the budget is refused before
    meshing, and gmsh meshes it no finer than the budget holds (Mesh.MeshSizeMin,
    :meth:`Budget.size_floor`).
    """
    name = domain.get("shape")
    shape = SHAPES.get(name) if isinstance(name, str) else None
    if shape is None:
        raise InputError(f"domain.shape: unknown shape {name!r}; allowed: {sorted(SHAPES)}")
    if not (isinstance(h, int | float | np.number) and math.isfinite(h) and h > 0):
        raise InputError(f"discretization.h: must be a positive number, got {h!r}")
    if cells not in CELL_TYPES:
        raise InputError(f"cells: must be one of {', '.join(CELL_TYPES)}; got {cells!r}")
    import gmsh  # imported lazily: only rank 0 meshes

    _gmsh_initialize(gmsh)
    try:
        # Size options first, so that a .geo file can read h as Mesh.MeshSizeMax.
        _set_mesh_options(gmsh, h, cells, recombine=False)
        built = shape.build(gmsh, domain, h, cells, min_cells)
        _set_mesh_options(gmsh, h, cells, recombine=cells == CellType.QUAD and not built.structured)
        if budget is not None and shape.outline is None:  # a .geo file: only gmsh knows it
            extent = _surfaces_extent(gmsh, built.surfaces)
            budget.check_extent(*extent)
            # A .geo file's own sizes (points, MeshSize, fields) may ask for any
            # refinement: gmsh clamps them all to this floor (Budget.size_floor).
            gmsh.option.setNumber("Mesh.MeshSizeMin", budget.size_floor(*extent))
        generate(gmsh, built, h)
        cloud = _extract_cloud(gmsh, built, cells)
    except InputError:
        raise
    except Exception as exc:
        if type(exc) is not Exception:  # gmsh reports its errors as plain Exception
            raise
        raise InputError(f"domain: gmsh failed: {exc}") from None
    finally:
        gmsh.finalize()
    return cloud


def generate(gmsh, built: GmshDomain, h: float) -> int:
    """Mesh the built surfaces (2D) at spacing h; returns the number of uniform refinements.

    Structured (transfinite) domains are meshed as they are.  An unstructured domain whose
    estimated node count (:data:`UNSTRUCTURED_DENSITY` per h^2 of its surfaces' bounding
    boxes) exceeds :data:`DIRECT_NODES` is meshed at sizes 2^k times larger (every size:
    Mesh.MeshSizeFactor scales h, the .geo file's own sizes and fields, and the budget's
    floor alike) and split uniformly k times (gmsh.model.mesh.refine: each triangle into 4
    triangles, each quad into 4 quads; new boundary nodes are placed on the curves), so
    that gmsh's algorithms mesh about DIRECT_NODES nodes.  Frontal-Delaunay and above all
    Blossom recombination grow faster than linearly (measured, plate with a hole,
    bench_meshing.py: 1e5 nodes 4.8 s as triangles, 64 s as quads; 1e6 nodes 133 s as
    triangles), splitting is linear: 1e6 nodes in 10 s either way, with the same smallest
    angles (triangles 40 / quads 45 degrees; 1st percentile 46 / 61).  k is lowered until
    every curve's coarse mesh scales (:func:`_scaling_refinements`).
    """
    refinements = 0
    if not built.structured:
        area, _ = _surfaces_extent(gmsh, built.surfaces)
        estimate = UNSTRUCTURED_DENSITY * area / h**2
        while estimate > DIRECT_NODES * 4**refinements:
            refinements += 1
        refinements = _scaling_refinements(gmsh, refinements)
        gmsh.option.setNumber("Mesh.MeshSizeFactor", 2.0**refinements)
    gmsh.model.mesh.generate(2)
    for _ in range(refinements):
        gmsh.model.mesh.refine()
    return refinements


def _scaling_refinements(gmsh, refinements: int) -> int:
    """The largest k <= ``refinements`` whose coarse curve meshes scale with the sizes.

    A curve whose segment count does not follow the sizes (a .geo's Transfinite Curve, a
    small hole at gmsh's minimum points per curve) would be split into 2^k times its fixed
    count: many more segments, and a denser mesh around them, than meshing at h gives.
    So each curve's 1D mesh at sizes x 2^k, split k times, may have at most
    CURVE_SCALING_SLACK times the segments of its 1D mesh at h, plus one: a curve shorter
    than about 4 (2^k - 2) h (rounded up to whole coarse segments) or at a fixed count lowers
    k.  The 1D meshes cost little (the boundary only).
    """

    def segments_per_curve(factor: float) -> np.ndarray:
        gmsh.option.setNumber("Mesh.MeshSizeFactor", factor)
        gmsh.model.mesh.generate(1)
        counts = [len(gmsh.model.mesh.getElementsByType(1, tag)[0]) for _, tag in curves]
        gmsh.model.mesh.clear()
        return np.array(counts)

    curves = gmsh.model.getEntities(1)
    if refinements == 0 or not curves:
        return refinements
    at_h = segments_per_curve(1.0)
    while refinements > 0:
        split = 2**refinements * segments_per_curve(2.0**refinements)
        if np.all(split <= CURVE_SCALING_SLACK * at_h + 1):
            break
        refinements -= 1
    return refinements


def _gmsh_initialize(gmsh) -> None:
    """Start gmsh quietly and non-interactively, ignoring the user's gmsh config files.

    gmsh asks questions on stdin (Msg::GetAnswer, GetValue, GetString: "Your choice of
    mesh element sizes will likely produce a very large mesh. Do you really want to
    continue?") unless General.NoPopup is set; General.ExpertMode skips that size question
    altogether (parefg's own budget has judged the size).  Without its own interrupt
    handling where supported.
    """
    options = {"readConfigFiles": False}
    if "interruptible" in inspect.signature(gmsh.initialize).parameters:
        options["interruptible"] = False
    gmsh.initialize(**options)
    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.option.setNumber("General.NoPopup", 1)
    gmsh.option.setNumber("General.ExpertMode", 1)
    gmsh.model.add("parefg")


def _surfaces_extent(gmsh, surfaces: list[int]) -> tuple[float, float]:
    """(area, perimeter) bounds of the surfaces from their bounding boxes (before meshing).

    The sum of the boxes' areas bounds the meshed area from above (each surface lies in
    its box and is meshed on its own); the boxes' perimeters estimate the boundary.
    """
    area = perimeter = 0.0
    for surface in surfaces:
        x0, y0, _, x1, y1, _ = gmsh.model.getBoundingBox(2, surface)
        area += (x1 - x0) * (y1 - y0)
        perimeter += 2 * ((x1 - x0) + (y1 - y0))
    return area, perimeter


def _set_mesh_options(gmsh, h: float, cells: str, recombine: bool) -> None:
    """Order-1 mesh at size h; unstructured quads by Blossom recombination of Frontal-Delaunay
    triangles (structured domains set their transfinite surfaces' cells themselves).

    gmsh's "Frontal-Delaunay for quads" (Mesh.Algorithm 8) crashes the
    process in Debian's gmsh 4.8, so quads come from recombining the plain
    Frontal-Delaunay triangulation (Mesh.Algorithm 6), which Blossom turns
    into all or nearly all quads.
    """
    gmsh.option.setNumber("Mesh.ElementOrder", 1)
    gmsh.option.setNumber("Mesh.MeshSizeMax", h)
    gmsh.option.setNumber("Mesh.MeshSizeMin", 0.0)
    gmsh.option.setNumber("Mesh.MeshSizeFactor", 1.0)
    gmsh.option.setNumber("Mesh.Algorithm", 6)  # Frontal-Delaunay
    gmsh.option.setNumber("Mesh.RecombinationAlgorithm", 1)  # Blossom
    gmsh.option.setNumber("Mesh.RecombineAll", int(recombine))


# --------------------------------------------------------------------------- extraction


def _extract_cloud(gmsh, built: GmshDomain, cells: str) -> NodeCloud:
    """Turn the gmsh mesh of the built surfaces into a NodeCloud with compact numbering."""
    node_tags, xyz, _ = gmsh.model.mesh.getNodes()
    row_of_tag = np.full(int(node_tags.max()) + 1, -1, dtype=np.int64)
    row_of_tag[node_tags.astype(np.int64)] = np.arange(len(node_tags))
    all_coords = xyz.reshape(-1, 3)[:, :DIM]  # (n_gmsh_nodes, DIM)
    if built.lattice is not None:
        origin, step = built.lattice
        all_coords = origin + np.round((all_coords - origin) / step) * step
    quads = _cells_of_type(gmsh, built.surfaces, GMSH_QUAD, 4, row_of_tag)
    triangles = _cells_of_type(gmsh, built.surfaces, GMSH_TRIANGLE, 3, row_of_tag)
    if cells == CellType.TRI and len(quads):  # a .geo may force recombination: split quads
        triangles = np.vstack([triangles, quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
        quads = np.empty((0, 4), dtype=np.int64)
    if len(quads) + len(triangles) == 0:
        raise InputError("domain: gmsh produced no 2D cells (is the mesh size h too large?)")
    # Keep only nodes used by the cells, in gmsh order.
    used = np.unique(np.concatenate([quads.ravel(), triangles.ravel()]))
    renumber = np.full(len(all_coords), -1, dtype=np.int64)  # -1: node of no cell
    renumber[used] = np.arange(len(used))
    # native float64 without another copy: gmsh's arrays carry an explicit '<' byte order
    coords = all_coords[used].view(np.float64)  # (n_nodes, DIM)
    quads = orient_counter_clockwise(coords, renumber[quads])
    triangles = orient_counter_clockwise(coords, renumber[triangles])
    line_keys, line_parts = _part_line_keys(
        gmsh, built.part_curves, renumber[row_of_tag], len(coords)
    )
    segments, segment_part, part_names = _boundary_segments(
        quads, triangles, line_keys, line_parts, list(built.part_curves), len(coords)
    )
    return NodeCloud(
        coords=coords,
        spacing=node_spacing(coords, quads, triangles),
        quads=quads,
        triangles=triangles,
        segments=segments,
        segment_part=segment_part,
        part_names=part_names,
        original_index=np.arange(len(coords), dtype=np.int64),
    )


def _cells_of_type(gmsh, surfaces, element_type: int, n_corners: int, row_of_tag) -> np.ndarray:
    """(n_cells, n_corners) int64 gmsh node rows of all cells of one type on the surfaces."""
    blocks = [np.empty((0, n_corners), dtype=np.int64)]
    for surface in surfaces:
        _, node_tags = gmsh.model.mesh.getElementsByType(element_type, surface)
        blocks.append(row_of_tag[np.asarray(node_tags, dtype=np.int64)].reshape(-1, n_corners))
    return np.vstack(blocks)


def _part_line_keys(gmsh, part_curves: dict, node_of_tag, n_nodes: int):
    """Edge keys min*N + max of the line elements of each part, and their part index."""
    keys, parts = [np.empty(0, dtype=np.int64)], [np.empty(0, dtype=np.int64)]
    for part, curves in enumerate(part_curves.values()):
        for curve in curves:
            _, node_tags = gmsh.model.mesh.getElementsByType(1, curve)
            ends = node_of_tag[np.asarray(node_tags, dtype=np.int64)].reshape(-1, 2)
            ends = ends[np.all(ends >= 0, axis=1)]  # lines off the domain's cells
            keys.append(ends.min(axis=1) * n_nodes + ends.max(axis=1))
            parts.append(np.full(len(ends), part, dtype=np.int64))
    return np.concatenate(keys), np.concatenate(parts)


def _boundary_segments(quads, triangles, line_keys, line_parts, part_names, n_nodes):
    """Cell edges used by one cell only, oriented as in their CCW cell, tagged by part.

    A counter-clockwise cell has its interior on the left of each of its edges,
    so a boundary edge taken in its cell's order has the domain on its left.
    """
    directed = directed_edges(quads, triangles)  # (n_cell_edges, 2)
    keys = directed.min(axis=1) * n_nodes + directed.max(axis=1)
    unique_keys, first, counts = np.unique(keys, return_index=True, return_counts=True)
    segments = directed[first[counts == 1]]  # (n_segments, 2)
    boundary_keys = unique_keys[counts == 1]
    segment_part = np.full(len(segments), len(part_names), dtype=np.int64)  # default: free
    if len(line_keys):
        order = np.argsort(line_keys, kind="stable")
        position = np.searchsorted(line_keys[order], boundary_keys).clip(max=len(order) - 1)
        on_part = line_keys[order][position] == boundary_keys
        segment_part[on_part] = line_parts[order][position[on_part]]
    empty = [name for p, name in enumerate(part_names) if not np.any(segment_part == p)]
    if empty:
        raise InputError(f"domain: boundary parts {empty} have no segments on the domain boundary")
    if np.any(segment_part == len(part_names)):
        part_names = [*part_names, FREE_PART]
    by_part = np.argsort(segment_part, kind="stable")
    return segments[by_part], segment_part[by_part], part_names
