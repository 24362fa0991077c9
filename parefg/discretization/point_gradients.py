"""grad u_h at a set of points, evaluated block by block without a gradient operator (SPEC 2).

A gradient operator (du_i/dx_j at every point, one entry per point and neighbour) would be
the largest array of a run, and only error norms (once) and nodal stresses (at output
steps) need it.  :class:`PointGradients` instead evaluates MLS with gradients at a block
of points, multiplies by the nodal values of u_h there and drops the block; the nodal
values a rank's points reach are gathered once per call (owned and ghost nodes).

The sums follow PETSc's AIJ product of the interleaved operator (4 rows per point: an
inode of two rows per DOF component, whose kernel adds the terms in pairs), so that the
numbers equal those of the assembled operator on one rank.  Points with one neighbour
list evaluate with the MLS of the run (the same neighbours, in the same order), so their
shape functions are those the operators were built from.
"""

from __future__ import annotations

import numpy as np
from petsc4py import PETSc

from parefg.discretization.assembly import gather, sorted_slots
from parefg.discretization.mls import MLS, ShapeValues
from parefg.discretization.neighbours import nodes_reaching_box

# Points per MLS block: bounds the transient shape arrays (a few MB at m = 2).
BLOCK_POINTS = 4096


class PointGradients:
    """Gradients of u_h at ``points`` (this rank's), from MLS re-evaluated per block.

    ``keep`` stores each block's sorted neighbours and shape gradients after the first use
    (compact: 20 bytes per point and neighbour), for point sets evaluated repeatedly (the
    nodes, at output steps); otherwise only the sorted list of the nodes the points reach
    is stored between calls.  ``kept`` passes
    those blocks (:func:`sorted_gradients` of consecutive runs of the points, in order)
    when the builder has already evaluated the shape gradients at the points.
    """

    def __init__(
        self,
        mls: MLS,
        points: np.ndarray,
        keep: bool,
        kept: list[tuple[np.ndarray, np.ndarray]] | None = None,
    ):
        self.mls, self.keep = mls, keep or kept is not None
        # None while the owning PointSet has released its points (PointSet.release_points)
        self.points: np.ndarray | None = points
        self.kept = kept  # (nodes, dphi) per block
        self._reached: np.ndarray | None = None  # sorted nodes the points reach, once found

    def _points(self) -> np.ndarray:
        """The points (restored by the owner before any evaluation)."""
        assert self.points is not None, "points released: PointSet.restore_points first"
        return self.points

    def _block(self, start: int) -> tuple[np.ndarray, np.ndarray]:
        """:func:`sorted_gradients` of the block at ``start``."""
        points = self._points()[start : start + BLOCK_POINTS]
        return sorted_gradients(self.mls.evaluate(points, gradients=True), len(self.mls.nodes))

    def _blocks(self):
        """The blocks in order (kept ones, or freshly evaluated)."""
        if self.kept is not None:
            yield from self.kept
            return
        kept = []
        for start in range(0, len(self._points()), BLOCK_POINTS):
            block = self._block(start)
            if self.keep:
                kept.append(block)
            yield block
        if self.keep:
            self.kept = kept

    def _reached_nodes(self) -> np.ndarray:
        """Sorted nodes whose nodal values the points' evaluation needs.  Not collective.

        From the kept blocks' neighbour lists (padding included) once they exist; else
        every node whose support meets the points' bounding box: a superset of the
        neighbour lists found in one pass over the nodes, not a neighbour search of all the
        points (which made a 2-rank run's error norms cost what 1 rank's did: 2.4 s for
        2.1 s at m = 2, 51842 DOFs).  Stored after the first call: the points do not
        change.  A rank whose points lie far apart (boundary points on opposite sides) has
        a box that holds most nodes: still correct, only more values gathered.
        """
        if self._reached is not None:
            return self._reached
        if self.kept is not None:
            blocks = [np.zeros(0, dtype=np.int64), *(n.ravel() for n, _ in self.kept)]
            self._reached = np.unique(np.concatenate(blocks))
            return self._reached
        points = self._points()
        if len(points) == 0:
            self._reached = np.zeros(0, dtype=np.int64)
            return self._reached
        self._reached = nodes_reaching_box(
            self.mls.nodes, self.mls.support_radius, points.min(axis=0), points.max(axis=0)
        )
        return self._reached

    def _nodal_values(self, comm, u: PETSc.Vec) -> np.ndarray:
        """u's nodal values (n_held, 2) by held node: every node's on one rank, else the
        rows of the nodes the points reach, gathered from their owners (the other rows are
        0 and never read).  Collective.

        By held node rather than by reached node, so that the blocks read their
        neighbours' rows with a plain gather (a search per entry cost 0.44 s of a 2-rank
        error norm at 80802 DOFs).
        """
        if comm.size == 1:
            return u.getArray(readonly=True).reshape(-1, 2)
        reached = self._reached_nodes()
        reached_ids = self.mls.global_ids(reached).astype(PETSc.IntType)
        indices = PETSc.IS().createBlock(2, reached_ids, comm=PETSc.COMM_SELF)
        gathered = PETSc.Vec().createSeq(2 * len(reached), comm=PETSc.COMM_SELF)
        scatter = PETSc.Scatter().create(u, indices, gathered, None)
        scatter.scatter(u, gathered, addv=PETSc.InsertMode.INSERT_VALUES)
        by_node = np.zeros((len(self.mls.nodes), 2))
        by_node[reached] = gathered.getArray().reshape(-1, 2)
        for obj in (scatter, gathered, indices):
            obj.destroy()
        return by_node

    def evaluate(self, comm, u: PETSc.Vec) -> np.ndarray:
        """(n_points, 2, 2) with [q, i, j] = d u_i / d x_j at the points.  Collective.

        ``u`` is the interleaved DOF vector (block size 2).
        """
        nodal = self._nodal_values(comm, u)
        out = np.empty((len(self._points()), 2, 2))
        start = 0
        for nodes, dphi in self._blocks():
            stop = start + len(nodes)
            _gradient_rows(dphi, nodal[nodes], out[start:stop])
            start = stop
        return out

    def evaluate_values(self, comm, u: PETSc.Vec, gradients: bool = False):
        """(n_points, 2) u_h at the points, without a value operator.  Collective.

        MLS values per block, each point's sum over its neighbours sorted by node and taken
        in that order from 0, as PETSc's AIJ product of the scalar value operator sums a
        row (no inodes: see point_set.point_operator), so on one rank the numbers are those
        of the operator.  With ``gradients`` the same MLS pass also gives grad u_h:
        returns (values, gradients as :meth:`evaluate` computes them).  MLS is evaluated
        here whether or not gradients are kept (kept blocks hold no values); nothing is
        kept between calls.
        """
        nodal = self._nodal_values(comm, u)
        points = self._points()
        out = np.empty((len(points), 2))
        grad = np.empty((len(points), 2, 2)) if gradients else None
        for start in range(0, len(points), BLOCK_POINTS):
            shape = self.mls.evaluate(points[start : start + BLOCK_POINTS], gradients)
            slots = sorted_slots(shape, len(self.mls.nodes))
            phi = gather(shape.phi, slots[0])  # (n_block, n_max), 0 at the padding (last)
            at = slots[1]  # the sorted neighbours: rows of nodal
            stop = start + len(phi)
            for c in range(2):
                values = nodal[at, c]  # (n_block, n_max) u_c at the neighbours
                total = np.zeros(len(phi))
                for k in range(phi.shape[1]):
                    total = total + phi[:, k] * values[:, k]
                out[start:stop, c] = total
            if grad is not None:
                _, dphi = sorted_gradients(shape, len(self.mls.nodes), slots)
                _gradient_rows(dphi, nodal[at], grad[start:stop])
        return out if grad is None else (out, grad)

    def integrate_values(self, weighted: np.ndarray, outs: list[PETSc.Vec]) -> None:
        """outs[k] = S^T ``weighted[k]`` per component without a value operator:
        ``weighted`` (K, n_points, 2) densities times the quadrature weights.  Collective.

        One MLS pass (values) for all K; each node's sum over this rank's points (in point
        order, so the numbers differ from PETSc's product with S at round-off), then added
        into the vectors across ranks (ADD_VALUES: only the nodes this rank reaches travel).
        """
        points = self._points()
        n_nodes = len(self.mls.nodes)
        sums = np.zeros((len(outs), 2, n_nodes))  # scratch by node held (own and ghosts)
        reached = np.zeros(n_nodes, dtype=bool)
        for start in range(0, len(points), BLOCK_POINTS):
            shape = self.mls.evaluate(points[start : start + BLOCK_POINTS], gradients=False)
            nodes = shape.neighbours[shape.mask]  # (n_entries,) point by point
            rows = start + np.nonzero(shape.mask)[0]
            phi = shape.phi[shape.mask]
            reached[nodes] = True
            # The block's nodes span a few rows of the cloud: its sums over that span only.
            # Over every node the sums cost blocks x nodes, quadratic in the cloud (K = 3,
            # square, m = 2: 2.31 -> 1.98 s at h = 1/128, 10.1 -> 8.2 s at 1/256), and the
            # pages of sums that no block reaches are now never touched.
            first = int(nodes.min(initial=0))
            span = slice(first, int(nodes.max(initial=-1)) + 1)
            for k in range(len(outs)):
                for c in range(2):
                    terms = phi * weighted[k, rows, c]
                    sums[k, c, span] += np.bincount(
                        nodes - first, weights=terms, minlength=span.stop - first
                    )
        touched = np.flatnonzero(reached)
        touched_ids = self.mls.global_ids(touched)
        dofs = (2 * touched_ids[:, None] + np.arange(2)).ravel().astype(PETSc.IntType)
        for k, out in enumerate(outs):
            out.set(0.0)
            out.setValues(dofs, sums[k][:, touched].T.ravel(), addv=PETSc.InsertMode.ADD_VALUES)
            out.assemblyBegin()
            out.assemblyEnd()


