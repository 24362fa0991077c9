"""Solving one time step: minimize J_n(u) = 1/2 u^T A u - b^T u + contact energy (SPEC 4).

Two solvers, chosen by what the scene needs:

* :class:`LinearStepSolver` -- no Gamma_C: J_n is quadratic, each step is one linear
  solve with A_const, factored (or preconditioned) once for the whole run.
* :class:`ContactStepSolver` -- semismooth Newton with PETSc SNES (``newtonls``).  The
  Jacobian A_const + contact terms depends only on the active set (closed / sticking
  points), so it is rebuilt -- and refactored -- only when the active set changes; while
  it is unchanged PETSc keeps the factorization (the matrix state does not move).

The VI-aware line search is a line-search *pre-check* on a ``basic`` (full-step) line
search: given the Newton update Y (PETSc steps x <- x - Y), the pre-check replaces Y by
t* Y with t* the exact minimizer of the convex, piecewise-quadratic J_n(x - t Y).  Its
derivative is monotone and piecewise linear in t; t* is found by Newton's method on the
current linear piece inside a shrinking bracket (exact after finitely many pieces).  So
J_n never increases, and every PETSc option (-snes_monitor, -ksp_type, -pc_type, even
another -snes_linesearch_type) still applies.

Convergence: the full Newton step stayed on one linear piece of the residual (every
Gamma_C point kept its open/closed and stick/slip-direction status) -- then the step
solved the affine residual of that piece exactly, whatever alpha does to the residual's
scale -- or, with a settled active set, the residual meets the SNES tolerances.
"""

from __future__ import annotations

import numpy as np
from petsc4py import PETSc

from parefg.assembly import add_owned_rows
from parefg.errors import SolverError

Reason = PETSc.SNES.ConvergedReason


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


class LinearStepSolver:
    """u = A^-1 b with one factorization reused by every step.  Collective."""

    def __init__(self, comm, a_const: PETSc.Mat):
        self.a_const = a_const
        self.ksp = PETSc.KSP().create(comm)
        self.ksp.setOperators(a_const)
        configure_linear_solver(self.ksp)
        self.ksp.setFromOptions()
        check_factorization(self.ksp, a_const)
        self.factorizations = 0
        self.jacobian_builds = 0

    def solve(self, b: PETSc.Vec, u: PETSc.Vec, t: float) -> tuple[int, int]:
        if self.factorizations == 0:
            self.ksp.setUp()
            self.factorizations = 1
        self.ksp.solve(b, u)
        reason = self.ksp.getConvergedReason()
        if reason < 0:
            raise SolverError(f"linear solve failed at t = {t:.6g}: KSP reason {reason}")
        return 0, self.ksp.getIterationNumber()


