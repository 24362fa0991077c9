"""Domains, gmsh meshing and the node cloud (SPEC 5).

Rank 0 builds the domain with the gmsh Python API, meshes it at target spacing
h and turns the mesh into a :class:`NodeCloud`: the EFG nodes (the mesh
vertices), the background integration cells (quadrilaterals and/or triangles,
counter-clockwise) and the boundary segments tagged with the boundary part they
belong to; optionally its interior nodes are jittered (:mod:`parefg.geometry.jitter`).
The cloud is then broadcast, so every rank holds the same arrays.

Each domain shape has one builder, registered by name in ``DOMAIN_BUILDERS``.
A builder creates the gmsh geometry and returns its surfaces and the curves of
each boundary part; meshing and extraction are shared.
"""

from __future__ import annotations

import contextlib
import inspect
import math
import os
import tempfile
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from parefg.errors import InputError
from parefg.geometry.geo import load_geo

# gmsh element type codes of first-order cells.
GMSH_TRIANGLE, GMSH_QUAD = 2, 3
# Boundary segments on no listed part (traction-free, kept for output).
FREE_PART = "_free"
BOX_PART_NAMES = ("bottom", "right", "top", "left")
Z_VERTICES = (
    (0.0, 0.0), (1.0, 0.0), (1.0, 0.25), (0.4, 0.25), (1.0, 0.75),
    (1.0, 1.0), (0.0, 1.0), (0.0, 0.75), (0.6, 0.75), (0.0, 0.25),
)  # fmt: skip
# Edge i runs from vertex i to i + 1: edge 0 is y = 0, edge 5 is y = 1.
Z_EDGE_NAMES = ("bottom",) + ("sides",) * 4 + ("top",) + ("sides",) * 4


@dataclass
class NodeCloud:
    """EFG nodes, background cells and tagged boundary segments of one domain.

    Attributes
    ----------
    coords : (n_nodes, 2) float
        Node positions x_I.
    spacing : (n_nodes,) float
        Local node spacing c_I: mean length of the mesh edges incident to node I.
    quads : (n_quads, 4) int64
        Quadrilateral cells, counter-clockwise (possibly empty).
    triangles : (n_triangles, 3) int64
        Triangular cells, counter-clockwise (possibly empty).
    segments : (n_segments, 2) int64
        Boundary segments (a, b) with the domain on their left, so the outward
        unit normal is (y_b - y_a, -(x_b - x_a)) / |x_b - x_a|.
    segment_part : (n_segments,) int64
        Index of each segment's boundary part in ``part_names``.
    part_names : list of str
        Boundary part names; ``"_free"`` collects segments of a user .geo that
        are on no listed part.
    original_index : (n_nodes,) int64
        Index of each node in the cloud as gmsh built it.
    """

    coords: np.ndarray
    spacing: np.ndarray
    quads: np.ndarray
    triangles: np.ndarray
    segments: np.ndarray
    segment_part: np.ndarray
    part_names: list[str]
    original_index: np.ndarray

    @property
    def n_nodes(self) -> int:
        """Number of nodes N."""
        return len(self.coords)


