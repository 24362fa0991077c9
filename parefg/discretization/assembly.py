"""Distributed sparse assembly: from shape-function values at points to PETSc matrices.

Degrees of freedom are interleaved with block size 2: node I carries DOFs 2I (x) and
2I + 1 (y).  Rank r owns the nodes ``node_ranges[r]:node_ranges[r + 1]`` and hence the
contiguous DOF block ``2 * node_ranges[r]:2 * node_ranges[r + 1]``.

Each rank evaluates the MLS shape functions at its own points only and builds its
contributions as scipy CSR matrices with *global* column indices.  Square operators
(mass, stiffness, penalty) have rows on every node the rank's points touch; the rows
owned by other ranks are sent to their owners in one all-to-all exchange
(:func:`parefg.parallel.owned_rows`), so each rank ends with exactly its block of rows
and the PETSc matrix is created with exact preallocation.  Rectangular point operators (values
at this rank's points) need no exchange: their rows are this rank's points.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from parefg.discretization import aot, assembly_numpy, backends
from parefg.discretization.mls import ShapeValues


def kernels_for(n_nodes: int):
    """The assembly kernels for a problem of ``n_nodes`` global nodes: the numba ones
    (:mod:`~parefg.discretization.assembly_kernels`, through :mod:`.aot`) or the numpy
    ones (:mod:`~parefg.discretization.assembly_numpy`); see
    :mod:`parefg.discretization.backends`."""
    if backends.choose(n_nodes) == "numba":
        return aot.kernels("assembly_kernels")  # compiled ahead of time, else numba's JIT
    return assembly_numpy


def sorted_slots(shape: ShapeValues, n_nodes: int):
    """Each point's neighbour slots ordered by node, padding last: (order, nodes, mask).

    ``order`` holds flat slot indices (:func:`gather`).  Sorted columns make the CSR
    arrays of the point operators final as built.
    """
    keys = np.where(shape.mask, shape.neighbours, n_nodes)  # (n_points, n_max)
    order = np.argsort(keys, axis=1, kind="stable")
    order += np.arange(0, order.size, max(order.shape[1], 1)).reshape(-1, 1)  # flat
    return order, gather(shape.neighbours, order), gather(shape.mask, order)


def gather(array: np.ndarray, order: np.ndarray) -> np.ndarray:
    """``array`` (n_points, n_max, ...) with its slots in the flat ``order`` of
    :func:`sorted_slots`: np.take_along_axis along axis 1, by one flat take."""
    flat = array.reshape(array.shape[0] * array.shape[1], *array.shape[2:])
    return np.take(flat, order, axis=0)


def _point_rows(nodes, mask, data, components, stride, n_cols) -> sp.csr_matrix:
    """CSR with r rows per point: row r q + i holds data[q, i, k] at column stride node_k + c_i.

    ``nodes``, ``mask`` (n_points, n_max) sorted by node; ``data`` (n_points, r, n_max);
    ``components`` (r,) the DOF component c_i of each row.
    """
    n_points, n_rows_per_point = len(nodes), len(components)
    columns = stride * nodes[:, None, :] + components[None, :, None]  # (n_points, r, n_max)
    keep = np.broadcast_to(mask[:, None, :], columns.shape)
    row_lengths = np.repeat(mask.sum(axis=1), n_rows_per_point)  # (r n_points,)
    indptr = np.concatenate([[0], np.cumsum(row_lengths)])
    return sp.csr_matrix(
        (np.broadcast_to(data, columns.shape)[keep], columns[keep], indptr),
        shape=(n_rows_per_point * n_points, n_cols),
    )


def value_operator(shape: ShapeValues, n_nodes: int, slots=None) -> sp.csr_matrix:
    """(n_points x n_nodes) scalar values S[q, I] = phi_I(x_q), columns sorted.

    It acts on each displacement component: the interleaved operator is kron(S, I_2)
    (:class:`~parefg.discretization.point_set.PointSet`).  ``slots``: the
    :func:`sorted_slots` of ``shape`` if the caller has them.
    """
    order, nodes, mask = sorted_slots(shape, n_nodes) if slots is None else slots
    phi = gather(shape.phi, order)[:, None, :]  # (n_points, 1, n_max)
    return _point_rows(nodes, mask, phi, np.zeros(1, dtype=np.int64), 1, n_nodes)


def gradient_operator(shape: ShapeValues, n_nodes: int) -> sp.csr_matrix:
    """(4 n_points x 2 n_nodes) gradients: row 4q + 2c + d = d phi_I / d x_d on DOF 2I + c.

    Only for the few boundary points of Nitsche's traction terms; the domain's gradients
    are re-evaluated in blocks (:mod:`parefg.discretization.point_gradients`).
    """
    if shape.dphi is None:
        raise ValueError("gradient_operator needs shape values evaluated with gradients")
    order, nodes, mask = sorted_slots(shape, n_nodes)
    dphi = gather(shape.dphi, order)  # (n_points, n_max, 2)
    per_row = dphi.transpose(0, 2, 1)[:, [0, 1, 0, 1], :]  # (n_points, 4, n_max): d = 0, 1, 0, 1
    return _point_rows(nodes, mask, per_row, np.array([0, 0, 1, 1]), 2, 2 * n_nodes)


@dataclass
class Coupling:
    """Which nodes share a point: the scalar CSR pattern of every Gram matrix of a point set.

    Points are processed in groups (the Gauss points of one cell or segment, contiguous
    in a :class:`~parefg.discretization.quadrature.Quadrature`): a group's neighbour lists
    overlap, so its Gram contributions are summed in a small dense matrix over the group's nodes and
    added to the CSR entries once per group.  Row I of the pattern holds exactly the
    nodes J with phi_I phi_J nonzero at some point (sorted), whatever the grouping.
    """

    shape: ShapeValues
    n_nodes: int
    indptr: np.ndarray  # (n_nodes + 1,)
    indices: np.ndarray  # (nnz,) column node of each entry
    group_start: np.ndarray  # (n_groups + 1,) points of group g: group_start[g]:group_start[g+1]
    node_start: np.ndarray  # (n_groups + 1,) the group's nodes: nodes[node_start[g]:...]
    nodes: np.ndarray  # (sum of group sizes,) sorted within each group
    pair_start: np.ndarray  # (n_groups + 1,) the group's coupled pairs
    pair_local: np.ndarray  # (n_pairs,) local pair i * group_size + j
    pair_position: np.ndarray  # (n_pairs,) CSR entry of each pair

    @classmethod
    def of(cls, shape: ShapeValues, n_nodes: int, cell: np.ndarray | None = None) -> Coupling:
        """The coupling of the points of ``shape``, grouped by equal consecutive ``cell`` ids.

        Without ``cell`` every point is its own group.  Not collective.
        """
        n_points = len(shape.neighbours)
        changes = np.arange(1, n_points) if cell is None else np.flatnonzero(np.diff(cell)) + 1
        group_start = np.concatenate([[0], changes, [n_points]]).astype(np.int64)
        if n_points == 0:
            empty = np.zeros(0, dtype=np.int64)
            zeros = np.zeros(n_nodes + 1, dtype=np.int64)
            return cls(
                shape,
                n_nodes,
                zeros,
                empty,
                group_start[:1],
                group_start[:1],
                empty,
                group_start[:1],
                empty.astype(np.int32),
                empty,
            )
        kernels = kernels_for(n_nodes)
        node_start, nodes = kernels.group_nodes(shape.neighbours, shape.mask, group_start, n_nodes)
        local_of = np.zeros(n_nodes, dtype=np.int64)  # scratch of the kernels
        pair_start, pair_local, rows, cols = kernels.touched_pairs(
            shape.neighbours, shape.mask, group_start, node_start, nodes, local_of
        )
        indptr, indices, position = kernels.pairs_to_csr(rows, cols, n_nodes)
        return cls(
            shape,
            n_nodes,
            indptr,
            indices,
            group_start,
            node_start,
            nodes,
            pair_start,
            pair_local,
            position,
        )

    def gram(self, left: np.ndarray, right: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """Blocks G[p, a, b] = sum_q w_q left[q, I, a] right[q, J, b] of each entry p = (I, J).

        ``left`` (n_points, n_max, n_left) and ``right`` (n_points, n_max, n_right) are
        per-slot shape data (phi[..., None] or dphi).  Returns (nnz, n_left, n_right).
        """
        data = np.zeros((len(self.indices), left.shape[2], right.shape[2]))
        if len(self.pair_local) == 0:
            return data
        kernels_for(self.n_nodes).gram_groups(
            np.ascontiguousarray(left, dtype=np.float64),
            np.ascontiguousarray(right, dtype=np.float64),
            np.ascontiguousarray(weights, dtype=np.float64),
            self.shape.neighbours,
            self.shape.mask,
            self.group_start,
            self.node_start,
            self.nodes,
            self.pair_start,
            self.pair_local,
            self.pair_position,
            data,
            np.zeros(self.n_nodes, dtype=np.int64),
        )
        return data

    def interleaved(self, blocks: np.ndarray, diagonal_only: bool = False) -> sp.csr_matrix:
        """(2 n_nodes)^2 CSR with entry (2I + a, 2J + b) = blocks[p, a, b], p = (I, J).

        ``diagonal_only`` stores only a = b: kron(G, I_2) for a scalar G given as
        blocks[p, 0, 0] = blocks[p, 1, 1].  Explicit zeros are kept (they are pattern).
        """
        return interleaved(self.indptr, self.indices, blocks, diagonal_only)


def interleaved(
    indptr, indices, blocks: np.ndarray, diagonal_only: bool = False, n_global: int | None = None
) -> sp.csr_matrix:
    """(2 n)^2 CSR of the scalar pattern (indptr, indices) with 2 x 2 ``blocks`` per entry.

    See :meth:`Coupling.interleaved`.  ``n_global``: the cloud's node count, which picks
    the kernels (default n, the pattern's rows: the count where a rank holds every node).
    """
    # float64, in any layout (the mass passes a zero-stride view: no copy is made of it)
    blocks = blocks if blocks.dtype == np.float64 else blocks.astype(np.float64)
    n_kernel = len(indptr) - 1 if n_global is None else n_global
    out_ptr, out_indices, data = kernels_for(n_kernel).interleave_blocks(
        indptr, indices, blocks, diagonal_only
    )
    n_dofs = 2 * (len(indptr) - 1)
    return sp.csr_matrix((data, out_indices, out_ptr), shape=(n_dofs, n_dofs))
