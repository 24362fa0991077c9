"""The per-step table: iterations, active contact points and the energy balance (SPEC 7).

A mixin of :class:`~parefg.timestepping.simulation.Simulation`.  Balance: kinetic +
elastic + penalty-stored + dissipated - external work stays constant up to the time
discretization error, with the work of the loads F (trapezoidal) and of moving Dirichlet
data.  Every method is collective.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from parefg.timestepping.schemes import State


class EnergyLedger:
    """History rows of a simulation."""

    comm: Any
    scene: Any
    disc: Any
    scheme: Any
    law: Any
    solver: Any
    history: list[dict[str, float]]
    keep_history: bool
    dirichlet_names: list[str]
    coulomb_iterations: int
    max_coulomb_per_step: int
    _du: PETSc.Vec
    _mean_forces: PETSc.Vec
    _last_forces: PETSc.Vec
    _next_forces: PETSc.Vec
    _product: PETSc.Vec
    _dirichlet_previous: dict[str, tuple[np.ndarray, np.ndarray]]

    _dirichlet_value: Callable[..., np.ndarray]  # Simulation's
    _check_row: Callable[..., None]  # StepChecks'

    def _record(self, old: State, new: State, t, forces, newton, linear) -> None:
        """Per-step table row: iterations, active points and energies.

        Balance: kinetic + elastic + penalty-stored + dissipated - external work is
        constant, with the work of the loads F and of the moving Dirichlet data.
        """
        previous = self.history[-1] if self.history else {}
        # this rank's shares, summed in one reduction: dissipation, active points, normal
        # and friction energy, Dirichlet energy and anchor work (each its own entry, so
        # each sum is the one a reduction of its own would give)
        local = np.zeros(6)
        if self.law is not None:
            un, ut = self.law.kinematics(new.u)
            local[0] = self.law.end_step(un, ut)
            local[1] = np.count_nonzero(un > self.law.gap)
            local[2] = self.law.local_normal_energy(un) + self.law.local_nitsche_energy(new.u)
            local[3] = self.law.local_friction_energy(ut)
        local[4:] = self._dirichlet_shares(new.u, t)
        total = np.empty_like(local)
        self.comm.Allreduce(local, total, op=MPI.SUM)
        dissipated = previous.get("dissipated_energy", 0.0) + total[0]
        active = int(total[1])
        contact_energy = total[2] + total[3]
        dirichlet_energy, anchor_work = total[4], total[5]
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
        self._check_row(row, int(round(t / self.scheme.dt)))
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
        """The boundary energy int e(u_h, ubar) on Gamma_D, and the work of the moving data.

        e is the Dirichlet method's (parefg.discretization.dirichlet; the penalty's
        alpha_D/2 |u_h - ubar|^2); the anchor work over the step is
        -int mean(f) . (ubar_n - ubar_{n-1}), f = -de/dubar, exact for the quadratic e.
        """
        energy, work = self._dirichlet_shares(u, t)
        return self.comm.allreduce(energy), self.comm.allreduce(work)

    def _dirichlet_shares(self, u: PETSc.Vec, t: float) -> tuple[float, float]:
        """This rank's shares of :meth:`_dirichlet_terms`; sets the level's ubar and force.

        Collective (the traces of u).
        """
        energy, work = 0.0, 0.0
        previous = self._dirichlet_previous
        current = {}
        for name in self.dirichlet_names:
            points, part = self.disc.boundary[name], self.disc.dirichlet_parts[name]
            ubar = self._dirichlet_value(name, t)
            density, force = part.energy_and_force(points.evaluate(u), part.point_traction(u), ubar)
            energy += np.dot(points.weights, density)
            # Without a previous level (start, resume) the work is not used: no ubar(t - dt),
            # which may lie outside the data's domain (t < 0).
            old_ubar, old_force = previous.get(name, (ubar, force))
            mean_force = 0.5 * (force + old_force)
            work -= np.dot(points.weights, (mean_force * (ubar - old_ubar)).sum(axis=1))
            current[name] = (ubar, force)
        self._dirichlet_previous = current
        return energy, work

    def _quadratic(self, matrix: PETSc.Mat, x: PETSc.Vec) -> float:
        """x^T A x for a square DOF matrix A (mass, stiffness).  Collective."""
        matrix.mult(x, self._product)
        return self._product.dot(x)