def build_node_cloud(
    comm,
    domain: dict,
    h: float,
    cells: str = "quad",
    jitter: float = 0.0,
    seed: int = 0,
    budget=None,
) -> NodeCloud:
    """Mesh a domain with gmsh on rank 0 and broadcast the node cloud.

    Collective.  Any failure on rank 0 (bad geometry, unreadable .geo, unknown
    physical name, empty part) is broadcast and raised as :class:`InputError`
    on every rank, so no rank is left waiting.

    Parameters
    ----------
    comm : mpi4py communicator
    domain : dict
        The scene's ``[domain]`` table: ``shape`` = "square" | "rectangle" |
        "z" | "polygon" | "geo" and that shape's parameters.
    h : float
        Target node spacing (> 0).
    cells : {"quad", "tri"}
        Background cell type; "quad" may leave a few triangles on unstructured
        meshes.
    jitter, seed : float, int
        The scene's ``discretization.jitter`` and ``.seed``: interior nodes move
        by at most jitter c_I (:func:`parefg.geometry.jitter.jitter_cloud`); 0 keeps the mesh nodes.
    budget : parefg.discretization.budget.Budget, optional
        Refuses a .geo domain too large for the machine before gmsh meshes it.
    """
    # Imported here: parefg.geometry.jitter builds on this module's NodeCloud and node_spacing.
    from parefg.geometry.jitter import jitter_cloud

    cloud, failure = None, None
    if comm.rank == 0:
        try:
            cloud = jitter_cloud(mesh_domain(domain, h, cells, budget), jitter, seed)
        except InputError as exc:
            failure = ("input", str(exc))
        except Exception as exc:  # a defect: still end every rank, not only rank 0
            failure = ("internal", f"{type(exc).__name__}: {exc}")
            root_exception = exc
    failure = comm.bcast(failure, root=0)
    if failure is not None:
        kind, message = failure
        if kind == "input":
            raise InputError(message)
        if comm.rank == 0:
            raise root_exception
        raise RuntimeError(f"node cloud construction failed on rank 0: {message}")
    return comm.bcast(cloud, root=0)


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
def mesh_domain(domain: dict, h: float, cells: str = "quad", budget=None) -> NodeCloud:
    """Build, mesh and extract one domain in this process (not collective).

    gmsh never reads stdin here (:func:`_gmsh_initialize`, :func:`_stdin_closed`).  With a
    ``budget`` (:class:`~parefg.discretization.budget.Budget`), a .geo domain whose surfaces'
    bounding boxes (an upper bound of its area) need more than the budget is refused before
    meshing, and gmsh meshes it no finer than the budget holds (Mesh.MeshSizeMin,
    :meth:`Budget.size_floor`).
    """
    shape = domain.get("shape")
    if shape not in DOMAIN_BUILDERS:
        raise InputError(
            f"domain.shape: unknown shape {shape!r}; allowed: {sorted(DOMAIN_BUILDERS)}"
        )
    if not (isinstance(h, int | float | np.number) and math.isfinite(h) and h > 0):
        raise InputError(f"discretization.h: must be a positive number, got {h!r}")
    if cells not in ("quad", "tri"):
        raise InputError(f"cells: must be 'quad' or 'tri', got {cells!r}")
    import gmsh  # imported lazily: only rank 0 meshes

    _gmsh_initialize(gmsh)
    try:
        # Size options first, so that a .geo file can read h as Mesh.MeshSizeMax.
        _set_mesh_options(gmsh, h, cells, recombine=False)
        built = DOMAIN_BUILDERS[shape](gmsh, domain, h, cells)
        _set_mesh_options(gmsh, h, cells, recombine=cells == "quad" and built.lattice is None)
        if budget is not None and shape == "geo":
            extent = _surfaces_extent(gmsh, built.surfaces)
            budget.check_extent(*extent)
            # A .geo file's own sizes (points, MeshSize, fields) may ask for any
            # refinement: gmsh clamps them all to this floor (Budget.size_floor).
            gmsh.option.setNumber("Mesh.MeshSizeMin", budget.size_floor(*extent))
        gmsh.model.mesh.generate(2)
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
    """Order-1 mesh at size h; quads by Blossom recombination of Frontal-Delaunay triangles.

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


# --------------------------------------------------------------------------- builders


@dataclass
class _GmshDomain:
    """What a builder made: the domain's surfaces and each part's curves (in part order).

    ``lattice`` = (origin, step), both (2,), for a structured grid whose nodes
    are snapped to origin + integer * step (gmsh places them with ~1e-12 noise).
    """

    surfaces: list[int]
    part_curves: dict[str, list[int]]
    lattice: tuple[np.ndarray, np.ndarray] | None = None


def _build_box(gmsh, domain: dict, h: float, cells: str):
    """Rectangle as a transfinite grid with n = ceil(L / h) cells per side."""
    lx, ly = domain.get("size", (1.0, 1.0)) if domain["shape"] == "rectangle" else (1.0, 1.0)
    x0, y0 = domain.get("origin", (0.0, 0.0)) if domain["shape"] == "rectangle" else (0.0, 0.0)
    if not (lx > 0 and ly > 0):
        raise InputError(f"domain.size: both lengths must be > 0, got {[lx, ly]}")
    corners = [(x0, y0), (x0 + lx, y0), (x0 + lx, y0 + ly), (x0, y0 + ly)]
    surface, lines = _add_polygon_surface(gmsh, corners, h)
    # Tolerance guards ceil against L / h landing a rounding error above an integer.
    n_x, n_y = (max(1, math.ceil(length / h - 1e-9)) for length in (lx, ly))
    for line, n_cells in zip(lines, (n_x, n_y, n_x, n_y), strict=True):
        gmsh.model.mesh.setTransfiniteCurve(line, n_cells + 1)
    gmsh.model.mesh.setTransfiniteSurface(surface)
    if cells == "quad":
        gmsh.model.mesh.setRecombine(2, surface)
    parts = {name: [line] for name, line in zip(BOX_PART_NAMES, lines, strict=True)}
    lattice = (np.array([x0, y0], dtype=float), np.array([lx / n_x, ly / n_y]))
    return _GmshDomain([surface], parts, lattice)


def _build_z(gmsh, domain: dict, h: float, cells: str):
    """The Z-shaped polygon of the paper's second example."""
    polygon = {"shape": "polygon", "vertices": Z_VERTICES, "edge_names": Z_EDGE_NAMES}
    return _build_polygon(gmsh, polygon, h, cells)


