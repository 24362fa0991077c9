"""The normal penalty force of a time step, registered by name in :data:`CONTACT_FORCES`.

``[time] contact_force`` names one.  Each maps the penetrations d0 = d_{n-1} (start of the
step) and d1 = u_nu - s (its unknown end) at the Gamma_C points to the force C_n the step
balances, its slope in d1 (the Jacobian weight) and its primitive in d1 (the step's
contact energy, convex, so the exact line search keeps its guarantee).  ``level`` is
C_{n-1}, the force the start level's acceleration holds.  Pure numpy; not collective.
"""

from __future__ import annotations

import numpy as np

from parefg.mechanics.discrete_gradient import dg_potential, dg_pressure, dg_slope


class NormalForce:
    """The interface: ``name`` in the registry and the three functions of (d0, d1)."""

    name: str
    #: the force depends on the start level (d0, C_{n-1}), not on d1 alone: it is not
    #: affine in u at a crossing point, and the level's force is C_n, not p(u_n)
    uses_start_level: bool

    @staticmethod
    def pressure(d0: np.ndarray, d1: np.ndarray, alpha: float, level: np.ndarray) -> np.ndarray:
        """The force C_n (n_c,) >= 0 where d1 > 0."""
        raise NotImplementedError

    @staticmethod
    def slope(d0: np.ndarray, d1: np.ndarray, alpha: float) -> np.ndarray:
        """d C_n / d d1 (n_c,) >= 0."""
        raise NotImplementedError

    @staticmethod
    def potential(d0: np.ndarray, d1: np.ndarray, alpha: float, level: np.ndarray) -> np.ndarray:
        """The primitive of :meth:`pressure` in d1 (n_c,), convex in d1."""
        raise NotImplementedError


class EndpointForce(NormalForce):
    """p(u_n) in step n: the pressure alpha_C (u_nu - s)^+ at the end of the step (the paper's).

    The trapezoidal rule then averages p(u_{n-1}) and p(u_n), which is not the work the
    penalty stores when a point crosses the obstacle within the step (measured: the impact
    scene gains 5.7x at beta = 1/4).
    """

    name = "endpoint"
    uses_start_level = False

    @staticmethod
    def pressure(d0: np.ndarray, d1: np.ndarray, alpha: float, level: np.ndarray) -> np.ndarray:
        return alpha * np.maximum(d1, 0.0)

    @staticmethod
    def slope(d0: np.ndarray, d1: np.ndarray, alpha: float) -> np.ndarray:
        # the kink d1 = 0 counts as closed, as ContactLaw._jacobian_closed (both slopes are
        # valid there; the open one left a body starting on the obstacle with a singular J)
        return alpha * (d1 >= 0.0)

    @staticmethod
    def potential(d0: np.ndarray, d1: np.ndarray, alpha: float, level: np.ndarray) -> np.ndarray:
        """alpha_C/2 ((u_nu - s)^+)^2."""
        return 0.5 * alpha * np.maximum(d1, 0.0) ** 2


class DiscreteGradientForce(NormalForce):
    """C_n = 2 DG(d_{n-1}, d_n) - C_{n-1} (Armero & Petocz 1998, Hauret & Le Tallec 2006).

    DG is the discrete gradient of phi(d) = alpha_C/2 (d^+)^2, so that
    (C_{n-1} + C_n)/2 (d_n - d_{n-1}) = phi(d_n) - phi(d_{n-1}) exactly.
    :func:`~parefg.mechanics.discrete_gradient.dg_pressure` is 2 DG - alpha_C d_{n-1}^+;
    with C_{n-1} the pressure at d_{n-1} the force differs from the endpoint one only at
    points that cross the obstacle within the step, where it is a rational function of
    d_n (not affine).
    """

    name = "discrete_gradient"
    uses_start_level = True

    @staticmethod
    def pressure(d0: np.ndarray, d1: np.ndarray, alpha: float, level: np.ndarray) -> np.ndarray:
        return dg_pressure(d0, d1, alpha) + _shift(d0, alpha, level)

    @staticmethod
    def slope(d0: np.ndarray, d1: np.ndarray, alpha: float) -> np.ndarray:
        return dg_slope(d0, d1, alpha)

    @staticmethod
    def potential(d0: np.ndarray, d1: np.ndarray, alpha: float, level: np.ndarray) -> np.ndarray:
        return dg_potential(d0, d1, alpha) + _shift(d0, alpha, level) * d1


def _shift(d0: np.ndarray, alpha: float, level: np.ndarray) -> np.ndarray:
    """alpha_C d_{n-1}^+ - C_{n-1}: zero when the start level holds the pressure."""
    return alpha * np.maximum(d0, 0.0) - level


#: [time] contact_force -> the step's normal force; the first is the default
CONTACT_FORCES: dict[str, type[NormalForce]] = {
    force.name: force for force in (DiscreteGradientForce, EndpointForce)
}
