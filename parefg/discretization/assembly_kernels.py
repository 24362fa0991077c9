"""Compiled (numba) kernels of the sparse assembly: node-to-point lists, pattern, Gram rows.

The mathematics is that of :mod:`parefg.discretization.assembly` (SPEC 3); this module only changes
how it is computed.  A Gram matrix of shape-function data at quadrature points,

    G[I, J, a, b] = sum_q w_q left_a(phi_I)(x_q) right_b(phi_J)(x_q),

is assembled row by row in CSR form: for node I, the points whose neighbour list holds
I (:func:`points_of_nodes`, a counting sort of the neighbour lists) contribute to the
columns J of their neighbours.  A dense ``slot`` array maps column J to its position in
row I, so every product lands in its CSR entry without a search, a sort or a COO
intermediate.  The pattern (:func:`coupling_pattern`) holds exactly the pairs (I, J)
that share a point, so it does not depend on how the points are split over ranks.

Nothing here is collective.  numba compiles on first use and caches the machine code
next to this file (``cache=True``); ``make setup`` also compiles the kernels called from
Python ahead of time, and runs call them through :mod:`.aot` without importing numba.
"""

import numpy as np

try:
    import numba
except ImportError:  # pragma: no cover - numba is a Debian package of the environment
    numba = None


def _jit(function):
    """Compile with numba when it is installed (no fastmath: sums keep their order)."""
    if numba is None:  # pragma: no cover
        return function
    return numba.njit(cache=True, fastmath=False, nogil=True)(function)


@_jit
def group_nodes(neighbours, mask, group_start, n_nodes):
    """Sorted distinct nodes of each group of points: CSR (node_start, nodes) by group."""
    n_groups, n_max = len(group_start) - 1, neighbours.shape[1]
    marker = np.full(n_nodes, -1, dtype=np.int64)
    scratch = np.empty(n_max * (group_start[1:] - group_start[:-1]).max(), dtype=np.int64)
    counts = np.zeros(n_groups + 1, dtype=np.int64)
    nodes = np.empty(mask.sum(), dtype=np.int64)  # upper bound, trimmed below
    for g in range(n_groups):
        count = 0
        for q in range(group_start[g], group_start[g + 1]):
            for k in range(n_max):
                if mask[q, k] and marker[neighbours[q, k]] != g:
                    marker[neighbours[q, k]] = g
                    scratch[count] = neighbours[q, k]
                    count += 1
        counts[g + 1] = counts[g] + count
        nodes[counts[g] : counts[g + 1]] = np.sort(scratch[:count])
    return counts, nodes[: counts[-1]]


@_jit
def _group_matrix(values, scale, neighbours, mask, first, last, local_of, size):
    """Dense (size n_comp, n_group_points) matrix of the group's shape data.

    Entry (i n_comp + c, t) = scale[q] values[q, k, c] for the group's point q = first + t
    and the neighbour slot k holding the group's local node i; zero elsewhere.
    """
    n_comp = values.shape[2]
    out = np.zeros((size * n_comp, last - first))
    for q in range(first, last):
        for k in range(neighbours.shape[1]):
            if mask[q, k]:
                i = local_of[neighbours[q, k]]
                for c in range(n_comp):
                    out[i * n_comp + c, q - first] = scale[q] * values[q, k, c]
    return out


@_jit
def _set_local(local_of, group_nodes):
    for i in range(len(group_nodes)):
        local_of[group_nodes[i]] = i


