"""How large a run will be, counted before anything is built (SPEC 9).

From the validated scene alone (microseconds of arithmetic, no gmsh) :func:`estimate_scene`
predicts the size of a run: the node count N from the domain's area A and perimeter P
at spacing h, the background cells, the quadrature points, the MLS neighbours per point
(the nodes within s c_I of a point: about pi s^2 per point at unit node density, capped by
N) and from those the peak resident memory of the largest rank::

    memory = base + (per-rank share of)  point data  n_points * n_max * bytes per slot
                                       + Gram pairs   n_cells * G^2    (nodes of a cell's points)
                                       + matrices     nnz(A) = 4 N R   (R = nodes within 2 s c)
                                       + Cholesky     nnz(L) = nnz(A) * fill(2 N)  (direct only)

The coefficients are measured (``scripts/bench/calibrate_budget.py``: the estimate is
0.88-1.43 times summary.json's ``peak_rss_mb`` with the direct solver, m = 1, 2 and 3, from
2e3 DOFs at m = 2 and 3; 1.37-1.71x with CG + GAMG at m = 1 from 7e4 DOFs, 1.06-1.23x at
m = 2 to 3e4 DOFs and 1.58 / 1.96x at 5e4 DOFs on 1 / 2 ranks; up to 2.1x for m = 1 below
2e4 DOFs, where the process's own base dominates; 2026-12-07, session 43); the direct
factorization's fill is a rough fit of MUMPS's nested-dissection fill on these stencils,
growing like log N.
:func:`cloud_size` counts the same from an actual node cloud.  Not collective.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from parefg.geometry.cells import UNSTRUCTURED_DENSITY, CellType
from parefg.geometry.grid_parts import scene_grid
from parefg.geometry.patch_parts import patched

# Unstructured gmsh meshes at target size h: N = UNSTRUCTURED_DENSITY A / h^2 + 0.5 P / h.
# Local geometry in units of the node spacing c_I: (nodes per c^2, cell area / c^2), the
# medians measured on gmsh's unstructured meshes, graded ones included (cloud_size).
UNSTRUCTURED_LOCAL = {CellType.QUAD: (1.03, 0.97), CellType.TRI: (1.155, 0.43)}
# Mean incident edge of a node of a structured triangle grid: (4 + 2 sqrt 2) / 6 steps.
TRIANGLE_GRID_SPACING = (4 + 2 * math.sqrt(2)) / 6
# n_max / (mean neighbours): padded neighbour lists are as long as the fullest point's.
# Transfinite patches (the "z"): the mean from the strips' near-square cells (the grid's
# local geometry, the median node), n_max in the parallelogram, whose 40-degree quads hold
# 1 / sin 40 = 1.56 x as many nodes per c^2: measured n_max / mean 1.63-1.67 for quads and
# 1.12-1.23 for triangles (split along the short diagonal) at h = 0.02, m = 1, 2, 3.
PADDING = {"grid": 1.15, "unstructured": 1.4, "patches quad": 1.8, "patches tri": 1.4}

# Measured bytes (scripts/bench/calibrate_budget.py; square, m = 1, 2, direct and iterative,
# 2e3 ... 1e6 DOFs, 1 and 2 ranks): a least-squares fit of peak_rss_mb, times 1.2 (base
# raised to the small m = 2 runs); the estimate is 0.9-1.5x the measured peak (module
# docstring).  The process: Python, numpy, PETSc, MPI (460e6 with numba and gmsh in that
# fit), and what it loads only when needed, each measured as the peak's difference
# (square, m = 2, h = 1/32, 2026-12-07) times the same 1.2: numba's JIT and LLVM where the
# kernels are not compiled ahead of time (+90 MB), gmsh and its mesh where rank 0 meshes
# (+40 MB; a rectangle's grid and the Z are made part by part without it, geometry.grid_parts
# and patch_parts).
BASE_BYTES = 350e6
JIT_BYTES = 110e6
GMSH_BYTES = 50e6
NODE_BYTES = 400  # node cloud and partition (every rank's, or its share of a grid's)
GRADIENT_SLOT_BYTES = 12  # per (point, neighbour) with gradients, consumed cell by cell
VALUE_SLOT_BYTES = 60  # per (point, neighbour), values only (boundary points)
PAIR_BYTES = 18  # per coupled node pair of one cell (Gram assembly, transient)
# per nonzero of the DOF matrices (M, K, A_const, Jacobian; PETSc); 60 until A_const was
# summed without scipy's temporaries (session 43: the 1e6-DOF m = 1 peak 9788 -> 6718 MB)
ENTRY_BYTES = 45
FACTOR_BYTES = 12  # per nonzero of the Cholesky factor (MUMPS), direct solvers only

# The domain's value operator S is not built from this size (CSR bytes on some rank) on:
# its arrays and their PETSc copy were the build's peak (m = 2, 8 x 8 points: ~7-10 KB per
# DOF each); an integration against the shape functions then takes MLS values block by
# block (PointGradients.integrate_values), one MLS pass each (2-4 at the start of a run).
# Below it S is built with the Gram data (no extra pass) and released for the time loop
# from 16 MB on (simulation.py).  The estimate then drops the domain points' slots.
BUILT_VALUE_BYTES = 128_000_000


@dataclass(frozen=True)
class Size:
    """What a run builds, counted before it is built (floats: they may be astronomically large).

    Attributes
    ----------
    n_nodes, n_cells : float
        EFG nodes N and background cells.
    n_domain_points, n_boundary_points : float
        Gauss points in the cells and on the boundary segments.
    neighbours : float
        Padded neighbour-list length n_max (nodes whose support covers a point).
    cell_nodes : float
        Nodes touching one cell's Gauss points (the Gram assembly pairs them all).
    reach : float
        Nodes coupled to one node in the stiffness matrix (supports that overlap).
    meshed_on_root : bool
        Rank 0 meshes the cloud with gmsh and partitions it (not a rectangle's grid, which
        each rank makes its part of).
    """

    n_nodes: float
    n_cells: float
    n_domain_points: float
    n_boundary_points: float
    neighbours: float
    cell_nodes: float
    reach: float
    meshed_on_root: bool = True

    @property
    def n_dofs(self) -> float:
        return 2 * self.n_nodes

    @property
    def matrix_entries(self) -> float:
        """Nonzeros of one DOF matrix (2 x 2 blocks of every coupled node pair)."""
        return 4 * self.n_nodes * self.reach

    @property
    def factor_entries(self) -> float:
        """Nonzeros of a Cholesky factor: nnz(A) times a nested-dissection fill ~ log N."""
        n_dofs = self.n_dofs
        fill = max(1.0, 0.6 * (math.log2(max(n_dofs, 1.0)) - 7))
        return min(self.matrix_entries * fill, n_dofs * (n_dofs + 1) / 2)


def memory_per_rank(size: Size, n_ranks: int, direct: bool = True, jit: bool = False) -> float:
    """Estimated peak resident bytes of the largest of ``n_ranks`` ranks running ``size``.

    ``direct``: the linear solver factors A_const (a factor of ``size.factor_entries``);
    an iterative one (CG + GAMG) keeps no factor.  ``jit``: the kernels are compiled by
    numba's JIT in the run (no module compiled ahead of time).
    """
    gradient_points = size.n_domain_points + size.n_nodes
    # S's entries: the padded lists over the largest padding (the mean at least); unbuilt if large
    entries = size.n_domain_points * size.neighbours / max(PADDING.values())
    if 12 * entries / n_ranks >= BUILT_VALUE_BYTES:
        gradient_points = size.n_nodes
    shared = (
        GRADIENT_SLOT_BYTES * gradient_points * size.neighbours
        + VALUE_SLOT_BYTES * size.n_boundary_points * size.neighbours
        + PAIR_BYTES * size.n_cells * size.cell_nodes * size.cell_nodes
        + ENTRY_BYTES * size.matrix_entries
        + (FACTOR_BYTES * size.factor_entries if direct else 0.0)
    )
    process = BASE_BYTES + (JIT_BYTES if jit else 0.0)
    if size.meshed_on_root:
        return process + GMSH_BYTES + NODE_BYTES * size.n_nodes + shared / n_ranks
    return process + (NODE_BYTES * size.n_nodes + shared) / n_ranks


# --------------------------------------------------------------------------- sizes


def _steps(length: float, h: float) -> float:
    """Cells of a transfinite edge: ceil(L / h), as geometry._build_box makes them."""
    ratio = length / h
    return ratio if ratio > 1e15 else max(1, math.ceil(ratio - 1e-9))


def _polygon_extent(vertices) -> tuple[float, float]:
    """(area, perimeter) of a closed polygon (shoelace formula; vertices as pairs)."""
    points = [(float(x), float(y)) for x, y in vertices]
    edges = list(zip(points, points[1:] + points[:1], strict=True))
    area = 0.5 * sum(x0 * y1 - x1 * y0 for (x0, y0), (x1, y1) in edges)
    perimeter = sum(math.hypot(x1 - x0, y1 - y0) for (x0, y0), (x1, y1) in edges)
    return abs(area), perimeter


def _padding(scene) -> float:
    """n_max / mean neighbours: structured grids (Shape.box), patches (Shape.patches) or not."""
    from parefg.geometry.shapes import SHAPES

    shape = SHAPES[scene.domain["shape"]]
    if shape.patches is not None:
        return PADDING[f"patches {scene.discretization.cells}"]
    return PADDING["grid" if shape.box is not None else "unstructured"]


def _size(scene, n_nodes, n_cells, n_segments, kappa: float, alpha: float) -> Size:
    """The size of a mesh given its counts and its local geometry around a node.

    In units of the local spacing c (supports have radius s c): ``kappa`` nodes per c^2,
    cells of area ``alpha`` c^2.  A point has kappa pi s^2 neighbours on average; a cell's
    points touch kappa |cell + disc of radius s c| nodes (Steiner: area + perimeter s c +
    pi s^2 c^2, perimeter ~ 4.5 sqrt(area)); a node couples with those within 2 s c.
    """
    s, q = scene.discretization.support, scene.discretization.quadrature
    mean = kappa * math.pi * s * s
    cell = kappa * (alpha + 4.5 * math.sqrt(alpha) * s + math.pi * s * s)
    return Size(
        n_nodes=n_nodes,
        n_cells=n_cells,
        n_domain_points=n_cells * q * q,
        n_boundary_points=n_segments * q,
        neighbours=min(n_nodes, _padding(scene) * mean + 1),
        cell_nodes=min(n_nodes, cell + 1),
        reach=min(n_nodes, 4 * mean + 1),
        meshed_on_root=scene_grid(scene) is None and not patched(scene),
    )


def grid_size(scene, lx: float, ly: float) -> Size:
    """Size of the transfinite grid of a rectangle lx x ly (shapes "square", "rectangle")."""
    n_x, n_y = _steps(lx, scene.discretization.h), _steps(ly, scene.discretization.h)
    hx, hy = lx / n_x, ly / n_y
    triangles = scene.discretization.cells == CellType.TRI
    spacing = 0.5 * (hx + hy) * (TRIANGLE_GRID_SPACING if triangles else 1.0)
    kappa = (spacing / hx) * (spacing / hy)  # ratios: h = 1e-300 must not underflow
    alpha = 1 / kappa / (2 if triangles else 1)
    n_cells = n_x * n_y * (2 if triangles else 1)
    n_nodes = (n_x + 1) * (n_y + 1)
    return _size(scene, n_nodes, n_cells, 2 * (n_x + n_y), kappa, alpha)


def patches_size(scene, patches) -> Size:
    """Size of a domain meshed as conforming transfinite patches (:class:`Patches`, "z").

    Counts are exact: F quads in all, B boundary segments and, by Euler's formula for a
    simply connected conforming quad mesh (V - E + F = 1, 4 F = 2 E - B), V = 1 + F + B / 2
    nodes; triangles split each quad in two.  The local geometry is a grid's of square cells.
    A curve has at least m cells (``min_cells`` of :class:`~parefg.geometry.shapes.Shape`).
    """
    h = scene.discretization.h

    def steps(length: float) -> float:
        return max(scene.discretization.degree, _steps(length, h))

    quads = sum(steps(a) * steps(b) for a, b in patches.sides)
    n_segments = sum(steps(length) for length in patches.boundary)
    triangles = scene.discretization.cells == CellType.TRI
    kappa = TRIANGLE_GRID_SPACING**2 if triangles else 1.0
    alpha = 1 / kappa / (2 if triangles else 1)
    n_cells = quads * (2 if triangles else 1)
    return _size(scene, 1 + quads + n_segments / 2, n_cells, n_segments, kappa, alpha)


def unstructured_size(scene, area: float, perimeter: float, h: float | None = None) -> Size:
    """Size of gmsh's Frontal-Delaunay mesh (recombined for quads) of a domain A, P at h.

    ``h`` defaults to the scene's (another size: :meth:`Budget.size_floor`).
    """
    h = scene.discretization.h if h is None else h
    boundary_nodes = perimeter / h
    n_nodes = UNSTRUCTURED_DENSITY * area / h / h + 0.5 * boundary_nodes + 3
    # Euler: 2 N - B - 2 triangles with B boundary nodes; about half as many quads
    n_cells = (
        n_nodes - 0.5 * boundary_nodes
        if scene.discretization.cells == CellType.QUAD
        else 2 * n_nodes - boundary_nodes
    )
    return _size(
        scene, n_nodes, n_cells, boundary_nodes + 3, *UNSTRUCTURED_LOCAL[scene.discretization.cells]
    )


def estimate_scene(scene) -> Size | None:
    """The size of ``scene``'s run from its domain and discretization; None for a .geo file.

    A .geo domain's area is known only once gmsh has read the file
    (:meth:`Budget.check_extent`).  Not collective; pure arithmetic on the scene.
    """
    from parefg.geometry.shapes import SHAPES

    shape = SHAPES[scene.domain["shape"]]
    if shape.box is not None:  # a structured grid
        _, (lx, ly) = shape.box(scene.domain)
        return grid_size(scene, float(lx), float(ly))
    if shape.patches is not None:
        return patches_size(scene, shape.patches(scene.domain))
    if shape.outline is not None:
        return unstructured_size(scene, *_polygon_extent(shape.outline(scene.domain)[0]))
    return None


def cloud_size(scene, cloud) -> Size:
    """The size of ``scene``'s run on an actual node cloud: its counts and local geometry.

    kappa and alpha (see :func:`_size`) are medians over nodes and cells, so that graded
    meshes (fine and coarse parts) and boundary nodes do not skew them.
    """
    import numpy as np

    from parefg.geometry.cloud import signed_areas

    dual_area = np.zeros(cloud.n_nodes)  # (n_nodes,) each cell's area shared by its corners
    alphas = [np.empty(0)]
    for cells in (cloud.quads, cloud.triangles):
        area = np.abs(signed_areas(cloud.coords, cells))  # (n_cells,)
        np.add.at(dual_area, cells.ravel(), np.repeat(area / cells.shape[1], cells.shape[1]))
        alphas.append(area / cloud.spacing[cells].mean(axis=1) ** 2)
    used = dual_area > 0
    kappa = float(np.median(cloud.spacing[used] ** 2 / dual_area[used])) if used.any() else 1.0
    alpha = np.concatenate(alphas)
    n_cells = len(alpha)
    return _size(
        scene,
        float(cloud.n_nodes),
        float(n_cells),
        float(len(cloud.segments)),
        kappa,
        float(np.median(alpha)) if n_cells else 1.0,
    )


# --------------------------------------------------------------------------- the limit
