"""The discrete EFG operators of one run, assembled once (SPEC 2, 3, 5).

scene -> node cloud -> partition -> MLS at this rank's quadrature points -> PETSc
operators.  Everything here is constant over the run (small deformation): mass M,
stiffness K, the Dirichlet operator D (penalty or Nitsche), and the point operators that evaluate
u_h (and its gradient) at quadrature points, Gamma_C points and nodes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from mpi4py import MPI
from petsc4py import PETSc

from parefg.boundary import BoundaryKind
from parefg.discretization.assembly import Coupling, interleaved, value_operator
from parefg.discretization.budget import Budget, check_problem_size
from parefg.discretization.dirichlet import DIRICHLET_METHODS, DirichletPart, local_operators
from parefg.discretization.domain_assembly import assemble_domain
from parefg.discretization.mls import MLS, MLSError, ShapeValues
from parefg.discretization.point_gradients import PointGradients
from parefg.discretization.quadrature import Quadrature, cell_quadrature, segment_quadrature
from parefg.discretization.trace_inverse import nitsche_beta
from parefg.geometry.cloud import NodeCloud
from parefg.geometry.gmsh_mesh import build_node_cloud
from parefg.geometry.partition import Partition, partition_cloud
from parefg.parallel import owned_rows, petsc_matrix, raise_everywhere
from parefg.profiling import phase


@dataclass
class PointSet:
    """This rank's points of one kind, with the operator evaluating u_h there.

    ``values`` is the scalar (n_points x n_nodes) PETSc matrix S[q, I] = phi_I(x_q); it
    acts on each displacement component (every other entry of the interleaved DOFs), so
    ``evaluate`` gives (u_x, u_y) at each point and ``integrate`` applies S^T to point
    forces: the interleaved operator kron(S, I_2) without storing it twice.  Gradients
    come from ``gradients`` (MLS re-evaluated at the points, block by block: only error
    norms and nodal stresses need them); None for point sets without gradients.
    """

    points: np.ndarray  # (n_points, 2)
    weights: np.ndarray  # (n_points,) quadrature weights (ones for nodes)
    normals: np.ndarray | None  # (n_points, 2) outward unit normals on boundaries
    values: PETSc.Mat
    part: np.ndarray | None = None  # (n_points,) boundary part index of each point
    rows: np.ndarray | None = None  # (n_points,) global, rank-independent row of each point
    gradients: PointGradients | None = field(default=None, repr=False)
    # work vectors at the points and the nodes, created on first use and reused (no PETSc
    # object per call)
    _point_vec: PETSc.Vec | None = field(default=None, init=False, repr=False)
    _node_vec: PETSc.Vec | None = field(default=None, init=False, repr=False)

    def _work(self) -> tuple[PETSc.Vec, PETSc.Vec]:
        if self._point_vec is None:
            self._point_vec = self.values.createVecLeft()
            self._node_vec = self.values.createVecRight()
        assert self._node_vec is not None
        return self._point_vec, self._node_vec

    def evaluate(self, u: PETSc.Vec) -> np.ndarray:
        """u_h at the points, (n_points, 2).  Collective."""
        point_vec, node_vec = self._work()
        dofs = u.getArray(readonly=True)
        out = np.empty((len(self.points), 2))
        for component in range(2):
            node_vec.setArray(dofs[component::2])
            self.values.mult(node_vec, point_vec)
            out[:, component] = point_vec.getArray(readonly=True)
        return out

    def evaluate_gradient(self, u: PETSc.Vec) -> np.ndarray:
        """grad u_h at the points, (n_points, 2, 2) with [q, i, j] = d u_i / d x_j.  Collective."""
        if self.gradients is None:
            raise ValueError("this point set has no gradients")
        return self.gradients.evaluate(self.values.getComm().tompi4py(), u)

    def integrate(self, density: np.ndarray, out: PETSc.Vec) -> None:
        """out = int density . phi_I = S^T (w density) per component; density (n_points, 2).

        Collective.
        """
        point_vec, node_vec = self._work()
        dofs = np.empty(2 * node_vec.getLocalSize())
        for component in range(2):
            point_vec.setArray(density[:, component] * self.weights)
            self.values.multTranspose(point_vec, node_vec)
            dofs[component::2] = node_vec.getArray(readonly=True)
        out.setArray(dofs)


@dataclass
class Discretization:
    """Node cloud, partition and the constant operators of a run (built collectively)."""

    comm: object
    cloud: NodeCloud
    partition: Partition
    node_range: tuple[int, int]  # this rank's nodes [start, stop)
    n_nodes: int
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

    @property
    def n_dofs(self) -> int:
        return 2 * self.n_nodes

    @property
    def owned(self) -> dict[str, sp.csr_matrix]:
        """This rank's rows of "mass", "stiffness", "dirichlet" as scipy CSR (global columns).

        Copies made on each access from the PETSc matrices (the values they were built from,
        explicit zeros included), for combining them into new matrices: no scipy twin of a
        PETSc matrix is kept.  Not collective.
        """
        matrices = {"mass": self.mass, "stiffness": self.stiffness, "dirichlet": self.dirichlet}
        return {name: scipy_rows(matrix) for name, matrix in matrices.items()}

    def create_vec(self) -> PETSc.Vec:
        """A zero DOF vector with this rank's block.  Collective."""
        return self.mass.createVecRight()


