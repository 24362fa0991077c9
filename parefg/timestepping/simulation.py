"""One run of a scene: its operators, initial state and steps, checked as they go (SPEC 4).

The loop skips what a scene does not need: without Gamma_C every step is one linear
solve with A_const factored once (:class:`LinearStepSolver`); with Gamma_C each step is
a semismooth Newton solve that reuses the factorization while the active set holds; with
g = 0 no tangential terms enter; errors are computed only with an exact solution.
"""

from __future__ import annotations

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from parefg.boundary import BoundaryKind
from parefg.errors import SolverError
from parefg.guards import DataGuard, RigidModes, require_constraints
from parefg.mechanics.contact import ContactLaw
from parefg.parallel import petsc_matrix
from parefg.profiling import phase
from parefg.timestepping.coulomb import CoulombStepSolver
from parefg.timestepping.energy import EnergyLedger
from parefg.timestepping.initial import InitialState
from parefg.timestepping.linear_solver import LinearStepSolver
from parefg.timestepping.loads import ExternalLoads
from parefg.timestepping.schemes import State, make_scheme, relative_errors
from parefg.timestepping.shared_jacobian import SharedConstant
from parefg.timestepping.step_checks import StepChecks, stored_energy
from parefg.timestepping.step_solver import ContactStepSolver

# The domain's value operator is dropped for the time loop from this size on (per rank): as
# the kept shape gradients (domain_assembly.KEEP_GRADIENT_BYTES), memory that matters only on
# large clouds, where the MLS pass that builds it again for the error norms is a small cost.
RELEASE_VALUE_BYTES = 16_000_000
#: A_const this large (CSR bytes on some rank) is kept in the contact Jacobian's storage
SHARED_JACOBIAN_BYTES = 16_000_000


