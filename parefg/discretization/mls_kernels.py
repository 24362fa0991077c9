"""Compiled (numba) MLS kernels: cell-list neighbour search and per-point shape functions.

The mathematics is that of :mod:`parefg.discretization.mls` (SPEC 2); this module only changes
how it is computed.  Per point x the kernel

1. evaluates w_I, dw_I/dx and the scaled shifted basis p_I = p((x_I - x) / R),
2. assembles the moment matrix A = sum_I w_I p_I p_I^T,
3. factors A = L L^T by a hand-written Cholesky (A is symmetric positive
   definite exactly when the point is well supported) and forms A^-1 column by
   column (n_basis <= 10, so this costs no more than assembling A),
4. returns phi_I = (gamma^T p_I) w_I with gamma = A^-1 e_0, the gradients from
   A gamma_k = e_{1+k} / R - A_k gamma, where A_k gamma = sum_I dw_I/dx_k (gamma^T p_I) p_I
   is accumulated without forming A_k, and the condition estimate
   ||A||_F ||A^-1||_F (infinite when the Cholesky factorization breaks down).

Nothing here is collective.  numba compiles on first use and caches the
machine code next to this file (``cache=True``), so only the first process
after an edit pays the compilation.
"""

import numpy as np

from parefg.discretization.weights import WEIGHTS, weight_pair

try:
    import numba
except ImportError:  # pragma: no cover - numba is a Debian package of the environment
    numba = None

AVAILABLE = numba is not None
# Weights the compiled kernel knows (registry name -> Weight.code); others use numpy.
WEIGHT_CODES = {name: weight.code for name, weight in WEIGHTS.items() if weight.code is not None}


def _jit(function):
    """Compile with numba when it is installed (no fastmath: results must match numpy).

    error_model="numpy": a division is the bare IEEE operation, without the zero-divisor
    test and branch that Python semantics put before each one (no divisor here can be
    zero: radii, scales and accepted Cholesky pivots are positive).
    """
    if numba is None:  # pragma: no cover
        return function
    return numba.njit(cache=True, fastmath=False, nogil=True, error_model="numpy")(function)


# (W(r), dW/dr) of the weight with the given code (Weight.code); both 0 for r >= 1.
weight_and_slope = _jit(weight_pair)


# ----------------------------------------------------------------------------- neighbour search


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


@_jit
def _cell_range(x, reach, origin, cell_size, n_cells):
    """First and one-past-last cell index along one axis that can hold nodes within reach."""
    low = max(int(np.floor((x - reach - origin) / cell_size)), 0)
    high = min(int(np.floor((x + reach - origin) / cell_size)) + 1, n_cells)
    return low, high


@_jit
def _covering_nodes(x, y, cells, found, distance):
    """Write the nodes I with |x - x_I| < d_I into found/distance; return how many.

    The nodes come class by class (unsorted); found/distance hold the first len(found).
    """
    origin, cell_size, reach, shape, first_cell, start, cell_nodes, coords, radius = cells
    count = 0
    for c in range(len(reach)):
        i_low, i_high = _cell_range(x, reach[c], origin[c, 0], cell_size[c], shape[c, 0])
        j_low, j_high = _cell_range(y, reach[c], origin[c, 1], cell_size[c], shape[c, 1])
        if j_low >= j_high:
            continue
        for i in range(i_low, i_high):
            row = first_cell[c] + i * shape[c, 1]  # cells j_low .. j_high - 1: one slot run
            for slot in range(start[row + j_low], start[row + j_high]):
                # The distance as the numpy backend rounds it: sqrt(dx^2 + dy^2).
                dx, dy = x - coords[slot, 0], y - coords[slot, 1]
                d = np.sqrt(dx * dx + dy * dy)
                if d < radius[slot]:
                    if count < len(found):
                        found[count], distance[count] = cell_nodes[slot], d
                    count += 1
    return count


@_jit
def _sort_by_distance(found, distance, count):
    """Insertion sort of the first count entries by (distance, node): lists are short."""
    for a in range(1, count):
        node, d = found[a], distance[a]
        b = a - 1
        while b >= 0 and (distance[b] > d or (distance[b] == d and found[b] > node)):
            found[b + 1], distance[b + 1] = found[b], distance[b]
            b -= 1
        found[b + 1], distance[b + 1] = node, d


