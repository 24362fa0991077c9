"""Linear solves of the time loop: one step without contact, and the PETSc KSP set-up.

:class:`LinearStepSolver` -- no Gamma_C: J_n is quadratic, each step is one linear solve
with A_const, factored (or preconditioned) once for the whole run; an iterative KSP that
stops above the step tolerance max(atol, rtol * scale) is refined with the same KSP (see
:mod:`parefg.timestepping.step_solver` for the tolerance).  The helpers here also set up
the KSP of the contact step's Newton solve and of the mass solve: a direct factorization
by default (MUMPS when PETSc has it), checked once for a singular matrix.
"""

from __future__ import annotations

import numpy as np
from petsc4py import PETSc

from parefg.errors import SolverError

FACTORIZATIONS = ("lu", "cholesky", "ilu", "icc")


def configure_linear_solver(ksp: PETSc.KSP) -> None:
    """Default: direct Cholesky with MUMPS; any -ksp_/-pc_ option overrides it."""
    ksp.setType(PETSc.KSP.Type.PREONLY)
    pc = ksp.getPC()
    pc.setType(PETSc.PC.Type.CHOLESKY)
    pc.setFactorSolverType("mumps")


def check_factorization(ksp: PETSc.KSP, matrix: PETSc.Mat) -> None:
    """Fail now, not at the first solve, if the chosen factorization package does not exist.

    PETSc looks the package (-pc_factor_mat_solver_type) up only when the preconditioner
    is set up, at the first solve.  A 2-row-per-rank matrix of ``matrix``'s type factored
    with the same preconditioner and package raises the same PETSc error right away, for
    the cost of nothing.  Call after setFromOptions.  Collective.
    """
    pc = ksp.getPC()
    if pc.getType() not in FACTORIZATIONS:
        return
    probe = PETSc.Mat().create(matrix.getComm())
    probe.setSizes(((2, None), (2, None)), bsize=2)
    probe.setType(matrix.getType())
    probe.setPreallocationNNZ(1)
    start, stop = probe.getOwnershipRange()
    for row in range(start, stop):
        probe.setValue(row, row, 1.0)
    probe.assemble()
    probe.setOption(PETSc.Mat.Option.SPD, True)
    trial = PETSc.KSP().create(matrix.getComm())
    trial.setOperators(probe)
    trial.setType(PETSc.KSP.Type.PREONLY)
    trial.getPC().setType(pc.getType())
    package = pc.getFactorSolverType()
    if package:
        trial.getPC().setFactorSolverType(package)
    try:
        trial.setUp()
    finally:
        trial.destroy()
        probe.destroy()


DEFAULT_TOLERANCES = {"rtol": 1e-10, "atol": 1e-50, "stol": 1e-13, "max_it": 200}
EXACT_FACTORIZATIONS = ("lu", "cholesky")
INEXACT_HINT = "inexact linear solve? tighten -ksp_rtol or use the default direct solver"


def is_exact(ksp: PETSc.KSP) -> bool:
    """True when ``ksp`` solves exactly (to round-off): preonly with an LU or Cholesky PC.

    Read from the types in use, so call after setFromOptions.  ILU/ICC, any Krylov method
    and any other PC are inexact.  Not collective.
    """
    return ksp.getType() == PETSc.KSP.Type.PREONLY and ksp.getPC().getType() in (
        EXACT_FACTORIZATIONS
    )


def step_scale(a_const: PETSc.Mat, b: PETSc.Vec, u0: PETSc.Vec, work: PETSc.Vec) -> float:
    """max(|b|, |A_const u_0|): the forces of a step without contact.  Collective.

    The step tolerance is rtol times this scale: it does not grow with the contact penalty,
    unlike |F(u_0)| (alpha times the predictor's penetration), and it is not zero when only
    the initial guess carries the step (b = 0, u_0 != 0).
    """
    a_const.mult(u0, work)
    return max(b.norm(), work.norm())


def ksp_failure(ksp: PETSc.KSP) -> str:
    return f"KSP reason {reason_name(PETSc.KSP.ConvergedReason, ksp.getConvergedReason())}"


class LinearStepSolver:
    """u = A^-1 b with one factorization (or preconditioner) reused by every step.  Collective.

    The answer is checked like a Newton step's: the residual |b - A u| must meet
    max(atol, rtol * step_scale) with the SNES tolerances (-snes_rtol, -snes_atol,
    -snes_max_it).  An exact solve meets it at once; an iterative KSP that stopped at its
    own, looser tolerance is refined (u += A^-1 r, the same KSP) until it does, and a sweep
    that does not reduce the residual is a failure.
    """

    def __init__(self, comm, a_const: PETSc.Mat):
        self.a_const = a_const
        self.ksp = PETSc.KSP().create(comm)
        self.ksp.setOperators(a_const)
        configure_linear_solver(self.ksp)
        self.ksp.setFromOptions()
        check_factorization(self.ksp, a_const)
        self.exact = is_exact(self.ksp)
        options = PETSc.Options()
        self.rtol = options.getReal("snes_rtol", DEFAULT_TOLERANCES["rtol"])
        self.atol = options.getReal("snes_atol", DEFAULT_TOLERANCES["atol"])
        self.max_sweeps = options.getInt("snes_max_it", DEFAULT_TOLERANCES["max_it"])
        self._residual, self._correction = a_const.createVecLeft(), a_const.createVecRight()
        self.factorizations = 0
        self.jacobian_builds = 0
        self.residual_norm = self.tolerance = float("nan")  # of the last step

    def solve(self, b: PETSc.Vec, u: PETSc.Vec, t: float) -> tuple[int, int]:
        """Solve A u = b to the step tolerance from the guess u (overwritten).  Collective."""
        if self.factorizations == 0:
            self.ksp.setUp()
            self.factorizations = 1
        self.tolerance = max(self.atol, self.rtol * step_scale(self.a_const, b, u, self._residual))
        self._solve(b, u, t)
        linear, previous = self.ksp.getIterationNumber(), np.inf
        for _ in range(self.max_sweeps):
            residual = self._residual
            self.a_const.mult(u, residual)
            residual.aypx(-1.0, b)  # b - A u
            self.residual_norm = residual.norm()
            if self.residual_norm <= self.tolerance:
                return 0, linear
            if not self.residual_norm < previous:  # also catches NaN
                break
            previous = self.residual_norm
            self._solve(residual, self._correction, t)
            u.axpy(1.0, self._correction)
            linear += self.ksp.getIterationNumber()
        raise SolverError(
            f"linear solve failed at t = {t:.6g}: residual {self.residual_norm:.3g} above the "
            f"step tolerance {self.tolerance:.3g} after {linear} linear iterations "
            f"({INEXACT_HINT})"
        )

    def _solve(self, rhs: PETSc.Vec, out: PETSc.Vec, t: float) -> None:
        self.ksp.solve(rhs, out)
        if self.ksp.getConvergedReason() < 0:
            raise SolverError(f"linear solve failed at t = {t:.6g}: {ksp_failure(self.ksp)}")


def reason_name(reasons, reason: int) -> str:
    """``NAME (code)`` of a PETSc converged-reason code, from its enum class ``reasons``."""
    names = {v: k for k, v in vars(reasons).items() if isinstance(v, int)}
    return f"{names.get(reason, 'UNKNOWN')} ({reason})"
