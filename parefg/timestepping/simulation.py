"""One run of a scene: operators -> initial state -> time loop -> errors (SPEC 4).

The loop skips what a scene does not need: without Gamma_C every step is one linear
solve with A_const factored once (:class:`LinearStepSolver`); with Gamma_C each step is
a semismooth Newton solve that reuses the factorization while the active set holds; with
g = 0 no tangential terms enter; errors are computed only with an exact solution.
"""

from __future__ import annotations

import math

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from parefg.boundary import BoundaryKind
from parefg.errors import SolverError
from parefg.guards import DataGuard, RigidModes, all_finite, require_constraints
from parefg.mechanics.contact import ContactLaw
from parefg.parallel import petsc_matrix, with_pattern
from parefg.profiling import phase
from parefg.timestepping.coulomb import CoulombStepSolver
from parefg.timestepping.schemes import State, make_scheme, relative_errors
from parefg.timestepping.step_solver import (
    ContactStepSolver,
    LinearStepSolver,
    configure_linear_solver,
)

# Energies held by the state; with the external work they balance (see Simulation._record).
STORED_ENERGIES = ("kinetic_energy", "elastic_energy", "penalty_energy", "dissipated_energy")
# A dynamic run whose stored energy exceeds this multiple of the energy it was given
# (initial energy + the largest |external work| so far) has diverged: energy-stable
# schemes stay within the time-discretization error of the balance (SPEC 4), an unstable
# one grows geometrically and passes this bound long before it overflows.
ENERGY_GROWTH = 1e6


