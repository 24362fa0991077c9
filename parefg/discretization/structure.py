"""Sparse sums and products whose pattern does not depend on round-off.

scipy's ``a + b``, ``a - b`` and ``a @ b`` drop every entry that comes out exactly 0, so
the pattern of a sum or product of signed terms (MLS shape functions of degree >= 2,
tractions) depends on whether some terms cancel to the last bit: on the backend that
evaluated them and on the CPU's rounding.  A matrix pattern here is structural instead:
an entry exists where some term of the sum could contribute, whatever the values.
Nothing here is collective.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp


def structural_sum(terms: list[tuple[float, sp.spmatrix]], shape: tuple[int, int]) -> sp.csr_matrix:
    """sum of sign * matrix over ``terms`` (sign +1, -1 or 0: the pattern only), its
    pattern the union of the matrices' patterns.  Summed in the order of ``terms``."""
    parts = [(sign, matrix.tocoo()) for sign, matrix in terms]
    rows = np.concatenate([np.zeros(0, dtype=np.int64), *(part.row for _, part in parts)])
    cols = np.concatenate([np.zeros(0, dtype=np.int64), *(part.col for _, part in parts)])
    data = np.concatenate([np.zeros(0), *(sign * part.data for sign, part in parts)])
    return sp.coo_matrix((data, (rows, cols)), shape=shape).tocsr()  # duplicates summed, kept


def weighted_product(left: sp.spmatrix, weights: np.ndarray, right: sp.spmatrix) -> sp.csr_matrix:
    """left^T diag(weights) right, with an entry (i, j) wherever a point q has
    left[q, i] weights[q] right[q, j] != 0: the pattern of the product of the absolute
    values (nothing cancels there), the values those of scipy's product."""
    product = (left.T @ sp.diags(weights) @ right).tocsr()
    pattern = (abs(left).T @ sp.diags(np.abs(weights)) @ abs(right)).tocsr()
    return structural_sum([(1.0, product), (0.0, pattern)], product.shape)
