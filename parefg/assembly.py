"""Distributed sparse assembly: from shape-function values at points to PETSc matrices.

Degrees of freedom are interleaved with block size 2: node I carries DOFs 2I (x) and
2I + 1 (y).  Rank r owns the nodes ``node_ranges[r]:node_ranges[r + 1]`` and hence the
contiguous DOF block ``2 * node_ranges[r]:2 * node_ranges[r + 1]``.

Each rank evaluates the MLS shape functions at its own points only and builds its
contributions as scipy CSR matrices with *global* column indices.  Square operators
(mass, stiffness, penalty) have rows on every node the rank's points touch; the rows
owned by other ranks are sent to their owners in one all-to-all exchange
(:func:`owned_rows`), so each rank ends with exactly its block of rows and the PETSc
matrix is created with exact preallocation.  Rectangular point operators (values or
gradients at this rank's points) need no exchange: their rows are this rank's points.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from mpi4py import MPI
from petsc4py import PETSc

from parefg.mls import ShapeValues


def shape_matrix(shape: ShapeValues, n_nodes: int, derivative: int | None = None) -> sp.csr_matrix:
    """Scalar point-to-node matrix: row q holds phi_I(x_q) (or d phi_I / d x_derivative).

    Returns a (n_points, n_nodes) CSR matrix; padding entries of the neighbour lists are dropped.
    """
    n_points, n_max = shape.neighbours.shape
    rows = np.repeat(np.arange(n_points), n_max).reshape(n_points, n_max)[shape.mask]
    cols = shape.neighbours[shape.mask]
    values = shape.phi if derivative is None else shape.dphi[:, :, derivative]
    return sp.csr_matrix((values[shape.mask], (rows, cols)), shape=(n_points, n_nodes))


def interleave(scalar: sp.spmatrix) -> sp.csr_matrix:
    """Expand a scalar (rows x nodes) operator to both displacement components.

    kron(S, I_2): entry (2q + c, 2I + c) = S[q, I], matching the interleaved DOF numbering.
    """
    return sp.kron(scalar, sp.identity(2, format="csr"), format="csr")


def _alltoallv(comm, send: np.ndarray, send_counts: np.ndarray) -> np.ndarray:
    """Exchange a 1-D array in blocks: block r of ``send`` goes to rank r.  Collective."""
    recv_counts = np.empty(comm.size, dtype=np.int64)
    comm.Alltoall(send_counts.astype(np.int64), recv_counts)
    recv = np.empty(int(recv_counts.sum()), dtype=send.dtype)
    send_displs = np.concatenate([[0], np.cumsum(send_counts)[:-1]])
    recv_displs = np.concatenate([[0], np.cumsum(recv_counts)[:-1]])
    mpi_type = MPI._typedict[send.dtype.char]
    comm.Alltoallv(
        [send, (send_counts, send_displs), mpi_type], [recv, (recv_counts, recv_displs), mpi_type]
    )
    return recv


def owned_rows(comm, local: sp.spmatrix, row_ranges: np.ndarray) -> sp.csr_matrix:
    """Sum every rank's contributions into the rows each rank owns.  Collective.

    Parameters
    ----------
    local : (n_rows, n_cols) sparse matrix with global row and column indices holding this
        rank's contributions (rows anywhere).
    row_ranges : (comm.size + 1,) rank r owns rows row_ranges[r]:row_ranges[r + 1].

    Returns
    -------
    (n_owned_rows, n_cols) CSR matrix of the summed owned rows, duplicates added, explicit
    zeros kept (they carry sparsity patterns reserved for later values).
    """
    coo = local.tocoo()
    owner = np.searchsorted(row_ranges, coo.row, side="right") - 1
    order = np.argsort(owner, kind="stable")
    counts = np.bincount(owner, minlength=comm.size)
    rows = _alltoallv(comm, coo.row[order].astype(np.int64), counts)
    cols = _alltoallv(comm, coo.col[order].astype(np.int64), counts)
    data = _alltoallv(comm, coo.data[order].astype(np.float64), counts)
    start, stop = row_ranges[comm.rank], row_ranges[comm.rank + 1]
    owned = sp.coo_matrix((data, (rows - start, cols)), shape=(stop - start, local.shape[1]))
    return owned.tocsr()  # sums duplicates, keeps explicit zeros


def _csr_arrays(matrix: sp.csr_matrix):
    matrix.sort_indices()
    return (
        matrix.indptr.astype(PETSc.IntType),
        matrix.indices.astype(PETSc.IntType),
        matrix.data.astype(PETSc.ScalarType),
    )


def petsc_matrix(comm, owned: sp.csr_matrix, n_cols_local: int, n_cols: int, block_size: int = 1):
    """PETSc AIJ matrix from this rank's owned rows (global columns).  Collective.

    The CSR arrays give the exact preallocation; no mallocs during later value updates
    within the same pattern.
    """
    n_rows_local = owned.shape[0]
    matrix = PETSc.Mat().createAIJ(
        size=((n_rows_local, PETSc.DETERMINE), (n_cols_local, n_cols)),
        csr=_csr_arrays(owned),
        bsize=block_size if block_size > 1 else None,
        comm=comm,
    )
    matrix.setOption(PETSc.Mat.Option.NEW_NONZERO_ALLOCATION_ERR, True)
    matrix.assemble()
    return matrix


def add_owned_rows(matrix, owned: sp.csr_matrix) -> None:
    """Add owned-row values (a pattern subset of ``matrix``) into a PETSc matrix.  Collective."""
    matrix.setValuesCSR(*_csr_arrays(owned), addv=PETSc.InsertMode.ADD_VALUES)
    matrix.assemble()


def gram_matrix(left: sp.csr_matrix, weights: np.ndarray, right: sp.csr_matrix) -> sp.csr_matrix:
    """sum_q weights_q left[q, :]^T right[q, :], the quadrature of a bilinear form."""
    return (left.T @ sp.diags(weights) @ right).tocsr()


def with_pattern(matrix: sp.csr_matrix, pattern: sp.csr_matrix) -> sp.csr_matrix:
    """``matrix`` with explicit zeros added wherever ``pattern`` has an entry.

    scipy's sparse sum drops zeros; going through COO keeps them, which reserves the
    Gamma_C coupling in A_const so that contact terms never change the PETSc pattern.
    """
    a, p = matrix.tocoo(), pattern.tocoo()
    rows = np.concatenate([a.row, p.row])
    cols = np.concatenate([a.col, p.col])
    data = np.concatenate([a.data, np.zeros(p.nnz)])
    return sp.coo_matrix((data, (rows, cols)), shape=matrix.shape).tocsr()