class Simulation(InitialState, EnergyLedger, StepChecks):
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
            self.loads = ExternalLoads(comm, disc, scene, self.guard)
            if self.loads.integrates_domain:  # every step integrates f against S
                disc.domain.ensure_values()
            self.a_const: PETSc.Mat | SharedConstant = self._a_const()
            self.solver: LinearStepSolver | ContactStepSolver
            method, symmetric = scene.solver.method, disc.symmetric
            degree = scene.discretization.degree
            blocks = disc.trace_blocks
            if self.law is None:
                self.solver = LinearStepSolver(
                    comm, self.a_const, method, symmetric, degree, blocks
                )
            else:
                shared = self._shared_rows(self.a_const)
                self.solver = _contact_solver(
                    comm, self.a_const, self.law, method, symmetric, shared, degree, blocks
                )
                if shared is not None:  # A_const lives on in the Jacobian's storage
                    self.a_const.destroy()
                self.a_const = self.solver.a_const
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
        self._mass_ksp: PETSc.KSP | None = None  # the mass solve, set up at its first use
        # ubar and u_h - ubar at the last level, per Dirichlet part (its anchor work)
        self._dirichlet_previous: dict[str, tuple[np.ndarray, np.ndarray]] = {}

    def _a_const(self) -> PETSc.Mat:
        """A_const = c_M M + K + D, with the Gamma_C pattern reserved (D: Dirichlet methods)."""
        matrix = self.disc.combined_rows(self.scheme.mass_coefficient, reserve_contact=True)
        n_local = matrix.shape[0]
        a_const = petsc_matrix(self.comm, matrix, n_local, self.disc.n_dofs, block_size=2)
        a_const.setOption(PETSc.Mat.Option.SPD, self.disc.symmetric)
        a_const.setNearNullSpace(self._rigid_body_modes(a_const))
        return a_const

    def _shared_rows(self, a_const: PETSc.Mat) -> np.ndarray | None:
        """This rank's Gamma_C rows when A_const holds SHARED_JACOBIAN_BYTES or more on some
        rank (the contact Jacobian then keeps A_const in its storage, one DOF matrix less:
        parefg.timestepping.shared_jacobian), else None: a small run keeps its copy and
        the Jacobian's rebuilds stay plain copies.  Collective."""
        held = 12 * a_const.getInfo(PETSc.Mat.InfoType.LOCAL)["nz_used"]
        if self.comm.allreduce(held, op=MPI.MAX) < SHARED_JACOBIAN_BYTES:
            return None
        return np.flatnonzero(np.diff(self.disc.contact_pattern.indptr))

    def _rigid_body_modes(self, matrix: PETSc.Mat) -> PETSc.NullSpace:
        """Translations and the rotation in nodal parameters, for GAMG (-pc_type gamg).

        MLS reproduces linear fields, so the nodal parameters of a rigid motion are the
        motion evaluated at the nodes.
        """
        coordinates = matrix.createVecRight()
        coordinates.setBlockSize(2)
        coordinates.setArray(self.disc.owned_coords.ravel())
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
        return self.loads.forces(t, self.disc.create_vec() if out is None else out)

    def _dirichlet_value(self, name: str, t: float) -> np.ndarray:
        """ubar(t) at the points of Dirichlet part ``name``, (n, 2), read-only; checked by the
        guard at its first evaluation for t (then cached: the step and the ledger share it)."""
        return self.loads.dirichlet_value(name, t)

    def _add_dirichlet_data(self, t: float, out: PETSc.Vec) -> None:
        """out += L^T (w ubar(t)) of every Dirichlet part (penalty: alpha_D int ubar . phi_I)."""
        self.loads.add_dirichlet(t, out)

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
            contact_energy += self.comm.allreduce(self.law.local_nitsche_energy(state.u))
        with np.errstate(over="ignore"):  # huge finite values may overflow its sums
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
        self._energy_budget = [stored_energy(row), 0.0]  # initial stored energy, max |work|
        self._check_row(row, 0)
        self.history = [row]
        self._release_domain_values()
        return state

    def _release_domain_values(self) -> None:
        """Drop the domain's value operator S for the time loop, unless a step uses it.

        S (~5 KB per DOF at m = 2, the largest point operator) has served the load vectors
        and the initial state by now; the error norms at the end take u_h from one more
        MLS pass over the Gauss points, so only operators of RELEASE_VALUE_BYTES or more
        on some rank are dropped: a small run keeps its S and its time.  With S go the
        Gauss points and weights (0.7 KB per DOF at m = 2), computed again from the cells
        by their next use.  Collective.
        """
        domain = self.disc.domain
        if self.loads.integrates_domain:
            return
        # a large domain's S was never built (size_estimate.BUILT_VALUE_BYTES)
        if domain.values is None or domain.release_values(RELEASE_VALUE_BYTES):
            domain.release_points()  # 24 bytes per point, computed again by a later use

    def resume(self, state: State, step: int, last_row: dict) -> State:
        """Continue from a checkpointed state after ``step`` (see parefg.io.checkpoint)."""
        t = step * self.scheme.dt
        self.external_forces(t, self._last_forces)
        self._spare = None
        self._dirichlet_previous = {}
        self._dirichlet_terms(state.u, t)
        self.guard.check()  # also the friction bound that restore() set
        self._energy_budget = [stored_energy(last_row), abs(last_row["external_work"])]
        self.history = [dict(last_row)]
        if isinstance(self.solver, CoulombStepSolver):
            self.solver.resume(state.u)  # its first bound, as in the uninterrupted run
        return state

    # -- restart ---------------------------------------------------------------------------
    def snapshot(self, state: State, step: int) -> dict:
        """What a restart after ``step`` needs, as this rank's arrays (no communication).

        "u", "v", "a": (n_owned, 2) nodal parameters of this rank's nodes; with a contact
        boundary "slip" (the accumulated slip xi) and "contact_level" (the step's normal
        force C_n that a_n holds, :meth:`ContactLaw.end_level`) at this rank's Gamma_C
        points; "step", "time" and "history" (the last per-step row: the energies and the
        running sums of dissipation and external work).  The friction bounds are not
        stored: :meth:`restore` recomputes them from t (Tresca) and from u (Coulomb's
        mu_f p(u_n)), as the uninterrupted run does at the next step.
        """
        snapshot: dict = {
            name: getattr(state, name).getArray().reshape(-1, 2).copy() for name in ("u", "v", "a")
        }
        if self.law is not None:
            snapshot["slip"] = np.array(self.law.slip, dtype=float)
            snapshot["contact_level"] = np.array(self.law.level_pressure, dtype=float)
        snapshot.update(step=int(step), time=step * self.scheme.dt, history=dict(self.history[-1]))
        return snapshot

    def restore(self, snapshot: dict) -> State:
        """The level of a :meth:`snapshot` (this rank's arrays), ready for the next step.

        Sets the contact state, then continues like :meth:`resume`.  Collective.
        """
        vectors = {}
        for name in ("u", "v", "a"):
            vectors[name] = self.disc.create_vec()
            vectors[name].setArray(np.asarray(snapshot[name], dtype=float).ravel())
        step = int(snapshot["step"])
        if self.law is not None:
            self.law.set_time(step * self.scheme.dt)
            self.law.slip = np.array(snapshot["slip"], dtype=float)
            self.law.level_pressure = np.array(snapshot["contact_level"], dtype=float)
        return self.resume(State(**vectors), step, snapshot["history"])

    # -- the loop ------------------------------------------------------------------------
    def step(self, state: State, n: int) -> State:
        """Advance from t_{n-1} to t_n = n dt.

        The returned State reuses the vectors of the level before ``state``: the vectors
        of ``state`` itself are overwritten by the step after next, so keep a level only
        by copying it.
        """
        t = n * self.scheme.dt
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
            self._add_history(state, t - self.scheme.dt, b)
        ut.copy(new.u)  # initial guess: the predictor
        if self.law is not None:
            # where friction acts in this step (friction law), decided at the predictor:
            # asked of new.u, its kinematics are kept for the solve's first residual
            self.law.gate(new.u)
            self.law.set_time(t)
            self.law.begin_step(state.u)  # the discrete gradient's start level
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
        self._contact_acceleration(new)
        # A finite but huge state overflows the energies (and the sums of _check_state):
        # _record's check reports it.
        with np.errstate(over="ignore", invalid="ignore"):
            self._check_state(new, n)
            self._record(state, new, t, forces, newton, linear)
        self._spare = state
        return new

    def _add_history(self, state: State, t_old: float, b: PETSc.Vec) -> None:
        """b -= w_a M a_{n-1} + w_r r_{n-1}, with (w_a, w_r) = scheme.history.  Collective.

        r_{n-1} = (K + D) u_{n-1} - F_{n-1} - L^T w ubar(t_{n-1}) + C(u_{n-1}):
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
        force.axpy(1.0, work)
        if self.law is not None:
            # C(u_{n-1}), the force the last step balanced (ContactLaw.add_level_force); before
            # the next gate its friction part alpha_T (u_tau - xi_{n-1}) is the last step's
            self.law.add_level_force(force, *self.law.kinematics(state.u))
        b.axpy(-force_weight, force)

    def _contact_acceleration(self, new: State) -> None:
        """Close the step's contact force C_n (ContactLaw.end_level) and a_n with it.

        The energy of Newmark(beta, 1/2) that the discrete-gradient force conserves is
        kinetic + elastic + penalty + dt^2 (beta - 1/4)/2 a^T M a, with a_n the acceleration
        of the forces C_n the scheme used.  For beta = 1/4 (the trapezoidal rule) the last
        term vanishes, so a_n may hold the pressure at t_n instead, the physical
        acceleration: a_n += M^-1 B_nu^T w (C_n - p(u_n)), a mass solve only in steps in
        which some point touched down or lifted off.  For beta > 1/4, a_n and C_n are
        kept: resetting them would change the conserved energy (measured: the impact
        scene at beta = 1/2 then gains energy without bound).  Collective.
        """
        law = self.law
        if law is None or not self.scheme.dynamic or not law.normal_force.uses_start_level:
            return
        un = law.kinematics(new.u)[0]
        physical = self.scheme.trapezoidal  # the same on every rank
        excess = law.end_level(un, physical)
        if not physical:
            return
        if not self.comm.allreduce(bool(np.any(law.crossing(un))), op=MPI.LOR):
            return
        law.operator.multTranspose(law.point_vector(excess), self._part)
        self._mass_solve(self._part, self._work)
        new.a.axpy(1.0, self._work)

    def _next_level(self, state: State) -> State:
        """The buffers of the new level: the spare one, unless it is ``state`` itself."""
        spare = self._spare
        self._spare = None
        return State.like(state.u) if spare is None or spare is state else spare

    def errors(self, u: PETSc.Vec, t: float) -> dict[str, float] | None:
        if self.scene.exact is None:
            return None
        return relative_errors(self.comm, self.disc, self.scene.exact, u, t)


def _contact_solver(
    comm,
    a_const: PETSc.Mat,
    law: ContactLaw,
    method: str,
    symmetric: bool,
    shared_rows,
    degree,
    trace_blocks,
) -> ContactStepSolver:
    """The Newton step solver, with the Coulomb fixed point around it when a part needs it."""
    solver = CoulombStepSolver if law.has_coulomb else ContactStepSolver
    return solver(comm, a_const, law, method, symmetric, shared_rows, degree, trace_blocks)
