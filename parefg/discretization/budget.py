"""Problem-size budget: refuse, before anything is built, a run the machine cannot hold (SPEC 9).

:class:`Budget` compares the estimate of :mod:`parefg.discretization.size_estimate` (the
node count, neighbours, matrix entries and peak memory of the largest rank, from the
scene alone or from its node cloud) with the memory the run may use on each machine:
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
from typing import Protocol

from petsc4py import PETSc

from parefg.discretization import aot
from parefg.discretization.size_estimate import (
    Size,
    cloud_size,
    estimate_scene,
    memory_per_rank,
    unstructured_size,
)
from parefg.errors import InputError
from parefg.parallel import raise_everywhere
from parefg.petsc_options import EXACT_FACTORIZATIONS

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


def _cgroup_limit() -> float:
    """This process's cgroup memory limit (v2 or v1) in bytes; inf without one."""
    for limit_file, _ in CGROUP_FILES:
        try:
            limit = Path(limit_file).read_text().strip()
        except OSError:
            continue
        if limit != "max" and float(limit) < 2**60:
            return float(limit)
    return math.inf


def machine_capacity() -> float:
    """Bytes the machine could give a run at all: the least of MemTotal, cgroup and ulimit limits.

    Unlike :func:`machine_memory` it does not move with the machine's load, so a decision
    taken on it (the mesh size floor) gives the same mesh in every run on this machine.
    """
    total = _proc_kib("/proc/meminfo", "MemTotal")
    if total is None:
        try:
            total = float(os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
        except (ValueError, OSError, AttributeError):
            total = math.inf
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    address_space = math.inf if soft == resource.RLIM_INFINITY else float(soft)
    return min(total, _cgroup_limit(), address_space)


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


class BudgetedDiscretization(Protocol):
    """The node spacing and the support dilation of a scene's ``[discretization]``."""

    @property
    def h(self) -> float: ...

    @property
    def support(self) -> float: ...


class BudgetedSolver(Protocol):
    """The method and PETSc options of a scene's ``[solver]``."""

    @property
    def method(self) -> str: ...

    @property
    def options(self) -> dict[str, str]: ...


class BudgetedScene(Protocol):
    """What the budget reads of a scene itself (the estimates read the rest).

    A protocol, not the Scene class: scenes sit above the discretization in the layers.
    """

    name: str
    discretization: BudgetedDiscretization
    solver: BudgetedSolver


def uses_direct_solver(scene: BudgetedScene) -> bool:
    """Whether the run factors its matrices: by its -pc_type, else by its method ("direct").

    The command line's -pc_type (in PETSc's options database) wins over the scene's
    [solver] pc_type, which wins over the method's own preconditioner: the order in which
    the step solver reads them (parefg.petsc_options.scene_options).
    """
    options = PETSc.Options()
    pc_type = options.getString("pc_type") if options.hasName("pc_type") else None
    pc_type = pc_type or scene.solver.options.get("pc_type")
    if pc_type:
        return pc_type in EXACT_FACTORIZATIONS
    return scene.solver.method == "direct"


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
    floor_rank_bytes : float or None
        Bytes per rank that :meth:`size_floor` budgets for: --max-memory, else a share of
        the machine's capacity (not of its free memory, which moves with the load, so that
        a .geo file is meshed alike in every run on one machine).  None: ``rank_bytes``.
    """

    scene: BudgetedScene
    rank_bytes: float
    host_ranks: int
    n_ranks: int
    given: bool
    floor_rank_bytes: float | None = None

    def refusal(
        self, size: Size, found: str = "needs", slack: float = 1.0, rank_bytes: float | None = None
    ) -> str | None:
        """The one-line reason ``size`` does not fit (in ``slack`` times the limit), or None.

        ``rank_bytes`` replaces the budget's own limit per rank.  Not collective.
        """
        scene = self.scene
        what = (
            f"scene {scene.name}: discretization.h = {scene.discretization.h:g}"
            f" with support = {scene.discretization.support:g}"
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
        needed = memory_per_rank(
            size, self.n_ranks, uses_direct_solver(scene), jit=not aot.available()
        )
        if needed <= slack * (self.rank_bytes if rank_bytes is None else rank_bytes):
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
        bisection on log h (the estimate only grows as h shrinks).  The limit is
        ``floor_rank_bytes`` (the machine's capacity, not its load), so the floor and the
        mesh are the same in every run on one machine; a mesh refined beyond the free
        memory is then refused by :meth:`check_cloud`.  Not collective.
        """
        h = self.scene.discretization.h
        limit = self.rank_bytes if self.floor_rank_bytes is None else self.floor_rank_bytes

        def fits(size_h: float) -> bool:
            size = unstructured_size(self.scene, area, perimeter, size_h)
            return self.refusal(size, rank_bytes=limit) is None

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
        raise_everywhere(comm, None if message is None else InputError(message), root=0)


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
    if max_memory is not None:
        machine = capacity = max_memory * GB
    else:
        machine = MEMORY_FRACTION * machine_memory()
        capacity = MEMORY_FRACTION * machine_capacity()
    share = (machine / host_ranks, host_ranks)
    # the tightest machine decides (min of (bytes per rank, ranks)), the same on every rank
    rank_bytes, tightest_ranks = comm.allreduce(share, op=MPI.MIN)
    floor_rank_bytes = comm.allreduce(capacity / host_ranks, op=MPI.MIN)
    return Budget(
        scene, rank_bytes, tightest_ranks, comm.size, max_memory is not None, floor_rank_bytes
    )


def check_problem_size(comm, scene, max_memory: float | None = None) -> Budget:
    """Refuse ``scene`` (InputError on every rank) if its run cannot fit; return its budget.

    Collective.  Call before anything is created: a refused scene leaves nothing behind.
    """
    budget = make_budget(comm, scene, max_memory)
    budget.check_scene(comm)
    return budget
