"""Penalty contact and return-mapping Tresca friction at the Gamma_C quadrature points (SPEC 4).

At each of this rank's Gamma_C points q (weight w_q, outward normal nu_q, tangent
tau_q = (-nu_2, nu_1), :class:`~parefg.mechanics.contact_frame.ContactFrame`) with
u_nu = nu . u_h, u_tau = tau . u_h:

    normal pressure   p_q = alpha_C (u_nu - s)^+                      (>= 0)
    friction force    f_q = clip(alpha_T (u_tau - xi_q), -g_q, g_q)    (xi: accumulated slip)
    bound             g_q = g_n(x_q) where the part's friction law acts, else 0 (mechanics.friction)
    energy            alpha_C/2 ((u_nu - s)^+)^2 + psi(u_tau - xi_q)
    psi(z)            alpha_T z^2/2 for |z| <= g/alpha_T, else g|z| - g^2/(2 alpha_T)

The residual gets B_nu^T (w p) + B_tau^T (w f); the semismooth Jacobian gets
alpha_C B_nu^T W B_nu on closed points and alpha_T B_tau^T W B_tau on sticking ones.
Everything is piecewise linear in u, so the energy along a Newton direction is convex
piecewise quadratic (see :meth:`ContactLaw.directional`).

Time discretization of the normal force (``[time] contact_force``, one of
:data:`parefg.mechanics.normal_force.CONTACT_FORCES`).  "endpoint" puts
p(u_n) in step n; the trapezoidal rule then averages p(u_{n-1}) and p(u_n), which is not
the work the penalty stores when a point crosses the obstacle within the step (measured:
the impact scene gains 5.7x at beta = 1/4).  "discrete_gradient" (default; Armero &
Petocz 1998, Hauret & Le Tallec 2006) puts C_n = 2 DG(d_{n-1}, d_n) - C_{n-1} in the
step, DG the discrete gradient of phi(d) = alpha_C/2 (d^+)^2 (d = u_nu - s), so that
(C_{n-1} + C_n)/2 (d_n - d_{n-1}) = phi(d_n) - phi(d_{n-1}) exactly.  C_n is nondecreasing
in d_n with a closed-form convex primitive
(:func:`~parefg.mechanics.discrete_gradient.dg_potential`): J_n stays convex and
the exact line search keeps its guarantee.  While C_{n-1} is the pressure at u_{n-1}
(always at beta = 1/4: Simulation._contact_acceleration), C_n is the endpoint force at
every point that does not cross; at a crossing point it is a rational function of d_n
(not affine: piece code -1, its Jacobian entry rebuilt at every iteration).

The friction law gates the bound once per step, before the solve (:meth:`ContactLaw.gate`):
"tresca" keeps g only at points touching at the Newmark predictor, "given" everywhere.
So the per-step energy stays convex, and every method below (energy, residual, Jacobian,
piece, directional derivative, return mapping, dissipation) sees the same gated bound: the
exact line search minimizes the energy whose gradient is the residual.
"coulomb" (g = mu_f p) sets its bound from a given iterate (:meth:`ContactLaw.set_pressure_bound`)
and keeps it fixed through one such convex solve; the fixed point around it is the step's.
"""

from __future__ import annotations

import operator
from contextlib import contextmanager

import numpy as np
import scipy.sparse as sp
from mpi4py import MPI
from petsc4py import PETSc

from parefg.boundary import BoundaryKind
from parefg.guards import DataGuard, PointDatum
from parefg.mechanics.contact_frame import ContactFrame
from parefg.mechanics.discrete_gradient import crossings
from parefg.mechanics.friction import FRICTION_LAWS, PRESSURE_LAWS, coulomb_bound
from parefg.mechanics.normal_force import CONTACT_FORCES, EndpointForce, NormalForce
from parefg.parallel import owned_rows

OPEN, STICK, SLIP = 0, 1, 2