def _stiffness_blocks(gradient_gram: np.ndarray, lam: float, mu: float) -> np.ndarray:
    """2 x 2 blocks of K per scalar entry from S[p, a, b] = int d_a phi_I d_b phi_J.

    K[2I+a, 2J+b] = int lam d_a phi_I d_b phi_J
                    + mu (delta_ab grad phi_I . grad phi_J + d_b phi_I d_a phi_J).
    Returns (nnz, 2, 2).
    """
    laplace = gradient_gram[:, 0, 0] + gradient_gram[:, 1, 1]  # (nnz,)
    blocks = lam * gradient_gram + mu * gradient_gram.transpose(0, 2, 1)
    return blocks + mu * laplace[:, None, None] * np.eye(2)


def _mass_blocks(gram: np.ndarray) -> np.ndarray:
    """kron(G, I_2) blocks (nnz, 2, 2) of a scalar Gram matrix given as (nnz, 1, 1)."""
    return gram * np.eye(2)


class _Builder:
    """Collective construction of a Discretization from a scene.

    The constructor meshes and partitions the node cloud (everything the operators are
    built on); :meth:`build` evaluates MLS and assembles.
    """

    def __init__(self, comm, scene, budget: Budget):
        self.comm, self.scene, self.budget = comm, scene, budget
        self.timings = {"mesh": 0.0, "neighbours": 0.0, "mls": 0.0, "assembly": 0.0}
        self.n_contact = 0
        with phase(self.timings, "mesh"):
            cloud = build_node_cloud(
                comm, scene.domain, scene.h, scene.cells, scene.jitter, scene.seed, budget
            )
            budget.check_cloud(comm, cloud)  # the actual size, before any MLS work
            self.cloud, self.partition = partition_cloud(cloud, comm.size)
        self.n_nodes = len(self.cloud.coords)
        self.node_ranges = self.partition.node_ranges  # (comm.size + 1,)
        self.dof_ranges = 2 * self.node_ranges
        start, stop = self.node_ranges[comm.rank], self.node_ranges[comm.rank + 1]
        self.node_range = (int(start), int(stop))
        self.n_nodes_local = int(stop - start)
        self.n_dofs_local = 2 * self.n_nodes_local
        self.mls = MLS(
            self.cloud.coords,
            scene.support * self.cloud.spacing,
            scene.degree,
            scene.weight,
            support_factor=scene.support,
        )
        self.conditions: list[np.ndarray] = []  # MLS condition numbers of every point set

    def build(self) -> Discretization:
        comm, cloud, n = self.comm, self.cloud, self.n_nodes
        domain, mass, stiffness = self._domain()
        boundary, dirichlet_parts, contact, dirichlet_local, pattern_local = self._boundaries()
        nodes = self._node_points()
        with phase(self.timings, "assembly"):
            dirichlet = self._square(dirichlet_local)
            contact_pattern = owned_rows(comm, pattern_local, self.dof_ranges)
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
            condition_range=(
                comm.allreduce(conditions.min(), op=MPI.MIN),
                comm.allreduce(conditions.max(), op=MPI.MAX),
            ),
        )

    def _domain(self) -> tuple[PointSet, PETSc.Mat, PETSc.Mat]:
        """The domain point set, M and K, from MLS evaluated block by block."""
        scene, quadrature = self.scene, self._domain_quadrature()
        operators, error = None, None
        try:
            operators = assemble_domain(
                self.mls, quadrature, scene.rho, lambda name: phase(self.timings, name)
            )
        except MLSError as failure:
            error = failure
        raise_everywhere(self.comm, error)
        assert operators is not None  # no rank failed
        if len(quadrature.points):
            self.conditions.append(np.array(operators.condition_range))
        with phase(self.timings, "assembly"):
            pattern = (operators.indptr, operators.indices)
            blocks = _mass_blocks(operators.mass)
            mass = self._square(interleaved(*pattern, blocks, diagonal_only=True))
            blocks = _stiffness_blocks(operators.gradient_gram, scene.lam, scene.mu)
            operators.gradient_gram = operators.mass = np.zeros(0)
            stiffness = self._square(interleaved(*pattern, blocks))
            del blocks
            csr = (operators.value_indptr, operators.value_indices, operators.value_data)
            domain = PointSet(
                points=quadrature.points,
                weights=quadrature.weights,
                normals=None,
                values=_point_operator(self.comm, csr, self.n_nodes_local, self.n_nodes),
                gradients=PointGradients(self.mls, quadrature.points, keep=False),
            )
        return domain, mass, stiffness

    def _shape(self, points: np.ndarray, gradients: bool) -> ShapeValues:
        """MLS at this rank's points; an MLS failure on any rank is raised on every rank."""
        with phase(self.timings, "neighbours"):
            neighbours = self.mls.find_neighbours(points)
        with phase(self.timings, "mls"):
            shape, error = None, None
            try:
                shape = self.mls.evaluate(points, gradients=gradients, neighbours=neighbours)
            except MLSError as failure:
                error = failure
            raise_everywhere(self.comm, error)
            assert shape is not None  # no rank failed
            self.conditions.append(shape.condition)
        return shape

    def _domain_quadrature(self) -> Quadrature:
        """Gauss points of this rank's cells."""
        rank, cloud, part = self.comm.rank, self.cloud, self.partition
        return cell_quadrature(
            cloud.coords,
            cloud.quads,
            cloud.triangles,
            self.scene.quadrature,
            quad_ids=np.flatnonzero(part.quad_owner == rank),
            triangle_ids=np.flatnonzero(part.triangle_owner == rank),
        )

    def _square(self, local: sp.csr_matrix) -> PETSc.Mat:
        """The PETSc DOF matrix of every rank's ``local`` contributions.  Collective.

        As :func:`~parefg.parallel.petsc_matrix`, without copying the CSR arrays first.
        """
        owned = owned_rows(self.comm, local, self.dof_ranges)
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

    def _point_set(self, quadrature, shape, gradients=False, keep_gradients=False, **extra):
        """The PointSet of ``quadrature``: its value operator, and its gradients if asked.

        ``keep_gradients`` keeps the shape gradients once used (the nodes: output steps
        evaluate them again); else they are re-evaluated per use (the domain: error norms).
        """
        local = value_operator(shape, self.n_nodes)
        csr = (local.indptr, local.indices, local.data)
        values = _point_operator(self.comm, csr, self.n_nodes_local, self.n_nodes)
        source = PointGradients(self.mls, quadrature.points, keep=keep_gradients)
        return PointSet(
            points=quadrature.points,
            weights=quadrature.weights,
            normals=quadrature.normals,
            values=values,
            gradients=source if gradients else None,
            **extra,
        )

    def _boundary_quadrature(self, part_ids: list[int]) -> tuple[Quadrature, np.ndarray]:
        """This rank's Gauss points on segments of the given parts, and their global rows."""
        cloud, part = self.cloud, self.partition
        on_parts = np.isin(cloud.segment_part, part_ids)
        # global, rank-independent numbering of the selected segments (for output rows)
        global_index = np.cumsum(on_parts) - 1
        mine = np.flatnonzero(on_parts & (part.segment_owner == self.comm.rank))
        quadrature = segment_quadrature(
            cloud.coords, cloud.segments, self.scene.quadrature, segment_ids=mine
        )
        n_gauss = self.scene.quadrature
        rows = global_index[quadrature.cell] * n_gauss + np.arange(len(quadrature.cell)) % n_gauss
        return quadrature, rows

    def _boundaries(self):
        """Point sets of every boundary condition; D, its parts and the Gamma_C pattern."""
        scene, cloud, n = self.scene, self.cloud, self.n_nodes
        boundary, parts, contact_parts = {}, {}, []
        dirichlet_local = sp.csr_matrix((2 * n, 2 * n))
        for name, bc in scene.boundaries.items():
            part_id = cloud.part_names.index(name)
            if bc.kind == BoundaryKind.CONTACT:
                contact_parts.append(part_id)
                continue
            quadrature, _ = self._boundary_quadrature([part_id])
            method = DIRICHLET_METHODS[bc.method] if bc.kind == BoundaryKind.DIRICHLET else None
            consistent = method is not None and method.consistent
            shape = self._shape(quadrature.points, gradients=consistent)
            with phase(self.timings, "assembly"):
                boundary[name] = self._point_set(quadrature, shape)
            if method is not None:
                parts[name], local = self._dirichlet_part(method, bc, quadrature, shape)
                dirichlet_local = dirichlet_local + local
        contact, pattern = None, sp.csr_matrix((2 * n, 2 * n))
        if contact_parts:
            quadrature, rows = self._boundary_quadrature(contact_parts)
            on_contact = np.isin(cloud.segment_part, contact_parts)  # every rank's segments
            self.n_contact = int(np.count_nonzero(on_contact)) * self.scene.quadrature
            shape = self._shape(quadrature.points, gradients=False)
            with phase(self.timings, "assembly"):
                part_of_point = cloud.segment_part[quadrature.cell]
                contact = self._point_set(quadrature, shape, part=part_of_point, rows=rows)
                coupling = Coupling.of(shape, n, quadrature.cell)
                pattern = coupling.interleaved(np.zeros((len(coupling.indices), 2, 2)))
        return boundary, parts, contact, dirichlet_local, pattern

    def _dirichlet_part(self, method, bc, quadrature: Quadrature, shape: ShapeValues):
        """One Dirichlet part by ``method``, and its local contributions to D.

        beta is alpha_D for the penalty, the part's safety times the coercivity bound of
        each segment (:func:`~parefg.discretization.trace_inverse.nitsche_beta`) for Nitsche.
        """
        scene, n = self.scene, self.n_nodes
        if method.consistent:
            with phase(self.timings, "assembly"):  # the trace-inverse estimate
                per_segment = bc.safety * nitsche_beta(
                    self.mls,
                    self.cloud,
                    self._nitsche_segments(),
                    np.unique(quadrature.cell),
                    scene.quadrature,
                    scene.lam,
                    scene.mu,
                )
            beta = np.repeat(per_segment, scene.quadrature)  # points are grouped by segment
        else:
            beta = np.full(len(quadrature.weights), scene.alpha_dirichlet)
        with phase(self.timings, "assembly"):
            assert quadrature.normals is not None
            local, load, traction = local_operators(
                method, shape, quadrature.weights, quadrature.normals, beta, n, scene.lam, scene.mu
            )
            part = DirichletPart(
                method=method.name,
                weights=quadrature.weights,
                beta=beta,
                load=petsc_matrix(self.comm, load, self.n_dofs_local, 2 * n),
                traction=None
                if traction is None
                else petsc_matrix(self.comm, traction, self.n_dofs_local, 2 * n),
            )
        return part, local

    def _nitsche_segments(self) -> np.ndarray:
        """Every segment (all ranks) of a Dirichlet part imposed by a consistent method."""
        cloud, names = self.cloud, []
        for name, bc in self.scene.boundaries.items():
            if bc.kind == BoundaryKind.DIRICHLET and DIRICHLET_METHODS[bc.method].consistent:
                names.append(cloud.part_names.index(name))
        return np.flatnonzero(np.isin(cloud.segment_part, names))

    def _node_points(self) -> PointSet:
        """u_h and its gradient at this rank's own nodes (MLS does not interpolate)."""
        start, stop = self.node_ranges[self.comm.rank], self.node_ranges[self.comm.rank + 1]
        points = self.cloud.coords[start:stop]
        shape = self._shape(points, gradients=False)  # gradients: PointGradients, on use
        with phase(self.timings, "assembly"):
            quadrature = Quadrature(
                points=points,
                weights=np.ones(len(points)),
                cell=np.arange(start, stop),
                normals=None,
            )
            rows = self.cloud.original_index[start:stop]
            nodes = self._point_set(
                quadrature, shape, gradients=True, keep_gradients=True, rows=rows
            )
        return nodes


