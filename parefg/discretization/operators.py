"""The discrete EFG operators of one run, assembled once (SPEC 2, 3, 5).

scene -> node cloud -> partition -> MLS at this rank's quadrature points -> PETSc
operators.  The cloud is meshed on rank 0 and partitioned there, each rank receiving its
part (:mod:`parefg.geometry.distribute`), except a rectangle's grid and the Z's patches,
which each rank makes its own part of (:mod:`parefg.geometry.grid_parts`,
:mod:`parefg.geometry.patch_parts`).  Everything here is constant
over the run (small deformation): mass M, stiffness K, the Dirichlet operator D (penalty
or Nitsche: built in :mod:`.boundary_operators`), and the point operators
(:mod:`.point_set`) that evaluate u_h (and its gradient) at quadrature points, Gamma_C
points and nodes.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from mpi4py import MPI
from petsc4py import PETSc

from parefg.discretization.assembly import interleaved, value_operator
from parefg.discretization.boundary_operators import BoundaryOperators
from parefg.discretization.budget import Budget, check_problem_size
from parefg.discretization.consistent_gradients import ConsistencySums, node_corrections
from parefg.discretization.dirichlet import DirichletPart
from parefg.discretization.domain_assembly import BlockPasses, value_rows
from parefg.discretization.ghosts import add_ghosts, evaluation_box
from parefg.discretization.mls import MLS, MLSError, ShapeValues
from parefg.discretization.point_gradients import PointGradients, sorted_gradients
from parefg.discretization.point_set import PointSet, point_operator
from parefg.discretization.quadrature import Quadrature, cell_quadrature
from parefg.discretization.size_estimate import BUILT_VALUE_BYTES
from parefg.geometry.cloud import NodeCloud
from parefg.geometry.distribute import partition_on_root
from parefg.geometry.gmsh_mesh import mesh_on_root
from parefg.geometry.grid_parts import mesh_by_parts
from parefg.geometry.partition import Partition
from parefg.geometry.patch_parts import mesh_by_patches
from parefg.parallel import add_entries, global_columns, owned_rows, raise_everywhere
from parefg.profiling import phase


@dataclass
class Discretization:
    """Node cloud, partition and the constant operators of a run (built collectively)."""

    comm: object
    cloud: NodeCloud  # the nodes this rank holds: its own and its ghosts (and the boundary's)
    partition: Partition
    node_range: tuple[int, int]  # this rank's nodes [start, stop) (global numbers)
    n_nodes: int  # global
    mass: PETSc.Mat  # M = int rho phi_I phi_J
    stiffness: PETSc.Mat  # K = a(phi_J, phi_I)
    dirichlet: PETSc.Mat  # D of the Dirichlet methods (parefg.discretization.dirichlet)
    contact_pattern: sp.csr_matrix  # owned rows of the Gamma_C coupling pattern (zeros)
    domain: PointSet
    nodes: PointSet
    boundary: dict[str, PointSet] = field(default_factory=dict)  # by boundary-condition name
    dirichlet_parts: dict[str, DirichletPart] = field(default_factory=dict)  # their load, beta
    contact: PointSet | None = None  # all Gamma_C points (every contact part)
    n_contact: int = 0  # Gamma_C points on all ranks (contact.rows range over 0..n_contact-1)
    timings: dict[str, float] = field(default_factory=dict)
    condition_range: tuple[float, float] = (1.0, 1.0)  # min, max MLS moment condition number
    symmetric: bool = True  # K's symmetry: False with VCI (Petrov-Galerkin test gradients)
    # this rank's (owned) global node ids of each coarse-trace group of the Dirichlet and
    # contact parts, the nodes its points reach: the iterative method's finest smoother
    # solves them together (parefg.timestepping.linear_solver.configure_finest_blocks)
    trace_blocks: list[np.ndarray] = field(default_factory=list)

    @property
    def n_dofs(self) -> int:
        return 2 * self.n_nodes

    @property
    def owned_coords(self) -> np.ndarray:
        """(n_owned, 2) this rank's own nodes' coordinates, in global order."""
        return self.cloud.coords[self.cloud.run_of(*self.node_range)]

    @property
    def owned(self) -> dict[str, sp.csr_matrix]:
        """This rank's rows of "mass", "stiffness", "dirichlet" as scipy CSR (global columns).

        Copies made on each access from the PETSc matrices (the values they were built from,
        explicit zeros included), for inspecting them: no scipy twin of a PETSc matrix is
        kept, and the step matrices are combined by :meth:`combined_rows`, which copies only
        what it sums.  Not collective.
        """
        matrices = {"mass": self.mass, "stiffness": self.stiffness, "dirichlet": self.dirichlet}
        return {name: scipy_rows(matrix) for name, matrix in matrices.items()}

    def combined_rows(self, mass_coefficient: float, reserve_contact: bool) -> sp.csr_matrix:
        """This rank's rows of mass_coefficient M + K + D as scipy CSR (global columns),
        with the Gamma_C pattern reserved (explicit zeros) where ``reserve_contact``.

        The pattern is the union of the terms' (entries summing to 0 are kept).  M's
        entries are placed into K's by position (K's pattern holds M's, :func:`_mass_slots`),
        and D and the reserved pattern, which touch only the rows near the boundary, are
        merged into those rows alone: at 2e5 DOFs (m = 1) 0.6 s against 3.3 s for scipy's
        sums and a COO pass over every entry.  The values are those sums' (x + y + 0 in the
        same order).  Not collective.
        """
        stiffness = scipy_rows(self.stiffness)
        matrix = stiffness
        if mass_coefficient:
            mass = scipy_rows(self.mass)
            slots = _mass_slots(stiffness, mass)
            if slots is None:  # not M's layout within K: scipy's sum (drops exact zeros)
                matrix = (mass_coefficient * mass + stiffness).tocsr()
            else:  # in place: scipy_rows made the arrays for this call
                stiffness.data[slots] = mass_coefficient * mass.data + stiffness.data[slots]
        boundary = scipy_rows(self.dirichlet).tocoo()
        rows, cols, data = [boundary.row], [boundary.col], [boundary.data]
        if reserve_contact:
            pattern = self.contact_pattern.tocoo()
            rows, cols, data = (
                rows + [pattern.row],
                cols + [pattern.col],
                data + [np.zeros(pattern.nnz)],
            )
        return add_entries(matrix, np.concatenate(rows), np.concatenate(cols), np.concatenate(data))

    def create_vec(self) -> PETSc.Vec:
        """A zero DOF vector with this rank's block.  Collective."""
        return self.mass.createVecRight()


