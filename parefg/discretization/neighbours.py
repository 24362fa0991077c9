"""Neighbour search of the MLS shape functions: the nodes whose support covers a point.

For each evaluation point x the neighbours are the nodes I with |x - x_I| < d_I (the
node's own support radius), listed nearest first (ties by node index) and padded to a
common width.  Two backends give identical lists (see
:data:`parefg.discretization.mls.BACKENDS`): ``"numba"`` walks a uniform cell list
(:func:`parefg.discretization.mls_kernels.fill_neighbours`, after a pass that counts the
covering nodes to size the lists); ``"numpy"`` queries a k-d tree
(scipy's cKDTree, imported only for this backend) for the candidates within the
largest radius and keeps those each node covers.

Nothing here is collective.
"""

import numpy as np


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
        self.max_radius = float(support_radius.max())
        self.cells = None  # the compiled search's cell list
        self.tree = None  # the numpy search's k-d tree
        if backend == "numba":
            from parefg.discretization import mls_kernels  # imports numba: only for this backend

            self.cells = mls_kernels.build_cells(nodes, self.max_radius)
        else:
            from scipy.spatial import cKDTree  # ~50 ms to import: only for this backend

            self.tree = cKDTree(nodes)

    def find(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Padded lists of the nodes I with |x - x_I| < d_I, nearest first.

        Returns
        -------
        neighbours : ndarray of int64, shape (n_points, n_max)
            Padding entries hold the point's nearest node.
        mask : ndarray of bool, shape (n_points, n_max)
        """
        if len(points) == 0:
            return np.zeros((0, 0), dtype=np.int64), np.zeros((0, 0), dtype=bool)
        if self.backend == "numba":
            from parefg.discretization import mls_kernels

            arguments = (points, self.nodes, self.support_radius, self.max_radius, self.cells)
            n_max = max(int(mls_kernels.count_neighbours(*arguments).max()), 1)
            return mls_kernels.fill_neighbours(*arguments, n_max)
        # The largest radius bounds every support: candidates within it ...
        distance, index = self._candidates(points)
        found = index < len(self.nodes)
        index = np.where(found, index, 0).astype(np.int64)
        # ... then keep the nodes whose own support covers the point, in front.
        mask = found & (distance < self.support_radius[index])
        order = np.argsort(~mask, axis=1, kind="stable")
        n_max = max(int(mask.sum(axis=1).max()), 1)
        neighbours = np.take_along_axis(index, order, axis=1)[:, :n_max]
        mask = np.take_along_axis(mask, order, axis=1)[:, :n_max]
        return np.where(mask, neighbours, neighbours[:, :1]), mask

    def _candidates(self, points):
        """Nodes within the largest support radius of each point, nearest first.

        The padding width k is guessed from a sample of points and doubled for the
        rows that come back full, so no row loses a node.

        Returns
        -------
        distance : ndarray, shape (n_points, k); inf at missing entries
        index : ndarray of int, shape (n_points, k); n_nodes at missing entries
        """
        n_nodes = len(self.nodes)
        sample = points[:: max(1, len(points) // 256)]
        counts = self.tree.query_ball_point(sample, r=self.max_radius, return_length=True)
        k = min(n_nodes, int(1.25 * np.max(counts)) + 1)
        distance, index = self._query(points, k)  # (n_points, k)
        full = index[:, -1] < n_nodes
        while full.any() and k < n_nodes:
            k = min(n_nodes, 2 * k)
            wider_distance, wider_index = self._query(points[full], k)
            distance = np.pad(
                distance, ((0, 0), (0, k - distance.shape[1])), constant_values=np.inf
            )
            index = np.pad(index, ((0, 0), (0, k - index.shape[1])), constant_values=n_nodes)
            distance[full], index[full] = wider_distance, wider_index
            full[full] = wider_index[:, -1] < n_nodes
        return distance, index

    def _query(self, points, k):
        """k nearest nodes within the largest support radius, (n_points, k) each."""
        return self.tree.query(
            points, k=list(range(1, k + 1)), distance_upper_bound=self.max_radius
        )
