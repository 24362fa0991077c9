"""The initial state of a run: u_0, v_0 by projection and a_0 from the t = 0 balance (SPEC 4).

A mixin of :class:`~parefg.timestepping.simulation.Simulation` (it uses the simulation's
operators, data guard, contact law and work vectors, declared below).  u_0 is the L2
projection of the scene's u0, or, for a dynamic scene with a Dirichlet part, its elliptic
projection, so that a time-independent solution starts at the discrete equilibrium.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from petsc4py import PETSc

from parefg.errors import SolverError
from parefg.parallel import petsc_matrix, set_from_options
from parefg.timestepping.linear_solver import (
    SOLVER_METHODS,
    LinearStepSolver,
    configure_linear_solver,
    set_up_factored,
)
from parefg.timestepping.schemes import State
from parefg.timestepping.step_solver import ContactStepSolver


class InitialState:
    """u_0, v_0, a_0 of a simulation.  Every method is collective."""

    comm: Any
    scene: Any
    disc: Any
    guard: Any
    scheme: Any
    law: Any
    dirichlet_names: list[str]
    neumann_names: list[str]
    _part: PETSc.Vec
    _mass_ksp: PETSc.KSP | None

    _add_dirichlet_data: Callable[..., None]  # Simulation's
    _rigid_body_modes: Callable[..., PETSc.NullSpace]  # Simulation's

    def _project(self, key: str, field) -> PETSc.Vec:
        """L2 projection M d = int rho f . phi of initial field ``key`` (zero stays zero)."""
        disc = self.disc
        points, _ = disc.domain.restore_points()
        x, y = points.T
        values = (
            self.guard.evaluate(("initial", key), field, points, 0.0, x, y).T
            * self.scene.material.rho
        )
        self.guard.check()
        result = disc.create_vec()
        if self.comm.allreduce(bool(np.any(values != 0.0))):
            rhs = disc.create_vec()
            disc.domain.integrate(values, rhs)
            self._mass_solve(rhs, result)
        return result

    def _mass_solve(self, rhs: PETSc.Vec, out: PETSc.Vec) -> None:
        if self._mass_ksp is None:
            ksp = PETSc.KSP().create(self.comm)
            ksp.setOperators(self.disc.mass)
            # once per run (u_0, v_0 projections and a_0): a direct factorization by
            # default, CG with the iterative method; -mass_ksp_type/-mass_pc_type override
            configure_linear_solver(ksp)
            set_from_options(ksp, "mass_", SOLVER_METHODS[self.scene.solver.method].mass)
            set_up_factored(ksp)
            self._mass_ksp = ksp
        self._mass_ksp.solve(rhs, out)
        if self._mass_ksp.getConvergedReason() < 0:
            raise SolverError(
                f"mass-matrix solve failed: KSP reason {self._mass_ksp.getConvergedReason()}"
            )

    def initial_state(self, forces: PETSc.Vec) -> State:
        """u_0, v_0 projected; a_0 from M a_0 = F_0 + L^T w ubar(0) - (K + D) u_0 - contact(u_0).

        ``forces`` is F_0 = external_forces(0).  A dynamic scene with a Dirichlet part
        takes u_0 by the elliptic projection of u0 (:meth:`_elliptic_projection`), so that
        a_0 is the L2 projection of the true acceleration; otherwise (or u0 = 0) by L2.
        """
        u = self._project("u", self.scene.initial.u)
        v = self._project("v", self.scene.initial.v)
        a = self.disc.create_vec()
        if self.scheme.dynamic and self.dirichlet_names and self.scene.initial.grad is not None:
            self._elliptic_projection(u)
        if self.scheme.dynamic:
            rhs = forces.copy()
            self._add_dirichlet_data(0.0, rhs)
            ku = self.disc.create_vec()
            self.disc.stiffness.mult(u, ku)
            rhs.axpy(-1.0, ku)
            self.disc.dirichlet.mult(u, ku)
            rhs.axpy(-1.0, ku)
            if self.law is not None:
                self.law.gate(u)
                self.law.set_time(0.0)
                un, ut = self.law.kinematics(u)
                self.law.slip = ut.copy()  # xi_0 = u_tau(0)
                self.law.begin_step(u)  # the step force at u_0 is the pressure there
                self.law.set_level(un)
                contact_forces = self.disc.create_vec()
                self.law.add_residual(contact_forces, un, ut)
                rhs.axpy(-1.0, contact_forces)
            self.guard.check()
            self._mass_solve(rhs, a)
        elif self.law is not None:
            self.law.slip = self.law.kinematics(u)[1]
        return State(u=u, v=v, a=a)

    def _elliptic_projection(self, u: PETSc.Vec) -> None:
        """u (overwritten; the guess) = P u0, the elliptic projection of u0 for the penalty
        operator, contact included:

            (K + D) P u0 + C(P u0) = -int div sigma(u0) . phi
                + int_{Gamma_N} sigma(u0) nu . phi + L^T w u0|_{Gamma_D},

        C the frictionless penalty contact force (friction carries no force at t = 0, where
        xi_0 = u_tau(0)).  For data compatible with u0 (p = sigma(u0) nu, ubar(0) = u0 on
        Gamma_D, Gamma_C pressed by its own traction) the t = 0 balance then gives
        M a_0 = int (f(0) + div sigma(u0)) . phi = int rho u''(0) . phi, the L2 projection of
        the true acceleration: a time-independent solution starts at the discrete
        equilibrium and stays there, where the L2 projection of u0 excites the stiff
        penalty modes (an undamped period-2 oscillation with beta = 1/2).  Incompatible data
        go into a_0, not into u_0 (the right-hand side uses u0, not the data).  Baker (1976)
        and Dupont (1973) start Galerkin schemes for second-order hyperbolic problems with
        this projection for their optimal error bounds.  Collective; one factorization more.
        """
        rhs = self._projection_rhs()
        matrix = self.disc.combined_rows(0.0, reserve_contact=self.law is not None)
        operator = petsc_matrix(self.comm, matrix, matrix.shape[0], self.disc.n_dofs, block_size=2)
        symmetric = self.disc.symmetric
        operator.setOption(PETSc.Mat.Option.SPD, symmetric)
        operator.setNearNullSpace(self._rigid_body_modes(operator))
        solver: LinearStepSolver | ContactStepSolver
        method, degree = self.scene.solver.method, self.scene.discretization.degree
        blocks = self.disc.trace_blocks
        if self.law is None:
            solver = LinearStepSolver(self.comm, operator, method, symmetric, degree, blocks)
        else:  # the bound is still 0
            solver = ContactStepSolver(
                self.comm, operator, self.law, method, symmetric, degree=degree, trace_blocks=blocks
            )
        try:
            if self.law is None:
                solver.solve(rhs, u, 0.0)
            else:
                with self.law.endpoint_force():  # no time step: no discrete gradient
                    solver.solve(rhs, u, 0.0)
        except SolverError as error:
            raise SolverError(f"initial elliptic projection of initial.u: {error}") from None
        finally:
            for obj in (getattr(solver, "snes", None), getattr(solver, "ksp", None), operator, rhs):
                if obj is not None:
                    obj.destroy()

    def _projection_rhs(self) -> PETSc.Vec:
        """The right-hand side of :meth:`_elliptic_projection` (a new vector).  Collective."""
        scene, disc, part = self.scene, self.disc, self._part
        rhs = disc.create_vec()
        points, _ = disc.domain.restore_points()
        x, y = points.T
        key = ("initial", "u")
        div = self.guard.evaluate(key, scene.initial.div_stress, points, 0.0, x, y)  # (2, n_q)
        disc.domain.integrate(-div.T, rhs)
        for name in self.neumann_names:
            boundary = disc.boundary[name]
            boundary.integrate(self._initial_traction(boundary), part)
            rhs.axpy(1.0, part)
        for name in self.dirichlet_names:
            boundary = disc.boundary[name]
            x, y = boundary.points.T
            trace = self.guard.evaluate(key, scene.initial.u, boundary.points, 0.0, x, y)
            disc.dirichlet_parts[name].add_load(trace.T, rhs)
        self.guard.check()
        return rhs

    def _initial_traction(self, points) -> np.ndarray:
        """sigma(u0) nu at boundary ``points``, (n, 2); checked by the guard."""
        x, y = points.points.T

        def gradient(x, y):
            return self.scene.initial.grad(x, y).reshape(4, -1)  # (4, n)

        rows = self.guard.evaluate(("initial", "u"), gradient, points.points, 0.0, x, y)
        grad = rows.T.reshape(-1, 2, 2)  # (n, 2, 2), [q, i, j] = d u0_i / d x_j
        strain = 0.5 * (grad + np.swapaxes(grad, 1, 2))
        trace = np.trace(strain, axis1=1, axis2=2)  # (n,)
        stress = (
            self.scene.material.lam * trace[:, None, None] * np.eye(2)
            + 2 * self.scene.material.mu * strain
        )
        return np.einsum("qij,qj->qi", stress, points.normals)
