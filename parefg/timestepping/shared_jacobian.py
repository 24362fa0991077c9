"""A_const kept in the storage of the contact Jacobian (one DOF matrix less per run).

The Jacobian of a contact step is J = A_const + C, with C the contact and friction terms
of the active set.  C reaches only the rows (and columns) of the DOFs whose shape
functions meet Gamma_C, the rows of the Gamma_C coupling pattern: everywhere else J and
A_const are the same numbers.  So a large run need not hold both matrices.
:class:`SharedConstant` turns A_const into the Jacobian (one copy when it is made; the
caller then lets A_const's own matrix go) and keeps aside only A_const's Gamma_C rows:

* A_const x = J x with the Gamma_C rows taken from the kept rows' product (once J holds
  contact terms): no difference of large numbers, the same sums as A_const's own rows;
* a new Jacobian writes the kept rows back into J (INSERT, the same pattern) before it
  adds the contact rows, so J = A_const + C exactly as a copy of A_const would give.

A_const is then one matrix and a strip of rows instead of two matrices (at m = 1 ~1 KB
per DOF less, at m = 2 ~2.6).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from petsc4py import PETSc

from parefg.parallel import add_owned_rows, petsc_matrix, raise_unless_everywhere


class SharedConstant:
    """A_const as J with its Gamma_C rows kept aside.  Construction is collective.

    ``jacobian`` is made from ``matrix`` (A_const), which the caller then lets go: it uses
    ``jacobian`` as the Jacobian and this object as A_const.  (A copy, made once: a
    duplicate carries none of A_const's flags, as a plain Jacobian does not, so the
    factorization runs in the same mode -- MUMPS reads the SPD flag -- and gives the same
    bits.)  ``rows``: the local (owned) row indices
    that contact terms may reach, the rows of the Gamma_C pattern.  Offers what the step
    solver, the rigid-motion check and the benchmarks ask of A_const: mult, createVecs /
    createVecRight / createVecLeft, norm (infinity, of A_const) and getNearNullSpace.
    """

    def __init__(self, comm, matrix: PETSc.Mat, rows: np.ndarray):
        self.comm, self.jacobian = comm, matrix.duplicate(copy=True)
        # GAMG needs the rigid-body modes on the matrix it is built from
        self.jacobian.setNearNullSpace(matrix.getNearNullSpace())
        self.rows = np.asarray(rows, dtype=np.int64)
        indptr, indices, values = matrix.getValuesCSR()  # owned rows, global columns
        lengths = np.diff(indptr)
        keep = np.zeros(len(lengths), dtype=bool)
        keep[self.rows] = True
        entries = np.repeat(keep, lengths)  # their stored entries, explicit zeros included
        kept_indptr = np.concatenate([[0], np.cumsum(np.where(keep, lengths, 0))])
        n_cols = matrix.getSize()[1]
        kept = sp.csr_matrix(
            (values[entries], indices[entries], kept_indptr), shape=(len(lengths), n_cols)
        )
        n_cols_local = matrix.getLocalSize()[1]
        self.kept = petsc_matrix(comm, kept, n_cols_local, n_cols, block_size=2)
        self._infinity_norm = matrix.norm(PETSc.NormType.NORM_INFINITY)
        self._work = matrix.createVecLeft()
        self._holds_constant = True  # J has A_const's values (no contact rows added yet)

    def mult(self, x: PETSc.Vec, y: PETSc.Vec) -> None:
        """y = A_const x.  Collective."""
        self.jacobian.mult(x, y)
        if self._holds_constant:
            return
        self.kept.mult(x, self._work)
        with y as out:
            out[self.rows] = self._work.getArray(readonly=True)[self.rows]

    def set_jacobian(self, contact_rows: sp.csr_matrix) -> None:
        """J = A_const + ``contact_rows`` (owned rows, global columns, within the Gamma_C
        rows).  Collective."""
        reached = np.flatnonzero(np.diff(contact_rows.indptr))
        inside = bool(np.all(np.isin(reached, self.rows)))  # else A_const x is wrong there
        raise_unless_everywhere(
            self.comm, inside, RuntimeError("contact terms reach rows outside the Gamma_C pattern")
        )
        indptr, indices, values = self.kept.getValuesCSR()
        self.jacobian.setValuesCSR(indptr, indices, values, addv=PETSc.InsertMode.INSERT_VALUES)
        self.jacobian.assemble()
        add_owned_rows(self.jacobian, contact_rows)
        self._holds_constant = False

    def createVecRight(self) -> PETSc.Vec:  # noqa: N802 (PETSc's name)
        return self.jacobian.createVecRight()

    def createVecLeft(self) -> PETSc.Vec:  # noqa: N802
        return self.jacobian.createVecLeft()

    def createVecs(self) -> tuple[PETSc.Vec, PETSc.Vec]:  # noqa: N802
        return self.jacobian.createVecs()

    def getNearNullSpace(self) -> PETSc.NullSpace:  # noqa: N802
        return self.jacobian.getNearNullSpace()

    def norm(self, norm_type=PETSc.NormType.NORM_INFINITY) -> float:
        """||A_const||_inf (taken when A_const was handed over).  Not collective."""
        if norm_type != PETSc.NormType.NORM_INFINITY:
            raise ValueError("SharedConstant keeps the infinity norm only")
        return self._infinity_norm
