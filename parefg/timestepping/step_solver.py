"""Solving one time step: minimize J_n(u) = 1/2 u^T A u - b^T u + contact energy (SPEC 4).

Without Gamma_C a step is one linear solve (:mod:`parefg.timestepping.linear_solver`);
with it:

* :class:`ContactStepSolver` -- semismooth Newton with PETSc SNES (``newtonls``).  The
  Jacobian A_const + contact terms depends only on the active set (closed / sticking
  points), so it is rebuilt -- and refactored -- only when the active set changes; while
  it is unchanged PETSc keeps the factorization (the matrix state does not move).

The VI-aware line search is a line-search *pre-check* on a ``basic`` (full-step) line
search: given the Newton update Y (PETSc steps x <- x - Y), the pre-check replaces Y by
t* Y with t* the exact minimizer of the convex, piecewise-quadratic J_n(x - t Y).  Its
derivative is monotone and piecewise linear in t (piecewise smooth where the
discrete-gradient contact force crosses the obstacle, parefg.mechanics.contact); t* is
found by Newton's method on the current piece inside a shrinking bracket.  So
J_n never increases, and every PETSc option (-snes_monitor, -ksp_type, -pc_type, ...)
still applies; -snes_linesearch_type may be basic (default), bt, cp or nleqerr (see
:data:`LINE_SEARCHES`).

Convergence (both solvers): the residual F(u) = A u - b + contact forces meets the step
tolerance ``max(atol, rtol * scale)`` with ``scale = max(|b|, |A_const u_0|)`` -- the forces of
the step without contact, which do not grow with the contact penalty (a tolerance relative
to |F(u_0)|, dominated by alpha times the predictor's penetration, would) -- and, with
contact, the active set did not change in the last iteration.  rtol, atol and max_it are
the SNES tolerances (-snes_rtol, -snes_atol, -snes_max_it; defaults 1e-10, 1e-50, 200).
Only when the linear solve is exact (KSP ``preonly`` with an LU or Cholesky PC, read after
setFromOptions) two shortcuts are taken: a full Newton step that stayed on its linear piece
of the residual solved the step exactly (with the basic, undamped line search its residual
is then not evaluated: one product with A_const less), and an update below stol |u| is at
round-off.  A Newton direction that is not a descent direction of J_n, where the residual
does not meet the tolerance, ends the step as a failure.

With a GAMG preconditioner that keeps its first interpolation for later Jacobians (the
iterative method's default), a step whose linear solve fails is redone from u_0, once,
with a hierarchy built for each Jacobian of that step (:func:`set_up_afresh`).

Products with A_const: one per Newton iterate (:class:`ReusedProduct` serves the same x
to the step scale, the residual and the line search), none at the accepted exact step.

The reused-factorization step (:meth:`ContactStepSolver._reused_step`): most steps are
one Newton step on the kept factorization that lands on the linear piece it started from.
Under the default SNES configuration (newtonls, the basic undamped line search, an exact
solve, nothing monitored or viewed; see :func:`_reused_step_allowed`) that step is taken
without SNES's machinery (measured on square, m = 2, h = 1/8: 0.85 against 0.95 ms per
step, the factored solve ~0.1 ms): the same residual, the same KSP solve with the kept
factorization and the same descent and piece tests, so it accepts exactly the steps SNES
would accept at its first iteration, with the same bits.  Any other case -- the active
set at u_0 is not the one the factorization was built for, a non-affine piece, a failed
or non-descent solve, a step that leaves its piece -- goes to SNES from the unchanged u_0.
"""

from __future__ import annotations

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from parefg.errors import InputError, SolverError
from parefg.parallel import add_owned_rows, set_from_options
from parefg.timestepping.linear_solver import (
    DEFAULT_SOLVER_METHOD,
    DEFAULT_TOLERANCES,
    INEXACT_HINT,
    SOLVER_METHODS,
    check_factorization,
    check_symmetric_use,
    configure_linear_solver,
    is_exact,
    keeps_interpolation,
    ksp_failure,
    reason_name,
    scaled_ksp_tolerance,
    set_ksp_tolerance,
    set_up_afresh,
    set_up_step_ksp,
    step_scale,
)
from parefg.timestepping.shared_jacobian import SharedConstant