@_jit
def neighbour_lists(points, cells, width):
    """Padded covering-node lists, nearest first (ties by node index), in one scan.

    Each point's sorted list goes to a flat buffer with room for ``width`` nodes per
    point (a guess: the buffer doubles when full), then into the padded arrays.

    Returns neighbours (n_points, n_max) int64, padded with the nearest node (0 where no
    node covers the point), and the mask (n_points, n_max) bool.
    """
    n_points = len(points)
    flat = np.empty(max(n_points * width, 16), dtype=np.int64)
    end = np.zeros(n_points + 1, dtype=np.int64)  # point q's list: flat[end[q]:end[q + 1]]
    found, distance = np.empty(max(width, 16), dtype=np.int64), np.empty(max(width, 16))
    for q in range(n_points):
        x, y = points[q, 0], points[q, 1]
        count = _covering_nodes(x, y, cells, found, distance)
        if count > len(found):  # the scratch was short: scan again with room for all
            found, distance = np.empty(2 * count, dtype=np.int64), np.empty(2 * count)
            count = _covering_nodes(x, y, cells, found, distance)
        _sort_by_distance(found, distance, count)
        if end[q] + count > len(flat):
            wider = np.empty(2 * len(flat) + count, dtype=np.int64)
            wider[: end[q]] = flat[: end[q]]
            flat = wider
        flat[end[q] : end[q] + count] = found[:count]
        end[q + 1] = end[q] + count
    n_max = 1
    for q in range(n_points):
        n_max = max(n_max, end[q + 1] - end[q])
    neighbours = np.zeros((n_points, n_max), dtype=np.int64)
    mask = np.zeros((n_points, n_max), dtype=np.bool_)
    for q in range(n_points):
        count = end[q + 1] - end[q]
        nearest = flat[end[q]] if count > 0 else 0
        for a in range(n_max):
            neighbours[q, a] = flat[end[q] + a] if a < count else nearest
            mask[q, a] = a < count
    return neighbours, mask


# ----------------------------------------------------------------------------- shape functions