def _build_polygon(gmsh, domain: dict, h: float, cells: str):
    """Counter-clockwise polygon; edges with equal names form one part."""
    vertices = np.asarray(domain.get("vertices", ()), dtype=float)  # (n_vertices, 2)
    names = list(domain.get("edge_names", ()))
    if vertices.ndim != 2 or vertices.shape[1] != 2 or len(vertices) < 3:
        raise InputError("domain.vertices: need at least 3 points [x, y]")
    if len(names) != len(vertices):
        raise InputError(
            f"domain.edge_names: need one name per edge ({len(vertices)}), got {len(names)}"
        )
    defect = polygon_defect(vertices)
    if defect is not None:
        raise InputError(f"domain.vertices: must be a simple polygon: {defect}")
    following = np.roll(vertices, -1, axis=0)
    signed_area = 0.5 * np.sum(vertices[:, 0] * following[:, 1] - following[:, 0] * vertices[:, 1])
    if not signed_area > 0:
        raise InputError("domain.vertices: must be counter-clockwise with positive area")
    surface, lines = _add_polygon_surface(gmsh, vertices, h)
    part_curves: dict[str, list[int]] = {}
    for name, line in zip(names, lines, strict=True):
        part_curves.setdefault(str(name), []).append(line)
    return _GmshDomain([surface], part_curves)


PAIRS_PER_CHUNK = 200_000  # candidate edge pairs tested at once by polygon_defect
MAX_POLYGON_VERTICES = 5000  # worst case (every pair a candidate): 7 s on a busy 2-core VM


def polygon_defect(vertices) -> str | None:
    """Why the closed polyline through ``vertices`` is not a simple polygon, or None.

    Edge i runs from vertex i to vertex i + 1 (the last back to vertex 0).  A
    simple polygon has no zero-length edge, no two coincident vertices, no two
    non-adjacent edges that cross or touch and no two adjacent edges that overlap
    (fold back).  Distances below 1e-9 times the polygon's extent count as touching,
    so the answer does not hang on round-off.  gmsh aborts the process on a
    self-intersecting curve loop: this is its gate.

    Only edge pairs whose ranges overlap along x (or y) are tested (edges sorted by
    their smallest coordinate, found with searchsorted), vectorized over
    PAIRS_PER_CHUNK pairs at a time; the worst case stays quadratic, hence
    MAX_POLYGON_VERTICES.
    """
    xy = np.asarray(vertices, dtype=float)  # (n, 2)
    n = len(xy)
    if n > MAX_POLYGON_VERTICES:
        return f"it has {n} vertices, at most {MAX_POLYGON_VERTICES} are allowed"
    ends = np.roll(xy, -1, axis=0)  # (n, 2) end of edge i
    tol = 1e-9 * float(np.ptp(xy, axis=0).max())
    short = np.flatnonzero(np.linalg.norm(ends - xy, axis=1) <= tol)
    if len(short):
        i = int(short[0])
        return f"edge {i} has zero length (vertices {i} and {(i + 1) % n} coincide)"
    low, high = np.minimum(xy, ends), np.maximum(xy, ends)  # (n, 2) edge bounding boxes
    # Along the axis that gives fewer candidates, edge order[k] can only meet the edges
    # order[k + 1 : reach[k]] that start before it ends.
    sweeps = []
    for axis in (0, 1):
        order = np.argsort(low[:, axis], kind="stable")
        reach = np.searchsorted(low[order, axis], high[order, axis] + tol, side="right")
        sweeps.append((order, reach - np.arange(n) - 1))  # (n,), (n,) >= 0
    order, counts = min(sweeps, key=lambda sweep: int(sweep[1].sum()))
    ends_before = np.cumsum(counts)  # (n,) pairs of rows 0..k
    start = 0
    while start < n:
        before = ends_before[start] - counts[start]
        stop = max(start + 1, int(np.searchsorted(ends_before, before + PAIRS_PER_CHUNK, "right")))
        rows = np.arange(start, stop)
        k = np.repeat(rows, counts[rows])  # (p,) sorted position of the first edge
        offsets = np.arange(len(k)) - np.repeat(
            np.cumsum(counts[rows]) - counts[rows], counts[rows]
        )
        defect = _pairs_defect(xy, ends, low, high, order[k], order[k + 1 + offsets], tol)
        if defect is not None:
            return defect
        start = stop
    return None


