"""M, K and the value operator of the domain, from MLS evaluated block by block (SPEC 3).

The domain's shape functions with gradients and the coupled node pairs of its cells are
the largest arrays of the build (tens of KB per DOF at m = 2).  :func:`assemble_domain`
walks blocks of consecutive cells twice, so that only one block's exist at a time:

1. each block's neighbour lists and coupled pairs give the scalar pattern of the Gram
   matrices (the distinct pairs of all blocks) and each point's row length in the value
   operator;
2. each block's MLS values and gradients are added into the pattern's entries
   (:func:`~parefg.discretization.assembly_kernels.gram_groups`, group by group) and
   written into its rows of the value operator S[q, I] = phi_I(x_q).

A domain of one block reuses pass 1's neighbour lists in pass 2, and a small domain
(the padded shape gradients within ``KEEP_GRADIENT_BYTES``) keeps its shape gradients
for the error norms (:class:`~parefg.discretization.point_gradients.PointGradients`),
which would otherwise evaluate MLS at the same points again.

Groups (cells) are added in the order of :meth:`Coupling.gram
<parefg.discretization.assembly.Coupling.gram>` over all points, and every point's shape
functions are those of one MLS call over all of them, so the sums are the same to the
last bit.  Not collective.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from parefg.discretization.assembly import kernels_for, sorted_slots, value_operator
from parefg.discretization.consistent_gradients import ConsistencySums, corrected_gradients
from parefg.discretization.mls import MLS, ShapeValues
from parefg.discretization.point_gradients import sorted_gradients
from parefg.discretization.quadrature import Quadrature

# Points per block: bounds the block's shape arrays and pairs (tens of MB at m = 2).
BLOCK_POINTS = 65536

# The kept gradients of a small domain (20 bytes per point and padded neighbour, per rank):
# their MLS costs more than their memory only on small clouds, where the fixed costs matter.
KEEP_GRADIENT_BYTES = 16_000_000


@dataclass
class DomainOperators:
    """The scalar Gram data on their pattern, and the value operator's CSR arrays."""

    indptr: np.ndarray  # (n_nodes + 1,) scalar pattern of M and K
    indices: np.ndarray  # (nnz,) sorted within each row
    mass: np.ndarray  # (nnz, 1, 1) int rho phi_I phi_J
    gradient_gram: np.ndarray  # (nnz, 2, 2) int d_a phi_I d_b phi_J
    # CSR of S (n_points x n_nodes): (n_points + 1,), (n_slots,) int32 nodes, (n_slots,) phi;
    # None when fill() was asked not to build S
    value_indptr: np.ndarray | None
    value_indices: np.ndarray | None
    value_data: np.ndarray | None
    condition_range: tuple[float, float]  # min, max MLS moment condition number
    gradients: list[tuple[np.ndarray, np.ndarray]] | None  # sorted_gradients per block, if kept