def scene_cloud_on_root(comm, scene, budget: Budget | None = None):
    """The scene's node cloud, meshed (or read from a cache) on rank 0, None on the other
    ranks (:func:`~parefg.geometry.gmsh_mesh.mesh_on_root`).  Collective.

    The one place a run's mesh inputs are taken from its scene: the prebuilt meshes of
    scripts/setup/prebuild_scenes.py are keyed by these.
    """
    return mesh_on_root(
        comm,
        scene.domain,
        scene.discretization.h,
        scene.discretization.cells,
        scene.discretization.jitter,
        scene.discretization.seed,
        budget,
        min_cells=scene.discretization.degree,
    )


def _stiffness_blocks(gradient_gram: np.ndarray, lam: float, mu: float) -> np.ndarray:
    """2 x 2 blocks of K per scalar entry from S[p, a, b] = int d_a phi_I d_b phi_J.

    K[2I+a, 2J+b] = int lam d_a phi_I d_b phi_J
                    + mu (delta_ab grad phi_I . grad phi_J + d_b phi_I d_a phi_J).
    Returns (nnz, 2, 2).  One new (nnz, 2, 2) array and one temporary: at 1e5 nodes these
    are ~150 MB each, whose first touch costs more than the arithmetic (a 206082-DOF
    build: 0.84 -> 0.45 s against lam G + mu G^T + mu tr(G) I with its four temporaries,
    same bits).
    """
    mu_laplace = mu * (gradient_gram[:, 0, 0] + gradient_gram[:, 1, 1])  # (nnz,)
    blocks = np.multiply(gradient_gram, lam)
    blocks += mu * gradient_gram.transpose(0, 2, 1)
    blocks[:, 0, 0] += mu_laplace
    blocks[:, 1, 1] += mu_laplace
    blocks[:, 0, 1] += 0.0  # as adding mu tr(G) x 0 did: -0.0 becomes +0.0
    blocks[:, 1, 0] += 0.0
    return blocks


