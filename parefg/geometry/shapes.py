"""The built-in domain shapes, registered by name in :data:`SHAPES` (SPEC 5, 6).

A :class:`Shape` is everything parefg knows about one value of ``[domain] shape``: the
keys its table may hold, the check across them, its outline (vertices and edge names,
when known before meshing) and the builder that creates its gmsh geometry.  The scene
schema reads the names and keys from here; :mod:`parefg.geometry.gmsh_mesh` meshes what
the builder made.  Nothing here is collective.
"""

from __future__ import annotations

import math
import os
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from parefg.errors import InputError
from parefg.geometry.cells import CellType
from parefg.geometry.geo import load_geo
from parefg.geometry.polygon import polygon_problem

BOX_PART_NAMES = ("bottom", "right", "top", "left")
Z_VERTICES = (
    (0.0, 0.0), (1.0, 0.0), (1.0, 0.25), (0.4, 0.25), (1.0, 0.75),
    (1.0, 1.0), (0.0, 1.0), (0.0, 0.75), (0.6, 0.75), (0.0, 0.25),
)  # fmt: skip
# Edge i runs from vertex i to i + 1: edge 0 is y = 0, edge 5 is y = 1.
Z_EDGE_NAMES = ("bottom",) + ("sides",) * 4 + ("top",) + ("sides",) * 4
Z_PART_NAMES = ("bottom", "top", "sides")  # the order a scene lists them in
# The Z as five transfinite patches: its vertices, then the bottom's and the top's
# splitting points (0.4, 0) and (0.6, 1).
Z_PATCH_POINTS = (*Z_VERTICES, (0.4, 0.0), (0.6, 1.0))
Z_PATCHES = (
    (0, 10, 3, 9),  # bottom-left [0, 0.4] x [0, 0.25]
    (10, 1, 2, 3),  # bottom-right [0.4, 1] x [0, 0.25]
    (9, 3, 4, 8),  # the parallelogram (0, 0.25) (0.4, 0.25) (1, 0.75) (0.6, 0.75)
    (7, 8, 11, 6),  # top-left [0, 0.6] x [0.75, 1]
    (8, 4, 5, 11),  # top-right [0.6, 1] x [0.75, 1]
)  # corners counter-clockwise, as indices into Z_PATCH_POINTS
# gmsh's diagonal of the triangles (cells = "tri"): the parallelogram's cells are split
# along their short diagonal (angles 40, 70, 70 degrees instead of 140, 20, 20).
Z_ARRANGEMENTS = ("Left", "Left", "Right", "Left", "Left")
# The outline through the splitting points: boundary curve i runs from point i to i + 1.
Z_BOUNDARY = (0, 10, 1, 2, 3, 4, 5, 11, 6, 7, 8, 9)
# the outline edge (Z_EDGE_NAMES) each boundary curve lies on (0 and 5 are split)
Z_EDGE_OF_CURVE = (0, 0, 1, 2, 3, 4, 5, 5, 6, 7, 8, 9)

#: (vertices (n, 2), edge names (n,)) of a domain's outline; edge i runs from vertex i to i + 1
Outline = tuple[Sequence, Sequence[str]]


@dataclass
class GmshDomain:
    """What a builder made: the domain's surfaces and each part's curves (in part order).

    ``structured``: every surface is transfinite and carries its own cell type (quads
    recombined per surface, or triangles), so no recombination algorithm runs.
    ``lattice`` = (origin, step), both (2,), for a structured grid whose nodes
    are snapped to origin + integer * step (gmsh places them with ~1e-12 noise).
    """

    surfaces: list[int]
    part_curves: dict[str, list[int]]
    lattice: tuple[np.ndarray, np.ndarray] | None = None
    structured: bool = False


@dataclass(frozen=True)
class Patches:
    """A domain meshed as conforming transfinite quadrilateral patches (the size estimate).

    ``sides`` = (length of one pair of opposite sides, of the other) of each patch;
    ``boundary`` = the lengths of the curves on the domain's boundary; a curve of length L
    gets max(min_cells, ceil(L / h)) cells (``min_cells``: see :class:`Shape`).
    """

    sides: tuple[tuple[float, float], ...]
    boundary: tuple[float, ...]


