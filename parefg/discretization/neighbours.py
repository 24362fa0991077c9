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


# a node within (1 + 1e-9) of its support radius of a box may reach points of the box
BOX_WIDENING = 1.0 + 1e-9


def nodes_reaching_box(nodes: np.ndarray, support_radius: np.ndarray, lower, upper) -> np.ndarray:
    """Sorted indices of the nodes whose supports reach the box [lower, upper] (each (2,)):
    a superset of the nodes that cover any point of it (the distance to the box widened by
    BOX_WIDENING, so that rounding never drops one).  One pass over the nodes; not
    collective."""
    gap = nodes - np.clip(nodes, lower, upper)  # (n_nodes, 2), zero inside the box
    return np.flatnonzero(np.hypot(gap[:, 0], gap[:, 1]) <= support_radius * BOX_WIDENING)


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


def build_cells(nodes, radius, classes, reach):
    """One uniform cell list per radius class, concatenated into flat arrays.

    Class c holds the nodes ``classes == c`` (labels 0 .. n_classes - 1), all of support
    radius below ``reach[c]``.  Its cells are at least that large, so the nodes of class c
    that cover a point lie in the (at most) 3 x 3 cells around it: a point scans the area
    of each class's own largest support, not that of the cloud's.  Cell k = i * shape[c, 1]
    + j of class c holds the slots ``start[first_cell[c] + k]:start[first_cell[c] + k + 1]``
    of the cell-ordered arrays, so a row of cells is one run of slots.

    Returns
    -------
    origin : ndarray, shape (n_classes, 2)
    cell_size : ndarray, shape (n_classes,)
        At least the reach; enlarged so that there are at most ~4 cells per node.
    reach : ndarray, shape (n_classes,)
    shape : ndarray of int64, shape (n_classes, 2)
        Number of cells per direction.
    first_cell : ndarray of int64, shape (n_classes + 1,)
    start : ndarray of int64, shape (n_cells + 1,)
    cell_nodes : ndarray of int64, shape (n_nodes,)
        The node in each slot.
    cell_coords, cell_radius : ndarray, shape (n_nodes, 2) and (n_nodes,)
        Its coordinates and radius, in slot order (the scan reads them in sequence).
    """
    n_classes = len(reach)
    origin, cell_size = np.zeros((n_classes, 2)), np.zeros(n_classes)
    shape = np.zeros((n_classes, 2), dtype=np.int64)
    starts, members, offset = [], [], 0
    for c in range(n_classes):  # a Python loop over the few classes, not over nodes
        member = np.flatnonzero(classes == c)
        origin[c], cell_size[c], shape[c], start, order = _uniform_cells(nodes[member], reach[c])
        starts.append(offset + start[:-1])
        members.append(member[order])
        offset += len(member)
    first_cell = np.zeros(n_classes + 1, dtype=np.int64)
    first_cell[1:] = np.cumsum(shape[:, 0] * shape[:, 1])
    start = np.concatenate([*starts, [offset]]).astype(np.int64)
    cell_nodes = np.concatenate(members)
    reach = np.ascontiguousarray(reach, dtype=float)
    coords, radius = np.ascontiguousarray(nodes[cell_nodes]), radius[cell_nodes]
    return origin, cell_size, reach, shape, first_cell, start, cell_nodes, coords, radius


