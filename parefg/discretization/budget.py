"""Problem-size budget: refuse, before anything is built, a run the machine cannot hold (SPEC 9).

From the validated scene alone (microseconds of arithmetic, no gmsh) :func:`estimate_scene`
predicts the size of a run: the node count N from the domain's area A and perimeter P
at spacing h, the background cells, the quadrature points, the MLS neighbours per point
(the nodes within s c_I of a point: about pi s^2 per point at unit node density, capped by
N) and from those the peak resident memory of the largest rank::

    memory = base + (per-rank share of)  point data  n_points * n_max * bytes per slot
                                       + Gram pairs   n_cells * G^2    (nodes of a cell's points)
                                       + matrices     nnz(A) = 4 N R   (R = nodes within 2 s c)
                                       + Cholesky     nnz(L) = nnz(A) * fill(2 N)

The coefficients are measured (``scripts/bench/calibrate_budget.py``: the estimate is within a
factor 2 of summary.json's ``peak_rss_mb``); the direct factorization's fill is a rough
fit of MUMPS's nested-dissection fill on these stencils, growing like log N.

:class:`Budget` compares such an estimate with the memory the run may use on each machine:
by default 80 % of what the machine has available (``MemAvailable``, a cgroup limit or
``ulimit -v``, whichever is least), shared by the ranks on that machine; ``--max-memory GB``
replaces it.  The verdict is taken on rank 0 and broadcast, so every rank refuses together.
The same budget is checked again where more is known: for a ``shape = "geo"`` domain once
gmsh has read the file (its surfaces' bounding box bounds the area), and once the node cloud
exists (the true node count and spacing), before any MLS work.
"""

from __future__ import annotations

import math
import os
import resource
from dataclasses import dataclass
from pathlib import Path

from parefg.errors import InputError

GB = 1e9  # --max-memory and the messages count decimal gigabytes
# Share of the available memory a run may take by default (the machine is shared).
MEMORY_FRACTION = 0.8
# PETSc is built with 32-bit indices: DOFs and the nonzeros of one rank's rows must fit.
MAX_INDEX = 2**31 - 1
# The node-cloud check refuses only beyond this factor of the limit (estimates differ ~10 %).
CLOUD_SLACK = 1.25
# Budget.size_floor searches element sizes in [FLOOR_RANGE h, h] (gmsh's own tolerance on
# sizes is about 1e-12 of the model); 60 halvings of that log range are exact to round-off.
FLOOR_RANGE = 1e-9
FLOOR_BISECTIONS = 60

# Unstructured gmsh meshes at target size h (measured on polygons, z and .geo domains):
# N = 1.16 A / h^2 + 0.5 P / h (1.16 ~ 2 / sqrt 3: equilateral triangles).
UNSTRUCTURED_DENSITY = 1.16
# Local geometry in units of the node spacing c_I: (nodes per c^2, cell area / c^2), the
# medians measured on gmsh's unstructured meshes, graded ones included (cloud_size).
UNSTRUCTURED_LOCAL = {"quad": (1.03, 0.97), "tri": (1.155, 0.43)}
# Mean incident edge of a node of a structured triangle grid: (4 + 2 sqrt 2) / 6 steps.
TRIANGLE_GRID_SPACING = (4 + 2 * math.sqrt(2)) / 6
# n_max / (mean neighbours): padded neighbour lists are as long as the fullest point's.
PADDING = {"grid": 1.15, "unstructured": 1.4}

