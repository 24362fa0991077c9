"""Vectorized numpy kernels of the sparse assembly, the same functions as the numba ones.

:mod:`parefg.discretization.assembly_kernels` computes, group by group in compiled
loops, the groups' nodes, their coupled pairs, the CSR pattern and the Gram blocks; this
module computes the same arrays with whole-array numpy operations (the backend of small
problems, :mod:`parefg.discretization.backends`, which never imports numba).  Patterns,
node lists and pair lists are identical; Gram values agree to round-off:

* a group's local Gram matrix is one dense product L R^T, as in the numba kernel, but the
  groups are stacked by shape (number of nodes, number of points), so that each group's
  product has its own dimensions whatever other groups are assembled with it (BLAS sums
  depend on the dimensions): a group's values do not depend on the split over ranks or
  blocks;
* the groups' values are added into their CSR entries in group order, starting from the
  entry's previous value (np.bincount adds its weights one after the other), which is the
  order of the numba kernel: blocks of groups added one after the other sum as all groups
  at once.

Nothing here is collective.
"""

import numpy as np

# Up to this many (row, col) keys, patterns use a dense table of keys instead of a sort.
DENSE_KEYS = 1 << 22


def _group_of_points(group_start):
    """Group index of each point, (n_points,)."""
    return np.repeat(np.arange(len(group_start) - 1), np.diff(group_start))


