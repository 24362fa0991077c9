"""Time schemes, registered by name in :data:`SCHEMES`: Newmark, generalized-alpha, static (SPEC 4).

Schemes are registered by name in :data:`SCHEMES`.  They write into vectors the caller
owns (the time loop allocates its work vectors once per run).  Each step minimizes

    J_n(u) = c_M/2 (u - ut_n)^T M (u - ut_n) + 1/2 u^T K u - F_n . u
           + alpha_D/2 ||u - ubar_n||^2_{Gamma_D} + contact and friction energy,

i.e. solves A_const u - b_n + contact forces = 0 with A_const = c_M M + K + alpha_D G_D
(assembled once) and b_n = c_M M ut_n + F_n + alpha_D g_D(t_n) (+ the previous level's
balance for generalized-alpha, see :attr:`GeneralizedAlphaScheme.history`).  Newmark has
c_M = 1 / (beta dt^2); the static scheme has c_M = 0 and steps the loads only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from petsc4py import PETSc


@dataclass
class State:
    """Nodal parameters (not values: MLS does not interpolate) of one time level."""

    u: PETSc.Vec
    v: PETSc.Vec
    a: PETSc.Vec

    @classmethod
    def like(cls, vec: PETSc.Vec) -> State:
        """Three zero vectors with the layout of ``vec``.  Collective."""
        return cls(*(vec.duplicate() for _ in range(3)))


class NewmarkScheme:
    """Newmark(beta, gamma): predictor ut, vt; a = (u - ut)/(beta dt^2), v = vt + gamma dt a."""

    name = "newmark"
    dynamic = True
    # (w_a, w_r): b_n -= w_a M a_{n-1} + w_r r_{n-1}, the previous level's share of the
    # step; None: the balance is at t_n alone (Newmark)
    history: tuple[float, float] | None = None

    def __init__(self, scene):
        self.dt, self.beta, self.gamma = scene.time.dt, scene.time.beta, scene.time.gamma

    @property
    def mass_coefficient(self) -> float:
        return 1.0 / (self.beta * self.dt**2)

    @property
    def acceleration_coefficient(self) -> float:
        """1 / (beta dt^2): a_n = (u_n - ut_n) / (beta dt^2)."""
        return 1.0 / (self.beta * self.dt**2)

    @property
    def trapezoidal(self) -> bool:
        """beta = 1/4, gamma = 1/2: an energy without acceleration term (mechanics.contact)."""
        return abs(self.beta - 0.25) <= 1e-12 and abs(self.gamma - 0.5) <= 1e-12

    def predict(self, state: State, ut: PETSc.Vec, vt: PETSc.Vec) -> None:
        """ut, vt (overwritten) from the previous level ``state``."""
        dt, beta, gamma = self.dt, self.beta, self.gamma
        state.u.copy(ut)
        ut.axpy(dt, state.v)
        ut.axpy(dt * dt * (0.5 - beta), state.a)
        state.v.copy(vt)
        vt.axpy(dt * (1.0 - gamma), state.a)

    def update(self, state: State, new: State, ut: PETSc.Vec, vt: PETSc.Vec) -> None:
        """new.v, new.a (overwritten) from the solved new.u and the predictors."""
        a, v = new.a, new.v
        new.u.copy(a)
        a.axpy(-1.0, ut)
        a.scale(self.acceleration_coefficient)
        vt.copy(v)
        v.axpy(self.gamma * self.dt, a)


def generalized_alpha_parameters(rho_inf: float) -> dict[str, float]:
    """alpha_m, alpha_f, beta, gamma of generalized-alpha for the spectral radius rho_inf.

    Chung & Hulbert (1993), eq. (25) and (17), (20): alpha_m = (2 rho - 1)/(rho + 1),
    alpha_f = rho/(rho + 1), gamma = 1/2 - alpha_m + alpha_f (second order),
    beta = (1 - alpha_m + alpha_f)^2 / 4 (unconditional stability, high-frequency
    dissipation maximal for the given rho_inf in [0, 1]).  rho_inf = 1 gives
    alpha_m = alpha_f = 1/2, beta = 1/4, gamma = 1/2: no dissipation.
    """
    alpha_m = (2.0 * rho_inf - 1.0) / (rho_inf + 1.0)
    alpha_f = rho_inf / (rho_inf + 1.0)
    return {
        "alpha_m": alpha_m,
        "alpha_f": alpha_f,
        "gamma": 0.5 - alpha_m + alpha_f,
        "beta": 0.25 * (1.0 - alpha_m + alpha_f) ** 2,
    }


class GeneralizedAlphaScheme(NewmarkScheme):
    """Generalized-alpha (Chung & Hulbert 1993) with the Newmark predictor and update.

    The balance is taken between the levels, each force as the alpha_f-weighted mean of its
    values at the two levels (the "generalized trapezoidal" form, Erlicher, Bonaventura &
    Bursi 2002, second order like the midpoint form f(u_{n-alpha_f})):

        (1 - alpha_m) M a_n + alpha_m M a_{n-1} + (1 - alpha_f) r_n + alpha_f r_{n-1} = 0,
        r(u, t) = (K + alpha_D G_D) u - F(t) - alpha_D g_D(t) + C(u)    (C: contact, friction)

    Divided by (1 - alpha_f), the step is Newmark's convex minimization with the stiffness
    coefficient 1 and c_M = (1 - alpha_m) / ((1 - alpha_f) beta dt^2): the contact energy
    and its penalty enter unchanged, at u_n (the law, the Jacobian and the exact line search
    are Newmark's).  The previous level enters b_n through :attr:`history`.  rho_inf = 1
    is Newmark(1/4, 1/2): its balance at t_{n-1} makes the history term vanish.
    """

    name = "generalized-alpha"

    def __init__(self, scene):
        self.dt, self.rho_inf = scene.time.dt, scene.time.rho_inf
        parameters = generalized_alpha_parameters(self.rho_inf)
        self.alpha_m, self.alpha_f = parameters["alpha_m"], parameters["alpha_f"]
        self.beta, self.gamma = parameters["beta"], parameters["gamma"]
        scale = 1.0 / (1.0 - self.alpha_f)
        self.history = (self.alpha_m * scale, self.alpha_f * scale)

    @property
    def mass_coefficient(self) -> float:
        return (1.0 - self.alpha_m) / ((1.0 - self.alpha_f) * self.beta * self.dt**2)


class StaticScheme:
    """Quasi-static load stepping: no inertia, the same minimization at each t_n."""

    name = "static"
    dynamic = False
    mass_coefficient = 0.0
    history: tuple[float, float] | None = None
    trapezoidal = False

    def __init__(self, scene):
        self.dt = scene.time.dt

    def predict(self, state: State, ut: PETSc.Vec, vt: PETSc.Vec) -> None:
        state.u.copy(ut)
        state.v.copy(vt)

    def update(self, state: State, new: State, ut: PETSc.Vec, vt: PETSc.Vec) -> None:
        new.u.copy(new.v)
        new.v.axpy(-1.0, state.u)
        new.v.scale(1.0 / self.dt)
        state.a.copy(new.a)


SCHEMES = {scheme.name: scheme for scheme in (NewmarkScheme, GeneralizedAlphaScheme, StaticScheme)}


def make_scheme(scene):
    """The scheme named by ``[time] scheme``."""
    return SCHEMES[scene.time.scheme](scene)


def relative_errors(comm, disc, exact, u: PETSc.Vec, t: float) -> dict[str, float]:
    """Relative L2 and H1-seminorm errors of u_h against the exact solution at t.  Collective."""
    points, weights = disc.domain.restore_points()  # computed again if released
    values, grads = disc.domain.evaluate_with_gradient(u)  # (n_q, 2), (n_q, 2, 2)
    u_exact = exact.u(points[:, 0], points[:, 1], t).T  # (n_q, 2)
    g_exact = np.moveaxis(exact.grad(points[:, 0], points[:, 1], t), -1, 0)  # (n_q, 2, 2)
    sums = np.array(
        [
            np.dot(weights, np.sum((values - u_exact) ** 2, axis=1)),
            np.dot(weights, np.sum(u_exact**2, axis=1)),
            np.dot(weights, np.sum((grads - g_exact) ** 2, axis=(1, 2))),
            np.dot(weights, np.sum(g_exact**2, axis=(1, 2))),
        ]
    )
    sums = comm.allreduce(sums)
    return {
        "l2_rel": float(np.sqrt(sums[0] / sums[1])) if sums[1] > 0 else float(np.sqrt(sums[0])),
        "h1_rel": float(np.sqrt(sums[2] / sums[3])) if sums[3] > 0 else float(np.sqrt(sums[2])),
    }