def _uniform_cells(nodes, cell_size):
    """(origin, cell size, shape, start, order) of a uniform cell list of the nodes:
    cell k = i * shape[1] + j holds nodes[order[start[k]:start[k + 1]]]."""
    origin = nodes.min(axis=0)
    extent = nodes.max(axis=0) - origin
    cell_size = max(cell_size, np.sqrt(extent[0] * extent[1] / (4.0 * len(nodes))))
    shape = (np.floor(extent / cell_size) + 1).astype(np.int64)  # (2,)
    ij = np.minimum(((nodes - origin) / cell_size).astype(np.int64), shape - 1)  # (n, 2)
    cell = ij[:, 0] * shape[1] + ij[:, 1]
    order = np.argsort(cell, kind="stable").astype(np.int64)
    start = np.zeros(shape[0] * shape[1] + 1, dtype=np.int64)
    start[1:] = np.cumsum(np.bincount(cell, minlength=shape[0] * shape[1]))
    return origin, float(cell_size), shape, start, order


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
        self.coordinates = None  # x, y: the numpy search's gathers
        self.cells = None  # the compiled search's cell lists, one per class
        self.width = 32  # the compiled search's guess of the list length (grown as needed)
        # the numpy search's (members, reach, k-d tree) per class
        self.trees: list[tuple[np.ndarray, float, Any]] = []
        if backend == "numba":
            self.cells = build_cells(nodes, support_radius, self.classes, self.reach)
        else:
            from scipy.spatial import cKDTree  # ~50 ms to import: only for this backend

            self.coordinates = (nodes[:, 0].copy(), nodes[:, 1].copy())
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
            from parefg.discretization import aot

            found = aot.kernels("mls_kernels").neighbour_lists(points, self.cells, self.width)
            self.width = found[0].shape[1]  # the next block's guess
            return found
        # Each point's covering nodes in one padded row, then sorted by (distance, node):
        # the padding (n_nodes, inf) goes last.
        neighbours = _sorted(*self._padded(points))  # (n_points, n_max)
        mask = neighbours < len(self.nodes)
        nearest = np.where(mask[:, :1], neighbours[:, :1], 0)  # (n_points, 1)
        np.copyto(neighbours, nearest, where=~mask)
        return neighbours, mask

    def _padded(self, points):
        """The covering nodes of each point in no particular order, padded to n_max.

        Returns
        -------
        index : ndarray of int64, shape (n_points, n_max)
            Node numbers; n_nodes at the padding.
        distance : ndarray, shape (n_points, n_max)
            |x - x_I|; inf at the padding.
        """
        n_nodes, n_points = len(self.nodes), len(points)
        found = [self._covering(points, *tree) for tree in self.trees]
        counts, node, distance = found[0]
        if len(found) > 1:  # each class's nodes come point by point: merge the classes
            row = np.concatenate([np.repeat(np.arange(n_points), c) for c, _, _ in found])
            order = np.argsort(row, kind="stable")
            node = np.concatenate([n for _, n, _ in found])[order]
            distance = np.concatenate([d for _, _, d in found])[order]
            counts = np.sum([c for c, _, _ in found], axis=0)
        n_max = max(int(counts.max()), 1)
        # The nodes, point by point, fill each row's first counts[q] entries.
        filled = np.arange(n_max) < counts[:, None]  # (n_points, n_max)
        index = np.full((n_points, n_max), n_nodes, dtype=np.int64)
        padded = np.full((n_points, n_max), np.inf)
        index[filled], padded[filled] = node, distance
        return index, padded

    def _covering(self, points, members, reach, tree):
        """The nodes of one class that cover the points, point by point.

        Returns
        -------
        counts : ndarray of int, shape (n_points,)
            How many nodes of the class cover each point.
        node, distance : ndarray, shape (counts.sum(),)
            The nodes and |x - x_I|, rounded as the numba kernel rounds it, sqrt(dx^2 + dy^2).
        """
        candidate = self._candidates(points, tree, reach)  # (n_points, k); len(members): none
        found = candidate < len(members)
        if found.mean() > 0.5:  # mostly found (one class): the distances of the whole array
            row, node = None, np.append(members, 0)[candidate]  # (n_points, k); 0: none
            x, y = points[:, :1], points[:, 1:]
        else:  # mostly padding (several classes): the distances of the found candidates
            row = np.repeat(np.arange(len(points)), found.sum(axis=1))
            node = members[candidate[found]]
            x, y = points[row, 0], points[row, 1]
        dx, dy = x - self.coordinates[0][node], y - self.coordinates[1][node]
        dx *= dx
        dy *= dy
        dx += dy
        distance = np.sqrt(dx, out=dx)
        covers = distance < self.support_radius[node]
        if row is None:
            covers &= found
            counts = covers.sum(axis=1)
        else:
            counts = np.bincount(row[covers], minlength=len(points))
        return counts, node[covers], distance[covers]

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


