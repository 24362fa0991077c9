"""Plane-strain linear elasticity: stresses from displacement gradients (SPEC 1).

The stiffness itself is assembled in :mod:`parefg.discretization.operators`; this module
holds the constitutive law where results need it pointwise.
"""

from __future__ import annotations

import numpy as np


def von_mises(lam: float, mu: float, grads: np.ndarray) -> np.ndarray:
    """Plane-strain von Mises stress (n,) from displacement gradients ``grads`` (n, 2, 2).

    sigma = lam tr(eps) I + 2 mu eps, with sigma_zz = lam tr(eps) (eps_zz = 0).
    Not collective.
    """
    strain = 0.5 * (grads + np.swapaxes(grads, 1, 2))
    trace = strain[:, 0, 0] + strain[:, 1, 1]
    sxx = lam * trace + 2 * mu * strain[:, 0, 0]
    syy = lam * trace + 2 * mu * strain[:, 1, 1]
    szz = lam * trace  # plane strain
    sxy = 2 * mu * strain[:, 0, 1]
    return np.sqrt(0.5 * ((sxx - syy) ** 2 + (syy - szz) ** 2 + (szz - sxx) ** 2) + 3 * sxy**2)
