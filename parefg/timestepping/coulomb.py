"""Coulomb friction in a step: a fixed point on Tresca bounds (SPEC 1, 4).

Coulomb's bound g = mu_f p depends on the solution through the contact pressure
p = alpha_C (u_nu - s)^+, so the step's equations are no longer the gradient of a convex
energy (the law is non-associated).  Each outer iteration k solves the convex Tresca step
of :class:`~parefg.timestepping.step_solver.ContactStepSolver` with the bound frozen,

    g^(0) = mu_f p(u_{n-1}),
    u^(k) = argmin J_n(u; g^(k-1)),   g^(k) = mu_f p(u^(k)),

so the exact line search keeps its guarantee inside every solve.  Starting from the last
step's pressure, not the predictor's, was measured 3x cheaper on a sliding block (m = 1,
h = 1/16, beta = 0.3025, gamma = 0.6: 804 against 2383 Newton iterations over 50 steps):
the predictor carries dt^2 (1/2 - beta) a, which is large where the penalty acts.  The
first step of a run starts from the predictor's pressure; a restart from the checkpointed
u_{n-1} (:meth:`CoulombStepSolver.resume`), so it repeats the uninterrupted run.

The step has converged when the Coulomb residual F(u^(k); mu_f p(u^(k))) -- the Tresca
residual with the bound taken from the iterate itself -- meets the step tolerance of the
inner solve (max(atol, rtol max(|b|, |A_const u|)), the SNES tolerances): the bound's lag
is then below what the step accepts from Newton anyway, and the friction force reported
at a sliding point is mu_f p of the final state.  Each outer iteration starts Newton from
the last iterate, so once the active set has settled an inner solve costs one Newton
iteration on the kept factorization.

Why not semismooth Newton on the nonsymmetric system: measured in
scripts/bench/bench_coulomb.py (prototype with LU and backtracking on |F|; no energy is left for
the exact line search), it needs fewer Newton iterations (84 against 246 on the
manufactured solution) but one nonsymmetric factorization per iteration (84 against 6
Cholesky), and it stalled where the sliding block stops, at every mu_f of 0.3 ... 2,
where the fixed point passes.  The fixed point contracts more slowly as mu_f grows: at
most 6, 9, 10, 15 and 44 outer iterations per step on the block for mu_f = 0.1, 0.3, 0.5,
1 and 2.  Beyond ``-coulomb_max_it`` outer iterations (default :data:`DEFAULT_MAX_OUTER`)
the step fails with a SolverError naming the residuals.  The option is read under the
options prefix of the step's SNES, like the -snes_max_it of the inner solves (the
command line or the scene's [solver] table set it).
"""

from __future__ import annotations

import numpy as np
from petsc4py import PETSc

from parefg.errors import InputError, SolverError
from parefg.timestepping.step_solver import ContactStepSolver

#: outer (bound) iterations per step before the step fails; -coulomb_max_it overrides
DEFAULT_MAX_OUTER = 100


class CoulombStepSolver(ContactStepSolver):
    """A step with Coulomb parts: Tresca solves on frozen bounds, iterated.  Collective.

    :attr:`outer_iterations` is the count of the last step (one inner solve each),
    :attr:`outer_residuals` the Coulomb residual after each of them.
    """

    def __init__(self, *args, **kwargs) -> None:
        """As :class:`ContactStepSolver`, plus the outer iteration's limit and counters."""
        super().__init__(*args, **kwargs)
        self.max_outer_option = f"-{self.snes.getOptionsPrefix() or ''}coulomb_max_it"
        self.max_outer = self._read_max_outer()
        self.outer_iterations = 0
        self.outer_residuals: list[float] = []
        self._previous_normal: np.ndarray | None = None  # u_nu of the last step, this rank

    def _read_max_outer(self) -> int:
        """-coulomb_max_it with the SNES's prefix; InputError unless >= 1.  Not collective.

        Every rank reads the same options and so decides alike; a value that is not an
        integer is PETSc's error, which the caller's petsc_configuration turns into an
        InputError.
        """
        options = PETSc.Options(self.snes.getOptionsPrefix())
        max_outer = options.getInt("coulomb_max_it", DEFAULT_MAX_OUTER)
        if max_outer < 1:
            raise InputError(f"{self.max_outer_option} {max_outer}: must be at least 1")
        return max_outer

    def resume(self, u_previous: PETSc.Vec) -> None:
        """Start the next step's fixed point from the pressure of ``u_previous`` (restart).

        A restarted run then takes the iterates of the uninterrupted one.  Collective.
        """
        self._previous_normal = self.law.kinematics(u_previous)[0]

    def solve(self, b: PETSc.Vec, u: PETSc.Vec, t: float) -> tuple[int, int]:
        """Solve the Coulomb step from the initial guess u (overwritten).  Collective.

        Returns the Newton and linear iterations summed over the outer iterations; the
        law's bound is mu_f p(u) of the returned u.
        """
        start = self._previous_normal
        self.law.set_pressure_bound(self.law.kinematics(u)[0] if start is None else start)
        newton = linear = 0
        self.outer_residuals = []
        for outer in range(1, self.max_outer + 1):
            inner_newton, inner_linear = super().solve(b, u, t)
            newton, linear = newton + inner_newton, linear + inner_linear
            self.law.set_pressure_bound(self.law.kinematics(u)[0])
            fnorm, _ = self._evaluate(u, self._check)  # F(u; mu_f p(u)), the same on all ranks
            self.outer_residuals.append(fnorm)
            self.outer_iterations = outer
            if fnorm <= self.tolerance:
                self.residual_norm = fnorm
                self._previous_normal = self.law.kinematics(u)[0]
                return newton, linear
            if not np.isfinite(fnorm):
                break
        raise SolverError(f"Coulomb friction failed at t = {t:.6g}: {self._why_outer()}")

    def _why_outer(self) -> str:
        """The residual history of a fixed point that did not converge."""
        residuals = self.outer_residuals
        last = residuals[-1]
        rate = ""
        if len(residuals) >= 3 and residuals[-3] > 0:
            rate = f", contraction {np.sqrt(last / residuals[-3]):.3g} per iteration"
        return (
            f"the fixed point on the friction bound did not converge: residual {last:.3g} "
            f"above the step tolerance {self.tolerance:.3g} after {len(residuals)} outer "
            f"iterations ({self.max_outer_option} {self.max_outer}){rate}; a smaller "
            "friction_coefficient or time.dt makes it contract"
        )