def scipy_rows(matrix: PETSc.Mat) -> sp.csr_matrix:
    """This rank's rows of a PETSc AIJ matrix as scipy CSR with global columns (a copy)."""
    indptr, indices, data = matrix.getValuesCSR()
    return sp.csr_matrix((data, indices, indptr), shape=(len(indptr) - 1, matrix.getSize()[1]))


def _point_operator(comm, csr, n_nodes_local: int, n_nodes: int) -> PETSc.Mat:
    """PETSc matrix of a scalar point operator from its CSR arrays (rows: this rank's points).

    Collective.  Without inodes: the rows of neighbouring points may share a pattern, and
    PETSc's inode product adds such rows' terms in pairs; the plain product sums each row
    in column order, as the interleaved operator (whose rows never share a pattern) did.
    """
    indptr, indices, data = csr
    matrix = PETSc.Mat().createAIJ(
        size=((len(indptr) - 1, PETSc.DETERMINE), (n_nodes_local, n_nodes)),
        csr=(
            indptr.astype(PETSc.IntType, copy=False),
            indices.astype(PETSc.IntType, copy=False),
            data.astype(PETSc.ScalarType, copy=False),
        ),
        comm=comm,
    )
    matrix.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, True)
    matrix.setOption(PETSc.Mat.Option.USE_INODES, False)
    matrix.assemble()  # drops the inode routines the first assembly chose
    return matrix


def build_discretization(comm, scene, budget: Budget | None = None) -> Discretization:
    """Mesh, partition, MLS and assemble every constant operator of ``scene``.  Collective.

    ``budget`` (default: the machine's, :func:`~parefg.discretization.budget.check_problem_size`)
    refuses the scene with InputError on every rank when its run cannot fit in memory: from its
    parameters, for a .geo before meshing, and from the node cloud before MLS.
    """
    if budget is None:
        budget = check_problem_size(comm, scene)
    return _Builder(comm, scene, budget).build()