def sorted_gradients(shape: ShapeValues, n_nodes: int, slots=None) -> tuple[np.ndarray, np.ndarray]:
    """(nodes, dphi) of ``shape`` (with gradients): neighbours sorted by node, padding last.

    nodes (n_points, n_max) int32, dphi (n_points, n_max, 2); dphi is 0 at padding.
    ``slots``: the :func:`~parefg.discretization.assembly.sorted_slots` of ``shape`` if
    the caller has them.
    """
    assert shape.dphi is not None  # evaluated with gradients
    order, nodes, _ = sorted_slots(shape, n_nodes) if slots is None else slots
    return nodes.astype(np.int32), gather(shape.dphi, order)


def _gradient_rows(dphi: np.ndarray, nodal: np.ndarray, out: np.ndarray) -> None:
    """out[q, c, d] = sum_k dphi[q, k, d] u_c(node k): ``nodal`` (n, n_max, 2) u at each
    point's sorted neighbours, summed as the interleaved operator's product sums."""
    for c in range(2):
        for d in range(2):
            out[:, c, d] = _pairwise_row_sums(dphi[:, :, d] * nodal[:, :, c])


def _pairwise_row_sums(products: np.ndarray) -> np.ndarray:
    """Row sums added as PETSc's inode product adds them: ((0 + (p0 + p1)) + (p2 + p3)) + ...

    ``products`` (n, n_max) with the padding (zeros) last; an odd last term pairs with a
    zero, which adds nothing.
    """
    if products.shape[1] % 2:
        products = np.pad(products, ((0, 0), (0, 1)))
    pairs = products[:, 0::2] + products[:, 1::2]  # (n, n_max / 2)
    total = np.zeros(len(products))
    for column in range(pairs.shape[1]):
        total = total + pairs[:, column]
    return total
