"""Compiled (numba) kernels of the VCI gradient correction (:mod:`.consistent_gradients`).

The same sums and corrected gradients as the numpy code there, in one pass over the
(point, neighbour) entries instead of arrays of basis products per entry (which cost
4x the MLS evaluation itself at m = 3).  Nothing here is collective; cached next to this
file (``cache=True``), compiled ahead of time by ``make setup`` and called through
:mod:`.aot` (this module is imported only where that module is missing).
"""

import numba
import numpy as np


def _jit(function):
    """Compile without fastmath (sums keep their order), IEEE division (no zero test)."""
    return numba.njit(cache=True, fastmath=False, nogil=True, error_model="numpy")(function)


@_jit
def _basis(y0, y1, radius, exponents, powers, p, dp):
    """p(y) and its x-gradient (dp[:, 0], dp[:, 1]) into p, dp; y = (x - x_I) / R."""
    degree = powers.shape[1] - 1
    powers[0, 0] = 1.0
    powers[1, 0] = 1.0
    for e in range(1, degree + 1):
        powers[0, e] = powers[0, e - 1] * y0
        powers[1, e] = powers[1, e - 1] * y1
    for c in range(exponents.shape[0]):
        a, b = exponents[c, 0], exponents[c, 1]
        p[c] = powers[0, a] * powers[1, b]
        dp[c, 0] = a * powers[0, max(a - 1, 0)] * powers[1, b] / radius
        dp[c, 1] = b * powers[0, a] * powers[1, max(b - 1, 0)] / radius


@_jit
def _entry_basis(point, node, radius, exponents, powers, p, dp):
    """p and its gradient (see _basis) at ``point`` for the node at ``node``."""
    y0, y1 = (point[0] - node[0]) / radius, (point[1] - node[1]) / radius
    _basis(y0, y1, radius, exponents, powers, p, dp)


@_jit
def domain_sums(
    points, weights, neighbours, mask, phi, dphi, nodes, radius, exponents, moments, rhs
):
    """moments[I] += w p p^T and rhs[I, a] -= w (phi_I d_a p + d_a phi_I p) over the entries."""
    n_p = exponents.shape[0]
    powers = np.empty((2, exponents.max() + 1))
    p, dp = np.empty(n_p), np.empty((n_p, 2))
    for q in range(points.shape[0]):
        w = weights[q]
        for k in range(neighbours.shape[1]):
            if not mask[q, k]:
                continue
            node = neighbours[q, k]
            _entry_basis(points[q], nodes[node], radius[node], exponents, powers, p, dp)
            value, gradient0, gradient1 = phi[q, k], dphi[q, k, 0], dphi[q, k, 1]
            for c in range(n_p):
                scaled = w * p[c]
                for d in range(c, n_p):
                    moments[node, c, d] += scaled * p[d]
                rhs[node, 0, c] -= w * (value * dp[c, 0] + gradient0 * p[c])
                rhs[node, 1, c] -= w * (value * dp[c, 1] + gradient1 * p[c])


@_jit
def boundary_sums(points, weights, normals, neighbours, mask, phi, nodes, radius, exponents, rhs):
    """rhs[I, a] += w phi_I p n_a over the boundary entries."""
    n_p = exponents.shape[0]
    powers = np.empty((2, exponents.max() + 1))
    p, dp = np.empty(n_p), np.empty((n_p, 2))
    for q in range(points.shape[0]):
        for k in range(neighbours.shape[1]):
            if not mask[q, k]:
                continue
            node = neighbours[q, k]
            _entry_basis(points[q], nodes[node], radius[node], exponents, powers, p, dp)
            scale = weights[q] * phi[q, k]
            for c in range(n_p):
                rhs[node, 0, c] += scale * normals[q, 0] * p[c]
                rhs[node, 1, c] += scale * normals[q, 1] * p[c]


@_jit
def correct(points, neighbours, mask, dphi, nodes, radius, exponents, coefficients, out):
    """out = dphi + xi_I . p((x - x_I) / R_I) at every entry (padding: dphi itself, 0)."""
    n_p = exponents.shape[0]
    powers = np.empty((2, exponents.max() + 1))
    p, dp = np.empty(n_p), np.empty((n_p, 2))
    for q in range(points.shape[0]):
        for k in range(neighbours.shape[1]):
            out[q, k, 0] = dphi[q, k, 0]
            out[q, k, 1] = dphi[q, k, 1]
            if not mask[q, k]:
                continue
            node = neighbours[q, k]
            _entry_basis(points[q], nodes[node], radius[node], exponents, powers, p, dp)
            for c in range(n_p):
                out[q, k, 0] += coefficients[node, 0, c] * p[c]
                out[q, k, 1] += coefficients[node, 1, c] * p[c]