class ContactStepSolver:
    """Semismooth Newton (SNES) with the exact line search of SPEC 4.  Collective."""

    def __init__(self, comm, a_const: PETSc.Mat, law):
        self.comm, self.a_const, self.law = comm, a_const, law
        self.jacobian = a_const.duplicate(copy=True)
        # GAMG needs the rigid-body modes on the matrix it is built from
        self.jacobian.setNearNullSpace(a_const.getNearNullSpace())
        self.b = a_const.createVecRight()
        self.smooth = a_const.createVecRight()  # A u - b at the last residual evaluation
        # work vectors of the line search and the energy, allocated once
        self._direction, self._product, self._trial = (a_const.createVecRight() for _ in range(3))
        self.factorizations = 0
        self.jacobian_builds = 0
        self.line_search_log: list[tuple[float, float]] = []  # (J before, J after) per iteration
        self.record_energy = False
        self._signature = None  # active set the Jacobian was built for
        self._last_active = None  # active set at the last residual evaluation
        self._step_active = None  # active set of the iterate a Newton step started from
        self._exact_piece = False
        self.snes = self._create_snes(comm)

    def _create_snes(self, comm) -> PETSc.SNES:
        snes = PETSc.SNES().create(comm)
        snes.setType(PETSc.SNES.Type.NEWTONLS)
        snes.setFunction(self._residual, self.a_const.createVecRight())
        snes.setJacobian(self._jacobian_callback, self.jacobian)
        snes.setLineSearchPreCheck(self._exact_line_search)
        snes.setConvergenceTest(self._converged)
        snes.setTolerances(rtol=1e-12, atol=1e-50, stol=1e-13, max_it=200)
        configure_linear_solver(snes.getKSP())
        # petsc4py 3.18 has no SNES.getLineSearch: the default goes through the options
        # database, only while setFromOptions reads it (no leak into later runs)
        options = PETSc.Options()
        default_line_search = not options.hasName("snes_linesearch_type")
        if default_line_search:
            options.setValue("snes_linesearch_type", "basic")
        try:
            snes.setFromOptions()
        finally:
            if default_line_search:
                options.delValue("snes_linesearch_type")
        check_factorization(snes.getKSP(), self.jacobian)
        return snes

    # -- J_n, its gradient and Jacobian ------------------------------------------
    def energy(self, u: PETSc.Vec) -> float:
        """J_n(u) up to a constant.  Collective."""
        au = self._product
        self.a_const.mult(u, au)
        quadratic = 0.5 * au.dot(u) - self.b.dot(u)
        return quadratic + self.law.energy(*self.law.kinematics(u))

    def _residual(self, snes, u: PETSc.Vec, residual: PETSc.Vec) -> None:
        self.a_const.mult(u, self.smooth)
        self.smooth.axpy(-1.0, self.b)
        self.smooth.copy(residual)
        un, ut = self.law.kinematics(u)
        self.law.add_residual(residual, un, ut)
        self._last_active = self.law.active_set(un, ut)

    def _jacobian_callback(self, snes, u, jacobian, preconditioner) -> None:
        un, ut = self.law.kinematics(u)
        active = self.law.active_set(un, ut)
        self._step_active = active
        changed = self._signature is None or not np.array_equal(active, self._signature)
        if not self.comm.allreduce(changed):
            return  # same matrix: PETSc keeps the factorization
        self.a_const.copy(self.jacobian, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
        add_owned_rows(self.jacobian, self.law.jacobian_rows(un, ut))
        self._signature = active
        self.jacobian_builds += 1

    # -- the VI-aware line search ---------------------------------------------
    def _exact_line_search(self, x: PETSc.Vec, y: PETSc.Vec) -> bool:
        """Scale the update y so that x - y minimizes J_n along -y.  Collective.

        If every Gamma_C point is on the same linear piece at x and at x - y, J_n is one
        quadratic on the whole segment and the full Newton step is its exact minimizer.
        """
        direction = self._direction
        y.copy(direction)
        direction.scale(-1.0)
        un, ut = self.law.kinematics(x)
        dn, dt = self.law.kinematics(direction)
        same_piece = np.array_equal(self.law.piece(un, ut), self.law.piece(un + dn, ut + dt))
        self._exact_piece = self.comm.allreduce(not same_piece) == 0
        before = self.energy(x) if self.record_energy else 0.0
        if not self._exact_piece:
            ad = self._product
            self.a_const.mult(direction, ad)
            curvature = ad.dot(direction)  # d^T A d
            start_slope = self.smooth.dot(direction)  # d^T (A x - b)

            def derivative(step):
                value, slope = self.law.directional(un, ut, dn, dt, step)
                return start_slope + step * curvature + value, curvature + slope

            y.scale(_minimize_monotone(derivative))
        if self.record_energy:
            trial = self._trial
            x.copy(trial)
            trial.axpy(-1.0, y)
            self.line_search_log.append((before, self.energy(trial)))
        return not self._exact_piece

    # -- convergence ------------------------------------------------------------
    def _converged(self, snes, it, norms) -> int:
        xnorm, ynorm, fnorm = norms
        if not np.isfinite(fnorm):
            return Reason.DIVERGED_FNORM_NAN
        if it == 0:
            self._fnorm0 = fnorm
            return Reason.CONVERGED_FNORM_ABS if fnorm == 0.0 else Reason.ITERATING
        if self._exact_piece:  # the full step solved the (affine) residual on its piece
            return Reason.CONVERGED_SNORM_RELATIVE
        rtol, atol, stol, max_it = snes.getTolerances()
        if ynorm <= stol * xnorm:
            # the update is at round-off: the iterate sits on a kink (e.g. u_nu = s to
            # round-off), where both pieces give the same (continuous) residual
            return Reason.CONVERGED_SNORM_RELATIVE
        settled = np.array_equal(self._last_active, self._step_active)
        settled = self.comm.allreduce(not settled) == 0
        if settled and fnorm <= atol:
            return Reason.CONVERGED_FNORM_ABS
        if settled and fnorm <= rtol * self._fnorm0:
            return Reason.CONVERGED_FNORM_RELATIVE
        if it >= max_it:
            return Reason.DIVERGED_MAX_IT
        return Reason.ITERATING

    def solve(self, b: PETSc.Vec, u: PETSc.Vec, t: float) -> tuple[int, int]:
        """Minimize J_n from the initial guess u (overwritten).  Collective."""
        b.copy(self.b)
        before = self.jacobian_builds
        self.snes.solve(None, u)
        reason = self.snes.getConvergedReason()
        newton, linear = self.snes.getIterationNumber(), self.snes.getLinearSolveIterations()
        self.factorizations += self.jacobian_builds - before
        if reason <= 0:
            raise SolverError(
                f"Newton failed at t = {t:.6g}: SNES reason {_reason_name(reason)} after "
                f"{newton} Newton and {linear} linear iterations"
            )
        return newton, linear


def _minimize_monotone(derivative, tol: float = 1e-13, max_iter: int = 200) -> float:
    """Root of a monotone piecewise-linear derivative on [0, inf); Newton inside a bracket.

    ``derivative(t)`` returns (phi'(t), slope of the current piece).  phi'(0) < 0 for a
    descent direction; if not, the direction is not a descent one and 0 is returned.
    """
    d0, _ = derivative(0.0)
    if d0 >= 0.0:
        return 0.0
    scale = abs(d0)
    value, slope = derivative(1.0)
    if abs(value) <= tol * scale:
        return 1.0
    lo, hi = 0.0, np.inf
    step = 1.0
    for _ in range(max_iter):
        if value < 0.0:
            lo = step
        else:
            hi = step
        if abs(value) <= tol * scale or hi - lo <= tol * hi:
            return step
        candidate = step - value / slope if slope > 0.0 else np.inf
        if not lo < candidate < hi:
            candidate = 2.0 * lo if np.isinf(hi) else 0.5 * (lo + hi)
        step = candidate
        value, slope = derivative(step)
    return step


def _reason_name(reason: int) -> str:
    names = {v: k for k, v in vars(Reason).items() if isinstance(v, int)}
    return f"{names.get(reason, 'UNKNOWN')} ({reason})"
