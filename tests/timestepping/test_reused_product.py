"""ReusedProduct: the saved A x is served only for the same x on every rank (step_solver).

Matrix: a random sparse SPD-pattern matrix distributed over the ranks; its products are
compared with fresh MatMult products bit for bit.
"""

import numpy as np
import scipy.sparse as sp
from mpi4py import MPI

from parefg.parallel import petsc_matrix
from parefg.timestepping.step_solver import ReusedProduct

COMM = MPI.COMM_WORLD
N_LOCAL = 7  # rows per rank


def _matrix():
    n = N_LOCAL * COMM.size
    rng = np.random.default_rng(5)  # the same global matrix on every rank
    full = sp.random(n, n, density=0.4, random_state=rng, format="csr") + sp.identity(n)
    start = N_LOCAL * COMM.rank
    owned = full[start : start + N_LOCAL].tocsr()
    return petsc_matrix(COMM, owned, N_LOCAL, n)


def _fresh(matrix, x):
    out = matrix.createVecLeft()
    matrix.mult(x, out)
    return out.getArray().copy()


def test_same_values_reuse_the_product_and_changed_values_recompute_it():
    matrix = _matrix()
    products = ReusedProduct(COMM, matrix)
    x, out = matrix.createVecRight(), matrix.createVecLeft()
    x.setArray(np.arange(1.0, N_LOCAL + 1) * (COMM.rank + 1))
    products.mult(x, out)
    assert np.array_equal(out.getArray(), _fresh(matrix, x))
    # a copy of x (another vector, the same values) is served from the saved product
    y = x.copy()
    out.set(np.nan)
    products.mult(y, out)
    assert np.array_equal(out.getArray(), _fresh(matrix, x))
    # one entry changed on the last rank only: every rank must recompute (a rank that
    # served its saved rows would return a stale product, or leave the others in MatMult)
    if COMM.rank == COMM.size - 1:
        y.getArray()[0] += 1.0
    products.mult(y, out)
    assert np.array_equal(out.getArray(), _fresh(matrix, y))
    assert not np.array_equal(_fresh(matrix, y), _fresh(matrix, x))


def test_remember_seeds_the_product_of_a_given_vector():
    """remember(x, A x) is served to the next mult at x (the step scale's A u_0)."""
    matrix = _matrix()
    products = ReusedProduct(COMM, matrix)
    x, seeded, out = matrix.createVecRight(), matrix.createVecLeft(), matrix.createVecLeft()
    x.setArray(np.linspace(-1.0, 1.0, N_LOCAL) + COMM.rank)
    matrix.mult(x, seeded)
    products.remember(x, seeded)
    seeded.set(0.0)  # the saved product is a copy
    products.mult(x, out)
    assert np.array_equal(out.getArray(), _fresh(matrix, x))