class Simulation:
    """The time loop of one scene on ``comm``.  Construction and every method are collective.

    The per-step work vectors and the two State buffers the loop alternates between are
    allocated once: petsc4py frees a PETSc object Python drops only at a collective
    ``PETSc.garbage_cleanup``, so a vector created per step is a leak.

    ``keep_history`` False keeps only the last row of :attr:`history` (a long run would
    otherwise hold one dict per step); :attr:`max_newton_per_step` covers every step.
    """

    def __init__(self, comm, scene, disc, keep_history: bool = True):
        require_constraints(scene)
        self.comm, self.scene, self.disc = comm, scene, disc
        self.keep_history = keep_history
        self.scheme = make_scheme(scene)
        self.guard = DataGuard(comm, scene)
        self.law = None
        if disc.contact is not None:
            self.law = ContactLaw(comm, disc, scene, self.guard)
            self.guard.check()  # the gap
        self.dirichlet_names = [
            n for n, bc in scene.boundaries.items() if bc.kind == BoundaryKind.DIRICHLET
        ]
        self.neumann_names = [
            n for n, bc in scene.boundaries.items() if bc.kind == BoundaryKind.NEUMANN
        ]
        self.timings: dict[str, float] = {"assembly": 0.0, "solve": 0.0, "output": 0.0}
        with phase(self.timings, "assembly"):
            self.a_const = self._a_const()
            if self.law is None:
                self.solver = LinearStepSolver(comm, self.a_const)
            else:
                self.solver = _contact_solver(comm, self.a_const, self.law)
            self.rigid_modes = self._rigid_mode_check()
        self.history: list[dict[str, float]] = []
        self._energy_budget = [0.0, 0.0]  # initial stored energy, largest |external work|
        self.newton_iterations = 0
        self.linear_iterations = 0
        self.max_newton_per_step = 0
        self.coulomb_iterations = self.max_coulomb_per_step = 0  # outer (bound) iterations
        create = disc.create_vec
        # predictors, right-hand side, a scratch vector, one part of a load, a matrix product
        self._ut, self._vt, self._b, self._work, self._part, self._product = (
            create() for _ in range(6)
        )
        self._du, self._mean_forces, self._history = create(), create(), create()
        self._last_forces, self._next_forces = create(), create()  # F_{n-1} and F_n
        self._spare: State | None = None  # buffers of the next level (the level before last)

    def _a_const(self) -> PETSc.Mat:
        """A_const = c_M M + K + alpha_D G_D, with the Gamma_C pattern reserved."""
        owned = self.disc.owned
        matrix = (
            self.scheme.mass_coefficient * owned["mass"]
            + owned["stiffness"]
            + self.scene.alpha_dirichlet * owned["dirichlet"]
        )
        matrix = with_pattern(matrix.tocsr(), self.disc.contact_pattern)
        n_local = matrix.shape[0]
        a_const = petsc_matrix(self.comm, matrix, n_local, self.disc.n_dofs, block_size=2)
        a_const.setOption(PETSc.Mat.Option.SPD, True)
        a_const.setNearNullSpace(self._rigid_body_modes(a_const))
        return a_const

    def _rigid_body_modes(self, matrix: PETSc.Mat) -> PETSc.NullSpace:
        """Translations and the rotation in nodal parameters, for GAMG (-pc_type gamg).

        MLS reproduces linear fields, so the nodal parameters of a rigid motion are the
        motion evaluated at the nodes.
        """
        start, stop = self.disc.node_range
        coordinates = matrix.createVecRight()
        coordinates.setBlockSize(2)
        coordinates.setArray(self.disc.cloud.coords[start:stop].ravel())
        return PETSc.NullSpace().createRigidBody(coordinates)

    def _rigid_mode_check(self) -> RigidModes | None:
        """Rigid-motion stiffness of a static scene held by contact alone; else None.

        Dynamic scenes have the mass term, and a Dirichlet part holds every rigid motion
        (alpha_D > 0 on a curve): their Jacobian is never singular.  A static scene with
        neither Dirichlet nor contact part was refused by require_constraints.
        """
        if self.scheme.dynamic or self.dirichlet_names or self.law is None:
            return None
        return RigidModes(self.comm, self.disc, self.a_const, self.law)

    # -- loads ---------------------------------------------------------------------
    def external_forces(self, t: float, out: PETSc.Vec | None = None) -> PETSc.Vec:
        """F(t): body force and Neumann tractions integrated against the shape functions.

        Written into ``out`` (a new vector if None), which is returned.  Collective; bad
        values go to ``self.guard`` (checked before the next solve).
        """
        disc, scene = self.disc, self.scene
        total = disc.create_vec() if out is None else out
        total.set(0.0)
        part = self._part
        points = disc.domain.points
        x, y = points.T
        force = self.guard.evaluate(("loads", "f"), scene.body_force, points, t, x, y, t)
        disc.domain.integrate(force.T, part)
        total.axpy(1.0, part)
        for name in self.neumann_names:
            points = disc.boundary[name]
            x, y = points.points.T
            nx, ny = points.normals.T
            traction = self.guard.evaluate(
                ("boundary", name, "traction"),
                scene.boundaries[name].traction,
                points.points,
                t,
                *(x, y, t, nx, ny),
            )
            points.integrate(traction.T, part)
            total.axpy(1.0, part)
        return total

    def _dirichlet_value(self, name: str, t: float) -> np.ndarray:
        """ubar(t) at the points of Dirichlet part ``name``, (n, 2); checked by the guard."""
        points = self.disc.boundary[name].points
        x, y = points.T
        field = self.scene.boundaries[name].value
        return self.guard.evaluate(("boundary", name, "value"), field, points, t, x, y, t).T

    def _add_dirichlet_data(self, t: float, out: PETSc.Vec) -> None:
        """out += alpha_D g_D(t), g_D = int_{Gamma_D} ubar(t) . phi_I."""
        part = self._part
        for name in self.dirichlet_names:
            self.disc.boundary[name].integrate(self._dirichlet_value(name, t), part)
            out.axpy(self.scene.alpha_dirichlet, part)

    # -- initial state ---------------------------------------------------------------
    def _project(self, key: str, field) -> PETSc.Vec:
        """L2 projection M d = int rho f . phi of initial field ``key`` (zero stays zero)."""
        disc = self.disc
        points = disc.domain.points
        x, y = points.T
        values = self.guard.evaluate(("initial", key), field, points, 0.0, x, y).T * self.scene.rho
        self.guard.check()
        result = disc.create_vec()
        if self.comm.allreduce(bool(np.any(values != 0.0))):
            rhs = disc.create_vec()
            disc.domain.integrate(values, rhs)
            self._mass_solve(rhs, result)
        return result

    def _mass_solve(self, rhs: PETSc.Vec, out: PETSc.Vec) -> None:
        if not hasattr(self, "_mass_ksp"):
            ksp = PETSc.KSP().create(self.comm)
            ksp.setOptionsPrefix("mass_")
            ksp.setOperators(self.disc.mass)
            # once per run (u_0, v_0 projections and a_0): a direct factorization beats CG
            # on the ill-conditioned MLS mass matrix; -mass_ksp_type/-mass_pc_type override
            configure_linear_solver(ksp)
            ksp.setFromOptions()
            self._mass_ksp = ksp
        self._mass_ksp.solve(rhs, out)
        if self._mass_ksp.getConvergedReason() < 0:
            raise SolverError(
                f"mass-matrix solve failed: KSP reason {self._mass_ksp.getConvergedReason()}"
            )

    def initial_state(self, forces: PETSc.Vec) -> State:
        """u_0, v_0 projected; a_0 from M a_0 = F_0 - (K + alpha_D G_D) u_0 - contact(u_0).

        ``forces`` is F_0 = external_forces(0).  A dynamic scene with a Dirichlet part
        takes u_0 by the elliptic projection of u0 (:meth:`_elliptic_projection`), so that
        a_0 is the L2 projection of the true acceleration; otherwise (or u0 = 0) by L2.
        """
        u = self._project("u", self.scene.initial_u)
        v = self._project("v", self.scene.initial_v)
        a = self.disc.create_vec()
        if self.scheme.dynamic and self.dirichlet_names and self.scene.initial_grad is not None:
            self._elliptic_projection(u)
        if self.scheme.dynamic:
            rhs = forces.copy()
            self._add_dirichlet_data(0.0, rhs)
            ku = self.disc.create_vec()
            self.disc.stiffness.mult(u, ku)
            rhs.axpy(-1.0, ku)
            self.disc.dirichlet.mult(u, ku)
            rhs.axpy(-self.scene.alpha_dirichlet, ku)
            if self.law is not None:
                self.law.gate(u)
                self.law.set_time(0.0)
                un, ut = self.law.kinematics(u)
                self.law.slip = ut.copy()  # xi_0 = u_tau(0)
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

            (K + alpha_D G_D) P u0 + C(P u0) = -int div sigma(u0) . phi
                + int_{Gamma_N} sigma(u0) nu . phi + alpha_D int_{Gamma_D} u0 . phi,

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
        owned = self.disc.owned
        matrix = (owned["stiffness"] + self.scene.alpha_dirichlet * owned["dirichlet"]).tocsr()
        if self.law is not None:
            matrix = with_pattern(matrix, self.disc.contact_pattern)
        operator = petsc_matrix(self.comm, matrix, matrix.shape[0], self.disc.n_dofs, block_size=2)
        operator.setOption(PETSc.Mat.Option.SPD, True)
        operator.setNearNullSpace(self._rigid_body_modes(operator))
        solver: LinearStepSolver | ContactStepSolver
        if self.law is None:
            solver = LinearStepSolver(self.comm, operator)
        else:
            solver = ContactStepSolver(self.comm, operator, self.law)  # bound still 0
        try:
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
        points = disc.domain.points
        x, y = points.T
        key = ("initial", "u")
        div = self.guard.evaluate(key, scene.initial_div_stress, points, 0.0, x, y)  # (2, n_q)
        disc.domain.integrate(-div.T, rhs)
        for name in self.neumann_names:
            boundary = disc.boundary[name]
            boundary.integrate(self._initial_traction(boundary), part)
            rhs.axpy(1.0, part)
        for name in self.dirichlet_names:
            boundary = disc.boundary[name]
            x, y = boundary.points.T
            trace = self.guard.evaluate(key, scene.initial_u, boundary.points, 0.0, x, y)
            boundary.integrate(trace.T, part)
            rhs.axpy(scene.alpha_dirichlet, part)
        self.guard.check()
        return rhs

    def _initial_traction(self, points) -> np.ndarray:
        """sigma(u0) nu at boundary ``points``, (n, 2); checked by the guard."""
        x, y = points.points.T

        def gradient(x, y):
            return self.scene.initial_grad(x, y).reshape(4, -1)  # (4, n)

        rows = self.guard.evaluate(("initial", "u"), gradient, points.points, 0.0, x, y)
        grad = rows.T.reshape(-1, 2, 2)  # (n, 2, 2), [q, i, j] = d u0_i / d x_j
        strain = 0.5 * (grad + np.swapaxes(grad, 1, 2))
        trace = np.trace(strain, axis1=1, axis2=2)  # (n,)
        stress = self.scene.lam * trace[:, None, None] * np.eye(2) + 2 * self.scene.mu * strain
        return np.einsum("qij,qj->qi", stress, points.normals)

    def start(self) -> State:
        """Initial state, and the t = 0 row of the per-step table."""
        self.external_forces(0.0, self._last_forces)
        state = self.initial_state(self._last_forces)
        self._spare = None
        self._dirichlet_previous = {}
        dirichlet_energy, _ = self._dirichlet_terms(state.u, 0.0)
        self.guard.check()
        contact_energy = 0.0
        if self.law is not None:
            contact_energy = self.law.normal_energy(self.law.kinematics(state.u)[0])
        self._check_state(state, 0)
        row = {
            "time": 0.0,
            "newton_iterations": 0,
            "linear_iterations": 0,
            "active_contact_points": 0,
            "kinetic_energy": 0.5 * self._quadratic(self.disc.mass, state.v),
            "elastic_energy": 0.5 * self._quadratic(self.disc.stiffness, state.u),
            "penalty_energy": dirichlet_energy + contact_energy,
            "dissipated_energy": 0.0,
            "external_work": 0.0,
        }
        row.update(self._coulomb_row(0))
        self._energy_budget = [_stored(row), 0.0]  # initial stored energy, max |work|
        self._check_row(row, 0)
        self.history = [row]
        return state

    def resume(self, state: State, step: int, last_row: dict) -> State:
        """Continue from a checkpointed state after ``step`` (see parefg.io.checkpoint)."""
        t = step * self.scheme.k
        self.external_forces(t, self._last_forces)
        self._spare = None
        self._dirichlet_previous = {}
        self._dirichlet_terms(state.u, t)
        self.guard.check()  # also the friction bound that read_checkpoint set
        self._energy_budget = [_stored(last_row), abs(last_row["external_work"])]
        self.history = [dict(last_row)]
        if isinstance(self.solver, CoulombStepSolver):
            self.solver.resume(state.u)  # its first bound, as in the uninterrupted run
        return state

    # -- the loop ------------------------------------------------------------------------
    def step(self, state: State, n: int) -> State:
        """Advance from t_{n-1} to t_n = n k.

        The returned State reuses the vectors of the level before ``state``: the vectors
        of ``state`` itself are overwritten by the step after next, so keep a level only
        by copying it.
        """
        t = n * self.scheme.k
        new = self._next_level(state)
        ut, vt = self._ut, self._vt
        self.scheme.predict(state, ut, vt)
        forces = self.external_forces(t, self._next_forces)
        b = self._b
        forces.copy(b)
        self._add_dirichlet_data(t, b)
        if self.scheme.mass_coefficient:
            self.disc.mass.mult(ut, self._work)
            b.axpy(self.scheme.mass_coefficient, self._work)
        if self.scheme.history is not None:  # generalized-alpha: the previous level's share
            self._add_history(state, t - self.scheme.k, b)
        ut.copy(new.u)  # initial guess: the predictor
        if self.law is not None:
            self.law.gate(ut)  # where friction acts in this step (friction law)
            self.law.set_time(t)
        self.guard.check()  # the step's data, before they reach the solve
        with phase(self.timings, "solve"):
            try:
                newton, linear = self.solver.solve(b, new.u, t)
            except SolverError:
                self._check_rigid_modes(new.u, t)  # the better message, if that is the cause
                raise
        self._check_rigid_modes(new.u, t)
        self.newton_iterations += newton
        self.linear_iterations += linear
        self.max_newton_per_step = max(self.max_newton_per_step, newton)
        self.scheme.update(state, new, ut, vt)
        self._check_state(new, n)
        # A finite but huge state overflows the energies: _record's check reports it.
        with np.errstate(over="ignore", invalid="ignore"):
            self._record(state, new, t, forces, newton, linear)
        self._spare = state
        return new

    def _add_history(self, state: State, t_old: float, b: PETSc.Vec) -> None:
        """b -= w_a M a_{n-1} + w_r r_{n-1}, with (w_a, w_r) = scheme.history.  Collective.

        r_{n-1} = (K + alpha_D G_D) u_{n-1} - F_{n-1} - alpha_D g_D(t_{n-1}) + C(u_{n-1}):
        the forces of the previous level (F_{n-1} is the step's ``_last_forces``).  Call
        before the step's ``law.gate`` / ``law.set_time``: C(u_{n-1}) is the force the last
        step ended with.
        """
        inertia_weight, force_weight = self.scheme.history
        work, force = self._work, self._history
        self.disc.mass.mult(state.a, work)
        b.axpy(-inertia_weight, work)
        self._last_forces.copy(force)
        self._add_dirichlet_data(t_old, force)
        force.scale(-1.0)
        self.disc.stiffness.mult(state.u, work)
        force.axpy(1.0, work)
        self.disc.dirichlet.mult(state.u, work)
        force.axpy(self.scene.alpha_dirichlet, work)
        if self.law is not None:
            self._add_level_contact_force(self.law, state.u, force)
        b.axpy(-force_weight, force)

    def _add_level_contact_force(self, law: ContactLaw, u: PETSc.Vec, out: PETSc.Vec) -> None:
        """out += C(u): the contact and friction force the last step balanced at u = u_{n-1}.

        The one place generalized-alpha evaluates the contact force of a level (the new
        level's force is the step solver's); a time discretization of contact that changes
        the force a step balances changes it here too.  Before the next gate, the friction
        force alpha_T (u_tau - xi_{n-1}) is the last step's (the return mapping left it
        inside the bound).  Collective.
        """
        law.add_residual(out, *law.kinematics(u))

    def _next_level(self, state: State) -> State:
        """The buffers of the new level: the spare one, unless it is ``state`` itself."""
        spare = self._spare
        self._spare = None
        return State.like(state.u) if spare is None or spare is state else spare

    # -- guards ------------------------------------------------------------------------
    def _check_rigid_modes(self, u: PETSc.Vec, t: float) -> None:
        """SolverError if the Jacobian at u leaves a rigid motion free.  Collective.

        Only static scenes held by contact alone are checked (see _rigid_mode_check).
        """
        if self.rigid_modes is None:
            return
        self.rigid_modes.check(t, *self.law.active_weights(*self.law.kinematics(u)))

    def _check_state(self, state: State, n: int) -> None:
        """SolverError naming the first non-finite field of u, v, a at step n.  Collective.

        One allreduce (of a bit mask).
        """
        fields = {"displacement": state.u, "velocity": state.v, "acceleration": state.a}
        self._raise_non_finite(
            "non-finite ", {name: vec.getArray(readonly=True) for name, vec in fields.items()}, n
        )

    def _check_row(self, row: dict, n: int) -> None:
        """SolverError naming the first non-finite energy of a history row.  Not collective.

        The energies are sums over all ranks, the same on each.  They are quadratic in the
        state, so they also catch a finite state beyond about 1e154 (times the material
        scale), where further arithmetic would overflow.
        """
        for name, value in row.items():
            if not math.isfinite(value):
                self._diverged(f"{name.replace('_', ' ')} is {value}", n)
        if not self.scheme.dynamic:
            return  # no inertia: nothing can grow from step to step
        initial, work = self._energy_budget
        work = self._energy_budget[1] = max(work, abs(row["external_work"]))
        stored = _stored(row)
        if stored > ENERGY_GROWTH * (initial + work):
            self._diverged(
                f"the stored energy {stored:.3g} exceeds {ENERGY_GROWTH:.0e} times the energy "
                f"supplied ({initial + work:.3g})",
                n,
            )

    def check_fields(self, n: int, fields: dict[str, np.ndarray]) -> None:
        """SolverError naming the first non-finite output field at step n.  Collective.

        ``fields`` maps names to this rank's values (the same names on every rank).
        """
        self._raise_non_finite("non-finite output field ", fields, n)

    def _raise_non_finite(self, what: str, arrays: dict[str, np.ndarray], n: int) -> None:
        """SolverError naming the first of ``arrays`` that is not finite on some rank.

        Collective: one allreduce of a bit mask (bit i: array i has a non-finite entry).
        """
        local = 0
        with np.errstate(over="ignore"):  # huge finite values may overflow the sum
            for bit, values in enumerate(arrays.values()):
                if not all_finite(np.asarray(values, dtype=float)):
                    local |= 1 << bit
        bad = self.comm.allreduce(local, op=MPI.BOR)
        for bit, name in enumerate(arrays):
            if bad >> bit & 1:
                self._diverged(f"{what}{name}", n)

    def _diverged(self, what: str, n: int) -> None:
        t = n * self.scheme.k
        raise SolverError(
            f"{what} at step {n}, t = {t:.6g}: the time integration diverged "
            "(check the loads, time.dt, the Newmark parameters and the penalty factors)"
        )

    def _record(self, old: State, new: State, t, forces, newton, linear) -> None:
        """Per-step table row: iterations, active points and energies.

        Balance: kinetic + elastic + penalty-stored + dissipated - external work is
        constant, with the work of the loads F and of the moving Dirichlet data.
        """
        previous = self.history[-1] if self.history else {}
        dissipated = previous.get("dissipated_energy", 0.0)
        active, contact_energy = 0, 0.0
        if self.law is not None:
            un, ut = self.law.kinematics(new.u)
            dissipated += self.law.end_step(un, ut)
            active = self.comm.allreduce(int(np.count_nonzero(un > self.law.gap)))
            contact_energy = self.law.normal_energy(un) + self.law.stored_friction_energy(ut)
        dirichlet_energy, anchor_work = self._dirichlet_terms(new.u, t)
        work = previous.get("external_work", 0.0) + anchor_work
        work += self._load_work(old.u, new.u, forces)
        row = {
            "time": t,
            "newton_iterations": newton,
            "linear_iterations": linear,
            "active_contact_points": active,
            "kinetic_energy": 0.5 * self._quadratic(self.disc.mass, new.v),
            "elastic_energy": 0.5 * self._quadratic(self.disc.stiffness, new.u),
            "penalty_energy": dirichlet_energy + contact_energy,
            "dissipated_energy": dissipated,
            "external_work": work,
        }
        row.update(self._coulomb_row(getattr(self.solver, "outer_iterations", 0)))
        self._check_row(row, int(round(t / self.scheme.k)))
        self.history.append(row)
        if not self.keep_history:
            del self.history[:-1]

    def _coulomb_row(self, outer: int) -> dict[str, int]:
        """The step's outer (friction-bound) iterations for a scene with Coulomb parts.

        Also counts them into the run's totals.  Without Coulomb parts the row has no such
        column (the per-step table of other scenes is unchanged).
        """
        if self.law is None or not self.law.has_coulomb:
            return {}
        self.coulomb_iterations += outer
        self.max_coulomb_per_step = max(self.max_coulomb_per_step, outer)
        return {"coulomb_iterations": outer}

    def coulomb_summary(self) -> dict[str, int]:
        """summary.json keys of the Coulomb fixed point (none without Coulomb parts)."""
        if self.law is None or not self.law.has_coulomb:
            return {}
        return {
            "coulomb_iterations": self.coulomb_iterations,
            "max_coulomb_per_step": self.max_coulomb_per_step,
        }

    def _load_work(self, u_old, u_new, forces) -> float:
        """Trapezoidal work of F over the step: (F_{n-1} + F_n)/2 . (u_n - u_{n-1}).

        Then F_n becomes F_{n-1}, and the old F_{n-1} the buffer of the next step's F.
        """
        du, mean = self._du, self._mean_forces
        u_new.copy(du)
        du.axpy(-1.0, u_old)
        forces.copy(mean)
        mean.axpy(1.0, self._last_forces)
        self._last_forces, self._next_forces = forces, self._last_forces
        return 0.5 * mean.dot(du)

    def _dirichlet_terms(self, u: PETSc.Vec, t: float) -> tuple[float, float]:
        """alpha_D/2 ||u_h - ubar||^2 on Gamma_D, and the work of the moving data ubar.

        The anchor work over the step is -alpha_D int mean(u_h - ubar) . (ubar_n - ubar_{n-1}).
        """
        energy, work = 0.0, 0.0
        previous = getattr(self, "_dirichlet_previous", {})
        current = {}
        for name in self.dirichlet_names:
            points = self.disc.boundary[name]
            ubar = self._dirichlet_value(name, t)
            diff = points.evaluate(u) - ubar
            energy += np.dot(points.weights, np.sum(diff**2, axis=1))
            # Without a previous level (start, resume) the work is not used: no ubar(t - k),
            # which may lie outside the data's domain (t < 0).
            old_ubar, old_diff = previous.get(name, (ubar, diff))
            mean_force = 0.5 * (diff + old_diff)
            work -= np.dot(points.weights, np.sum(mean_force * (ubar - old_ubar), axis=1))
            current[name] = (ubar, diff)
        self._dirichlet_previous = current
        alpha = self.scene.alpha_dirichlet
        return 0.5 * alpha * self.comm.allreduce(energy), alpha * self.comm.allreduce(work)

    def errors(self, u: PETSc.Vec, t: float) -> dict[str, float] | None:
        if self.scene.exact is None:
            return None
        return relative_errors(self.comm, self.disc, self.scene.exact, u, t)

    def _quadratic(self, matrix: PETSc.Mat, x: PETSc.Vec) -> float:
        """x^T A x for a square DOF matrix A (mass, stiffness).  Collective."""
        matrix.mult(x, self._product)
        return self._product.dot(x)


def _contact_solver(comm, a_const: PETSc.Mat, law: ContactLaw) -> ContactStepSolver:
    """The Newton step solver, with the Coulomb fixed point around it when a part needs it."""
    if law.has_coulomb:
        return CoulombStepSolver(comm, a_const, law)
    return ContactStepSolver(comm, a_const, law)


def _stored(row: dict) -> float:
    """Kinetic + elastic + penalty-stored + dissipated energy of a history row."""
    return sum(row[name] for name in STORED_ENERGIES)
