"""This rank's Gamma_C quadrature points in their normal-tangential frame (SPEC 4).

At each point q (weight w_q, outward normal nu_q, tangent tau_q = (-nu_2, nu_1)) the
rotated value operator B = [B_nu; B_tau] maps the nodal parameters to
u_nu = nu . u_h(x_q) and u_tau = tau . u_h(x_q), and B^T maps point forces back to the
DOFs.  :class:`~parefg.mechanics.contact.ContactLaw` builds the penalty law on it.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from mpi4py import MPI
from petsc4py import PETSc

from parefg.discretization.coarse_trace import project_rows
from parefg.parallel import petsc_matrix

# kept kinematics results: the accepted u survives the next step's predictor (begin_step
# asks for it after gate has asked for the predictor)
KEPT_KINEMATICS = 2


class ContactFrame:
    """Weights, normals, tangents and the rotated operator of the points.  Collective.

    Parameters
    ----------
    comm
        The run's communicator.
    points
        The discretization's Gamma_C points (``disc.contact``): ``weights`` (n_c,),
        ``points`` and ``normals`` (n_c, 2), ``part`` (n_c,) and the value operator
        ``values`` (scalar n_c x n_nodes PETSc), projected by ``projection`` where the
        coarse trace applies (P on (u_x, u_y), then each point's own rotation, as the
        traction rows: on a bend of a group, under 30 degrees, the two do not commute).
    """

    def __init__(self, comm, points) -> None:
        self.comm = comm
        self.weights = points.weights  # (n_c,)
        self.points = points.points  # (n_c, 2)
        self.normals = points.normals  # (n_c, 2)
        self.tangents = np.column_stack([-self.normals[:, 1], self.normals[:, 0]])  # (n_c, 2)
        self.part = points.part
        self.projection = points.projection  # P on point fields, or None (pointwise law)
        # kron(S, I_2) of the scalar value operator: rows 2q, 2q + 1 = (u_x, u_y)(x_q)
        values = sp.kron(_scipy_from_petsc(points.values), sp.identity(2), format="csr")
        if points.projection is not None:  # Nitsche contact on the coarse trace: P u
            values = project_rows(points.projection, values)
        local = (_rotated(self.normals, self.tangents) @ values).tocsr()
        n_local, n_dofs = 2 * points.values.getLocalSize()[1], 2 * points.values.getSize()[1]
        # Nitsche contact: the law's "u_nu" is u_nu - sigma_nu(u_h) / gamma (ContactLaw)
        self.gamma = points.gamma  # (n_c,) or None (penalty contact)
        self.traction_op = None  # PETSc sigma_nu(u_h) at the points (Nitsche only)
        if points.normal_traction is not None:
            self.traction_op = points.normal_traction
            normal_traction = _scipy_from_petsc(self.traction_op)
            shifted = local[0::2] - sp.diags(1.0 / self.gamma) @ normal_traction
            local = _interleave_rows(shifted.tocsr(), local[1::2])
        self.operator = petsc_matrix(comm, local, n_local, n_dofs)
        # for the Jacobian, on the DOFs the points reach only (ascending): its products
        # then have a row per such DOF, not one per DOF of the whole problem
        self.n_dofs = n_dofs
        self.dof_columns = np.unique(local.indices)
        compact = sp.csr_matrix(
            (local.data, np.searchsorted(self.dof_columns, local.indices), local.indptr),
            shape=(local.shape[0], len(self.dof_columns)),
        )
        self.normal_op = compact[0::2]  # (n_c, len(dof_columns)) scipy
        self.tangent_op = compact[1::2]
        # (2 n_c,) work vector at the points, reused by every call (no PETSc object per call)
        self._point_vec = self.operator.createVecLeft()
        self._pair_weights = np.repeat(self.weights, 2).reshape(-1, 2)  # (n_c, 2) w_q, w_q
        self._traction_vec: PETSc.Vec | None = None
        # the last KEPT_KINEMATICS results: (vector, its handle and state, (u_nu, u_tau))
        self._kept: list[tuple[PETSc.Vec, tuple[int, int], tuple[np.ndarray, np.ndarray]]] = []

    def kinematics(self, u: PETSc.Vec) -> tuple[np.ndarray, np.ndarray]:
        """(u_nu, u_tau) at the points (read-only arrays).  Collective.

        A step asks for the same u several times (each Newton iterate: its residual,
        convergence test, Jacobian and line search; the accepted u: the energy row, the
        contact acceleration, the next step's start level), so the last results are kept
        with the vector's PETSc object state.  Every change of the values through PETSc
        increases the state; so does releasing a writable numpy view (``getArray()``),
        which an observer may take on one rank only: on several ranks they agree on the
        kept result with one reduction (else one rank would skip the collective product
        the others enter).  The kept vector is referenced: its handle cannot be reused by
        another vector meanwhile.
        """
        key = (u.handle, u.stateGet())
        kept = None
        for _, kept_key, result in self._kept:
            if kept_key == key:
                kept = result
                break
        if self.comm.size > 1:
            everywhere = np.array(kept is not None, dtype=np.int32)
            self.comm.Allreduce(MPI.IN_PLACE, everywhere, op=MPI.LAND)
            kept = kept if everywhere else None
        if kept is not None:
            return kept
        out = self._point_vec
        self.operator.mult(u, out)
        values = out.getArray(readonly=True).reshape(-1, 2)
        result = values[:, 0].copy(), values[:, 1].copy()
        for array in result:
            array.flags.writeable = False  # shared by the callers of the kept result
        self._kept = [(u, key, result), *self._kept[: KEPT_KINEMATICS - 1]]
        return result

    def normal_traction(self, u: PETSc.Vec) -> np.ndarray:
        """sigma_nu(u_h) at the points (zeros without Nitsche contact).  Collective."""
        if self.traction_op is None:
            return np.zeros(len(self.weights))
        if self._traction_vec is None:
            self._traction_vec = self.traction_op.createVecLeft()
        self.traction_op.mult(u, self._traction_vec)
        return self._traction_vec.getArray(readonly=True).copy()

    def normal_displacement(self, u: PETSc.Vec) -> np.ndarray:
        """nu . u_h at the points: the physical one also under Nitsche contact.  Collective."""
        un = self.kinematics(u)[0]
        if self.traction_op is None:
            return un
        return un + self.normal_traction(u) / self.gamma

    def tractions(self, pressure, friction) -> tuple[np.ndarray, np.ndarray]:
        """(normal, tangential) traction the body feels at the points.  Not collective.

        A law on the projection P u (hat or coarse trace) applies B^T P^T W (p nu + f tau) =
        B^T W P(p nu + f tau) (P is W-self-adjoint): the traction density is P of the law's
        point values, smoother than they are (Hertz, h = 0.1: largest point value 1.36 p0
        against 2.9 p0) and with the same resultant.  Without P, the law's values.
        """
        if self.projection is None:
            return pressure, friction
        vector = pressure[:, None] * self.normals + friction[:, None] * self.tangents
        vector = self.projection @ vector
        return (
            np.einsum("ij,ij->i", vector, self.normals),
            np.einsum("ij,ij->i", vector, self.tangents),
        )

    def point_vector(self, normal: np.ndarray) -> PETSc.Vec:
        """The work vector at the points, holding (normal_q, 0) (overwritten by later calls)."""
        out = self._point_vec
        out.setArray(np.column_stack([normal, np.zeros_like(normal)]).ravel())
        return out

    def _add_point_forces(self, residual: PETSc.Vec, pressure, friction) -> None:
        """residual += B_nu^T (w pressure) + B_tau^T (w friction).  Collective."""
        point_forces = self._point_vec
        pairs = np.empty((len(self.weights), 2))  # (n_c, 2) w (pressure, friction) per point
        pairs[:, 0], pairs[:, 1] = pressure, friction
        pairs *= self._pair_weights
        point_forces.setArray(pairs.ravel())
        self.operator.multTransposeAdd(point_forces, residual, residual)


def _rotated(normals: np.ndarray, tangents: np.ndarray) -> sp.csr_matrix:
    """(2 n_c, 2 n_c) rotation: rows 2q = nu_q . (u_x, u_y)_q, 2q + 1 = tau_q . (u_x, u_y)_q."""
    n_points = len(normals)
    q = np.arange(n_points)
    return sp.csr_matrix(
        (
            np.concatenate([normals[:, 0], normals[:, 1], tangents[:, 0], tangents[:, 1]]),
            (
                np.concatenate([2 * q, 2 * q, 2 * q + 1, 2 * q + 1]),
                np.concatenate([2 * q, 2 * q + 1, 2 * q, 2 * q + 1]),
            ),
        ),
        shape=(2 * n_points, 2 * n_points),
    )


def _interleave_rows(even: sp.csr_matrix, odd: sp.csr_matrix) -> sp.csr_matrix:
    """Rows 2q = even[q], 2q + 1 = odd[q]."""
    stacked = sp.vstack([even, odd], format="csr")
    n_points = even.shape[0]
    order = np.column_stack([np.arange(n_points), n_points + np.arange(n_points)]).ravel()
    return stacked[order]


def _scipy_from_petsc(matrix: PETSc.Mat) -> sp.csr_matrix:
    """This rank's rows of a PETSc AIJ matrix as scipy CSR with global columns."""
    indptr, indices, data = matrix.getValuesCSR()
    return sp.csr_matrix((data, indices, indptr), shape=(len(indptr) - 1, matrix.getSize()[1]))