def _pairs_defect(xy, ends, low, high, e, f, tol) -> str | None:
    """The first defect among the edge pairs (e, f), each (p,) int."""
    n = len(xy)
    e, f = np.minimum(e, f), np.maximum(e, f)
    near = np.all((low[e] <= high[f] + tol) & (low[f] <= high[e] + tol), axis=1)
    e, f = e[near], f[near]
    coincide = np.linalg.norm(xy[e] - xy[f], axis=1) <= tol
    if np.any(coincide):
        k = np.lexsort((f[coincide], e[coincide]))[0]
        a, b = int(e[coincide][k]), int(f[coincide][k])
        return f"vertices {a} and {b} coincide ({_point(xy[a])})"
    a, b, c, d = xy[e], ends[e], xy[f], ends[f]  # (p, 2)
    following = f == e + 1  # edge f starts where edge e ends: c = b
    closing = (e == 0) & (f == n - 1)  # edge f ends where edge e starts: d = a
    # Adjacent edges overlap when the far end of one lies on the other.
    fold = following & ((_segment_distance(d, a, b) <= tol) | (_segment_distance(a, c, d) <= tol))
    fold |= closing & ((_segment_distance(c, a, b) <= tol) | (_segment_distance(b, c, d) <= tol))
    crossing = (_cross(b - a, c - a) * _cross(b - a, d - a) < 0) & (
        _cross(d - c, a - c) * _cross(d - c, b - c) < 0
    )
    gap = np.minimum.reduce(
        [_segment_distance(c, a, b), _segment_distance(d, a, b), _segment_distance(a, c, d),
         _segment_distance(b, c, d)]
    )  # fmt: skip
    bad = fold | (~following & ~closing & (crossing | (gap <= tol)))
    if not np.any(bad):
        return None
    k = np.lexsort((f[bad], e[bad]))[0]
    first, second = int(e[bad][k]), int(f[bad][k])
    how = "overlap" if fold[bad][k] else "cross or touch"
    return (
        f"edges {first} and {second} {how} ({_point(xy[first])} -> {_point(ends[first])} and "
        f"{_point(xy[second])} -> {_point(ends[second])})"
    )


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(...,) z-component of u x v for (..., 2) vectors."""
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(...,) distance from points p to segments [a, b], all (..., 2) (b != a)."""
    ab = b - a
    t = np.clip(np.sum((p - a) * ab, axis=-1) / np.sum(ab * ab, axis=-1), 0.0, 1.0)
    return np.linalg.norm(p - a - t[..., None] * ab, axis=-1)


def _point(p: np.ndarray) -> str:
    return f"[{p[0]:g}, {p[1]:g}]"


def _add_polygon_surface(gmsh, vertices, h: float):
    """Plane surface bounded by a closed polyline; returns (surface, line tags)."""
    points = [gmsh.model.geo.addPoint(x, y, 0.0, h) for x, y in vertices]
    lines = [
        gmsh.model.geo.addLine(a, b) for a, b in zip(points, points[1:] + points[:1], strict=True)
    ]
    loop = gmsh.model.geo.addCurveLoop(lines)
    surface = gmsh.model.geo.addPlaneSurface([loop])
    gmsh.model.geo.synchronize()
    return surface, lines


def _build_from_geo(gmsh, domain: dict, h: float, cells: str):
    """A user .geo file, checked by :mod:`parefg.geometry.geo`; its physical curves are the parts.

    gmsh reads the checked text from a file in a private temporary directory, not
    the user's file: what runs is what was checked, and nothing beside the user's
    file (gmsh merges ``NAME.opt`` when it exists) or in its name (gmsh uncompresses
    ``*.gz`` through the shell) reaches gmsh.
    """
    path = str(domain.get("file", ""))
    try:
        text = load_geo(path, mesh_size_max=h)
    except InputError as exc:
        raise InputError(f"domain.file {path!r}: {exc}") from None
    with tempfile.TemporaryDirectory(prefix="parefg-geo-") as private:
        checked = os.path.join(private, "domain.geo")
        with open(checked, "w", encoding="utf-8") as stream:
            stream.write(text)
        try:
            gmsh.open(checked)
        except Exception as exc:
            _reset_geo_parser(gmsh)
            if type(exc) is not Exception:  # gmsh reports its errors as plain Exception
                raise
            message = str(exc).replace(checked, path)
            raise InputError(f"domain: gmsh failed: {message}") from None
    named_curves: dict[str, list[int]] = {}
    for dim, tag in gmsh.model.getPhysicalGroups(1):
        name = gmsh.model.getPhysicalName(dim, tag)
        entities = gmsh.model.getEntitiesForPhysicalGroup(dim, tag)
        named_curves.setdefault(name, []).extend(int(e) for e in entities)
    parts = list(domain.get("parts", ()))
    unknown = [name for name in parts if name not in named_curves]
    if unknown:
        raise InputError(
            f"domain.parts: {unknown} are not physical curves of {path!r}; "
            f"it has {sorted(named_curves)}"
        )
    surface_groups = gmsh.model.getPhysicalGroups(2)
    surfaces = [
        int(e) for _, tag in surface_groups for e in gmsh.model.getEntitiesForPhysicalGroup(2, tag)
    ]
    if not surfaces:
        surfaces = [tag for _, tag in gmsh.model.getEntities(2)]
    if not surfaces:
        raise InputError(f"domain.file: {path!r} defines no surface")
    return _GmshDomain(sorted(set(surfaces)), {name: named_curves[name] for name in parts})