def _mass_blocks(gram: np.ndarray) -> np.ndarray:
    """The blocks of kron(G, I_2) that ``interleaved(..., diagonal_only=True)`` reads,
    blocks[p, a, a] = G[p], from a scalar Gram matrix given as (nnz, 1, 1).

    A read-only view with zero strides: the off-diagonal entries (G[p] too) are never read,
    and no (nnz, 2, 2) array is made (~150 MB at 1e5 nodes, whose first touch cost 0.2 s).
    """
    return np.lib.stride_tricks.as_strided(
        gram, shape=(len(gram), 2, 2), strides=(gram.strides[0], 0, 0), writeable=False
    )


def _points_and_weights(rule: Quadrature) -> tuple[np.ndarray, np.ndarray]:
    return rule.points, rule.weights


class _Builder(BoundaryOperators):
    """Collective construction of a Discretization from a scene.

    The constructor meshes and partitions the node cloud (everything the operators are
    built on); :meth:`build` evaluates MLS and assembles the domain operators here and the
    boundary ones in :class:`~parefg.discretization.boundary_operators.BoundaryOperators`.
    """

    def __init__(self, comm, scene, budget: Budget):
        self.comm, self.scene, self.budget = comm, scene, budget
        self.timings = {"mesh": 0.0, "neighbours": 0.0, "mls": 0.0, "assembly": 0.0}
        self.n_contact = 0
        with phase(self.timings, "mesh"):
            # a rectangle's grid or the Z's patches: each rank makes its own part (its
            # size is the estimate's)
            self.cloud, self.partition = (
                mesh_by_parts(comm, scene)
                or mesh_by_patches(comm, scene)
                or self._partitioned_on_root()
            )
            # the nodes whose supports reach where this rank evaluates MLS (ghosts)
            box = evaluation_box(self.cloud, self.partition, comm.rank, self._grouping())
            self.cloud = add_ghosts(
                comm, self.cloud, self.partition.node_ranges, scene.discretization.support, box
            )
        self.node_ranges = self.partition.node_ranges  # (comm.size + 1,)
        self.n_nodes = int(self.node_ranges[-1])  # global; the cloud holds n_held of them
        self.n_held = len(self.cloud.coords)
        self.dof_ranges = 2 * self.node_ranges
        start, stop = self.node_ranges[comm.rank], self.node_ranges[comm.rank + 1]
        self.node_range = (int(start), int(stop))
        self.owned_nodes = self.cloud.run_of(*self.node_range)  # where they sit in the cloud
        self.n_nodes_local = int(stop - start)
        self.n_dofs_local = 2 * self.n_nodes_local
        # every matrix below is built on the held nodes' positions, mapped to global
        # numbers where it becomes a PETSc matrix (None: the positions are global)
        self.dof_ids = None
        if self.cloud.node_ids is not None:
            self.dof_ids = (2 * self.cloud.node_ids[:, None] + np.arange(2)).ravel()
        support_radius = scene.discretization.support * self.cloud.spacing
        self.mls = MLS(
            self.cloud.coords,
            support_radius,
            scene.discretization.degree,
            scene.discretization.weight,
            support_factor=scene.discretization.support,
            region=box,
            node_ids=self.cloud.node_ids,
            n_global=self.n_nodes,
        )
        self.conditions: list[np.ndarray] = []  # MLS condition numbers of every point set
        self.trace_blocks: list[np.ndarray] = []  # owned nodes of each coarse-trace group

    def _partitioned_on_root(self) -> tuple[NodeCloud, Partition]:
        """The scene's cloud meshed on rank 0 and partitioned there, each rank's part sent
        to it (:func:`~parefg.geometry.distribute.partition_on_root`).  Collective."""
        # None on ranks > 0: partition_on_root sends them theirs
        cloud = scene_cloud_on_root(self.comm, self.scene, self.budget)
        self.budget.check_cloud(self.comm, cloud)  # the actual size, before any MLS work
        return partition_on_root(self.comm, cloud)

    def build(self) -> Discretization:
        comm, cloud, n = self.comm, self.cloud, self.n_nodes
        domain, mass, stiffness = self._domain()
        boundary, dirichlet_parts, contact, dirichlet_local, pattern_local = self._boundaries()
        nodes = self._node_points()
        with phase(self.timings, "assembly"):
            dirichlet = self._square(dirichlet_local)
            contact_pattern = self._owned_rows(pattern_local)
        conditions = np.concatenate(self.conditions) if self.conditions else np.ones(1)
        return Discretization(
            comm=comm,
            cloud=cloud,
            partition=self.partition,
            node_range=self.node_range,
            n_nodes=n,
            mass=mass,
            stiffness=stiffness,
            dirichlet=dirichlet,
            contact_pattern=contact_pattern,
            domain=domain,
            nodes=nodes,
            boundary=boundary,
            dirichlet_parts=dirichlet_parts,
            contact=contact,
            n_contact=self.n_contact,
            timings=self.timings,
            symmetric=self.scene.discretization.integration != "vci",
            trace_blocks=self.trace_blocks,
            condition_range=(
                comm.allreduce(conditions.min(), op=MPI.MIN),
                comm.allreduce(conditions.max(), op=MPI.MAX),
            ),
        )

    def _domain(self) -> tuple[PointSet, PETSc.Mat, PETSc.Mat]:
        """The domain point set, M and K, from MLS evaluated block by block."""
        rule = self._domain_rule()
        scene, quadrature = self.scene, rule()
        passes = BlockPasses(self.mls, quadrature, lambda name: phase(self.timings, name))
        indptr, indices, row_lengths = self._collectively(passes.pattern)
        correction = None
        if scene.discretization.integration == "vci":
            mls = self.mls
            sums = ConsistencySums(
                mls.nodes, mls.support_radius, mls.degree, compiled=mls.backend == "numba"
            )
            self._collectively(lambda: passes.add_consistency_sums(sums))
            self._boundary_consistency_sums(sums)
            with phase(self.timings, "assembly"):
                correction = node_corrections(
                    self.comm, sums, self.node_ranges, self.cloud.node_ids
                )
        # S only where it is small on every rank (BUILT_VALUE_BYTES; see PointSet.integrate)
        values = self.comm.allreduce(12 * int(row_lengths.sum()), op=MPI.MAX) < BUILT_VALUE_BYTES
        operators = self._collectively(
            lambda: passes.fill(
                scene.material.rho, indptr, indices, row_lengths, correction, values
            )
        )
        if len(quadrature.points):
            self.conditions.append(np.array(operators.condition_range))
        with phase(self.timings, "assembly"):
            pattern = (operators.indptr, operators.indices)
            blocks = _mass_blocks(operators.mass)
            mass = self._square(
                interleaved(*pattern, blocks, diagonal_only=True, n_global=self.n_nodes)
            )
            blocks = _stiffness_blocks(
                operators.gradient_gram, scene.material.lam, scene.material.mu
            )
            operators.gradient_gram = operators.mass = np.zeros(0)
            stiffness = self._square(interleaved(*pattern, blocks, n_global=self.n_nodes))
            del blocks
            csr = (operators.value_indptr, operators.value_indices, operators.value_data)
            domain = PointSet(
                points=quadrature.points,
                weights=quadrature.weights,
                normals=None,
                values=self._point_operator(csr) if values else None,
                gradients=PointGradients(
                    self.mls, quadrature.points, keep=False, kept=operators.gradients
                ),
                rebuild=self._values_again(passes.block_bounds()),
                regenerate=lambda: _points_and_weights(rule()),
            )
        return domain, mass, stiffness

    def _values_again(self, bounds: np.ndarray):
        """A function building the domain's value operator again from its points (see
        PointSet.rebuild).

        It holds only what it needs (the MLS, the block bounds), not the builder.
        Collective when called.
        """
        comm, mls, n_local, n_nodes = self.comm, self.mls, self.n_nodes_local, self.n_nodes

        return lambda points: _held_point_operator(
            comm, mls, value_rows(mls, points, bounds), n_local, n_nodes
        )

    def _domain_rule(self) -> Callable[[], Quadrature]:
        """A function computing the Gauss points of this rank's cells (the same numbers at
        every call), holding the cloud, not the builder.  Not collective."""
        cloud, order = self.cloud, self.scene.discretization.quadrature
        # the distributed cloud holds this rank's cells only
        return lambda: cell_quadrature(cloud.coords, cloud.quads, cloud.triangles, order)

    def _collectively(self, work):
        """``work()``; an MLSError on any rank is raised on every rank (no rank left waiting)."""
        result, error = None, None
        try:
            result = work()
        except MLSError as failure:
            error = failure
        raise_everywhere(self.comm, error)
        return result

    def _boundary_consistency_sums(self, sums: ConsistencySums) -> None:
        """The VCI terms of this rank's segments of every part (the whole boundary)."""
        every_part = list(range(len(self.cloud.part_names)))
        boundary, *_ = self._boundary_quadrature(every_part)
        shape = self._shape(boundary.points, gradients=False)
        with phase(self.timings, "assembly"):
            assert boundary.normals is not None
            sums.add_boundary(shape, boundary.points, boundary.weights, boundary.normals)

    def _shape(self, points: np.ndarray, gradients: bool) -> ShapeValues:
        """MLS at this rank's points; an MLS failure on any rank is raised on every rank."""
        with phase(self.timings, "neighbours"):
            neighbours = self.mls.find_neighbours(points)
        with phase(self.timings, "mls"):
            shape = self._collectively(
                lambda: self.mls.evaluate(points, gradients=gradients, neighbours=neighbours)
            )
            self.conditions.append(shape.condition)
        return shape

    def _square(self, local: sp.csr_matrix) -> PETSc.Mat:
        """The PETSc DOF matrix of every rank's ``local`` contributions.  Collective.

        As :func:`~parefg.parallel.petsc_matrix`, without copying the CSR arrays first.
        """
        owned = self._owned_rows(local)
        del local
        owned.sort_indices()
        matrix = PETSc.Mat().createAIJ(
            size=((self.n_dofs_local, PETSc.DETERMINE), (self.n_dofs_local, 2 * self.n_nodes)),
            csr=tuple(
                array.astype(kind, copy=False)
                for array, kind in zip(
                    (owned.indptr, owned.indices, owned.data),
                    (PETSc.IntType, PETSc.IntType, PETSc.ScalarType),
                    strict=True,
                )
            ),
            bsize=2,
            comm=self.comm,
        )
        matrix.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, True)
        matrix.assemble()
        return matrix

    def _owned_rows(self, local: sp.csr_matrix) -> sp.csr_matrix:
        """:func:`~parefg.parallel.owned_rows` of a (2 n_held)^2 matrix on the held
        nodes' DOFs: this rank's rows, global columns.  Collective."""
        return owned_rows(self.comm, local, self.dof_ranges, self.dof_ids, 2 * self.n_nodes)

    def _global_dof_columns(self, local: sp.csr_matrix) -> sp.csr_matrix:
        """``local`` (rows x 2 n_held, columns the held nodes' DOFs) with global columns
        (2 n_nodes of them).  Not collective."""
        if self.dof_ids is None:
            return local
        return global_columns(local, self.dof_ids, 2 * self.n_nodes)

    def _point_operator(self, csr) -> PETSc.Mat:
        """:func:`_held_point_operator` of this rank's MLS.  Collective."""
        return _held_point_operator(self.comm, self.mls, csr, self.n_nodes_local, self.n_nodes)

    def _point_set(
        self, quadrature, shape, gradients=False, keep_gradients=False, **extra
    ) -> PointSet:
        """The PointSet of ``quadrature``: its value operator, and its gradients if asked.

        ``keep_gradients`` keeps the shape gradients once used (the nodes: output steps
        evaluate them again), starting from those of ``shape`` if it has them; else they
        are re-evaluated per use.
        """
        local = value_operator(shape, self.n_held)
        values = self._point_operator((local.indptr, local.indices, local.data))
        kept = None
        if keep_gradients and shape.dphi is not None:
            kept = [sorted_gradients(shape, self.n_held)]
        source = PointGradients(self.mls, quadrature.points, keep=keep_gradients, kept=kept)
        return PointSet(
            points=quadrature.points,
            weights=quadrature.weights,
            normals=quadrature.normals,
            values=values,
            gradients=source if gradients else None,
            **extra,
        )

    def _node_points(self) -> PointSet:
        """u_h and its gradient at this rank's own nodes (MLS does not interpolate).

        The shape gradients are evaluated with the values when von Mises stresses are
        output (every run writes its final step), else never.
        """
        start, stop = self.node_range
        points = self.cloud.coords[self.owned_nodes]
        shape = self._shape(points, gradients="von_mises" in self.scene.output.fields)
        with phase(self.timings, "assembly"):
            quadrature = Quadrature(
                points=points,
                weights=np.ones(len(points)),
                cell=np.arange(start, stop),
                normals=None,
            )
            rows = self.cloud.original_index[self.owned_nodes]
            nodes = self._point_set(
                quadrature, shape, gradients=True, keep_gradients=True, rows=rows
            )
        return nodes