class ContactLaw(ContactFrame):
    """Contact and friction state of this rank's Gamma_C points.  Construction is collective.

    The gap and the friction bound are evaluated through ``guard`` (a
    :class:`~parefg.guards.DataGuard`, by default one of its own): whoever drives the law
    calls ``guard.check()`` before the values reach a solve.
    """

    def __init__(self, comm, disc, scene, guard: DataGuard | None = None):
        super().__init__(comm, disc.contact)
        self.guard = DataGuard(comm, scene) if guard is None else guard
        self.alpha_t = scene.penalty.alpha_friction
        # Nitsche contact (Chouly & Hild, symmetric): the penalty law with alpha_C = gamma
        # on the frame's u_nu - sigma_nu / gamma, i.e. p = [gamma (u_nu - s) - sigma_nu]^+
        self.alpha_c = scene.penalty.alpha_contact if self.gamma is None else self.gamma
        # the discrete gradient needs a previous level: static load steps use the endpoint
        self.normal_force: type[NormalForce] = (
            CONTACT_FORCES[scene.time.contact_force] if scene.time.dynamic else EndpointForce
        )
        self.dof_ranges = 2 * disc.partition.node_ranges
        self._bcs = _contact_parts(disc.cloud.part_names, scene.boundaries)
        self.has_friction = not all(bc.friction_is_zero for bc in self._bcs.values())
        self.gap = self._per_part("gap", lambda bc, x, y, n: bc.gap(x, y), 0.0)
        if disc.contact.projection is not None:  # the law compares P u_nu with P s
            self.gap = disc.contact.projection @ self.gap
        self._friction_data = self._friction_bounds() if self.has_friction else []
        self._init_coulomb()
        self.bound_data = np.zeros(len(self.weights))  # g_n(x_q) at the points, set by set_time
        self.acting = np.ones(len(self.weights), dtype=bool)  # where the law lets g act (gate)
        self.bound = np.zeros(len(self.weights))  # g_n where acting, else 0: used by the step
        self.slip = np.zeros(len(self.weights))  # xi, accumulated slip
        self.start_penetration = np.zeros(len(self.weights))  # d_{n-1} = u_nu - s at t_{n-1}
        # C_{n-1}: the normal force at t_{n-1} as the acceleration a_{n-1} holds it
        self.level_pressure = np.zeros(len(self.weights))
        self.step_status = np.zeros(len(self.weights), dtype=np.int8)  # at the last step's end
        self.step_friction = np.zeros(len(self.weights))
        # (the objects they were computed from, (pressure, friction)) of the last forces()
        self._kept_forces: tuple[tuple, tuple[np.ndarray, np.ndarray]] | None = None

    def _friction_bounds(self) -> list[tuple[np.ndarray, PointDatum]]:
        """(points of the part, its g as a PointDatum) of each contact part.  Not collective."""
        bounds = []
        for part_id, bc in self._bcs.items():
            on = self.part == part_id
            points, normals = self.points[on], self.normals[on]
            x, y, nx, ny = points[:, 0], points[:, 1], normals[:, 0], normals[:, 1]
            key = ("boundary", bc.name, "friction")
            arguments = {"x": x, "y": y, "nx": nx, "ny": ny}
            bounds.append((on, PointDatum(self.guard, key, bc.friction, points, arguments, True)))
        return bounds

    def _init_coulomb(self) -> None:
        """mu_f at the points of Coulomb parts (0 elsewhere); has_coulomb on every rank."""
        self.coefficient = np.zeros(len(self.weights))  # (n_c,) mu_f
        self.coulomb = np.zeros(len(self.weights), dtype=bool)  # (n_c,) on a Coulomb part
        for part_id, bc in self._bcs.items():
            if bc.friction_law in PRESSURE_LAWS:
                on = self.part == part_id
                self.coefficient[on] = bc.friction_coefficient
                self.coulomb[on] = True
        # from the scene, the same on every rank: decides the collective outer loop
        self.has_coulomb = any(
            bc.friction_law in PRESSURE_LAWS and not bc.friction_is_zero
            for bc in self._bcs.values()
        )

    def set_pressure_bound(self, un) -> None:
        """The bound hook of Coulomb parts: g = mu_f p(u_nu) at their points.

        ``un`` is u_nu of the iterate the bound is taken from; the other points keep the
        bound of :meth:`gate` and :meth:`set_time`, which reset the Coulomb points to 0
        (so call this after them, before the solve).  Not collective.
        """
        if self.has_coulomb:
            pressure_bound = coulomb_bound(self.coefficient, self.pressure(un))
            self.bound = np.where(self.coulomb, pressure_bound, self.bound)

    def _per_part(self, key: str, evaluate, t: float, nonnegative=False) -> np.ndarray:
        """Evaluate a datum (boundary.NAME.key) of each contact part at its points.

        Not collective: bad values are recorded by the guard (see DataGuard.evaluate).
        """
        out = np.zeros(len(self.weights))
        for part_id, bc in self._bcs.items():
            on = self.part == part_id
            points = self.points[on]
            x, y = points[:, 0], points[:, 1]
            key_path = ("boundary", bc.name, key)
            normals = self.normals[on]
            out[on] = self.guard.evaluate(
                key_path, evaluate, points, t, bc, x, y, normals, nonnegative=nonnegative
            )
        return out

    def set_time(self, t: float) -> None:
        """Friction bound g(x, t) >= 0 at the points (bad values go to the guard).

        The bound the step uses is g where the last :meth:`gate` let friction act.  Each
        part's g is a :class:`~parefg.guards.PointDatum`: a time-separable bound
        g(x, t) = sum_k a_k(t) g_k(x) costs the K numbers a_k(t) per time.  Not collective.
        """
        if not self.has_friction:
            return
        self.bound_data = np.zeros(len(self.weights))
        for on, datum in self._friction_data:
            self.bound_data[on] = datum.values(t)
        self.bound = np.where(self.acting, self.bound_data, 0.0)

    def gate(self, u_predicted: PETSc.Vec) -> None:
        """Fix for the coming step where each part's friction law lets the bound act.

        ``u_predicted`` is the Newmark predictor ut_n; see parefg.mechanics.friction for why the
        gate is decided before the solve (a convex J_n).  Nothing to checkpoint: the
        predictor follows from the checkpointed (u, v, a).
        Call before :meth:`set_time` or after it: both keep bound = g * acting.  Collective.
        """
        if not self.has_friction:
            return
        un_predicted = self.kinematics(u_predicted)[0]
        for part_id, bc in self._bcs.items():
            on = self.part == part_id
            law = FRICTION_LAWS[bc.friction_law]
            self.acting[on] = law(un_predicted[on], self.gap[on])
        self.bound = np.where(self.acting, self.bound_data, 0.0)

    @contextmanager
    def endpoint_force(self):
        """Within the block the normal force is the pressure at u (a static problem)."""
        saved, self.normal_force = self.normal_force, EndpointForce
        try:
            yield self
        finally:
            self.normal_force = saved

    def begin_step(self, u_start: PETSc.Vec) -> None:
        """Record d_{n-1} = u_nu - s at the start of the step, for the step force.  Collective."""
        self.start_penetration = self.kinematics(u_start)[0] - self.gap

    def set_level(self, un) -> None:
        """C_n = the pressure alpha_C (u_nu - s)^+ at u (the initial state).  Not collective."""
        self.level_pressure = self.pressure(un)

    def end_level(self, un, physical: bool) -> np.ndarray:
        """Close the step's normal force C_n; returns w (C_n - pressure) at the points.

        The step solved with C_n = :meth:`step_pressure`, so that (C_{n-1} + C_n)/2 does
        the penalty's work exactly.  ``physical``: the caller resets C_n to the pressure
        alpha_C (u_nu - s)^+ and corrects a_n by M^-1 B_nu^T (returned excess), which
        the trapezoidal rule's energy (no acceleration term) allows.  Otherwise C_n is
        kept (and the excess is returned as zeros).  Not collective.
        """
        step = self.step_pressure(un)
        if not physical:
            self.level_pressure = step
            return np.zeros_like(step)
        pressure = self.pressure(un)
        self.level_pressure = pressure
        return self.weights * (step - pressure)

    def crossing(self, un) -> np.ndarray:
        """(n_c,) bool: the step crossed the obstacle (d = 0) at the point."""
        down, up = crossings(self.start_penetration, un - self.gap)
        return down | up

    def forces(self, un, ut) -> tuple[np.ndarray, np.ndarray]:
        """Normal force of the step (see :meth:`step_pressure`) and friction force f.

        The last answer for read-only (u_nu, u_tau) (:meth:`kinematics`' results) is kept
        with the law's state it was computed from: a Newton step asks for the forces at its
        iterate twice (the residual, the line search's start).  The law replaces its arrays
        (start level, level force, slip, bound) and never writes into them, so the same
        objects hold the same values.  Do not write into the returned arrays.
        """
        state = self._force_state(un, ut)
        if self._kept_forces is not None and all(map(operator.is_, self._kept_forces[0], state)):
            return self._kept_forces[1]
        forces = self.step_pressure(un), self.friction_force(ut)
        if not (un.flags.writeable or ut.flags.writeable):
            self._kept_forces = (state, forces)
        return forces

    def _force_state(self, un, ut) -> tuple:
        """The objects the forces at (u_nu, u_tau) are computed from."""
        return (
            un,
            ut,
            self.normal_force,
            self.start_penetration,
            self.level_pressure,
            self.slip,
            self.bound,
        )

    def friction_force(self, ut) -> np.ndarray:
        """f = clip(alpha_T (u_tau - xi), -g, g) at the points (zeros without friction)."""
        if not self.has_friction:
            return np.zeros_like(ut)
        return np.clip(self.alpha_t * (ut - self.slip), -self.bound, self.bound)

    def status(self, un, ut) -> np.ndarray:
        """OPEN / STICK / SLIP per point (int8); closed points stick unless |f| reached g."""
        closed = un > self.gap
        sliding = self._sliding(ut)
        return np.where(~closed, OPEN, np.where(sliding, SLIP, STICK)).astype(np.int8)

    def _sliding(self, ut) -> np.ndarray:
        if not self.has_friction:
            return np.ones(len(ut), dtype=bool)
        return np.abs(self.alpha_t * (ut - self.slip)) >= self.bound

    def _jacobian_closed(self, un) -> np.ndarray:
        """Closed for the Jacobian: u_nu >= s, the kink u_nu = s on the closed piece.

        Both pieces give the force 0 at the kink and the closed one, alpha_C (u_nu - s),
        is exact there, so either slope is a valid Newton derivative; the open one left
        a static scene that starts at u = 0 on the obstacle (s = 0) with J = K + friction,
        singular in the normal motions, whose LU pivots of round-off size made the first
        Newton direction (a descent one or not) depend on the CPU.
        """
        return un >= self.gap

    def active_set(self, un, ut) -> np.ndarray:
        """Packed (closed, stick) flags: the data the semismooth Jacobian depends on."""
        return np.concatenate([self._jacobian_closed(un), ~self._sliding(ut)])

    def piece(self, un, ut) -> np.ndarray:
        """Which linear piece of the residual each point is on (int8 code per point).

        closed/open times stick/slip forward/slip backward: on one piece the residual is
        affine in u, so a full Newton step that stays on its piece solves the step exactly.
        A negative code marks a point whose normal force is not affine in u (the discrete
        gradient of a step that crosses the obstacle there): no piece shortcut applies.
        """
        code = self._jacobian_closed(un).astype(np.int8)
        if self.has_friction:
            z = self.alpha_t * (ut - self.slip)
            friction_state = np.where(z >= self.bound, 1, np.where(z <= -self.bound, 2, 0))
            code = code + 2 * friction_state.astype(np.int8)
        if self.normal_force.uses_start_level:
            code = np.where(self.crossing(un), -1, code).astype(np.int8)
        return code

    def add_residual(self, residual: PETSc.Vec, un, ut) -> None:
        """residual += B_nu^T (w p) + B_tau^T (w f) with the step's forces.  Collective."""
        self._add_point_forces(residual, *self.forces(un, ut))

    def add_level_force(self, residual: PETSc.Vec, un, ut) -> None:
        """residual += the force the last step ended with at its u_n.  Collective.

        The normal part is C_n (:meth:`end_level`), which with the discrete gradient is not
        the pressure at u_n after a crossing; the friction part is the last step's.
        """
        pressure, friction = self.forces(un, ut)
        if self.normal_force.uses_start_level:
            pressure = self.level_pressure
        self._add_point_forces(residual, pressure, friction)

    def active_weights(self, un, ut) -> tuple[np.ndarray, np.ndarray]:
        """Jacobian weights of the active set: w alpha_C on closed, w alpha_T on sticking points.

        Returns two arrays (n_c,); the tangential one is zero without friction.
        """
        closed = self.weights * self.step_slope(un)
        if not self.has_friction:
            return closed, np.zeros_like(closed)
        return closed, (~self._sliding(ut)) * self.weights * self.alpha_t

    def jacobian_rows(self, un, ut) -> sp.csr_matrix:
        """Owned rows of alpha_C B_nu^T W_closed B_nu + alpha_T B_tau^T W_stick B_tau.

        Collective.
        """
        closed, stick = self.active_weights(un, ut)
        local = self.normal_op.T @ sp.diags(closed) @ self.normal_op
        if self.has_friction:
            local = local + self.tangent_op.T @ sp.diags(stick) @ self.tangent_op
        return owned_rows(self.comm, local.tocsr(), self.dof_ranges, self.dof_columns, self.n_dofs)

    def _penetration(self, un) -> np.ndarray:
        return np.maximum(un - self.gap, 0.0)  # (u_nu - s)^+

    def pressure(self, un) -> np.ndarray:
        """Normal pressure p = alpha_C (u_nu - s)^+ >= 0 at the points."""
        return self.alpha_c * self._penetration(un)

    def step_pressure(self, un) -> np.ndarray:
        """Normal force C_n of the step at the points (``[time] contact_force``)."""
        force, d0 = self.normal_force, self.start_penetration
        return force.pressure(d0, un - self.gap, self.alpha_c, self.level_pressure)

    def step_slope(self, un) -> np.ndarray:
        """d(step_pressure)/d u_nu at the points (>= 0)."""
        return self.normal_force.slope(self.start_penetration, un - self.gap, self.alpha_c)

    def _step_potential(self, un) -> np.ndarray:
        """Primitive of :meth:`step_pressure` in u_nu (convex): the step's contact energy."""
        force, d0 = self.normal_force, self.start_penetration
        return force.potential(d0, un - self.gap, self.alpha_c, self.level_pressure)

    def _normal_potential(self, un) -> np.ndarray:
        """alpha_C/2 ((u_nu - s)^+)^2 at the points."""
        return 0.5 * self.alpha_c * self._penetration(un) ** 2

    def energy(self, un, ut) -> float:
        """The step's contact plus friction potential, summed over all ranks.  Collective."""
        local = np.dot(self.weights, self._step_potential(un))
        if self.has_friction:
            local += np.dot(self.weights, self._friction_potential(ut - self.slip))
        return self.comm.allreduce(local, op=MPI.SUM)

    def _friction_potential(self, z) -> np.ndarray:
        g, a = self.bound, self.alpha_t
        elastic = np.abs(a * z) <= g
        return np.where(elastic, 0.5 * a * z**2, g * np.abs(z) - 0.5 * g**2 / a)

    def normal_energy(self, un) -> float:
        """alpha_C/2 ||(u_nu - s)^+||^2 on Gamma_C.  Collective."""
        return self.comm.allreduce(self.local_normal_energy(un), op=MPI.SUM)

    def local_normal_energy(self, un) -> float:
        """This rank's share of :meth:`normal_energy`.  Not collective."""
        return float(np.dot(self.weights, self._normal_potential(un)))

    def local_nitsche_energy(self, u: PETSc.Vec) -> float:
        """This rank's share of -||sigma_nu(u_h)||^2 / (2 gamma) on Gamma_C (0 for the penalty).

        The stiffness term of Nitsche contact (its -N in D): with it, kinetic + elastic +
        contact energies are what the discrete-gradient step conserves.  Collective.
        """
        if self.traction_op is None:
            return 0.0
        traction = self.normal_traction(u)
        return float(-0.5 * np.dot(self.weights, traction**2 / self.gamma))

    def local_friction_energy(self, ut) -> float:
        """This rank's share of alpha_T/2 |u_tau - xi|^2 after the slip update (the friction
        spring energy).  Not collective."""
        if not self.has_friction:
            return 0.0
        z = ut - self.slip
        return float(np.dot(self.weights, 0.5 * self.alpha_t * z**2))

    def directional(self, un, ut, d_nu, d_tau, step) -> tuple[float, float]:
        """Derivative and slope of the contact energy along u + step d.  Collective.

        ``d_nu``, ``d_tau`` are the normal and tangential components of the direction d at
        the points.  Returns (sum_q w_q [d_nu p_q + d_tau f_q], sum_q w_q [alpha_C d_nu^2
        closed_q + alpha_T d_tau^2 stick_q]) evaluated at u + step d: the value and the
        slope of the current linear piece of the (monotone, piecewise linear) directional
        derivative.
        """
        # at step 0 the iterate itself (the same values: un + 0 d_nu differs from un at most
        # in the sign of a zero), whose forces the residual has just computed
        un_s, ut_s = (un, ut) if step == 0.0 else (un + step * d_nu, ut + step * d_tau)
        pressure, friction = self.forces(un_s, ut_s)
        value = np.dot(self.weights, d_nu * pressure + d_tau * friction)
        slope = np.dot(self.weights, self.step_slope(un_s) * d_nu**2)
        if self.has_friction:
            slope += np.dot(self.weights, self.alpha_t * d_tau**2 * ~self._sliding(ut_s))
        # a buffer reduction: mpi4py's object allreduce would pickle the array
        total = np.empty(2)
        self.comm.Allreduce(np.array([value, slope]), total, op=MPI.SUM)
        return float(total[0]), float(total[1])

    def end_step(self, un, ut) -> float:
        """Record the step's status and friction force, then update the slip.

        The status is taken with the slip the step was solved with: after the return
        mapping a sliding point sits exactly at |alpha_T (u_tau - xi)| = g, where round-off
        would decide between stick and slip.  Then the return mapping
        xi_n = u_tau - clip(u_tau - xi, -g/alpha_T, g/alpha_T).  Returns this rank's share
        of the step's frictional dissipation sum_q w_q g_q |xi_n - xi_{n-1}| (the caller
        sums it with the other energies of the step).  Not collective.
        """
        self.step_status = self.status(un, ut)
        self.step_friction = self.friction_force(ut)
        if not self.has_friction:
            return 0.0
        z = ut - self.slip
        elastic = np.clip(z, -self.bound / self.alpha_t, self.bound / self.alpha_t)
        increment = z - elastic
        self.slip = self.slip + increment
        return float(np.dot(self.weights, self.bound * np.abs(increment)))


def _contact_parts(part_names: list[str], boundaries: dict) -> dict:
    """Part id (index in the cloud's part names) -> boundary condition of each contact part."""
    return {
        part_id: boundaries[name]
        for part_id, name in enumerate(part_names)
        if name in boundaries and boundaries[name].kind == BoundaryKind.CONTACT
    }