@_jit
def touched_pairs(neighbours, mask, group_start, node_start, nodes, local_of):
    """Local pairs (i, j) of each group's nodes that share a point of the group.

    With B the group's (size, n_group_points) 0/1 incidence matrix, (i, j) is coupled
    when (B B^T)[i, j] > 0 (a count of shared points, exact in floating point).
    ``local_of`` (n_nodes,) is scratch.  Returns pair_start (n_groups + 1,), pair_local
    (n_pairs,) = i size + j, and the global nodes pair_row, pair_col (n_pairs,).
    """
    n_groups, n_points = len(group_start) - 1, neighbours.shape[0]
    sizes = node_start[1:] - node_start[:-1]  # (n_groups,)
    pair_local = np.empty(np.sum(sizes * sizes), dtype=np.int32)  # capacity, trimmed below
    pair_start = np.zeros(n_groups + 1, dtype=np.int64)
    ones = np.ones((n_points, neighbours.shape[1], 1))
    unit = np.ones(n_points)
    for g in range(n_groups):
        _set_local(local_of, nodes[node_start[g] : node_start[g + 1]])
        incidence = _group_matrix(
            ones, unit, neighbours, mask, group_start[g], group_start[g + 1], local_of, sizes[g]
        )
        shared = np.dot(incidence, incidence.T.copy()).ravel()  # (size^2,) shared points
        position = pair_start[g]
        for ij in range(len(shared)):
            if shared[ij] > 0.0:
                pair_local[position] = ij
                position += 1
        pair_start[g + 1] = position
    pair_local = pair_local[: pair_start[-1]]
    pair_row = np.empty(len(pair_local), dtype=np.int64)
    pair_col = np.empty(len(pair_local), dtype=np.int64)
    for g in range(n_groups):
        size, base = sizes[g], node_start[g]
        for e in range(pair_start[g], pair_start[g + 1]):
            pair_row[e] = nodes[base + pair_local[e] // size]
            pair_col[e] = nodes[base + pair_local[e] % size]
    return pair_start, pair_local, pair_row, pair_col


@_jit
def pairs_to_csr(pair_row, pair_col, n_nodes):
    """Distinct (row, col) pairs as CSR (indptr, sorted indices) and each pair's CSR position."""
    row_start = np.zeros(n_nodes + 1, dtype=np.int64)
    for e in range(len(pair_row)):
        row_start[pair_row[e] + 1] += 1
    row_start = np.cumsum(row_start)
    fill = row_start[:-1].copy()
    by_row = np.empty(len(pair_row), dtype=np.int64)  # counting sort of the pairs by row
    for e in range(len(pair_row)):
        by_row[fill[pair_row[e]]] = e
        fill[pair_row[e]] += 1
    marker = np.full(n_nodes, -1, dtype=np.int64)
    slot = np.zeros(n_nodes, dtype=np.int64)  # column -> CSR position within the current row
    indptr = np.zeros(n_nodes + 1, dtype=np.int64)
    indices = np.empty(len(pair_row), dtype=np.int64)  # upper bound, trimmed below
    position = np.empty(len(pair_row), dtype=np.int64)
    for row in range(n_nodes):
        count = 0
        for t in range(row_start[row], row_start[row + 1]):
            col = pair_col[by_row[t]]
            if marker[col] != row:
                marker[col] = row
                indices[indptr[row] + count] = col
                count += 1
        columns = np.sort(indices[indptr[row] : indptr[row] + count])
        indices[indptr[row] : indptr[row] + count] = columns
        indptr[row + 1] = indptr[row] + count
        for c in range(count):
            slot[columns[c]] = indptr[row] + c
        for t in range(row_start[row], row_start[row + 1]):
            position[by_row[t]] = slot[pair_col[by_row[t]]]
    return indptr, indices[: indptr[-1]], position


@_jit
def gram_groups(
    left, right, weights, neighbours, mask, group_start, node_start, nodes,
    pair_start, pair_local, pair_position, data, local_of,
):  # fmt: skip
    """Add the Gram matrix's values on its pattern into ``data``, one dense product per group.

    Per group, with L and R the group's (size n_comp, n_group_points) matrices of
    w_q left and right (:func:`_group_matrix`), the local Gram matrix is L R^T; its
    coupled pairs are added into their CSR entries.

    Parameters
    ----------
    left : (n_points, n_max, n_left), right : (n_points, n_max, n_right)
        Shape-function data per point and neighbour slot (phi, or its gradient).
    weights : (n_points,) quadrature weights.
    data : (nnz, n_left, n_right), accumulated: data[p, a, b] += sum_q w_q left[q, I, a]
        right[q, J, b] for the entry p = (I, J) (groups in order, so blocks of groups
        added one after the other sum as all groups at once).
    local_of : (n_nodes,) scratch.
    """
    n_left, n_right = left.shape[2], right.shape[2]
    unit = np.ones(len(weights))
    for g in range(len(group_start) - 1):
        size, first, last = node_start[g + 1] - node_start[g], group_start[g], group_start[g + 1]
        _set_local(local_of, nodes[node_start[g] : node_start[g + 1]])
        weighted = _group_matrix(left, weights, neighbours, mask, first, last, local_of, size)
        plain = _group_matrix(right, unit, neighbours, mask, first, last, local_of, size)
        dense = np.dot(weighted, plain.T.copy())  # (size n_left, size n_right)
        for e in range(pair_start[g], pair_start[g + 1]):
            i, j = pair_local[e] // size, pair_local[e] % size
            for a in range(n_left):
                for b in range(n_right):
                    data[pair_position[e], a, b] += dense[i * n_left + a, j * n_right + b]


@_jit
def pair_positions(indptr, indices, pair_row, pair_col):
    """CSR entry of each (row, col) pair of a pattern holding them all (binary search)."""
    position = np.empty(len(pair_row), dtype=np.int64)
    for e in range(len(pair_row)):
        first, last = indptr[pair_row[e]], indptr[pair_row[e] + 1]
        position[e] = first + np.searchsorted(indices[first:last], pair_col[e])
    return position


@_jit
def interleave_blocks(indptr, indices, blocks, diagonal_only):
    """Interleaved (2 n x 2 n) CSR from a scalar pattern with a 2 x 2 block per entry.

    Entry (2I + a, 2J + b) = blocks[p, a, b] for the scalar entry p = (I, J); with
    ``diagonal_only`` only b = a is stored (kron(S, I_2)).  Column order stays sorted.
    """
    n_rows = len(indptr) - 1
    per_row = 1 if diagonal_only else 2
    out_ptr = np.zeros(2 * n_rows + 1, dtype=np.int64)
    for row in range(n_rows):
        length = per_row * (indptr[row + 1] - indptr[row])
        out_ptr[2 * row + 1] = out_ptr[2 * row] + length
        out_ptr[2 * row + 2] = out_ptr[2 * row + 1] + length
    out_indices = np.empty(out_ptr[-1], dtype=np.int32)  # 2 n < 2^31 (budget.MAX_INDEX)
    out_data = np.empty(out_ptr[-1])
    for row in range(n_rows):
        for a in range(2):
            position = out_ptr[2 * row + a]
            for p in range(indptr[row], indptr[row + 1]):
                for b in range(2):
                    if diagonal_only and b != a:
                        continue
                    out_indices[position] = 2 * indices[p] + b
                    out_data[position] = blocks[p, a, b]
                    position += 1
    return out_ptr, out_indices, out_data
