"""This rank's points of one kind (quadrature, Gamma_C, nodes) and the operator giving u_h there.

A :class:`PointSet` holds this rank's points with the scalar PETSc matrix
S[q, I] = phi_I(x_q) (:func:`point_operator`), which evaluates u_h at the points and
integrates point forces back onto the nodes.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from parefg.discretization.point_gradients import PointGradients

if TYPE_CHECKING:
    import scipy.sparse as sp


@dataclass
class PointSet:
    """This rank's points of one kind, with the operator evaluating u_h there.

    ``values`` is the scalar (n_points x n_nodes) PETSc matrix S[q, I] = phi_I(x_q); it
    acts on each displacement component (every other entry of the interleaved DOFs), so
    ``evaluate`` gives (u_x, u_y) at each point and ``integrate`` applies S^T to point
    forces: the interleaved operator kron(S, I_2) without storing it twice.  Gradients
    come from ``gradients`` (MLS re-evaluated at the points, block by block: only error
    norms and nodal stresses need them); None for point sets without gradients.

    A point set with ``rebuild`` (the domain's) may drop ``values`` between uses
    (:meth:`release_values`), or never build it (a large domain): ``evaluate`` and
    ``integrate`` then work from MLS values block by block, and :meth:`ensure_values`
    builds it (again) for a caller that integrates at every step.  One with ``regenerate`` may also
    drop its points and weights (:meth:`release_points`, 24 bytes per point): every
    method here computes them again when it needs them (:meth:`restore_points`), and so
    must any other reader of ``points`` or ``weights`` after a release.
    """

    points: np.ndarray | None  # (n_points, 2); None between release_points() and a use
    weights: np.ndarray | None  # (n_points,) quadrature weights (ones for nodes)
    normals: np.ndarray | None  # (n_points, 2) outward unit normals on boundaries
    values: PETSc.Mat | None  # None between release_values() and the next use
    part: np.ndarray | None = None  # (n_points,) boundary part index of each point
    rows: np.ndarray | None = None  # (n_points,) global, rank-independent row of each point
    gradients: PointGradients | None = field(default=None, repr=False)
    # Gamma_C with Nitsche contact: sigma_nu(u_h) at the points (PETSc, n_points x
    # 2 n_nodes, zero rows on penalty parts) and gamma (n_points,)
    normal_traction: PETSc.Mat | None = field(default=None, repr=False)
    gamma: np.ndarray | None = None
    # Gamma_C with Nitsche contact: the coarse trace's projection P on point fields (scipy,
    # n_points x n_points, identity rows on penalty parts; parefg.discretization.coarse_trace):
    # the contact law acts on P u (normal_traction is already projected)
    projection: sp.csr_matrix | None = field(default=None, repr=False)
    # builds ``values`` again from the points (collective): MLS there once more, by block
    rebuild: Callable[[np.ndarray], PETSc.Mat] | None = field(default=None, repr=False)
    # computes (points, weights) again, the same numbers in the same order (not collective)
    regenerate: Callable[[], tuple[np.ndarray, np.ndarray]] | None = field(default=None, repr=False)
    # work vectors at the points and the nodes, created on first use and reused (no PETSc
    # object per call)
    _point_vec: PETSc.Vec | None = field(default=None, init=False, repr=False)
    _node_vec: PETSc.Vec | None = field(default=None, init=False, repr=False)

    def release_values(self, keep_below: int) -> bool:
        """Destroy the value operator until its next use when it holds ``keep_below`` bytes
        or more on some rank (its CSR: 12 bytes per entry); returns whether it did.

        Only a point set with ``rebuild``: its next use pays the MLS of the points again,
        which small operators are not worth.  Collective (every rank decides alike).
        """
        if self.rebuild is None or self.values is None:
            return False
        held = 12 * self.values.getInfo(PETSc.Mat.InfoType.LOCAL)["nz_used"]
        comm = self.values.getComm().tompi4py()
        if comm.allreduce(held, op=MPI.MAX) < keep_below:
            return False
        for obj in (self.values, self._point_vec, self._node_vec):
            if obj is not None:
                obj.destroy()
        self.values = self._point_vec = self._node_vec = None
        return True

    def release_points(self) -> bool:
        """Drop the points and weights until their next use (a point set with
        ``regenerate``); returns whether it did.  Not collective."""
        if self.regenerate is None:
            return False
        self.points = self.weights = None
        if self.gradients is not None:
            self.gradients.points = None
        return True

    def restore_points(self) -> tuple[np.ndarray, np.ndarray]:
        """(points, weights), computed again if they were released (and kept from then on:
        the uses after a release are the end of a run, or a step that evaluates data point
        by point).  Not collective."""
        if self.points is None or self.weights is None:
            assert self.regenerate is not None  # only such point sets release theirs
            self.points, self.weights = self.regenerate()
            if self.gradients is not None:
                self.gradients.points = self.points
        return self.points, self.weights

    def _operator(self) -> PETSc.Mat:
        """The value operator, built again if it was released.  Collective."""
        if self.values is None:
            assert self.rebuild is not None  # only such point sets release theirs
            self.values = self.rebuild(self.restore_points()[0])
        return self.values

    def ensure_values(self) -> None:
        """Build the value operator if it was not built or was released (for a caller that
        integrates at every step).  Collective."""
        self._operator()

    def _work(self) -> tuple[PETSc.Mat, PETSc.Vec, PETSc.Vec]:
        """(the value operator, a point vector, a node vector).  Collective."""
        values = self._operator()
        if self._point_vec is None:
            self._point_vec = values.createVecLeft()
            self._node_vec = values.createVecRight()
        assert self._node_vec is not None
        return values, self._point_vec, self._node_vec

    def evaluate(self, u: PETSc.Vec) -> np.ndarray:
        """u_h at the points, (n_points, 2).  Collective.

        A released value operator is not built again for this: MLS values block by block
        (:meth:`PointGradients.evaluate_values`) need no more memory than a block.
        """
        points, _ = self.restore_points()
        if self.values is None and self.gradients is not None:
            return self.gradients.evaluate_values(u.getComm().tompi4py(), u)
        values, point_vec, node_vec = self._work()
        dofs = u.getArray(readonly=True)
        out = np.empty((len(points), 2))
        for component in range(2):
            node_vec.setArray(dofs[component::2])
            values.mult(node_vec, point_vec)
            out[:, component] = point_vec.getArray(readonly=True)
        return out

    def evaluate_gradient(self, u: PETSc.Vec) -> np.ndarray:
        """grad u_h at the points, (n_points, 2, 2) with [q, i, j] = d u_i / d x_j.  Collective."""
        if self.gradients is None:
            raise ValueError("this point set has no gradients")
        self.restore_points()
        return self.gradients.evaluate(u.getComm().tompi4py(), u)

    def evaluate_with_gradient(self, u: PETSc.Vec) -> tuple[np.ndarray, np.ndarray]:
        """(:meth:`evaluate`, :meth:`evaluate_gradient`) of u, in one MLS pass when the
        value operator was released (the error norms of a large run).  Collective."""
        if self.values is None and self.gradients is not None:
            self.restore_points()
            return self.gradients.evaluate_values(u.getComm().tompi4py(), u, gradients=True)
        return self.evaluate(u), self.evaluate_gradient(u)

    def integrate(self, density: np.ndarray, out: PETSc.Vec) -> None:
        """out = int density . phi_I = S^T (w density) per component; density (n_points, 2).

        Without a value operator (not built for a large domain, or released) the MLS values
        are evaluated block by block (:meth:`PointGradients.integrate_values`), one MLS
        pass per call: a caller integrating at every step builds the operator first
        (:meth:`ensure_values`).  Collective.
        """
        self.integrate_many(density[None], [out])

    def integrate_many(self, densities: np.ndarray, outs: list[PETSc.Vec]) -> None:
        """outs[k] = S^T (w densities[k]), densities (K, n_points, 2): :meth:`integrate`
        of each, in one MLS pass when there is no value operator.  Collective."""
        _, weights = self.restore_points()
        if self.values is None and self.gradients is not None:
            self.gradients.integrate_values(densities * weights[None, :, None], outs)
            return
        for density, out in zip(densities, outs, strict=True):
            self._integrate_with_operator(density, out)

    def _integrate_with_operator(self, density: np.ndarray, out: PETSc.Vec) -> None:
        """out = S^T (w density) by PETSc's product with S.  Collective."""
        _, weights = self.restore_points()
        values, point_vec, node_vec = self._work()
        dofs = np.empty(2 * node_vec.getLocalSize())
        for component in range(2):
            point_vec.setArray(density[:, component] * weights)
            values.multTranspose(point_vec, node_vec)
            dofs[component::2] = node_vec.getArray(readonly=True)
        out.setArray(dofs)


def point_operator(comm, csr, n_nodes_local: int, n_nodes: int) -> PETSc.Mat:
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
