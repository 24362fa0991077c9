"""The energy-consistent normal penalty force of a time step: the discrete gradient.

For phi(d) = alpha/2 (d^+)^2 (d = u_nu - s, the penetration) and a step from d0 to d1,
the force p with (phi'(d0) + p)/2 (d1 - d0) = phi(d1) - phi(d0) (Armero & Petocz 1998;
Hauret & Le Tallec 2006): the trapezoidal average of the forces at both ends of the step
does exactly the work the penalty stores, also when the point touches down or lifts off
within the step.  :func:`dg_pressure` is nondecreasing in d1 with the convex primitive
:func:`dg_potential`, so a step using it stays a convex minimization.  Pure numpy on
arrays of Gamma_C points; not collective.
"""

from __future__ import annotations

import numpy as np

#: below this x the closed-form energies use their Taylor series (no cancellation)
_SERIES_BELOW = 0.5
_SERIES_TERMS = 40


def _x_minus_log1p(x: np.ndarray) -> np.ndarray:
    """x - log(1 + x) >= 0 for x >= 0, without cancellation at small x."""
    x = np.asarray(x, dtype=float)
    small = x < _SERIES_BELOW
    xs = np.where(small, x, 0.0)
    # sum_{n >= 2} (-1)^n x^n / n by Horner; 40 terms at x < 0.5 leave < 1e-12 relative
    series = np.zeros_like(xs)
    for n in range(_SERIES_TERMS, 1, -1):
        series = series * xs + (-1.0) ** n / n
    with np.errstate(invalid="ignore"):
        direct = x - np.log1p(np.where(small, 0.0, x))
    return np.where(small, series * xs * xs, direct)


def dg_pressure(d0: np.ndarray, d1: np.ndarray, alpha: float) -> np.ndarray:
    """Energy-consistent normal force of a step from penetration d0 to d1 (Gamma_C points).

    p = 2 DG(d0, d1) - phi'(d0), DG = (phi(d1) - phi(d0)) / (d1 - d0) the discrete
    gradient of phi(d) = alpha/2 (d^+)^2, so that (phi'(d0) + p)/2 (d1 - d0) = phi(d1) -
    phi(d0) exactly: the trapezoidal average of the forces at both ends of the step does
    the work the penalty stores.  In closed form (no division by d1 - d0 where it can
    vanish: across the obstacle |d1 - d0| >= max(|d0|, |d1|)):

        both sides alike  alpha d1^+                 (the endpoint force)
        touch-down        alpha d1^2 / (d1 - d0)     d0 <= 0 < d1
        lift-off          alpha d0 d1 / (d0 - d1)    d1 <= 0 < d0 (a pull, <= 0)

    Nondecreasing and C^1 in d1 for d0 != 0.  Not collective.
    """
    down, up = crossings(d0, d1)
    safe = np.where(down | up, d1 - d0, 1.0)
    crossing = np.where(down, d1 * d1, d0 * d1) / np.where(down, safe, -safe)
    return alpha * np.where(down | up, crossing, np.maximum(d1, 0.0))


def dg_slope(d0: np.ndarray, d1: np.ndarray, alpha: float) -> np.ndarray:
    """d p / d d1 of :func:`dg_pressure` (>= 0), the Jacobian weight.  Not collective."""
    down, up = crossings(d0, d1)
    # ratios first (|r| <= 1 across the obstacle): squaring d1 - d0 could underflow
    safe = np.where(down | up, d1 - d0, 1.0)
    r0, r1 = d0 / safe, d1 / safe
    crossing = np.where(down, r1 * (r1 - 2.0 * r0), r0 * r0)
    return alpha * np.where(down | up, crossing, (d1 > 0.0).astype(float))


def dg_potential(d0: np.ndarray, d1: np.ndarray, alpha: float) -> np.ndarray:
    """Primitive of :func:`dg_pressure` in d1, zero at d1 = 0: convex in d1.

        d0 > 0, d1 <= 0   alpha d0^2 (x - log(1 + x)),       x = -d1 / d0
        d0 <= 0, d1 > 0   alpha m^2 (x^2/2 - x + log(1 + x)), x = d1 / m, m = -d0
        otherwise         alpha/2 (d1^+)^2

    (with m = 0 the second row is alpha/2 d1^2).  Not collective.
    """
    down, up = crossings(d0, d1)
    tiny = np.finfo(float).tiny
    lift = d0 * d0 * _x_minus_log1p(np.where(up, -d1 / np.maximum(d0, tiny), 0.0))
    m = np.maximum(-d0, 0.0)
    x = np.where(down, d1 / np.maximum(m, tiny), 0.0)
    # x^2/2 - x + log1p(x) = x^2/2 - (x - log1p(x)); at large x use the unscaled form
    large = x >= _SERIES_BELOW
    xs = np.where(large, 0.0, x)
    touch_small = m * m * (0.5 * xs * xs - _x_minus_log1p(xs))
    with np.errstate(invalid="ignore", divide="ignore"):
        touch_large = 0.5 * d1 * d1 - m * d1 + m * m * np.log1p(np.where(large, x, 0.0))
    touch = np.where(large, touch_large, touch_small)
    alike = 0.5 * np.maximum(d1, 0.0) ** 2
    return alpha * np.where(up, lift, np.where(down, touch, alike))


def crossings(d0, d1) -> tuple[np.ndarray, np.ndarray]:
    """(touch-down, lift-off) flags: the step crosses the obstacle (d = 0) at the point."""
    closed0, closed1 = d0 > 0.0, d1 > 0.0
    return ~closed0 & closed1, closed0 & ~closed1