def scipy_rows(matrix: PETSc.Mat) -> sp.csr_matrix:
    """This rank's rows of a PETSc AIJ matrix as scipy CSR with global columns (a copy)."""
    indptr, indices, data = matrix.getValuesCSR()
    return sp.csr_matrix((data, indices, indptr), shape=(len(indptr) - 1, matrix.getSize()[1]))


def _mass_slots(stiffness: sp.csr_matrix, mass: sp.csr_matrix) -> np.ndarray | None:
    """The entry of K (this rank's rows, canonical CSR) holding each entry of M, or None
    where M is not in K's layout.

    Both are interleaved from one scalar pattern (:func:`interleaved`): row 2I + a of K
    holds (2J, 2J + 1) for each J of the scalar row I, M's only 2J + a, so M's k-th entry
    of a row is K's (2k + a)-th.  Checked: the row lengths, and the columns found.
    """
    if not np.array_equal(stiffness.indptr, 2 * mass.indptr):  # K's rows twice as long
        return None
    # M's entry p of row r sits in K's pair p (entries 2p, 2p + 1) at the row's component
    # r % 2 (a rank's rows start at an even DOF: whole nodes)
    component = np.repeat((np.arange(mass.shape[0]) % 2).astype(np.int8), np.diff(mass.indptr))
    slots = 2 * np.arange(mass.nnz, dtype=np.int64) + component
    if not np.array_equal(stiffness.indices[slots], mass.indices):
        return None
    return slots


def build_discretization(comm, scene, budget: Budget | None = None) -> Discretization:
    """Mesh, partition, MLS and assemble every constant operator of ``scene``.  Collective.

    ``budget`` (default: the machine's, :func:`~parefg.discretization.budget.check_problem_size`)
    refuses the scene with InputError on every rank when its run cannot fit in memory: from its
    parameters, for a .geo before meshing, and from the node cloud before MLS.
    """
    if budget is None:
        budget = check_problem_size(comm, scene)
    return _Builder(comm, scene, budget).build()


def _held_point_operator(comm, mls: MLS, csr, n_local: int, n_nodes: int) -> PETSc.Mat:
    """:func:`~parefg.discretization.point_set.point_operator` of CSR arrays (indptr,
    indices, data) whose columns are positions in ``mls``'s held nodes.  Collective."""
    indptr, indices, data = csr
    return point_operator(comm, (indptr, mls.global_ids(indices), data), n_local, n_nodes)
