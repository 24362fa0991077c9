"""Neighbour search of the MLS shape functions: the nodes whose support covers a point.

For each evaluation point x the neighbours are the nodes I with |x - x_I| < d_I (the
node's own support radius, the distance rounded as sqrt(dx^2 + dy^2)), listed nearest
first (ties by node index) and padded to a common width with the nearest node (node 0
where no node covers x).  Two backends give identical lists (see
:data:`parefg.discretization.mls.BACKENDS`).

The nodes are split into radius classes (:func:`radius_classes`), each spanning less
than a factor :data:`CLASS_RATIO` of radii, and every point is searched in every class
within that class's own largest radius (its reach).  On a graded cloud (radii from
h/10 to h) a single search within the cloud's largest radius would scan ~(d_max/d_min)^2
times the covering nodes; per class it scans at most ~9/pi CLASS_RATIO^2 times them.  A
uniform cloud is one class.  ``"numba"`` walks one uniform cell list per class
(:func:`parefg.discretization.mls_kernels.neighbour_lists`, one scan per point);
``"numpy"`` queries one k-d tree per class (scipy's cKDTree, imported only for this
backend) for the candidates within the class's reach and keeps those each node covers.

Nothing here is collective.
"""

from typing import Any

import numpy as np

#: Largest ratio of support radii within one radius class.
CLASS_RATIO = 2.0
# A class's reach is its largest radius widened by 16 ulps: every node whose rounded
# distance is below its radius then lies within the reach exactly, wherever it rounds.
REACH_WIDENING = 1.0 + 16.0 * np.finfo(float).eps