@dataclass(frozen=True)
class Shape:
    """One built-in domain shape.

    Attributes
    ----------
    name : str
        The value of ``[domain] shape``.
    build : callable
        (gmsh, domain, h, cells, min_cells) -> :class:`GmshDomain`: creates the gmsh
        geometry.  ``min_cells``: at least that many cells along each curve of a patched
        domain (the MLS degree m: a degree-m basis needs m + 1 node rows across the Z's
        0.25-thick strips); the other shapes ignore it.
    keys : tuple of str
        The keys of its ``[domain]`` table besides ``shape``, in reading order.
    outline : callable or None
        domain -> :data:`Outline`; None when only gmsh knows the outline (a .geo file).
    check : callable or None
        domain -> (key, why) of the first problem across its keys, or None.
    parts : tuple of str or None
        Its boundary part names in the order a scene lists them; None: the distinct
        edge names of the outline in edge order, or a .geo domain's ``parts``.
    box : callable or None
        domain -> (origin, size) of a rectangle meshed as a structured grid; None for
        the other shapes.
    patches : callable or None
        domain -> :class:`Patches` of a domain meshed as transfinite patches ("z").
    """

    name: str
    build: Callable[..., GmshDomain]
    keys: tuple[str, ...] = ()
    outline: Callable[[dict], Outline] | None = None
    check: Callable[[dict], tuple[str, str] | None] | None = None
    parts: tuple[str, ...] | None = None
    box: Callable[[dict], tuple[Sequence[float], Sequence[float]]] | None = None
    patches: Callable[[dict], Patches] | None = None


def _unit_box(domain: dict) -> tuple[Sequence[float], Sequence[float]]:
    """(origin, size) of the unit square."""
    return (0.0, 0.0), (1.0, 1.0)


def _given_box(domain: dict) -> tuple[Sequence[float], Sequence[float]]:
    """(origin, size) of a rectangle from its keys."""
    return domain.get("origin", (0.0, 0.0)), domain.get("size", (1.0, 1.0))


def _box_shape(name: str, box, keys: tuple[str, ...]) -> Shape:
    """A rectangle shape whose (origin, size) is ``box(domain)``."""

    def outline(domain: dict) -> Outline:
        (x0, y0), (lx, ly) = box(domain)
        return [(x0, y0), (x0 + lx, y0), (x0 + lx, y0 + ly), (x0, y0 + ly)], BOX_PART_NAMES

    def build(gmsh, domain: dict, h: float, cells: str, min_cells: int = 1) -> GmshDomain:
        origin, size = box(domain)
        return _build_box(gmsh, origin, size, h, cells)

    return Shape(name, build, keys, outline, box=box)


def _build_box(gmsh, origin, size, h: float, cells: str) -> GmshDomain:
    """Rectangle as a transfinite grid with n = ceil(L / h) cells per side."""
    (x0, y0), (lx, ly) = origin, size
    if not (lx > 0 and ly > 0):
        raise InputError(f"domain.size: both lengths must be > 0, got {[lx, ly]}")
    corners = [(x0, y0), (x0 + lx, y0), (x0 + lx, y0 + ly), (x0, y0 + ly)]
    surface, lines = _add_polygon_surface(gmsh, corners, h)
    lattice_origin, step, (n_x, n_y) = box_lattice(origin, size, h)
    for line, n_cells in zip(lines, (n_x, n_y, n_x, n_y), strict=True):
        gmsh.model.mesh.setTransfiniteCurve(line, n_cells + 1)
    _set_transfinite_surface(gmsh, surface, cells)
    parts = {name: [line] for name, line in zip(BOX_PART_NAMES, lines, strict=True)}
    return GmshDomain([surface], parts, (lattice_origin, step), structured=True)


def box_lattice(origin, size, h: float) -> tuple[np.ndarray, np.ndarray, tuple[int, int]]:
    """(origin (2,), step (2,), (n_x, n_y)) of a rectangle's transfinite grid at h: its
    nodes are origin + (i, j) step, 0 <= i <= n_x, 0 <= j <= n_y, n = ceil(L / h) cells a
    side (the one computation of :func:`_build_box`'s lattice and of
    :mod:`parefg.geometry.grid_parts`, which rebuilds it to the bit)."""
    (x0, y0), (lx, ly) = origin, size
    n_x, n_y = transfinite_cells(lx, h), transfinite_cells(ly, h)
    return np.array([x0, y0], dtype=float), np.array([lx / n_x, ly / n_y]), (n_x, n_y)


