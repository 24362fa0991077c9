"""MLS weight functions W(r) of the normalized distance r = |x - x_I| / d_I (SPEC 2).

Every weight is registered by name in :data:`WEIGHTS`; the scene key
``discretization.weight`` selects one through :func:`get_weight` and the scene schema
reads its allowed values from there.  All weights have compact support: W(r) = 0 and
W'(r) = 0 for r >= 1.

Each weight is written in two forms, both here: vectorized numpy functions (the numpy
backend of :mod:`parefg.discretization.mls`) and one branch of :func:`weight_pair`, the
scalar form that :mod:`parefg.discretization.mls_kernels` compiles.  They are not one
formula evaluated twice because their operation orders differ (4 r^2 against 4 r r), and
each backend's results must keep their last bits; tests/discretization/test_mls.py checks
that the two forms agree to round-off.
"""

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from parefg.errors import InputError

# Width of the truncated Gaussian, relative to the support radius.
GAUSSIAN_WIDTH = 0.4


@dataclass(frozen=True)
class Weight:
    """A radial weight W(r), vectorized over arrays of r >= 0.

    Attributes
    ----------
    name : str
        Registry name (value of ``discretization.weight``).
    value : callable
        r -> W(r), same shape as r, zero for r >= 1.
    derivative : callable
        r -> dW/dr, same shape as r, zero for r >= 1.
    code : int or None
        Its branch of :func:`weight_pair` (the compiled kernel), or None when the
        compiled kernel does not know it (then MLS computes with numpy).
    """

    name: str
    value: Callable[[np.ndarray], np.ndarray]
    derivative: Callable[[np.ndarray], np.ndarray]
    code: int | None = None


# Branches of weight_pair, one per compiled weight.
CUBIC, QUARTIC, GAUSSIAN = 0, 1, 2


def weight_pair(code, r):
    """(W(r), dW/dr) of the weight with the given code at one r >= 0; both 0 for r >= 1.

    Plain Python that numba compiles (:func:`parefg.discretization.mls_kernels.weight_and_slope`):
    keep it to scalar arithmetic.
    """
    if r >= 1.0:
        return 0.0, 0.0
    if code == CUBIC:
        if r <= 0.5:
            return 2.0 / 3.0 - 4.0 * r * r + 4.0 * r**3, -8.0 * r + 12.0 * r * r
        return 4.0 / 3.0 - 4.0 * r + 4.0 * r * r - 4.0 / 3.0 * r**3, -4.0 + 8.0 * r - 4.0 * r * r
    if code == QUARTIC:
        return 1.0 - 6.0 * r * r + 8.0 * r**3 - 3.0 * r**4, -12.0 * r + 24.0 * r * r - 12.0 * r**3
    floor = np.exp(-((1.0 / GAUSSIAN_WIDTH) ** 2))
    gauss = np.exp(-((r / GAUSSIAN_WIDTH) ** 2))
    return (gauss - floor) / (1.0 - floor), -2.0 * r / GAUSSIAN_WIDTH**2 * gauss / (1.0 - floor)


def _cubic_value(r):
    """Cubic spline: 2/3 - 4r^2 + 4r^3 (r <= 1/2), 4/3 - 4r + 4r^2 - 4r^3/3 (1/2 < r < 1)."""
    r = np.asarray(r, dtype=float)
    inner = 2.0 / 3.0 - 4.0 * r**2 + 4.0 * r**3
    outer = 4.0 / 3.0 - 4.0 * r + 4.0 * r**2 - 4.0 / 3.0 * r**3
    return np.where(r <= 0.5, inner, np.where(r < 1.0, outer, 0.0))


def _cubic_derivative(r):
    """dW/dr of the cubic spline: -8r + 12r^2 (r <= 1/2), -4 + 8r - 4r^2 (1/2 < r < 1)."""
    r = np.asarray(r, dtype=float)
    inner = -8.0 * r + 12.0 * r**2
    outer = -4.0 + 8.0 * r - 4.0 * r**2
    return np.where(r <= 0.5, inner, np.where(r < 1.0, outer, 0.0))


def _quartic_value(r):
    """Quartic spline: 1 - 6r^2 + 8r^3 - 3r^4 for r < 1."""
    r = np.asarray(r, dtype=float)
    return np.where(r < 1.0, 1.0 - 6.0 * r**2 + 8.0 * r**3 - 3.0 * r**4, 0.0)


def _quartic_derivative(r):
    """dW/dr of the quartic spline: -12r + 24r^2 - 12r^3 for r < 1."""
    r = np.asarray(r, dtype=float)
    return np.where(r < 1.0, -12.0 * r + 24.0 * r**2 - 12.0 * r**3, 0.0)


def _gaussian_value(r):
    """Truncated Gaussian: (exp(-(r/c)^2) - exp(-(1/c)^2)) / (1 - exp(-(1/c)^2)), c = 0.4."""
    r = np.asarray(r, dtype=float)
    floor = np.exp(-((1.0 / GAUSSIAN_WIDTH) ** 2))
    value = (np.exp(-((r / GAUSSIAN_WIDTH) ** 2)) - floor) / (1.0 - floor)
    return np.where(r < 1.0, value, 0.0)


def _gaussian_derivative(r):
    """dW/dr of the truncated Gaussian: -2 r / c^2 exp(-(r/c)^2) / (1 - exp(-(1/c)^2))."""
    r = np.asarray(r, dtype=float)
    floor = np.exp(-((1.0 / GAUSSIAN_WIDTH) ** 2))
    slope = -2.0 * r / GAUSSIAN_WIDTH**2 * np.exp(-((r / GAUSSIAN_WIDTH) ** 2)) / (1.0 - floor)
    return np.where(r < 1.0, slope, 0.0)


#: ``discretization.weight`` -> its Weight; the first one is the default
WEIGHTS: dict[str, Weight] = {
    weight.name: weight
    for weight in (
        Weight("cubic", _cubic_value, _cubic_derivative, CUBIC),
        Weight("quartic", _quartic_value, _quartic_derivative, QUARTIC),
        Weight("gaussian", _gaussian_value, _gaussian_derivative, GAUSSIAN),
    )
}


def get_weight(name: str) -> Weight:
    """Return the registered weight called ``name``.

    Raises
    ------
    InputError
        If no weight has that name; the message lists the known names.
    """
    try:
        return WEIGHTS[name]
    except (KeyError, TypeError):
        known = ", ".join(f'"{key}"' for key in WEIGHTS)
        raise InputError(
            f"discretization.weight: unknown weight {name!r}; allowed: {known}"
        ) from None


DEFAULT_WEIGHT = next(iter(WEIGHTS))