def _blocks(cell: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(block bounds over points, group starts): blocks end at group (cell) boundaries."""
    n_points = len(cell)
    group_start = np.concatenate([[0], np.flatnonzero(np.diff(cell)) + 1, [n_points]])
    group_start = group_start.astype(np.int64)
    targets = np.arange(BLOCK_POINTS, n_points, BLOCK_POINTS)
    inner = group_start[np.searchsorted(group_start, targets)]
    return np.unique(np.concatenate([[0], inner, [n_points]])), group_start


def _groups_of(group_start: np.ndarray, first: int, last: int) -> np.ndarray:
    """The group starts of the block of points [first, last), relative to its first point."""
    return group_start[(group_start >= first) & (group_start <= last)] - first


def _pairs(neighbours, mask, group_start, n_nodes, kernels):
    """The groups' nodes and coupled pairs (see Coupling.of) of one block."""
    node_start, nodes = kernels.group_nodes(neighbours, mask, group_start, n_nodes)
    local_of = np.zeros(n_nodes, dtype=np.int64)  # scratch of the kernels
    pairs = kernels.touched_pairs(neighbours, mask, group_start, node_start, nodes, local_of)
    return node_start, nodes, pairs


def value_rows(mls: MLS, points: np.ndarray, bounds: np.ndarray) -> tuple:
    """The CSR arrays (indptr, indices, data) of S that :meth:`BlockPasses.fill` wrote, again.

    MLS values (no gradients) of the same blocks of points (``bounds``:
    :meth:`BlockPasses.block_bounds`), so the neighbour lists and shape functions are those
    of the build, to the bit.  Not collective.
    """
    n_nodes = len(mls.nodes)
    lengths, indices, data = [np.zeros(0, dtype=np.int64)], [np.zeros(0, np.int32)], [np.zeros(0)]
    for first, last in zip(bounds[:-1], bounds[1:], strict=True):
        piece = value_operator(mls.evaluate(points[first:last], gradients=False), n_nodes)
        lengths.append(np.diff(piece.indptr))
        indices.append(piece.indices.astype(np.int32))
        data.append(piece.data)
    indptr = np.concatenate([[0], np.cumsum(np.concatenate(lengths))]).astype(np.int64)
    return indptr, np.concatenate(indices), np.concatenate(data)


def assemble_domain(mls: MLS, quadrature: Quadrature, rho: float, timer) -> DomainOperators:
    """The domain's Gram data and value operator (see the module docstring).  Not collective.

    ``timer(name)`` is a context manager timing the phases "neighbours", "mls" and
    "assembly".  Raises MLSError as :meth:`MLS.evaluate` does.  Plain Gauss integration:
    with VCI the builder runs the passes of :class:`BlockPasses` itself, since the
    gradient correction is summed over ranks between them.
    """
    passes = BlockPasses(mls, quadrature, timer)
    pattern = passes.pattern()
    return passes.fill(rho, *pattern)


class BlockPasses:
    """The two passes of :func:`assemble_domain` over blocks of consecutive cells.

    Between them, :meth:`add_consistency_sums` may add the domain terms of the VCI
    gradient correction (:mod:`.consistent_gradients`); ``fill`` then builds the
    stiffness's Gram data from the corrected gradients.
    """

    def __init__(self, mls: MLS, quadrature: Quadrature, timer):
        self.mls, self.quadrature, self.timer = mls, quadrature, timer
        self.n_nodes = len(mls.nodes)  # those held: the index space of the blocks' arrays
        self.kernels = kernels_for(mls.n_global)
        bounds, group_start = _blocks(quadrature.cell)
        self.blocks = [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]
        # one array per block, passed to both passes: the numpy kernels keep what they derive
        # from a block's arrays while they are passed again (assembly_numpy._slots)
        self.block_groups = [_groups_of(group_start, first, last) for first, last in self.blocks]
        self.searched: list[tuple | None] = [None] * len(self.blocks)  # of a one-block domain
        self.padded_slots = 0  # points x padded neighbours over all blocks
        self.shapes: list[ShapeValues | None] = [None] * len(self.blocks)  # of a one-block domain

    def block_bounds(self) -> np.ndarray:
        """(n_blocks + 1,) the first point of each block and the end of the last."""
        return np.array([0, *(last for _, last in self.blocks)], dtype=np.int64)

    def block_pairs(self, index: int) -> tuple:
        """(neighbours, mask, node_start, nodes, pairs) of block ``index`` (see _pairs):
        pass 1's for a domain of one block (its arrays exist in pass 2 anyway), else
        searched again."""
        found = self.searched[index]
        if found is not None:
            self.searched[index] = None  # pass 2 takes them
            return found
        first, last = self.blocks[index]
        with self.timer("neighbours"):
            neighbours, mask = self.mls.find_neighbours(self.quadrature.points[first:last])
        with self.timer("assembly"):
            pairs = _pairs(neighbours, mask, self.block_groups[index], self.n_nodes, self.kernels)
        found = (neighbours, mask, *pairs)
        if len(self.blocks) == 1:
            self.searched[index] = found
        return found

    def pattern(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pass 1: the scalar pattern (indptr, indices) and the row lengths of S."""
        points, n_nodes, timer = self.quadrature.points, self.n_nodes, self.timer
        rows, cols = [np.zeros(0, dtype=np.int64)], [np.zeros(0, dtype=np.int64)]
        row_lengths = np.zeros(len(points), dtype=np.int64)
        for index, (first, last) in enumerate(self.blocks):
            neighbours, mask, *_, (_, _, pair_row, pair_col) = self.block_pairs(index)
            self.padded_slots += neighbours.size
            with timer("assembly"):
                block_ptr, block_indices, _ = self.kernels.pairs_to_csr(pair_row, pair_col, n_nodes)
                rows.append(np.repeat(np.arange(n_nodes), np.diff(block_ptr)))
                cols.append(block_indices)
                row_lengths[first:last] = mask.sum(axis=1)
        with timer("assembly"):
            indptr, indices, _ = self.kernels.pairs_to_csr(
                np.concatenate(rows), np.concatenate(cols), n_nodes
            )
        return indptr, indices, row_lengths

    def block_shape(self, index: int, searched: tuple) -> ShapeValues:
        """MLS values and gradients of block ``index``: kept from the consistency sums of a
        one-block domain, else evaluated."""
        shape = self.shapes[index]
        if shape is not None:
            self.shapes[index] = None
            return shape
        first, last = self.blocks[index]
        with self.timer("mls"):
            return self.mls.evaluate(
                self.quadrature.points[first:last], gradients=True, neighbours=searched[:2]
            )

    def add_consistency_sums(self, sums: ConsistencySums) -> None:
        """The domain terms of the VCI correction, block by block (after :meth:`pattern`)."""
        for index, (first, last) in enumerate(self.blocks):
            found = self.block_pairs(index)
            shape = self.block_shape(index, found)
            with self.timer("assembly"):
                points, weights = self.quadrature.points, self.quadrature.weights
                sums.add_domain(shape, points[first:last], weights[first:last])
            if len(self.blocks) == 1:  # pass 2 takes both again
                self.searched[index], self.shapes[index] = found, shape

    def fill(
        self, rho: float, indptr, indices, row_lengths, correction=None, values: bool = True
    ) -> DomainOperators:
        """Pass 2: MLS per block, its Gram contributions and (with ``values``) its rows of S.

        ``correction`` (the (n_nodes, 2, n_p) coefficients of
        :func:`~.consistent_gradients.node_corrections`) makes the test functions'
        gradients in K the VCI ones (row I of K: corrected grad phi_I).
        """
        mls, quadrature, n_nodes, timer = self.mls, self.quadrature, self.n_nodes, self.timer
        points = quadrature.points
        keep = self.padded_slots * 20 <= KEEP_GRADIENT_BYTES  # int32 node + 2 float64 each
        kept = []
        with timer("assembly"):
            mass = np.zeros((len(indices), 1, 1))
            gradient_gram = np.zeros((len(indices), 2, 2))
            lengths = row_lengths if values else np.zeros(0, dtype=np.int64)  # S's rows
            value_indptr = np.concatenate([[0], np.cumsum(lengths)])
            value_indices = np.empty(value_indptr[-1], dtype=np.int32)
            value_data = np.empty(value_indptr[-1])
        low, high = np.inf, 0.0
        for index, (first, last) in enumerate(self.blocks):
            searched = self.block_pairs(index)
            neighbours, mask, node_start, nodes, (pair_start, pair_local, pair_row, pair_col) = (
                searched
            )
            shape = self.block_shape(index, searched)
            low, high = min(low, shape.condition.min()), max(high, shape.condition.max())
            with timer("assembly"):
                groups = self.block_groups[index]
                position = self.kernels.pair_positions(indptr, indices, pair_row, pair_col)
                weights = quadrature.weights[first:last]
                local_of = np.zeros(n_nodes, dtype=np.int64)
                block_pairs = (neighbours, mask, groups, node_start, nodes, pair_start, pair_local)
                common = (*block_pairs, position)  # the arguments of gram_groups for M and K
                phi = np.ascontiguousarray(shape.phi[:, :, None])
                self.kernels.gram_groups(phi, phi, rho * weights, *common, mass, local_of)
                dphi = np.ascontiguousarray(shape.dphi)
                test = dphi  # the test function's gradients: VCI corrects these only
                if correction is not None:
                    test = corrected_gradients(
                        shape,
                        points[first:last],
                        mls.nodes,
                        mls.support_radius,
                        correction,
                        mls.degree,
                        mls.backend == "numba",
                    )
                self.kernels.gram_groups(
                    test, dphi, np.ascontiguousarray(weights), *common, gradient_gram, local_of
                )
                slots = sorted_slots(shape, n_nodes)
                if values:
                    piece = value_operator(shape, n_nodes, slots)  # block's rows, sorted columns
                    value_indices[value_indptr[first] : value_indptr[last]] = piece.indices
                    value_data[value_indptr[first] : value_indptr[last]] = piece.data
                if keep:
                    kept.append(sorted_gradients(shape, n_nodes, slots))
        return DomainOperators(
            indptr,
            indices,
            mass,
            gradient_gram,
            value_indptr=value_indptr if values else None,
            value_indices=value_indices if values else None,
            value_data=value_data if values else None,
            condition_range=(low, high),
            gradients=kept if keep else None,
        )