def group_nodes(neighbours, mask, group_start, n_nodes):
    """Sorted distinct nodes of each group of points: CSR (node_start, nodes) by group."""
    group = _group_of_points(group_start)
    n_keys = (len(group_start) - 1) * n_nodes
    keys = _distinct((group[:, None] * n_nodes + neighbours)[mask], n_keys)
    counts = np.bincount(keys // n_nodes, minlength=len(group_start) - 1)
    node_start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    return node_start, keys % n_nodes


def _distinct(keys, n_keys):
    """Sorted distinct values of ``keys`` (int64 in [0, n_keys))."""
    if n_keys <= max(DENSE_KEYS, 4 * len(keys)):
        present = np.zeros(n_keys, dtype=bool)
        present[keys] = True
        return np.flatnonzero(present)
    return np.unique(keys)


class _Slots:
    """The masked neighbour slots of the points, by group and by group shape.

    Groups of equal shape (number of nodes, number of points) form a batch.  Per batch:
    its groups in order, their shape, the flat place (g size + i) P + t of each of its
    slots in the stacked (n_groups_in_batch, size, P) matrices (group g in the batch, node
    i local to the group, point t of the group) and the slot's point q and neighbour k.
    """

    def __init__(self, neighbours, mask, group_start, node_start, nodes):
        n_nodes = int(max(neighbours.max(initial=0), nodes.max(initial=0))) + 1
        self.sizes, counts = np.diff(node_start), np.diff(group_start)  # (n_groups,)
        group = _group_of_points(group_start)  # (n_points,)
        q, k = np.nonzero(mask)  # points and slots, in point order
        g = group[q]
        # Local index of each slot's node: its place among the sorted keys g n + node.
        node_group = np.repeat(np.arange(len(self.sizes)), self.sizes)
        node_keys = node_group * n_nodes + nodes  # sorted
        slot_keys = g * n_nodes + neighbours[q, k]
        if len(self.sizes) * n_nodes <= max(DENSE_KEYS, 4 * len(slot_keys)):
            local = np.empty(len(self.sizes) * n_nodes, dtype=np.int64)
            local[node_keys] = np.arange(len(nodes)) - node_start[node_group]
            i = local[slot_keys]
        else:
            i = np.searchsorted(node_keys, slot_keys) - node_start[g]
        shapes, self.batch_of = np.unique(
            self.sizes * (counts.max(initial=0) + 1) + counts, return_inverse=True
        )
        n_batches = len(shapes)
        groups, group_bounds = _split(self.batch_of, n_batches)  # groups by batch, in order
        self.place = np.empty(len(self.sizes), dtype=np.int64)  # group -> index in its batch
        self.place[groups] = np.arange(len(groups)) - np.repeat(
            group_bounds[:-1], np.diff(group_bounds)
        )
        # Per slot, sorted by batch: (g size + i) with g the group's place in its batch, the
        # point's place t in the group, the flat slot q n_max + k.
        slot_order, slot_bounds = _split(self.batch_of[g], n_batches)
        g, i, q, k = g[slot_order], i[slot_order], q[slot_order], k[slot_order]
        row = self.place[g] * self.sizes[g] + i
        t = q - group_start[g]
        slot = q * neighbours.shape[1] + k
        self.batches = []
        for b in range(n_batches):
            members = groups[group_bounds[b] : group_bounds[b + 1]]
            size, n_points = int(self.sizes[members[0]]), int(counts[members[0]])
            part = slice(slot_bounds[b], slot_bounds[b + 1])
            self.batches.append((members, size, n_points, row[part], t[part], slot[part]))

    def matrices(self, values, scale, batch):
        """(n_groups_in_batch, size n_comp, n_points) stacked group matrices of a batch.

        Entry (i n_comp + c, t) = scale[q] values[q, k, c] for the group's point t and its
        node i (the numba kernel's _group_matrix); ``scale`` None stands for ones.
        """
        members, size, n_points, row, t, slot = batch
        n_comp = values.shape[2]
        out = np.zeros(len(members) * size * n_comp * n_points)
        picked = np.take(values.reshape(-1, n_comp), slot, axis=0)  # (n_slots, n_comp)
        if scale is not None:
            picked = np.take(scale, slot // values.shape[1])[:, None] * picked
        base = row * (n_comp * n_points) + t
        for c in range(n_comp):
            out[base + c * n_points] = picked[:, c]
        return out.reshape(len(members), size * n_comp, n_points)


_CACHE: list = []  # the last _Slots and the arrays it was built from


def _slots(neighbours, mask, group_start, node_start, nodes) -> _Slots:
    """The _Slots of these arrays, reused while the caller passes the same ones again (the
    pattern and both Gram matrices of a block; the arrays are not changed in between)."""
    key = (neighbours, mask, group_start, node_start, nodes)
    if _CACHE and all(a is b for a, b in zip(_CACHE[0], key, strict=True)):
        return _CACHE[1]
    slots = _Slots(*key)
    _CACHE[:] = [key, slots]
    return slots


def _split(labels, n_labels):
    """Indices sorted stably by label, and the bounds of each label's run."""
    order = np.argsort(labels, kind="stable")
    bounds = np.concatenate([[0], np.cumsum(np.bincount(labels, minlength=n_labels))])
    return order, bounds


def touched_pairs(neighbours, mask, group_start, node_start, nodes, local_of):
    """Local pairs (i, j) of each group's nodes that share a point of the group.

    As the numba kernel: (i, j) is coupled when (B B^T)[i, j] > 0 for the group's 0/1
    incidence matrix B (an exact count).  ``local_of`` is unused (the numba kernel's
    scratch).  Returns pair_start (n_groups + 1,), pair_local (n_pairs,) = i size + j
    (int32), and the global nodes pair_row, pair_col (n_pairs,).
    """
    del local_of
    n_groups = len(group_start) - 1
    slots = _slots(neighbours, mask, group_start, node_start, nodes)
    ones = np.ones((*neighbours.shape, 1))
    found = []  # per batch: (groups of its pairs, local pairs), in batch order
    n_pairs = np.zeros(n_groups, dtype=np.int64)
    for batch in slots.batches:
        groups, size = batch[0], batch[1]
        incidence = slots.matrices(ones, None, batch)
        shared = incidence @ incidence.transpose(0, 2, 1)  # (n, size, size) shared points
        member, ij = np.nonzero(shared.reshape(len(groups), size * size) > 0.0)
        counts = np.bincount(member, minlength=len(groups))
        n_pairs[groups] = counts
        # A group's pairs are consecutive and in order: the e-th is its pair first + e.
        first = np.concatenate([[0], np.cumsum(counts)[:-1]])[member]
        found.append((groups[member], np.arange(len(member)) - first, ij))
    pair_start = np.concatenate([[0], np.cumsum(n_pairs)]).astype(np.int64)
    pair_local = np.empty(pair_start[-1], dtype=np.int32)
    for group, offset, ij in found:
        pair_local[pair_start[group] + offset] = ij
    pair_group = _group_of_points(pair_start)
    size = slots.sizes[pair_group]
    base = node_start[pair_group]
    pair_row = nodes[base + pair_local // size]
    pair_col = nodes[base + pair_local % size]
    return pair_start, pair_local, pair_row, pair_col


def pairs_to_csr(pair_row, pair_col, n_nodes):
    """Distinct (row, col) pairs as CSR (indptr, sorted indices) and each pair's CSR position."""
    keys = pair_row.astype(np.int64) * n_nodes + pair_col
    n_keys = n_nodes * n_nodes
    if n_keys <= max(DENSE_KEYS, 4 * len(keys)):
        present = np.zeros(n_keys, dtype=bool)
        present[keys] = True
        distinct = np.flatnonzero(present)
        slot = np.empty(n_keys, dtype=np.int64)
        slot[distinct] = np.arange(len(distinct))
        position = slot[keys]
    else:
        distinct, position = np.unique(keys, return_inverse=True)
    indptr = np.concatenate([[0], np.cumsum(np.bincount(distinct // n_nodes, minlength=n_nodes))])
    return indptr.astype(np.int64), distinct % n_nodes, position.astype(np.int64)


def gram_groups(
    left, right, weights, neighbours, mask, group_start, node_start, nodes,
    pair_start, pair_local, pair_position, data, local_of,
):  # fmt: skip
    """Add the Gram matrix's values on its pattern into ``data``: the numba kernel's sums.

    Per group the local Gram matrix L R^T of the (size n_comp, n_group_points) matrices of
    w_q left and right; its coupled pairs are added into their CSR entries, group after
    group.  Arguments as for :func:`parefg.discretization.assembly_kernels.gram_groups`
    (``local_of`` unused).
    """
    del local_of
    n_left, n_right = left.shape[2], right.shape[2]
    slots = _slots(neighbours, mask, group_start, node_start, nodes)
    pair_group = _group_of_points(pair_start)
    pair_order, pair_bounds = _split(slots.batch_of[pair_group], len(slots.batches))
    values = np.empty((n_left, n_right, len(pair_local)))  # each pair's contribution
    for b, batch in enumerate(slots.batches):
        size = batch[1]
        weighted = slots.matrices(left, weights, batch)
        plain = slots.matrices(right, None, batch)
        dense = weighted @ plain.transpose(0, 2, 1)  # (n, size n_left, size n_right)
        pairs = pair_order[pair_bounds[b] : pair_bounds[b + 1]]
        i, j = np.divmod(pair_local[pairs].astype(np.int64), size)
        row = (slots.place[pair_group[pairs]] * size + i) * n_left
        base = row * (size * n_right) + j * n_right  # flat (g, i n_left, j n_right) in dense
        dense = dense.reshape(-1)
        for a in range(n_left):
            for c in range(n_right):
                values[a, c, pairs] = np.take(dense, base + (a * size * n_right + c))
    # data[p] = ((data[p] + first group's value) + second's) + ...: bincount adds in order.
    n_entries = len(data)
    index = np.concatenate([np.arange(n_entries), pair_position])
    for a in range(n_left):
        for c in range(n_right):
            summands = np.concatenate([data[:, a, c], values[a, c]])
            data[:, a, c] = np.bincount(index, weights=summands, minlength=n_entries)


def pair_positions(indptr, indices, pair_row, pair_col):
    """CSR entry of each (row, col) pair of a pattern holding them all."""
    n_nodes = len(indptr) - 1
    keys = np.repeat(np.arange(n_nodes, dtype=np.int64), np.diff(indptr)) * n_nodes + indices
    query = pair_row.astype(np.int64) * n_nodes + pair_col
    if n_nodes * n_nodes <= max(DENSE_KEYS, 4 * len(query)):
        slot = np.empty(n_nodes * n_nodes, dtype=np.int64)
        slot[keys] = np.arange(len(keys))
        return slot[query]
    return np.searchsorted(keys, query)  # keys are sorted: rows in order, columns sorted


def interleave_blocks(indptr, indices, blocks, diagonal_only):
    """Interleaved (2 n x 2 n) CSR from a scalar pattern with a 2 x 2 block per entry.

    Entry (2I + a, 2J + b) = blocks[p, a, b] for the scalar entry p = (I, J); with
    ``diagonal_only`` only b = a is stored (kron(S, I_2)).  Column order stays sorted.
    """
    per_row = 1 if diagonal_only else 2
    lengths = per_row * np.diff(indptr)  # (n_rows,) entries of rows 2I and 2I + 1 each
    out_ptr = np.concatenate([[0], np.cumsum(np.repeat(lengths, 2))]).astype(np.int64)
    row = np.repeat(np.arange(len(lengths)), np.diff(indptr))  # (nnz,) scalar row of p
    within = per_row * (np.arange(len(indices)) - indptr[row])  # p's place in its row
    out_indices = np.empty(out_ptr[-1], dtype=np.int32)  # 2 n < 2^31 (budget.MAX_INDEX)
    out_data = np.empty(out_ptr[-1])
    for a in range(2):
        start = out_ptr[2 * row + a] + within
        for b in (a,) if diagonal_only else (0, 1):
            target = start + (b if not diagonal_only else 0)
            out_indices[target] = 2 * indices + b
            out_data[target] = blocks[:, a, b]
    return out_ptr, out_indices, out_data