def basis_size(degree):
    """Tuple of n_basis zeros: the kernels' compile-time stand-in for the degree.

    numba types a tuple with its length, so ``len(size)`` is a constant inside the
    kernel; it compiles one kernel per degree with the small loops over basis terms
    unrolled (about three times faster than a run-time n_basis).
    """
    return (0.0,) * ((degree + 1) * (degree + 2) // 2)


@_jit
def _basis_row(xi, eta, size, row):
    """Pascal basis [xi^a eta^b], ordered by total degree, into row (n_basis,).

    Powers are repeated products, rounded exactly as mls.pascal_basis rounds them.
    """
    row[0], row[1], row[2] = 1.0, xi, eta
    if len(size) > 3:
        row[3], row[4], row[5] = xi * xi, xi * eta, eta * eta
    if len(size) > 6:
        row[6], row[7] = xi * xi * xi, xi * xi * eta
        row[8], row[9] = xi * (eta * eta), eta * eta * eta


@_jit
def _cholesky(moment, size, factor):
    """Lower-triangular L with L L^T = A into factor; False when a pivot is not positive."""
    n = len(size)
    for j in range(n):
        pivot = moment[j, j]
        for k in range(j):
            pivot -= factor[j, k] * factor[j, k]
        # An exact test, but harmless: a matrix that passes it with a round-off pivot gets
        # an estimate >= 1/eps, which mls.py classifies as singular like a breakdown.
        if not pivot > 0.0:
            return False
        factor[j, j] = np.sqrt(pivot)
        for i in range(j + 1, n):
            entry = moment[i, j]
            for k in range(j):
                entry -= factor[i, k] * factor[j, k]
            factor[i, j] = entry / factor[j, j]
    return True


@_jit
def _inverse(factor, size, inverse):
    """A^-1 from L (L L^T = A) by forward and back substitution of each unit column."""
    n = len(size)
    for column in range(n):
        for i in range(n):  # L y = e_column
            value = 1.0 if i == column else 0.0
            for k in range(i):
                value -= factor[i, k] * inverse[k, column]
            inverse[i, column] = value / factor[i, i]
        for i in range(n - 1, -1, -1):  # L^T z = y
            value = inverse[i, column]
            for k in range(i + 1, n):
                value -= factor[k, i] * inverse[k, column]
            inverse[i, column] = value / factor[i, i]


@_jit
def _frobenius_condition(moment, inverse, size):
    """||A||_F ||A^-1||_F."""
    moment_sum, inverse_sum = 0.0, 0.0
    for i in range(len(size)):
        for j in range(len(size)):
            moment_sum += moment[i, j] * moment[i, j]
            inverse_sum += inverse[i, j] * inverse[i, j]
    return np.sqrt(moment_sum) * np.sqrt(inverse_sum)


@_jit
def _weights(point, nodes, radius, code, neighbours, mask, w, dw):
    """w_I and dw_I/dx at one point into w (n_max,), dw (n_max, 2); return the scale R."""
    scale = 0.0
    for k in range(len(neighbours)):
        w[k], dw[k, 0], dw[k, 1] = 0.0, 0.0, 0.0
        if not mask[k]:
            continue
        node = neighbours[k]
        dx, dy = nodes[node, 0] - point[0], nodes[node, 1] - point[1]  # x_I - x
        distance = np.sqrt(dx * dx + dy * dy)
        w[k], slope = weight_and_slope(code, distance / radius[node])
        if distance > 0.0:
            # dw/dx = W'(r) (x - x_I) / (|x - x_I| d_I)
            dw[k, 0] = -slope / (distance * radius[node]) * dx
            dw[k, 1] = -slope / (distance * radius[node]) * dy
        scale = max(scale, radius[node])
    return scale if scale > 0.0 else 1.0


@_jit
def _moment(point, nodes, neighbours, mask, w, scale, size, basis, moment):
    """Basis rows p_I into basis (n_max, n_basis) and A = sum w_I p_I p_I^T into moment."""
    n_b = len(size)
    for i in range(n_b):
        for j in range(n_b):
            moment[i, j] = 0.0
    for k in range(len(neighbours)):
        if not mask[k]:
            continue
        node = neighbours[k]
        xi, eta = (nodes[node, 0] - point[0]) / scale, (nodes[node, 1] - point[1]) / scale
        _basis_row(xi, eta, size, basis[k])
        for i in range(n_b):  # lower triangle; A is symmetric
            weighted = w[k] * basis[k, i]
            for j in range(i + 1):
                moment[i, j] += weighted * basis[k, j]
    for i in range(n_b):
        for j in range(i):
            moment[j, i] = moment[i, j]


@_jit
def _gradients(inverse, size, basis, mask, w, dw, basis_gamma, scale, dphi_point, rhs):
    """dphi_I/dx_d = (gamma_d^T p_I) w_I + (gamma^T p_I) dw_I/dx_d at one point, d = 0, 1.

    rhs (4, n_basis) is scratch: rows 0-1 the right-hand sides, rows 2-3 gamma_0, gamma_1.
    """
    n_b = len(size)
    # rhs_d = e_{1+d} / R - sum_I dw_I/dx_d (gamma^T p_I) p_I   (= e_{1+d} / R - A_d gamma)
    for i in range(n_b):
        rhs[0, i] = rhs[1, i] = 0.0
    rhs[0, 1] = rhs[1, 2] = 1.0 / scale
    for k in range(basis.shape[0]):
        if mask[k]:
            factor_x, factor_y = dw[k, 0] * basis_gamma[k], dw[k, 1] * basis_gamma[k]
            for i in range(n_b):
                rhs[0, i] -= factor_x * basis[k, i]
                rhs[1, i] -= factor_y * basis[k, i]
    for i in range(n_b):  # gamma_d = A^-1 rhs_d
        rhs[2, i] = rhs[3, i] = 0.0
        for j in range(n_b):
            rhs[2, i] += inverse[i, j] * rhs[0, j]
            rhs[3, i] += inverse[i, j] * rhs[1, j]
    for k in range(basis.shape[0]):
        if mask[k]:
            value_x, value_y = 0.0, 0.0
            for i in range(n_b):
                value_x += rhs[2, i] * basis[k, i]
                value_y += rhs[3, i] * basis[k, i]
            dphi_point[k, 0] = w[k] * value_x + dw[k, 0] * basis_gamma[k]
            dphi_point[k, 1] = w[k] * value_y + dw[k, 1] * basis_gamma[k]


@_jit
def shape_functions(points, nodes, radius, code, size, neighbours, mask, gradients):
    """phi (n, n_max), dphi (n, n_max, 2) (empty unless gradients) and condition (n,).

    ``size`` is :func:`basis_size` of the degree.  Points whose Cholesky factorization
    breaks down get condition inf and phi = 0.
    """
    n_points, n_max = neighbours.shape
    n_b = len(size)
    # Every entry is written below (0 at padding and at rejected points).
    phi = np.empty((n_points, n_max))
    dphi = np.empty((n_points if gradients else 0, n_max, 2))
    condition = np.full(n_points, np.inf)
    # Per-point scratch, reused; rhs holds the right-hand side and gamma_k.
    w, dw, basis = np.empty(n_max), np.empty((n_max, 2)), np.empty((n_max, n_b))
    moment, factor, inverse = np.empty((n_b, n_b)), np.zeros((n_b, n_b)), np.empty((n_b, n_b))
    basis_gamma, rhs = np.zeros(n_max), np.empty((4, n_b))
    for q in range(n_points):
        scale = _weights(points[q], nodes, radius, code, neighbours[q], mask[q], w, dw)
        _moment(points[q], nodes, neighbours[q], mask[q], w, scale, size, basis, moment)
        phi[q, :] = 0.0
        if gradients:
            dphi[q, :, :] = 0.0
        if not _cholesky(moment, size, factor):
            continue
        _inverse(factor, size, inverse)
        condition[q] = _frobenius_condition(moment, inverse, size)
        for k in range(n_max):  # gamma = A^-1 e_0 = column 0 of A^-1
            basis_gamma[k] = 0.0
            if mask[q, k]:
                for i in range(n_b):
                    basis_gamma[k] += basis[k, i] * inverse[i, 0]
                phi[q, k] = w[k] * basis_gamma[k]
        if gradients:
            _gradients(inverse, size, basis, mask[q], w, dw, basis_gamma, scale, dphi[q], rhs)
    return phi, dphi, condition