def radius_classes(support_radius: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Radius classes of the nodes: d_I in [d_min r^c, d_min r^(c+1)), r = CLASS_RATIO.

    Returns
    -------
    classes : ndarray of int64, shape (n_nodes,)
        The class of each node, numbered 0 .. n_classes - 1 without gaps.
    reach : ndarray, shape (n_classes,)
        Each class's largest radius, times :data:`REACH_WIDENING`.
    """
    level = np.floor(np.log2(support_radius / support_radius.min()) / np.log2(CLASS_RATIO))
    _, classes = np.unique(level, return_inverse=True)
    classes = classes.reshape(-1).astype(np.int64)
    reach = np.zeros(int(classes.max()) + 1)
    np.maximum.at(reach, classes, support_radius)
    return classes, reach * REACH_WIDENING


class NeighbourSearch:
    """Covering-node lists of one node cloud.

    Parameters
    ----------
    nodes : ndarray, shape (n_nodes, 2)
        Node coordinates x_I (C-contiguous float).
    support_radius : ndarray, shape (n_nodes,)
        Support radius d_I of each node (positive).
    backend : {"numba", "numpy"}
    """

    def __init__(self, nodes: np.ndarray, support_radius: np.ndarray, backend: str):
        self.nodes, self.support_radius, self.backend = nodes, support_radius, backend
        self.classes, self.reach = radius_classes(support_radius)
        self.coordinates = (nodes[:, 0].copy(), nodes[:, 1].copy())  # x, y: numpy's gathers
        self.cells = None  # the compiled search's cell lists, one per class
        self.width = 32  # the compiled search's guess of the list length (grown as needed)
        # the numpy search's (members, reach, k-d tree) per class
        self.trees: list[tuple[np.ndarray, float, Any]] = []
        if backend == "numba":
            from parefg.discretization import mls_kernels  # imports numba: only for this backend

            self.cells = mls_kernels.build_cells(nodes, support_radius, self.classes, self.reach)
        else:
            from scipy.spatial import cKDTree  # ~50 ms to import: only for this backend

            for c, reach in enumerate(self.reach):
                members = np.flatnonzero(self.classes == c)
                self.trees.append((members, float(reach), cKDTree(nodes[members])))

    def find(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Padded lists of the nodes I with |x - x_I| < d_I, nearest first.

        Returns
        -------
        neighbours : ndarray of int64, shape (n_points, n_max)
            Padding entries hold the point's nearest node (0 if no node covers it).
        mask : ndarray of bool, shape (n_points, n_max)
        """
        if len(points) == 0:
            return np.zeros((0, 0), dtype=np.int64), np.zeros((0, 0), dtype=bool)
        if self.backend == "numba":
            from parefg.discretization import mls_kernels

            found = mls_kernels.neighbour_lists(points, self.cells, self.width)
            self.width = found[0].shape[1]  # the next block's guess
            return found
        # The covering nodes of each class, then all of them sorted by (distance, node).
        compact = len(self.trees) > 1
        found = [self._covering(points, *tree, compact) for tree in self.trees]
        index, distance = found[0]  # (n_points, k) each
        if compact:
            index = np.concatenate([i for i, _ in found], axis=1)
            distance = np.concatenate([d for _, d in found], axis=1)
        order = np.lexsort((index, distance), axis=1)
        index = np.take_along_axis(index, order, axis=1)
        mask = index < len(self.nodes)
        n_max = max(int(mask.sum(axis=1).max()), 1)
        neighbours, mask = index[:, :n_max], mask[:, :n_max]
        nearest = np.where(mask[:, :1], neighbours[:, :1], 0)
        return np.where(mask, neighbours, nearest), mask

    def _covering(self, points, members, reach, tree, compact):
        """The nodes of one class that cover each point, in no particular order.

        ``compact``: drop the columns that cover no point (else the candidates' width).

        Returns
        -------
        index : ndarray of int64, shape (n_points, k)
            Node numbers; n_nodes at the padding.
        distance : ndarray, shape (n_points, k)
            |x - x_I| rounded as sqrt(dx^2 + dy^2); inf at the padding.
        """
        n_nodes = len(self.nodes)
        candidate = self._candidates(points, tree, reach)  # (n_points, k); len(members): none
        found = candidate < len(members)
        index = np.append(members, 0)[candidate]  # node 0 at the missing candidates
        # The distance as the numba kernel rounds it: sqrt(dx^2 + dy^2).
        dx = points[:, :1] - self.coordinates[0][index]  # (n_points, k)
        dy = points[:, 1:] - self.coordinates[1][index]
        distance = np.sqrt(dx * dx + dy * dy)
        mask = found & (distance < self.support_radius[index])
        if compact:  # the columns that hold a covering node of some point, in front
            keep = max(int(mask.sum(axis=1).max()), 1)
            order = np.argsort(~mask, axis=1, kind="stable")[:, :keep]
            mask = np.take_along_axis(mask, order, axis=1)
            index = np.take_along_axis(index, order, axis=1)
            distance = np.take_along_axis(distance, order, axis=1)
        return np.where(mask, index, n_nodes), np.where(mask, distance, np.inf)

    @staticmethod
    def _candidates(points, tree, reach):
        """The tree's nodes within ``reach`` of each point, (n_points, k); tree.n at the
        missing entries.

        The padding width k is guessed from a sample of points and doubled for the
        rows that come back full, so no row loses a node.
        """
        n = tree.n
        sample = points[:: max(1, len(points) // 256)]
        counts = tree.query_ball_point(sample, r=reach, return_length=True)
        k = min(n, int(1.25 * np.max(counts)) + 1)
        index = _query(tree, points, k, reach)  # (n_points, k)
        full = index[:, -1] < n
        while full.any() and k < n:
            k = min(n, 2 * k)
            wider = _query(tree, points[full], k, reach)
            index = np.pad(index, ((0, 0), (0, k - index.shape[1])), constant_values=n)
            index[full] = wider
            full[full] = wider[:, -1] < n
        return index


def _query(tree, points, k, reach):
    """Indices of the k nearest tree nodes within reach, (n_points, k); tree.n if fewer."""
    return tree.query(points, k=list(range(1, k + 1)), distance_upper_bound=reach)[1]