Reason = PETSc.SNES.ConvergedReason

# Measured (square, z, stick, impact): bt, cp and nleqerr give the errors of "basic" to
# 1e-11.  l2 fits a parabola to |F|^2, which is only piecewise smooth here: on impact it
# jumps to lambda ~ 2 past a kink at every iteration although lambda = 1 gives |F| ~ 1e-13,
# and fails at max_it (t = 0.36).  shell has no function; ncglinear belongs to NCG.
LINE_SEARCHES = ("basic", "bt", "cp", "nleqerr")

# SNES options under which the reused-factorization step is the step SNES takes: the
# tolerances and the defaults the step sets (their values are checked separately)
REUSED_STEP_SNES_OPTIONS = (
    "snes_rtol",
    "snes_atol",
    "snes_stol",
    "snes_max_it",
    "snes_type",
    "snes_linesearch_type",
    "snes_linesearch_damping",
)


#: round-off growth of an exact step's residual beyond eps sqrt(n) |J|_inf |u|_inf
ROUNDOFF_GROWTH = 1e3


class ContactStepSolver:
    """Semismooth Newton (SNES) with the exact line search of SPEC 4.  Collective."""

    def __init__(
        self,
        comm,
        a_const: PETSc.Mat,
        law,
        method: str = DEFAULT_SOLVER_METHOD,
        symmetric: bool = True,
        shared_rows: np.ndarray | None = None,
        degree: int | None = None,
        trace_blocks=None,
    ):
        """``degree``: the MLS degree, whose preconditioner the method may adapt, with the
        discretization's ``trace_blocks`` (:meth:`SolverMethod.finest_level`).
        ``shared_rows``: the local Gamma_C rows, to keep A_const in the Jacobian's
        storage (:class:`~parefg.timestepping.shared_jacobian.SharedConstant`; the
        caller then uses ``self.a_const``, not the matrix it gave); None: J is a copy."""
        self.comm, self.law = comm, law
        self.method = SOLVER_METHODS[method]
        self._finest = self.method.finest_level(degree, trace_blocks)
        self.symmetric = symmetric  # A_const's symmetry (False with VCI): the factorization
        self.a_const: PETSc.Mat | SharedConstant
        if shared_rows is None:
            self.a_const, self.jacobian = a_const, a_const.duplicate(copy=True)
            # GAMG needs the rigid-body modes on the matrix it is built from
            self.jacobian.setNearNullSpace(a_const.getNearNullSpace())
        else:  # the caller lets a_const go: J and a strip of A_const's rows are kept
            self.a_const = SharedConstant(comm, a_const, shared_rows)
            self.jacobian = self.a_const.jacobian
        self.b = a_const.createVecRight()
        # A_const x of the last x it was formed for: the step scale's A u_0 is the first
        # residual's, the line search's A x - b at x is the residual's just computed at x
        self._products = ReusedProduct(comm, self.a_const)
        # work vectors of the line search, the residual check and the energy, allocated once
        self._direction, self._product, self._smooth, self._check, self._update = (
            a_const.createVecRight() for _ in range(5)
        )
        self._start = a_const.createVecRight()  # u_0 of the step, for a retried solve
        self.factorizations = 0
        self.jacobian_builds = 0
        # the Jacobian build whose exact-step acceptances have been checked (see _verify)
        self._verified_build = -1
        self.residual_norm = self.tolerance = float("nan")  # of the last step
        self._signature: np.ndarray | None = None  # active set the Jacobian was built for
        # active set of the iterate a Newton step started from (set before any step test)
        self._step_active: np.ndarray = np.zeros(0, dtype=bool)
        self._exact_piece = False
        self._step_norm = 0.0  # |update| the pre-check handed to the line search
        # the pre-check found the full step exact: the line search's trial point x - y
        # solves the step, and its residual is not evaluated (see _residual)
        self._solved_by_step = False
        self._failure: str | None = None  # why the running step must fail
        self.snes = self._create_snes(comm)
        self.exact = is_exact(self.snes.getKSP())
        # GAMG set up for a new Jacobian keeps the interpolation of an earlier one: a linear
        # solve failing with it is retried once with a new hierarchy (see solve)
        self._keeps_interpolation = keeps_interpolation(self.snes.getKSP(), self.method)
        self._set_up = False  # the step preconditioner was set up at least once
        self._interpolation_kept = False  # its last set-up kept an earlier interpolation
        self._afresh = False  # every set-up builds a new hierarchy (a retried step)
        self.fresh_preconditioners = 0  # retries with a new hierarchy
        self.scaled_tolerance = scaled_ksp_tolerance(self.method)
        # read while the step's options are in the database (the caller's scene options)
        self._reuse = (
            self.exact
            and self._full_trial
            and self.snes.getType() == PETSc.SNES.Type.NEWTONLS
            and _reused_step_allowed(PETSc.Options().getAll())
        )
        self.reused_steps = 0  # steps taken by _reused_step

    def _create_snes(self, comm) -> PETSc.SNES:
        snes = PETSc.SNES().create(comm)
        snes.setType(PETSc.SNES.Type.NEWTONLS)
        snes.setFunction(self._residual, self.a_const.createVecRight())
        snes.setJacobian(self._jacobian_callback, self.jacobian)
        snes.setLineSearchPreCheck(self._exact_line_search)
        snes.setConvergenceTest(self._converged)
        snes.setTolerances(**DEFAULT_TOLERANCES)
        configure_linear_solver(snes.getKSP(), self.symmetric)
        # the line search evaluates F at x - y exactly (basic, undamped): see _residual
        self._full_trial = _check_line_search(PETSc.Options())
        # the step's options are the unprefixed ones (-snes_rtol, -ksp_type: the README's);
        # petsc4py 3.18 has no SNES.getLineSearch, so the default line search is offered
        # through the options database while this SNES reads it, and removed after
        # (and the solver method's KSP options, read by the SNES's KSP)
        set_from_options(snes, "", {"snes_linesearch_type": "basic", **self.method.step})
        check_symmetric_use(snes.getKSP(), self.symmetric)
        check_factorization(snes.getKSP(), self.jacobian)
        return snes

    # -- J_n, its gradient and Jacobian ------------------------------------------
    def energy(self, u: PETSc.Vec) -> float:
        """J_n(u) up to a constant.  Collective."""
        au = self._product
        self.a_const.mult(u, au)
        quadratic = 0.5 * au.dot(u) - self.b.dot(u)
        return quadratic + self.law.energy(*self.law.kinematics(u))

    def _smooth_residual(self, u: PETSc.Vec, out: PETSc.Vec) -> PETSc.Vec:
        """out = A_const u - b, the gradient of J_n without contact.  Collective."""
        self._products.mult(u, out)
        out.axpy(-1.0, self.b)
        return out

    def _evaluate(self, u: PETSc.Vec, residual: PETSc.Vec) -> tuple[float, np.ndarray]:
        """residual = F(u); returns |F(u)| and this rank's active set at u.  Collective."""
        self._smooth_residual(u, residual)
        un, ut = self.law.kinematics(u)
        self.law.add_residual(residual, un, ut)
        return residual.norm(), self.law.active_set(un, ut)

    def _residual(self, snes, u: PETSc.Vec, residual: PETSc.Vec) -> None:
        """SNES's function: residual = F(u) (its norm and the active set are not needed).

        At the trial point of a full step the pre-check found exact (an exact solve, every
        point on one affine piece of F: F(x - y) = F(x) - J y = 0 up to round-off), the
        step is solved and the convergence test accepts it whatever |F| is: F is set to
        that exact 0 instead of being evaluated (it would cost one product with A_const).
        """
        if self._solved_by_step:  # the convergence test accepts the step (and resets this)
            residual.set(0.0)
            return
        self._smooth_residual(u, residual)
        self.law.add_residual(residual, *self.law.kinematics(u))

    def _jacobian_callback(self, snes, u, jacobian, preconditioner) -> None:
        un, ut = self.law.kinematics(u)
        active = self.law.active_set(un, ut)
        self._step_active = active
        # a normal force that is not affine in u (negative piece code) has a Jacobian that
        # varies with u: rebuild it now, and again at the next call whatever the active set
        varying = bool(np.any(self.law.piece(un, ut) < 0))
        built = self._signature
        changed = varying or built is None or not np.array_equal(active, built)
        if not self.comm.allreduce(changed):
            return  # same matrix: PETSc keeps the factorization
        contact_rows = self.law.jacobian_rows(un, ut)
        if isinstance(self.a_const, SharedConstant):
            self.a_const.set_jacobian(contact_rows)
        else:
            self.a_const.copy(self.jacobian, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
            add_owned_rows(self.jacobian, contact_rows)
        self._signature = None if varying else active
        self.jacobian_builds += 1
        # set up now, not in SNES's linear solve: a factorization short of workspace is
        # redone (set_up_factored), and GAMG's finest level is made for the new matrix
        ksp = snes.getKSP()
        ksp.setOperators(jacobian, preconditioner)
        if self._afresh:  # a retried step (see solve): no earlier interpolation kept
            set_up_afresh(ksp, self.method, self._finest)
        else:
            set_up_step_ksp(ksp, self._finest)
        self._interpolation_kept = self._keeps_interpolation and self._set_up and not self._afresh
        self._set_up = True

    # -- the VI-aware line search ---------------------------------------------
    def _exact_line_search(self, x: PETSc.Vec, y: PETSc.Vec) -> bool:
        """Scale the update y so that x - y minimizes J_n along -y.  Collective.

        With an exact linear solve, if every Gamma_C point is on the same linear piece at x
        and at x - y, J_n is one quadratic on the whole segment and the full Newton step is
        its exact minimizer.  Everything is computed here, at x: a line search of another
        type evaluates the residual at other points.  A direction along which J_n does not
        decrease stops the step (see :meth:`_not_descent`), whatever the solver.
        """
        direction = self._direction
        un, ut, d_nu, d_tau, start_slope, start = self._line_start(x, y)
        curvature = None  # d^T A d, computed only for the scan

        def derivative(step):
            value, slope = self.law.directional(un, ut, d_nu, d_tau, step)
            return start_slope + step * curvature + value, curvature + slope

        if start >= 0.0:  # phi'(0)
            self._not_descent(x, start)
            self._exact_piece = False
            y.scale(0.0)
            return True
        self._exact_piece = self.exact and self._on_one_piece(un, ut, d_nu, d_tau)
        self._solved_by_step = self._exact_piece and self._full_trial
        if not self._exact_piece:
            self.a_const.mult(direction, self._product)
            curvature = self._product.dot(direction)
            y.scale(_minimize_monotone(derivative, derivative(0.0)))
        self._step_norm = y.norm()
        return not self._exact_piece

    def _line_start(self, x: PETSc.Vec, y: PETSc.Vec):
        """The line x + t d, d = -y (in self._direction), at t = 0.  Collective.

        Returns u_nu, u_tau at x, d_nu, d_tau, d^T (A_const x - b) and phi'(0), the
        derivative of J_n along d.
        """
        direction = self._direction
        y.copy(direction)
        direction.scale(-1.0)
        un, ut = self.law.kinematics(x)
        d_nu, d_tau = self.law.kinematics(direction)
        start_slope = self._smooth_residual(x, self._smooth).dot(direction)  # d^T (A x - b)
        value, _ = self.law.directional(un, ut, d_nu, d_tau, 0.0)
        return un, ut, d_nu, d_tau, start_slope, start_slope + value

    def _on_one_piece(self, un, ut, d_nu, d_tau, piece=None) -> bool:
        """Every point on the same affine piece of F at u and at u + d.  Collective.

        ``piece``: the law's pieces at u, if the caller has them."""
        if piece is None:
            piece = self.law.piece(un, ut)
        # (piece == ...).all(): np.array_equal on arrays of one shape, without its layers
        same_piece = (piece >= 0).all() and (piece == self.law.piece(un + d_nu, ut + d_tau)).all()
        return self.comm.allreduce(not same_piece) == 0

    def _not_descent(self, x: PETSc.Vec, slope: float) -> None:
        """phi'(0) >= 0: fail the step unless x already meets the tolerance.  Collective.

        For an SPD Jacobian the exact Newton direction is always a descent one; phi'(0) >= 0
        means an inexact (or broken) linear solve, or round-off at a converged iterate.
        """
        fnorm, _ = self._evaluate(x, self._check)
        if fnorm <= self.tolerance:
            return  # nothing left to gain: the step of 0 keeps x, which the test accepts
        self._failure = (
            "the Newton direction is not a descent direction (directional derivative "
            f"{slope:.3g} >= 0 at |F| = {fnorm:.3g}, tolerance {self.tolerance:.3g}; "
            f"{INEXACT_HINT})"
        )

    # -- convergence ------------------------------------------------------------
    def _converged(self, snes, it, norms) -> int:
        """|F(x)| <= tolerance on a settled active set; shortcuts only for exact solves.

        |F(x)| is the norm of SNES's function vector, which newtonls keeps at the iterate
        after every line search (the next direction solves with it); the active set is
        taken here at the iterate.  A step the pre-check found exact is accepted without
        either (on one affine piece the active set cannot change).
        """
        xnorm, ynorm, _ = norms
        if self._failure is not None:
            return Reason.DIVERGED_LINE_SEARCH
        if self._solved_by_step:  # the pre-check's exact full step (see _residual)
            self._solved_by_step = False
            self.residual_norm = float("nan")  # not evaluated
            return Reason.CONVERGED_SNORM_RELATIVE
        # newtonls holds F(x) in its function vector (the next Newton step solves with it)
        fnorm = snes.getFunction()[0].norm()
        active = self.law.active_set(*self.law.kinematics(snes.getSolution()))
        self.residual_norm = fnorm
        if not np.isfinite(fnorm):
            return Reason.DIVERGED_FNORM_NAN
        if it == 0:
            return Reason.CONVERGED_FNORM_ABS if fnorm <= self.tolerance else Reason.ITERATING
        settled = self.comm.allreduce(not np.array_equal(active, self._step_active)) == 0
        if settled and fnorm <= self.tolerance:
            return Reason.CONVERGED_FNORM_ABS
        rtol, atol, stol, max_it = snes.getTolerances()
        small_update = ynorm <= stol * xnorm
        # exact solve: the full step solved the (affine) residual on its piece, or the update
        # is at round-off because the iterate sits on a kink (e.g. u_nu = s to round-off)
        # (the shortcut needs the full step: another line search type may have scaled it)
        full_step = abs(ynorm - self._step_norm) <= 1e-8 * self._step_norm
        if self.exact and ((self._exact_piece and full_step) or small_update):
            return Reason.CONVERGED_SNORM_RELATIVE
        if small_update:
            self._failure = (
                f"the Newton update is below stol |u| while |F| = {fnorm:.3g} exceeds the "
                f"tolerance {self.tolerance:.3g} ({INEXACT_HINT})"
            )
            return Reason.DIVERGED_LINE_SEARCH
        if it >= max_it:
            return Reason.DIVERGED_MAX_IT
        return Reason.ITERATING

    def solve(self, b: PETSc.Vec, u: PETSc.Vec, t: float) -> tuple[int, int]:
        """Minimize J_n from the initial guess u (overwritten).  Collective."""
        b.copy(self.b)
        rtol, atol, _, max_it = self.snes.getTolerances()
        self.tolerance = max(atol, rtol * step_scale(self.a_const, b, u, self._check))
        self._products.remember(u, self._check)  # A u_0: the first residual's product
        if self.scaled_tolerance:
            set_ksp_tolerance(self.snes.getKSP(), self.tolerance)
        self._failure = None
        self._solved_by_step = False
        if self._reuse and max_it >= 1:
            iterations = self._reused_step(u)
            if iterations is not None:
                self.reused_steps += 1
                self._verify(u, t)
                return iterations
        u.copy(self._start)
        reason, newton, linear = self._snes_solve(u)
        retried = reason == Reason.DIVERGED_LINEAR_SOLVE and self._interpolation_kept
        if retried:
            # an interpolation made for an earlier Jacobian may not serve this one: the step
            # again from u_0, once, each Jacobian with a hierarchy of its own
            self.fresh_preconditioners += 1
            self._start.copy(u)
            self._failure = None
            self._solved_by_step = False
            self._afresh = True
            try:
                set_up_afresh(self.snes.getKSP(), self.method, self._finest)
                reason, newton_again, linear_again = self._snes_solve(u)
            finally:
                self._afresh = False
            self._interpolation_kept = False
            newton, linear = newton + newton_again, linear + linear_again
        if reason <= 0:
            again = " (redone with a new preconditioner hierarchy)" if retried else ""
            raise SolverError(
                f"Newton failed at t = {t:.6g}{again}: {self._why(reason, newton, linear)}"
            )
        self._verify(u, t)
        return newton, linear

    def _snes_solve(self, u: PETSc.Vec) -> tuple[int, int, int]:
        """SNES from u (overwritten): its reason, Newton and linear iterations.  Collective."""
        before = self.jacobian_builds
        self.snes.solve(None, u)
        self.factorizations += self.jacobian_builds - before
        snes = self.snes
        return snes.getConvergedReason(), snes.getIterationNumber(), snes.getLinearSolveIterations()

    def _verify(self, u: PETSc.Vec, t: float) -> None:
        """Check a step accepted as an exact solve, once per Jacobian build.  Collective.

        The exact-step shortcuts accept a full Newton step on one affine piece without
        evaluating F, trusting the factorization to solve J y = F.  The first such step of
        each factorization pays one residual evaluation to confirm it: a factorization
        that solves another system (Cholesky of a nonsymmetric matrix reads one triangle)
        fails the run here, not silently.  Scale-aware: F of an exact step is the round-off
        of evaluating J u, up to ~ eps |J|_inf |u|_inf per entry, which a stiff penalty lifts
        above the step tolerance (alpha_C = 1e12 E/h: |F| = 2e-9 against 2e-10); the bound
        is the larger of the two, with ROUNDOFF_GROWTH sqrt(n) for the 2-norm and the
        factorization's growth.
        """
        if not np.isnan(self.residual_norm) or self._verified_build == self.jacobian_builds:
            return
        self._verified_build = self.jacobian_builds
        fnorm, _ = self._evaluate(u, self._check)
        infinity = PETSc.NormType.INFINITY
        size = self.jacobian.getSize()[0]
        roundoff = ROUNDOFF_GROWTH * np.sqrt(size) * np.finfo(float).eps
        bound = max(self.tolerance, roundoff * self.jacobian.norm(infinity) * u.norm(infinity))
        if not fnorm <= bound:  # also catches NaN
            raise SolverError(
                f"Newton failed at t = {t:.6g}: a step accepted as an exact solve leaves "
                f"|F| = {fnorm:.3g} above the tolerance {self.tolerance:.3g} and its "
                f"round-off {bound:.3g} (the factorization does not solve the Jacobian: a "
                "nonsymmetric matrix factored by Cholesky?)"
            )

    def _reused_step(self, u: PETSc.Vec) -> tuple[int, int] | None:
        """The step without SNES, when SNES would end it at its first test or Newton step.

        SNES's iteration from u_0, with the same calls: |F(u_0)| <= tolerance ends it at
        once (0 iterations); else the Jacobian at u_0 is the factored one (the active set
        it was built for, no non-affine piece), J y = F(u_0) is solved with that
        factorization, and the full step u_0 - y is accepted when y is a descent direction
        and every point stays on its affine piece (_exact_line_search's exact step).
        Returns (Newton, linear) iterations; None, with u unchanged, where SNES must take
        the step.  Collective.
        """
        residual = self._check  # F(u_0); the step scale no longer needs this vector
        fnorm, active = self._evaluate(u, residual)
        if not np.isfinite(fnorm):
            return None  # SNES reports it
        if fnorm <= self.tolerance:
            self.residual_norm = fnorm
            return 0, 0
        un, ut = self.law.kinematics(u)
        built = self._signature
        stale = built is None or not (active == built).all()  # one shape (this rank's points)
        piece = self.law.piece(un, ut)
        if self.comm.allreduce(stale or bool(np.any(piece < 0))):
            return None  # SNES rebuilds the Jacobian
        ksp = self.snes.getKSP()
        ksp.solve(residual, self._update)
        if ksp.getConvergedReason() < 0:
            return None
        un, ut, d_nu, d_tau, _, start = self._line_start(u, self._update)
        if start >= 0.0 or not self._on_one_piece(un, ut, d_nu, d_tau, piece):
            return None
        u.axpy(-1.0, self._update)
        self.residual_norm = float("nan")  # not evaluated, as SNES's exact step
        return 1, ksp.getIterationNumber()

    def _why(self, reason: int, newton: int, linear: int) -> str:
        counts = f"after {newton} Newton and {linear} linear iterations"
        if self._failure is not None:
            return f"{self._failure}, {counts}"
        detail = ""
        if reason == Reason.DIVERGED_LINEAR_SOLVE:
            detail = f", {ksp_failure(self.snes.getKSP())}"
        return f"SNES reason {reason_name(Reason, reason)}{detail} {counts}"


class ReusedProduct:
    """y = A x that reuses the last product when x holds the same values.  Collective.

    A Newton step forms A x at the same x up to three times (the step scale at u_0, the
    residual, the line search's slope); the saved product is copied instead (the same
    bits as a new product).  A must not change while the object is used.
    """

    def __init__(self, comm, matrix: PETSc.Mat | SharedConstant):
        self.comm, self.matrix = comm, matrix
        self._input, self._output = matrix.createVecRight(), matrix.createVecLeft()
        self._valid = False  # the same on every rank: set by collective calls only

    def mult(self, x: PETSc.Vec, out: PETSc.Vec) -> PETSc.Vec:
        """out = A x (returned).  Collective."""
        if self._valid and self._holds(x):
            self._output.copy(out)
        else:
            self.matrix.mult(x, out)
            self.remember(x, out)
        return out

    def remember(self, x: PETSc.Vec, product: PETSc.Vec) -> None:
        """Keep ``product`` = A x for a later :meth:`mult` at the same x.  Not collective."""
        x.copy(self._input)
        product.copy(self._output)
        self._valid = True

    def _holds(self, x: PETSc.Vec) -> bool:
        """x has the values of the saved input on every rank.  Collective (one allreduce)."""
        # one layout: np.array_equal without its layers
        same = bool((x.getArray(readonly=True) == self._input.getArray(readonly=True)).all())
        return same if self.comm.size == 1 else self.comm.allreduce(same, op=MPI.LAND)


def _minimize_monotone(derivative, start, tol: float = 1e-13, max_iter: int = 200) -> float:
    """Root of a monotone piecewise-linear derivative on [0, inf); Newton inside a bracket.

    ``derivative(t)`` returns (phi'(t), slope of the current piece); ``start`` is
    derivative(0), with phi'(0) < 0 (a descent direction: the caller checks).
    """
    d0, _ = start
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


def _reused_step_allowed(options: dict) -> bool:
    """No option that changes SNES's first Newton step, or prints or records it.

    ``options`` is the options database (PETSc.Options().getAll()).  Only the SNES
    options of :data:`REUSED_STEP_SNES_OPTIONS`, and no KSP or PC monitor or viewer (their
    output is the user's: -ksp_monitor, -ksp_view, -ksp_converged_reason).  Not collective.
    """
    for key in options:
        if "snes_" in key and key not in REUSED_STEP_SNES_OPTIONS:
            return False
        if ("ksp_" in key or "pc_" in key) and any(
            word in key for word in ("monitor", "view", "converged_reason")
        ):
            return False
    return True


def _check_line_search(options: PETSc.Options) -> bool:
    """Refuse a -snes_linesearch_type the exact pre-check does not work with.  Not collective.

    Returns whether the line search takes the pre-check's step as it is: "basic" without
    damping evaluates F at x - y and accepts it.
    """
    kind = options.getString("snes_linesearch_type", "basic")
    if kind not in LINE_SEARCHES:
        raise InputError(
            f"-snes_linesearch_type {kind}: not supported with the exact line search; "
            f"allowed: {', '.join(LINE_SEARCHES)}"
        )
    return kind == "basic" and options.getReal("snes_linesearch_damping", 1.0) == 1.0