# Measured bytes (scripts/bench/calibrate_budget.py): python, numpy, PETSc, MPI, numba, gmsh
BASE_BYTES = 260e6
NODE_BYTES = 400  # node cloud and partition, held by every rank; gmsh's mesh on rank 0
GRADIENT_SLOT_BYTES = 170  # per (point, neighbour) with gradients: ShapeValues, operators
VALUE_SLOT_BYTES = 60  # per (point, neighbour), values only (boundary points)
PAIR_BYTES = 28  # per coupled node pair of one cell (Gram assembly, transient)
ENTRY_BYTES = 40  # per nonzero of the DOF matrices (M, K, G_D, A_const; scipy and PETSc)
FACTOR_BYTES = 16  # per nonzero of the Cholesky factors (A_const and mass, MUMPS)


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
    """

    n_nodes: float
    n_cells: float
    n_domain_points: float
    n_boundary_points: float
    neighbours: float
    cell_nodes: float
    reach: float

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


def memory_per_rank(size: Size, n_ranks: int) -> float:
    """Estimated peak resident bytes of the largest of ``n_ranks`` ranks running ``size``."""
    gradient_points = size.n_domain_points + size.n_nodes
    shared = (
        GRADIENT_SLOT_BYTES * gradient_points * size.neighbours
        + VALUE_SLOT_BYTES * size.n_boundary_points * size.neighbours
        + PAIR_BYTES * size.n_cells * size.cell_nodes * size.cell_nodes
        + ENTRY_BYTES * size.matrix_entries
        + FACTOR_BYTES * size.factor_entries
    )
    return BASE_BYTES + NODE_BYTES * size.n_nodes + shared / n_ranks


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
    """n_max / mean neighbours: structured grids for the box shapes (Shape.box)."""
    from parefg.geometry.shapes import SHAPES

    structured = SHAPES[scene.domain["shape"]].box is not None
    return PADDING["grid" if structured else "unstructured"]


def _size(scene, n_nodes, n_cells, n_segments, kappa: float, alpha: float) -> Size:
    """The size of a mesh given its counts and its local geometry around a node.

    In units of the local spacing c (supports have radius s c): ``kappa`` nodes per c^2,
    cells of area ``alpha`` c^2.  A point has kappa pi s^2 neighbours on average; a cell's
    points touch kappa |cell + disc of radius s c| nodes (Steiner: area + perimeter s c +
    pi s^2 c^2, perimeter ~ 4.5 sqrt(area)); a node couples with those within 2 s c.
    """
    s, q = scene.support, scene.quadrature
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
    )


def grid_size(scene, lx: float, ly: float) -> Size:
    """Size of the transfinite grid of a rectangle lx x ly (shapes "square", "rectangle")."""
    n_x, n_y = _steps(lx, scene.h), _steps(ly, scene.h)
    hx, hy = lx / n_x, ly / n_y
    triangles = scene.cells == "tri"
    spacing = 0.5 * (hx + hy) * (TRIANGLE_GRID_SPACING if triangles else 1.0)
    kappa = (spacing / hx) * (spacing / hy)  # ratios: h = 1e-300 must not underflow
    alpha = 1 / kappa / (2 if triangles else 1)
    n_cells = n_x * n_y * (2 if triangles else 1)
    n_nodes = (n_x + 1) * (n_y + 1)
    return _size(scene, n_nodes, n_cells, 2 * (n_x + n_y), kappa, alpha)


def unstructured_size(scene, area: float, perimeter: float, h: float | None = None) -> Size:
    """Size of gmsh's Frontal-Delaunay mesh (recombined for quads) of a domain A, P at h.

    ``h`` defaults to the scene's (another size: :meth:`Budget.size_floor`).
    """
    h = scene.h if h is None else h
    boundary_nodes = perimeter / h
    n_nodes = UNSTRUCTURED_DENSITY * area / h / h + 0.5 * boundary_nodes + 3
    # Euler: 2 N - B - 2 triangles with B boundary nodes; about half as many quads
    n_cells = (
        n_nodes - 0.5 * boundary_nodes if scene.cells == "quad" else 2 * n_nodes - boundary_nodes
    )
    return _size(scene, n_nodes, n_cells, boundary_nodes + 3, *UNSTRUCTURED_LOCAL[scene.cells])


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


def _proc_kib(path: str, key: str) -> float | None:
    """The ``key:  N kB`` line of a /proc file, in bytes; None if absent or unreadable."""
    try:
        for line in Path(path).read_text().splitlines():
            if line.startswith(key + ":"):
                return float(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def _meminfo_available() -> float:
    """Bytes the kernel says can be allocated without swapping (MemAvailable)."""
    available = _proc_kib("/proc/meminfo", "MemAvailable")
    if available is not None:
        return available
    try:  # not Linux: free physical pages
        return float(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return math.inf


# (limit, usage) files of cgroup v2 and v1, as mounted inside a container
CGROUP_FILES = (
    ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory.current"),
    ("/sys/fs/cgroup/memory/memory.limit_in_bytes", "/sys/fs/cgroup/memory/memory.usage_in_bytes"),
)


def _cgroup_headroom() -> float:
    """Bytes left under this process's cgroup memory limit (v2 or v1); inf without one."""
    for limit_file, usage_file in CGROUP_FILES:
        try:
            limit = Path(limit_file).read_text().strip()
            usage = float(Path(usage_file).read_text().strip())
        except (OSError, ValueError):
            continue
        if limit != "max" and float(limit) < 2**60:  # v1 says "unlimited" with ~2**63
            return max(0.0, float(limit) - usage)
    return math.inf


