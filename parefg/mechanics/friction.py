"""Friction laws: which Gamma_C points carry the friction bound g in a step (SPEC 1).

A law is chosen per contact part (``[boundary.NAME] friction_law``).  It maps the contact
state at the start of the step to the points where the bound acts; the step then
minimizes J_n with the bound g_eff = g_n on those points and 0 elsewhere.

Coulomb (``"coulomb"``, g = mu_f p with the contact pressure p = alpha_C (u_nu - s)^+ of
the unknown u_n) is the pressure-dependent law of :data:`PRESSURE_LAWS`: its bound is not
data but part of the solution, so it is not gated (it vanishes by itself where the body
does not touch, with no lag at a status change) and the step solves it by a fixed point
on Tresca bounds, g^(k) = mu_f p(u^(k)) (parefg.timestepping.coulomb).

Why the start of the step: gating by the status of the unknown u_n itself
(psi(z) H(u_nu - s)) makes J_n non-convex and its directional derivative jump where a
point closes, so the exact line search and the convergence test would lose their meaning.
With the gate fixed before the solve, psi_n keeps its convex form with a per-point bound,
and the energy, residual, Jacobian and directional derivative all see the same g_eff.
The state used is the Newmark predictor ut_n, the step's best guess of u_n known before
the solve.  (Also counting points closed at t_{n-1} was measured worse: on the impact
scene 402 point-steps ended OPEN while carrying friction, against 32 with the predictor;
the paper's "given" has 7498.)  While a point is open its slip follows u_tau (g = 0 in
the return mapping), so it touches down with an unstressed friction spring.
The price is a lag at a status change: a point that touches down within step n, but not
at the predictor, gets its friction from step n + 1 on, and one that lifts off within
step n, but not at the predictor, still carried friction during step n (it is reported
as OPEN with that force: the force that acted, which the energy balance counts).

Not collective: pure numpy on this rank's points.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

#: the friction law of a contact part when the scene names none
DEFAULT_FRICTION_LAW = "tresca"
#: the default instead when the bound g is derived from [exact] (parefg.scene.boundaries)
DERIVED_FRICTION_LAW = "given"


#: relative distance to the obstacle below which a predicted point counts as touching
TOUCH_RTOL = 1e-9


def _touching(un_predicted, gap) -> np.ndarray:
    """Closed at the predictor: u_nu >= s (SPEC 1), to TOUCH_RTOL (|s| + |u_nu|).

    The tolerance keeps round-off out of the decision: a rigid approach puts every point
    of the impact scene at u_nu = s to round-off at t = 0.05, where a bare ``>=`` made
    1 and 2 ranks choose differently (mean v_x at T 0.47626 vs 0.47660).  A point exactly
    at the obstacle (s = 0, u = 0 at t = 0, as in the manufactured scenes) touches.
    """
    return un_predicted - gap >= -TOUCH_RTOL * (np.abs(gap) + np.abs(un_predicted))


def _everywhere(un_predicted, gap) -> np.ndarray:
    """The paper's given friction: g acts on all of Gamma_C, touching or not."""
    return np.ones(len(gap), dtype=bool)


#: name -> gate(u_nu of the predictor, s) -> (n,) bool: the points where g acts in the step.
#: A pressure-dependent law (PRESSURE_LAWS) acts everywhere: its bound mu_f p is zero where
#: the iterate does not touch.
FRICTION_LAWS: dict[str, Callable[..., np.ndarray]] = {
    "tresca": _touching,
    "given": _everywhere,
    "coulomb": _everywhere,
}

#: the laws whose bound is mu_f times the contact pressure ([boundary.NAME]
#: friction_coefficient), set by ContactLaw.set_pressure_bound instead of a given g
PRESSURE_LAWS = ("coulomb",)


def coulomb_bound(coefficient, pressure) -> np.ndarray:
    """Coulomb's bound g = mu_f p (SPEC 1: mu_f (-sigma_nu), -sigma_nu = p >= 0)."""
    return coefficient * pressure