def transfinite_cells(length: float, h: float, at_least: int = 1) -> int:
    """Cells along a transfinite curve of this length: ceil(length / h), at least ``at_least``.

    The tolerance guards ceil against length / h landing a rounding error above an integer.
    """
    return max(at_least, math.ceil(length / h - 1e-9))


def _set_transfinite_surface(gmsh, surface: int, cells: str, arrangement: str = "Left") -> None:
    """A transfinite surface of quads, or of triangles (each quad split along the diagonal
    that gmsh's ``arrangement`` names)."""
    gmsh.model.mesh.setTransfiniteSurface(surface, arrangement)
    if cells == CellType.QUAD:
        gmsh.model.mesh.setRecombine(2, surface)


def _z_outline(domain: dict) -> Outline:
    return Z_VERTICES, Z_EDGE_NAMES


def _z_patches(domain: dict) -> Patches:
    """The side lengths of the Z's patches and of its boundary curves."""

    def length(start: int, end: int) -> float:
        return math.dist(Z_PATCH_POINTS[start], Z_PATCH_POINTS[end])

    sides = tuple((length(a, b), length(b, c)) for a, b, c, _ in Z_PATCHES)
    ends = zip(Z_BOUNDARY, Z_BOUNDARY[1:] + Z_BOUNDARY[:1], strict=True)
    return Patches(sides, tuple(length(a, b) for a, b in ends))


def _build_z(gmsh, domain: dict, h: float, cells: str, min_cells: int = 1) -> GmshDomain:
    """The Z-shaped polygon of the paper's second example as five transfinite patches.

    The patches (:data:`Z_PATCHES`) share their common curves, so the mesh is conforming;
    a curve of length L gets ceil(L / h) cells, at least ``min_cells``, which is the same
    on opposite sides of a patch (they have equal lengths).  At h = 1/8 its strips have 2
    cells across, 3 node rows: a cubic MLS basis there needs ``min_cells`` = 3.  Its parts
    are those of the polygon (:data:`Z_EDGE_NAMES`), in the same order.
    """
    points = [gmsh.model.geo.addPoint(x, y, 0.0, h) for x, y in Z_PATCH_POINTS]
    lines: dict[tuple[int, int], int] = {}  # (start, end) point indices -> line tag

    def line(start: int, end: int) -> int:
        """The signed tag of the line from point start to point end (made once)."""
        if (end, start) in lines:
            return -lines[(end, start)]
        if (start, end) not in lines:
            lines[(start, end)] = gmsh.model.geo.addLine(points[start], points[end])
        return lines[(start, end)]

    surfaces = []
    for corners in Z_PATCHES:
        loop = [line(a, b) for a, b in zip(corners, corners[1:] + corners[:1], strict=True)]
        surfaces.append(gmsh.model.geo.addPlaneSurface([gmsh.model.geo.addCurveLoop(loop)]))
    gmsh.model.geo.synchronize()
    for (start, end), tag in lines.items():
        length = math.dist(Z_PATCH_POINTS[start], Z_PATCH_POINTS[end])
        gmsh.model.mesh.setTransfiniteCurve(tag, transfinite_cells(length, h, min_cells) + 1)
    for surface, arrangement in zip(surfaces, Z_ARRANGEMENTS, strict=True):
        _set_transfinite_surface(gmsh, surface, cells, arrangement)
    part_curves: dict[str, list[int]] = {}
    ends = zip(Z_BOUNDARY, Z_BOUNDARY[1:] + Z_BOUNDARY[:1], strict=True)
    for (start, end), edge in zip(ends, Z_EDGE_OF_CURVE, strict=True):
        part_curves.setdefault(Z_EDGE_NAMES[edge], []).append(abs(line(start, end)))
    return GmshDomain(surfaces, part_curves, structured=True)


def _polygon_outline(domain: dict) -> Outline:
    return domain["vertices"], domain["edge_names"]


def _check_polygon(domain: dict) -> tuple[str, str] | None:
    """One edge name per edge, a simple and counter-clockwise polygon."""
    vertices, names = domain["vertices"], domain["edge_names"]
    if len(names) != len(vertices):
        return "edge_names", f"needs one name per edge ({len(vertices)})"
    problem = polygon_problem(vertices)
    return None if problem is None else ("vertices", problem)


