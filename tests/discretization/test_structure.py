"""Sparse sums and products with structural patterns (parefg.discretization.structure):
an entry whose terms cancel to exactly 0 stays in the pattern, so patterns do not depend
on the last bits of the values (a backend, a CPU)."""

import numpy as np
import scipy.sparse as sp

from parefg.discretization.structure import structural_sum, weighted_product


def test_a_sum_that_cancels_keeps_its_entry():
    a = sp.csr_matrix(np.array([[1.0, 2.0], [0.0, 3.0]]))
    b = sp.csr_matrix(np.array([[1.0, 0.0], [4.0, 0.0]]))
    assert (a - b).nnz == 3  # scipy drops the cancelled (0, 0)
    total = structural_sum([(1.0, a), (-1.0, b)], (2, 2))
    assert total.nnz == 4
    np.testing.assert_array_equal(total.toarray(), (a - b).toarray())
    only_pattern = structural_sum([(1.0, a), (0.0, b)], (2, 2))
    np.testing.assert_array_equal(only_pattern.toarray(), a.toarray())
    assert only_pattern.nnz == 4


def test_a_product_whose_points_cancel_keeps_its_entry():
    # two points with values of opposite signs: column 0 against column 1 cancels exactly
    left = sp.csr_matrix(np.array([[1.0, 0.5], [1.0, -0.5]]))
    weights = np.array([2.0, 2.0])
    product = weighted_product(left, weights, left)
    reference = left.T @ sp.diags(weights) @ left
    assert reference.nnz == 2  # scipy drops the cancelled off-diagonal pair
    assert product.nnz == 4
    np.testing.assert_array_equal(product.toarray(), reference.toarray())
    # a zero weight contributes nothing, not even to the pattern
    assert weighted_product(left, np.array([2.0, 0.0]), sp.csr_matrix(np.eye(2))).nnz == 2