def _address_space_headroom() -> float:
    """Bytes of address space left under ``ulimit -v`` (RLIMIT_AS); inf when unlimited."""
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft == resource.RLIM_INFINITY:
        return math.inf
    used = _proc_kib("/proc/self/status", "VmSize") or 0.0
    return max(0.0, soft - used)


def machine_memory() -> float:
    """Bytes this process may take now: the least of MemAvailable, cgroup and ulimit headroom."""
    return min(_meminfo_available(), _cgroup_headroom(), _address_space_headroom())


def _format_count(count: float) -> str:
    """A count for a message: 0.25, 38, 4225, 1.0e+12, "more than 1e300"."""
    if not math.isfinite(count):
        return "more than 1e300"
    if count >= 1e6:
        return f"{count:.1e}"
    return f"{count:.2g}" if count < 10 else f"{count:.0f}"


def _about(count: float) -> str:
    """An estimated count for a message: "about 4225", or "more than 1e300"."""
    return f"about {_format_count(count)}" if math.isfinite(count) else _format_count(count)


@dataclass(frozen=True)
class Budget:
    """The memory a scene's run may use, and the checks against it.

    Every check is collective or rank-0-only as documented; all of them refuse with
    :class:`InputError` (exit 2) and one line giving the estimate and the limit.

    Attributes
    ----------
    scene : Scene
        The validated scene (its name, domain and discretization).
    rank_bytes : float
        Bytes allowed to each rank: the tightest machine's limit over its rank count.
    host_ranks : int
        Ranks on that machine (the limit is shown per machine: rank_bytes * host_ranks).
    n_ranks : int
        Ranks of the run (the shared work is split among them).
    given : bool
        Whether the limit is --max-memory (else the machine's available memory).
    """

    scene: object
    rank_bytes: float
    host_ranks: int
    n_ranks: int
    given: bool

    def refusal(self, size: Size, found: str = "needs", slack: float = 1.0) -> str | None:
        """The one-line reason ``size`` does not fit (in ``slack`` times the limit), or None.

        Not collective.
        """
        scene = self.scene
        what = (
            f"scene {scene.name}: discretization.h = {scene.h:g} with support = {scene.support:g}"
            f" {found} {_about(size.n_nodes)} nodes"
        )
        if not size.n_dofs <= MAX_INDEX:
            return (
                f"{what} ({_about(size.n_dofs)} DOFs); PETSc's 32-bit indices allow at most "
                f"{MAX_INDEX} DOFs; use a larger h"
            )
        if not size.matrix_entries / self.n_ranks <= MAX_INDEX:
            return (
                f"{what} ({_about(size.matrix_entries / self.n_ranks)} matrix entries per rank); "
                f"PETSc's 32-bit indices allow at most {MAX_INDEX} per rank; use a larger h, "
                "a smaller support or more ranks"
            )
        needed = memory_per_rank(size, self.n_ranks)
        if needed <= slack * self.rank_bytes:
            return None
        limit = "--max-memory" if self.given else "80% of the available memory"
        return (
            f"{what}, {_about(size.neighbours)} neighbours per point and "
            f"{_about(needed * self.host_ranks / GB)} GB of memory on this machine "
            f"(limit {_format_count(self.rank_bytes * self.host_ranks / GB)} GB: {limit}); "
            "use a larger h or smaller support, or raise --max-memory GB if the machine has it"
        )

    def check_scene(self, comm) -> None:
        """Refuse the scene from its parameters alone (a .geo: later).  Collective."""
        size = estimate_scene(self.scene)
        self._decide(comm, None if size is None else self.refusal(size))

    def check_extent(self, area: float, perimeter: float) -> None:
        """Refuse a .geo domain of this area and perimeter before gmsh meshes it.

        Not collective: called on rank 0 inside meshing, whose InputError every rank raises.
        """
        message = self.refusal(unstructured_size(self.scene, area, perimeter))
        if message is not None:
            raise InputError(message)

    def size_floor(self, area: float, perimeter: float) -> float:
        """The smallest element size at which a domain of this extent still fits (<= h).

        gmsh clamps every element size it computes (point sizes, MeshSize, fields,
        curvature) to [Mesh.MeshSizeMin, Mesh.MeshSizeMax]; with this floor as
        MeshSizeMin, a .geo file whose sizes ask for less (``MeshSize{...} = 1e-9``, a
        Threshold field's SizeMin) gets a mesh no finer than a bounding box filled at
        the floor, which the budget holds, instead of exhausting the machine inside
        gmsh.  Legitimate refinement is untouched while the budget allows it.  Found by
        bisection on log h (the estimate only grows as h shrinks).  Not collective.
        """
        h = self.scene.h

        def fits(size_h: float) -> bool:
            size = unstructured_size(self.scene, area, perimeter, size_h)
            return self.refusal(size) is None

        fine, coarse = h * FLOOR_RANGE, h
        if fits(fine):
            return fine
        if not fits(coarse):
            return h
        for _ in range(FLOOR_BISECTIONS):
            middle = math.sqrt(fine * coarse)
            fine, coarse = (fine, middle) if fits(middle) else (middle, coarse)
        return coarse

    def check_cloud(self, comm, cloud) -> None:
        """Refuse the run once the node cloud exists, before any MLS work.  Collective.

        A .geo file with refining mesh sizes can exceed what its bounding box predicts.
        Only an excess beyond the estimates' own spread (CLOUD_SLACK) is refused here, so
        a scene the parameters let through is not refused for the same size.
        """
        message = None
        if comm.rank == 0:
            size = cloud_size(self.scene, cloud)
            message = self.refusal(size, found="meshed with", slack=CLOUD_SLACK)
        self._decide(comm, message)

    def _decide(self, comm, message: str | None) -> None:
        """Raise rank 0's verdict on every rank (no rank judges round-off on its own)."""
        message = comm.bcast(message, root=0)
        if message is not None:
            raise InputError(message)


