"""Checks after every step: a free rigid motion, non-finite fields, energy that explodes.

A mixin of :class:`~parefg.timestepping.simulation.Simulation`.  Each check raises a
SolverError that names what went wrong and when, on every rank (the decisions are taken
from allreduced values, or from energies that are the same on every rank).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc

from parefg.errors import SolverError
from parefg.guards import all_finite
from parefg.timestepping.schemes import State

# Energies held by the state; with the external work they balance (see EnergyLedger._record).
STORED_ENERGIES = ("kinetic_energy", "elastic_energy", "penalty_energy", "dissipated_energy")
# A dynamic run whose stored energy exceeds this multiple of the energy it was given
# (initial energy + the largest |external work| so far) has diverged: energy-stable
# schemes stay within the time-discretization error of the balance (SPEC 4), an unstable
# one grows geometrically and passes this bound long before it overflows.
ENERGY_GROWTH = 1e6


def stored_energy(row: dict) -> float:
    """Kinetic + elastic + penalty-stored + dissipated energy of a history row."""
    return sum(row[name] for name in STORED_ENERGIES)


class StepChecks:
    """The guards of the time loop."""

    comm: Any
    scheme: Any
    law: Any
    rigid_modes: Any
    _energy_budget: list[float]

    def _check_rigid_modes(self, u: PETSc.Vec, t: float) -> None:
        """SolverError if the Jacobian at u leaves a rigid motion free.  Collective.

        Only static scenes held by contact alone are checked (see _rigid_mode_check).
        """
        if self.rigid_modes is None or self.law is None:
            return
        self.rigid_modes.check(t, *self.law.active_weights(*self.law.kinematics(u)))

    def _check_state(self, state: State, n: int) -> None:
        """SolverError naming the first non-finite field of u, v, a at step n.  Collective.

        One allreduce (of a bit mask).  Call it under ``np.errstate(over="ignore")``: huge
        finite values may overflow the sums (:func:`~parefg.guards.all_finite`).
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
        stored = stored_energy(row)
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
        with np.errstate(over="ignore"):  # huge finite values may overflow the sums
            self._raise_non_finite("non-finite output field ", fields, n)

    def _raise_non_finite(self, what: str, arrays: dict[str, np.ndarray], n: int) -> None:
        """SolverError naming the first of ``arrays`` that is not finite on some rank.

        Collective: one allreduce of a bit mask (bit i: array i has a non-finite entry).
        Call it under ``np.errstate(over="ignore")``: huge finite values may overflow the sums.
        """
        local = 0
        for bit, values in enumerate(arrays.values()):
            if not all_finite(np.asarray(values, dtype=float)):
                local |= 1 << bit
        bad = self.comm.allreduce(local, op=MPI.BOR)
        for bit, name in enumerate(arrays):
            if bad >> bit & 1:
                self._diverged(f"{what}{name}", n)

    def _diverged(self, what: str, n: int) -> None:
        t = n * self.scheme.dt
        raise SolverError(
            f"{what} at step {n}, t = {t:.6g}: the time integration diverged "
            "(check the loads, time.dt, the Newmark parameters and the penalty factors)"
        )
