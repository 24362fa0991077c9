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

from parefg.discretization.assembly_numpy import pair_positions


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
    values (nothing cancels there), the values those of scipy's product (the same
    association, (left^T diag(weights)) right, the same bits)."""
    scaled = (left.T @ sp.diags(weights)).tocsr()  # columns of zero weight drop out
    product = (scaled @ right).tocsr()
    pattern = (abs(scaled) @ abs(right)).tocsr()
    return _placed(product, pattern)


def _placed(values: sp.csr_matrix, pattern: sp.csr_matrix) -> sp.csr_matrix:
    """``values`` on ``pattern``'s entries (which include all of values'), 0 elsewhere.

    Square matrices (DOF by DOF): the entries are found as the assembly finds its pairs
    (:func:`~parefg.discretization.assembly_numpy.pair_positions`).
    """
    if pattern.shape[0] != pattern.shape[1]:
        raise ValueError(f"a structural product must be square, got {pattern.shape}")
    values.sort_indices()
    pattern.sort_indices()
    rows = np.repeat(np.arange(values.shape[0], dtype=np.int64), np.diff(values.indptr))
    at = pair_positions(pattern.indptr, pattern.indices, rows, values.indices)
    inside = np.all((at >= 0) & (at < len(pattern.indices)))
    if not (
        inside
        and np.array_equal(pattern.indices[at], values.indices)
        and np.array_equal(np.searchsorted(pattern.indptr, at, side="right") - 1, rows)
    ):
        raise ValueError("the pattern misses entries of the values")
    data = np.zeros(len(pattern.indices))
    data[at] = values.data
    return sp.csr_matrix((data, pattern.indices, pattern.indptr), shape=pattern.shape)