def _reset_geo_parser(gmsh) -> None:
    """Parse an empty .geo after a parse error.

    gmsh 4.8's .geo parser keeps state after an error, so the next file it
    reads in this process fails with "syntax error (;)"; that next file is
    this throwaway one instead.
    """
    with tempfile.NamedTemporaryFile("w", suffix=".geo") as empty:
        empty.write("\n")
        empty.flush()
        try:
            gmsh.merge(empty.name)
        except Exception:  # the expected, state-clearing failure
            pass


DOMAIN_BUILDERS: dict[str, Callable] = {
    "square": _build_box,
    "rectangle": _build_box,
    "z": _build_z,
    "polygon": _build_polygon,
    "geo": _build_from_geo,
}


# --------------------------------------------------------------------------- extraction


def _extract_cloud(gmsh, built: _GmshDomain, cells: str) -> NodeCloud:
    """Turn the gmsh mesh of the built surfaces into a NodeCloud with compact numbering."""
    node_tags, xyz, _ = gmsh.model.mesh.getNodes()
    row_of_tag = np.full(int(node_tags.max()) + 1, -1, dtype=np.int64)
    row_of_tag[node_tags.astype(np.int64)] = np.arange(len(node_tags))
    all_coords = xyz.reshape(-1, 3)[:, :2]  # (n_gmsh_nodes, 2)
    if built.lattice is not None:
        origin, step = built.lattice
        all_coords = origin + np.round((all_coords - origin) / step) * step
    quads = _cells_of_type(gmsh, built.surfaces, GMSH_QUAD, 4, row_of_tag)
    triangles = _cells_of_type(gmsh, built.surfaces, GMSH_TRIANGLE, 3, row_of_tag)
    if cells == "tri" and len(quads):  # a .geo may force recombination: split quads
        triangles = np.vstack([triangles, quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
        quads = np.empty((0, 4), dtype=np.int64)
    if len(quads) + len(triangles) == 0:
        raise InputError("domain: gmsh produced no 2D cells (is the mesh size h too large?)")
    # Keep only nodes used by the cells, in gmsh order.
    used = np.unique(np.concatenate([quads.ravel(), triangles.ravel()]))
    renumber = np.full(len(all_coords), -1, dtype=np.int64)  # -1: node of no cell
    renumber[used] = np.arange(len(used))
    coords = np.ascontiguousarray(all_coords[used])  # (n_nodes, 2)
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


# --------------------------------------------------------------------------- mesh helpers


def directed_edges(quads: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(n_cells_edges, 2) int64 edges (c_i, c_{i+1}) of every cell, in cell order."""
    blocks = [np.empty((0, 2), dtype=np.int64)]
    for cells in (quads, triangles):
        blocks.append(np.stack([cells, np.roll(cells, -1, axis=1)], axis=-1).reshape(-1, 2))
    return np.vstack(blocks).astype(np.int64)


def mesh_edges(quads: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(n_edges, 2) int64 unique undirected mesh edges (a < b), sorted."""
    directed = directed_edges(quads, triangles)
    return np.unique(np.sort(directed, axis=1), axis=0)


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
    """(n_nodes,) c_I = mean length of the mesh edges incident to node I."""
    edges = mesh_edges(quads, triangles)
    lengths = np.linalg.norm(coords[edges[:, 1]] - coords[edges[:, 0]], axis=1)
    total = np.bincount(edges.ravel(), weights=np.repeat(lengths, 2), minlength=len(coords))
    count = np.bincount(edges.ravel(), minlength=len(coords))
    return total / count