class RegionSearch:
    """The covering-node lists of :class:`NeighbourSearch`, searched among the nodes whose
    supports reach a box only; the box grows to take points outside it.

    A rank evaluates MLS in and near its own part of the domain.  Searching only the
    nodes that can cover a point of that box keeps the search's arrays (cell lists or
    k-d trees, radius classes: ~40 bytes per node) proportional to the part,
    not to the whole cloud.  The lists are those of a search over every node: a node that
    covers a point of the box lies within its radius of the box, and the lists keep the
    node numbers and their (distance, node) order.  Points outside the box enlarge it to
    their bounding box as well and rebuild the search (``rebuilds`` counts them).
    ``members``: the searched nodes, sorted (None: every node).

    Parameters
    ----------
    nodes, support_radius, backend :
        As for :class:`NeighbourSearch`, of the nodes held (read, not copied).
    box : array_like, shape (2, 2)
        Lower and upper corners of the box the points are expected in.
    complete : bool
        Whether ``nodes`` are the whole cloud.  If not (a rank holding its part and the
        ghosts that reach ``box``, :mod:`parefg.discretization.ghosts`), a point outside
        the box could miss nodes that are not held: RuntimeError instead of a rebuild.
    """

    def __init__(
        self, nodes: np.ndarray, support_radius: np.ndarray, backend: str, box, complete=True
    ):
        self.nodes, self.support_radius, self.backend = nodes, support_radius, backend
        self.complete = complete
        self.rebuilds = 0
        self.box = np.asarray(box, dtype=float)  # (2, 2)
        self.members: np.ndarray | None = None
        self.search = self._cover()

    def _cover(self) -> NeighbourSearch:
        """The search among the nodes whose supports reach ``self.box``; sets ``members``."""
        members = nodes_reaching_box(self.nodes, self.support_radius, *self.box)
        if len(members) == 0:  # no node reaches the box: keep one, as an empty cloud can't
            members = np.array([0])
        if len(members) == len(self.nodes):  # every node (one rank): no copies
            self.members = None
            return NeighbourSearch(self.nodes, self.support_radius, self.backend)
        self.members = members
        return NeighbourSearch(
            np.ascontiguousarray(self.nodes[members]), self.support_radius[members], self.backend
        )

    def find(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """As :meth:`NeighbourSearch.find` over every node."""
        if len(points):
            lower, upper = points.min(axis=0), points.max(axis=0)
            if np.any(lower < self.box[0]) or np.any(upper > self.box[1]):
                if not self.complete:  # a defect: the rank's evaluation box missed a point
                    outside = (points < self.box[0]).any(axis=1) | (points > self.box[1]).any(
                        axis=1
                    )
                    raise RuntimeError(
                        f"MLS point {points[outside][0].tolist()} lies outside the box "
                        f"{self.box.tolist()} whose nodes this rank holds"
                    )
                self.rebuilds += 1
                grown = [np.minimum(lower, self.box[0]), np.maximum(upper, self.box[1])]
                self.box = np.array(grown)
                self.search = self._cover()
        local, mask = self.search.find(points)
        if self.members is None:
            return local, mask
        neighbours = self.members[local]
        neighbours[~mask[:, :1].any(axis=1)] = 0  # a point no node covers: node 0, as in the list
        return neighbours, mask


def _sorted(index, distance):
    """index with each row sorted by (distance, index), (n_points, n_max).

    A k-d tree lists one class's candidates nearest first, ties in its own order: rows in
    distance order only get their runs of equal distances sorted by node (one sort of
    integer keys, run * (n_nodes + 1) + node), the others (several classes) a full sort.
    """
    later, earlier = distance[:, 1:], distance[:, :-1]
    unsorted = (later < earlier).any(axis=1)
    tied = ((later == earlier) & (index[:, 1:] < index[:, :-1])).any(axis=1) & ~unsorted
    rows = np.flatnonzero(tied)
    if len(rows):
        run = np.zeros((len(rows), index.shape[1]), dtype=np.int64)
        np.cumsum(distance[rows, 1:] != distance[rows, :-1], axis=1, out=run[:, 1:])
        base = index.max() + 1  # > every node number and the padding's
        index[rows] = np.sort(run * base + index[rows], axis=1) % base
    rows = np.flatnonzero(unsorted)
    if len(rows):
        order = np.lexsort((index[rows], distance[rows]), axis=1)
        index[rows] = np.take_along_axis(index[rows], order, axis=1)
    return index


def _query(tree, points, k, reach):
    """Indices of the k nearest tree nodes within reach, (n_points, k); tree.n if fewer."""
    return tree.query(points, k=list(range(1, k + 1)), distance_upper_bound=reach)[1]