def make_budget(comm, scene, max_memory: float | None = None) -> Budget:
    """The budget of ``scene`` on ``comm``: --max-memory GB per machine, or its available memory.

    Collective (ranks per machine, and the tightest machine's share).

    Raises
    ------
    InputError
        ``max_memory`` not a finite number > 0.
    """
    if max_memory is not None and not (math.isfinite(max_memory) and max_memory > 0):
        raise InputError(f"--max-memory: must be a number of GB > 0, got {max_memory!r}")
    from mpi4py import MPI

    host = comm.Split_type(MPI.COMM_TYPE_SHARED)
    host_ranks = host.size
    host.Free()
    machine = max_memory * GB if max_memory is not None else MEMORY_FRACTION * machine_memory()
    share = (machine / host_ranks, host_ranks)
    # the tightest machine decides (min of (bytes per rank, ranks)), the same on every rank
    rank_bytes, tightest_ranks = comm.allreduce(share, op=MPI.MIN)
    return Budget(scene, rank_bytes, tightest_ranks, comm.size, max_memory is not None)


def check_problem_size(comm, scene, max_memory: float | None = None) -> Budget:
    """Refuse ``scene`` (InputError on every rank) if its run cannot fit; return its budget.

    Collective.  Call before anything is created: a refused scene leaves nothing behind.
    """
    budget = make_budget(comm, scene, max_memory)
    budget.check_scene(comm)
    return budget