def _build_polygon(gmsh, domain: dict, h: float, cells: str, min_cells: int = 1) -> GmshDomain:
    """Counter-clockwise polygon; edges with equal names form one part."""
    vertices = np.asarray(domain.get("vertices", ()), dtype=float)  # (n_vertices, 2)
    names = list(domain.get("edge_names", ()))
    if vertices.ndim != 2 or vertices.shape[1] != 2 or len(vertices) < 3:
        raise InputError("domain.vertices: need at least 3 points [x, y]")
    problem = _check_polygon({"vertices": vertices, "edge_names": names})
    if problem is not None:
        raise InputError(f"domain.{problem[0]}: {problem[1]}")
    surface, lines = _add_polygon_surface(gmsh, vertices, h)
    part_curves: dict[str, list[int]] = {}
    for name, line in zip(names, lines, strict=True):
        part_curves.setdefault(str(name), []).append(line)
    return GmshDomain([surface], part_curves)


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


def _build_from_geo(gmsh, domain: dict, h: float, cells: str, min_cells: int = 1) -> GmshDomain:
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
    named_curves = _physical_curves(gmsh)
    parts = list(domain.get("parts", ()))
    unknown = [name for name in parts if name not in named_curves]
    if unknown:
        raise InputError(
            f"domain.parts: {unknown} are not physical curves of {path!r}; "
            f"it has {sorted(named_curves)}"
        )
    surfaces = _surfaces(gmsh)
    if not surfaces:
        raise InputError(f"domain.file: {path!r} defines no surface")
    return GmshDomain(surfaces, {name: named_curves[name] for name in parts})


def _physical_curves(gmsh) -> dict[str, list[int]]:
    """Physical curve name -> its curve tags, in the model gmsh has read."""
    named_curves: dict[str, list[int]] = {}
    for dim, tag in gmsh.model.getPhysicalGroups(1):
        name = gmsh.model.getPhysicalName(dim, tag)
        entities = gmsh.model.getEntitiesForPhysicalGroup(dim, tag)
        named_curves.setdefault(name, []).extend(int(e) for e in entities)
    return named_curves


def _surfaces(gmsh) -> list[int]:
    """Sorted tags of the physical surfaces, or of all surfaces when none is physical."""
    surface_groups = gmsh.model.getPhysicalGroups(2)
    surfaces = [
        int(e) for _, tag in surface_groups for e in gmsh.model.getEntitiesForPhysicalGroup(2, tag)
    ]
    if not surfaces:
        surfaces = [tag for _, tag in gmsh.model.getEntities(2)]
    return sorted(set(surfaces))


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


#: ``[domain] shape`` -> its Shape; the first one is the default
SHAPES: dict[str, Shape] = {
    shape.name: shape
    for shape in (
        _box_shape("square", _unit_box, ()),
        _box_shape("rectangle", _given_box, ("size", "origin")),
        Shape("z", _build_z, (), _z_outline, parts=Z_PART_NAMES, patches=_z_patches),
        Shape(
            "polygon", _build_polygon, ("vertices", "edge_names"), _polygon_outline, _check_polygon
        ),
        Shape("geo", _build_from_geo, ("file", "parts")),
    )
}
DEFAULT_SHAPE = next(iter(SHAPES))


def domain_part_names(domain: dict) -> list[str]:
    """Boundary part names of a validated domain (see :attr:`Shape.parts`)."""
    shape = SHAPES[domain["shape"]]
    if shape.parts is not None:
        return list(shape.parts)
    names = shape.outline(domain)[1] if shape.outline is not None else domain["parts"]
    return list(dict.fromkeys(names))


def part_segments(domain: dict) -> dict[str, np.ndarray] | None:
    """Boundary part name -> (n, 2, 2) segments [start, end] of a validated domain's outline.

    None for a .geo domain, whose curves only gmsh knows.
    """
    outline = SHAPES[domain["shape"]].outline
    if outline is None:
        return None
    vertices, names = outline(domain)
    start = np.asarray(vertices, dtype=float)  # (n_edges, 2); edge i runs to vertex i + 1
    segments = np.stack([start, np.roll(start, -1, axis=0)], axis=1)  # (n_edges, 2, 2)
    return {name: segments[[n == name for n in names]] for name in dict.fromkeys(names)}
