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

The points go through these steps LANES at a time, the small dense algebra (2.-4.) in
loops over the lanes, innermost, on scratch kept on the stack, which LLVM vectorizes; per
point the operations and their order are those of one point alone, and of the numpy
backend's, so no result depends on the grouping.

Nothing here is collective.  numba compiles on first use and caches the
machine code next to this file (``cache=True``), so only the first process
after an edit pays the compilation; ``make setup`` also compiles the kernels
called from Python ahead of time, which runs call through :mod:`.aot`
without importing numba.
"""

import numpy as np

from parefg.discretization.weights import WEIGHTS, weight_pair

try:
    import llvmlite.ir
    import numba
    from numba.core import cgutils
    from numba.extending import intrinsic
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


def _inlined(function):
    """_jit, inlined into its caller by numba: the caller's stack scratch stays unaliased."""
    if numba is None:  # pragma: no cover
        return function
    return numba.njit(cache=True, fastmath=False, nogil=True, error_model="numpy", inline="always")(
        function
    )


# (W(r), dW/dr) of the weight with the given code (Weight.code); both 0 for r >= 1.
weight_and_slope = _jit(weight_pair)


# Points evaluated together, one per SIMD lane (8 doubles fill an AVX-512 register, two
# AVX2 ones): see the module docstring.
LANES = 8

if numba is not None:

    @intrinsic
    def _lane_scratch(typing_context, rows, columns):
        """Pointer to rows x columns x LANES float64 on the caller's stack.

        rows and columns are compile-time: an integer literal or a tuple (its length, as
        :func:`basis_size`).  Scratch on the stack rather than np.empty: LLVM then knows
        that it aliases none of the heap arrays the loops read, which is what lets it
        vectorize a loop that stores into it.  Call it only in the function that uses the
        scratch: the memory lives as long as that function's frame.
        """

        def length(kind):
            return kind.count if isinstance(kind, numba.types.BaseTuple) else kind.literal_value

        count = length(rows) * length(columns) * LANES

        def codegen(context, builder, signature, args):
            return cgutils.alloca_once(builder, llvmlite.ir.DoubleType(), size=count)

        return numba.types.CPointer(numba.types.float64)(rows, columns), codegen


# ----------------------------------------------------------------------------- neighbour search


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


@_inlined
def _lane_basis(offset, k, size, row):
    """The Pascal basis rows p(offset[k, :, b]) of all lanes into row (n_basis, 1, LANES).

    Powers are repeated products, rounded exactly as mls.pascal_basis rounds them.
    """
    for b in range(LANES):
        xi, eta = offset[k, 0, b], offset[k, 1, b]
        row[0, 0, b], row[1, 0, b], row[2, 0, b] = 1.0, xi, eta
        if len(size) > 3:
            row[3, 0, b], row[4, 0, b], row[5, 0, b] = xi * xi, xi * eta, eta * eta
        if len(size) > 6:
            row[6, 0, b], row[7, 0, b] = xi * xi * xi, xi * xi * eta
            row[8, 0, b], row[9, 0, b] = xi * (eta * eta), eta * eta * eta


@_jit
def _lane_group(points, nodes, radius, code, size, neighbours, mask, gradients, first, scratch):
    """phi, dphi and condition of the points first .. first + LANES - 1 into the outputs.

    One function, steps 1.-4. of the module docstring in sequence, lane b holding point
    first + b (lanes past the last point repeat it).  It is not split into functions on
    purpose: the heap arrays must come in as arguments and the small matrices must live
    on this function's stack for LLVM to vectorize the lane loops, and numba's inlining of
    helpers that would keep both true compiles ~10x slower (a minute per degree).
    """
    w, dw, offset, basis_gamma, lane_phi, lane_dphi, phi, dphi, condition = scratch
    n_points, n_max = neighbours.shape
    n_b = len(size)
    moment = numba.carray(_lane_scratch(size, size), (n_b, n_b, LANES))
    factor = numba.carray(_lane_scratch(size, size), (n_b, n_b, LANES))
    inverse = numba.carray(_lane_scratch(size, size), (n_b, n_b, LANES))
    rhs = numba.carray(_lane_scratch(2, size), (2, n_b, LANES))
    gamma_d = numba.carray(_lane_scratch(2, size), (2, n_b, LANES))
    row = numba.carray(_lane_scratch(size, 1), (n_b, 1, LANES))
    sums = numba.carray(_lane_scratch(2, 1), (2, 1, LANES))
    valid = numba.carray(_lane_scratch(1, 1), (1, 1, LANES))  # 1.0 / 0.0: A factored
    inverse_scale = numba.carray(_lane_scratch(1, 1), (1, 1, LANES))  # 1 / R

    # 1. w_I, dw_I/dx and the scaled offsets (x_I - x) / R, lane by lane (a gather per
    # neighbour, scalar).  0 at padding; padding offsets keep earlier, finite, values, so
    # the sums over all rows below add exact zeros for them.  The basis rows p_I =
    # p(offset_I) are recomputed in each loop that needs them: cheaper than storing them.
    for b in range(LANES):
        q = min(first + b, n_points - 1)
        scale = 0.0  # R: the largest covering radius (1 where none covers)
        for k in range(n_max):
            if mask[q, k]:
                scale = max(scale, radius[neighbours[q, k]])
        scale = scale if scale > 0.0 else 1.0
        for k in range(n_max):
            w[k, b], dw[k, 0, b], dw[k, 1, b] = 0.0, 0.0, 0.0
            if not mask[q, k]:
                continue
            node = neighbours[q, k]
            dx, dy = nodes[node, 0] - points[q, 0], nodes[node, 1] - points[q, 1]  # x_I - x
            distance = np.sqrt(dx * dx + dy * dy)
            w[k, b], slope = weight_and_slope(code, distance / radius[node])
            if distance > 0.0:
                # dw/dx = W'(r) (x - x_I) / (|x - x_I| d_I)
                dw[k, 0, b] = -slope / (distance * radius[node]) * dx
                dw[k, 1, b] = -slope / (distance * radius[node]) * dy
            offset[k, 0, b], offset[k, 1, b] = dx / scale, dy / scale
        inverse_scale[0, 0, b] = 1.0 / scale  # for the gradients

    # 2. A = sum_I w_I p_I p_I^T, summed in list order (lower triangle; A is symmetric).
    for i in range(n_b):
        for j in range(i + 1):
            for b in range(LANES):
                moment[i, j, b] = 0.0
    for k in range(n_max):
        _lane_basis(offset, k, size, row)
        for i in range(n_b):
            for j in range(i + 1):
                for b in range(LANES):
                    moment[i, j, b] += w[k, b] * row[i, 0, b] * row[j, 0, b]
    for i in range(n_b):
        for j in range(i):
            for b in range(LANES):
                moment[j, i, b] = moment[i, j, b]

    # 3. A = L L^T.  A lane whose pivot is not positive goes on with pivot 1 (its results
    # are discarded), as MLS._invert does, so no NaN enters the vectorized loops.  The
    # test is exact, but harmless: a matrix that passes it with a round-off pivot gets an
    # estimate >= 1/eps, which mls.py classifies as singular.
    for b in range(LANES):
        valid[0, 0, b] = 1.0
    for j in range(n_b):
        for b in range(LANES):
            factor[j, j, b] = moment[j, j, b]  # the pivot, reduced below
        for k in range(j):
            for b in range(LANES):
                factor[j, j, b] -= factor[j, k, b] * factor[j, k, b]
        for b in range(LANES):
            positive = factor[j, j, b] > 0.0
            valid[0, 0, b] = valid[0, 0, b] if positive else 0.0
            factor[j, j, b] = np.sqrt(factor[j, j, b] if positive else 1.0)
        for i in range(j + 1, n_b):
            for b in range(LANES):
                factor[i, j, b] = moment[i, j, b]
            for k in range(j):
                for b in range(LANES):
                    factor[i, j, b] -= factor[i, k, b] * factor[j, k, b]
            for b in range(LANES):
                factor[i, j, b] = factor[i, j, b] / factor[j, j, b]
    # A^-1 by forward and back substitution of each unit column.
    for column in range(n_b):
        for i in range(n_b):  # L y = e_column
            for b in range(LANES):
                inverse[i, column, b] = 1.0 if i == column else 0.0
            for k in range(i):
                for b in range(LANES):
                    inverse[i, column, b] -= factor[i, k, b] * inverse[k, column, b]
            for b in range(LANES):
                inverse[i, column, b] = inverse[i, column, b] / factor[i, i, b]
        for i in range(n_b - 1, -1, -1):  # L^T z = y
            for k in range(i + 1, n_b):
                for b in range(LANES):
                    inverse[i, column, b] -= factor[k, i, b] * inverse[k, column, b]
            for b in range(LANES):
                inverse[i, column, b] = inverse[i, column, b] / factor[i, i, b]
    # The condition estimate ||A||_F ||A^-1||_F (inf where the factorization broke down).
    for b in range(LANES):
        sums[0, 0, b] = sums[1, 0, b] = 0.0
    for i in range(n_b):
        for j in range(n_b):
            for b in range(LANES):
                sums[0, 0, b] += moment[i, j, b] * moment[i, j, b]
                sums[1, 0, b] += inverse[i, j, b] * inverse[i, j, b]
    for b in range(min(LANES, n_points - first)):
        estimate = np.sqrt(sums[0, 0, b]) * np.sqrt(sums[1, 0, b])
        condition[first + b] = estimate if valid[0, 0, b] > 0.0 else np.inf

    # 4. phi_I = (gamma^T p_I) w_I with gamma = A^-1 e_0 (column 0 of A^-1) and, for the
    # gradients, rhs_d = e_{1+d} / R - sum_I dw_I/dx_d (gamma^T p_I) p_I (= e_{1+d} / R -
    # A_d gamma, without forming A_d).  Sums go to stack scratch first and are then copied
    # to the heap rows: a loop that stores into heap arrays it reads does not vectorize.
    for d in range(2):
        for i in range(n_b):
            for b in range(LANES):
                rhs[d, i, b] = 0.0
    for b in range(LANES):
        rhs[0, 1, b] = rhs[1, 2, b] = inverse_scale[0, 0, b]
    for k in range(n_max):
        _lane_basis(offset, k, size, row)
        for b in range(LANES):
            sums[0, 0, b] = 0.0
        for i in range(n_b):
            for b in range(LANES):
                sums[0, 0, b] += row[i, 0, b] * inverse[i, 0, b]
        for b in range(LANES):
            basis_gamma[k, b] = sums[0, 0, b]
            lane_phi[k, b] = w[k, b] * sums[0, 0, b]
        for d in range(2):
            for i in range(n_b):
                for b in range(LANES):
                    rhs[d, i, b] -= dw[k, d, b] * sums[0, 0, b] * row[i, 0, b]
    if gradients:
        # dphi_I/dx_d = (gamma_d^T p_I) w_I + (gamma^T p_I) dw_I/dx_d, gamma_d = A^-1 rhs_d.
        for d in range(2):
            for i in range(n_b):
                for b in range(LANES):
                    gamma_d[d, i, b] = 0.0
                for j in range(n_b):
                    for b in range(LANES):
                        gamma_d[d, i, b] += inverse[i, j, b] * rhs[d, j, b]
        for k in range(n_max):
            _lane_basis(offset, k, size, row)
            for d in range(2):
                for b in range(LANES):
                    sums[d, 0, b] = 0.0
                for i in range(n_b):
                    for b in range(LANES):
                        sums[d, 0, b] += gamma_d[d, i, b] * row[i, 0, b]
            for d in range(2):
                for b in range(LANES):
                    lane_dphi[k, d, b] = w[k, b] * sums[d, 0, b] + dw[k, d, b] * basis_gamma[k, b]

    for b in range(min(LANES, n_points - first)):
        q = first + b
        if valid[0, 0, b] == 0.0:
            continue  # phi, dphi stay 0
        for k in range(n_max):
            if mask[q, k]:  # padding: phi, dphi stay 0
                phi[q, k] = lane_phi[k, b]
                if gradients:
                    dphi[q, k, 0], dphi[q, k, 1] = lane_dphi[k, 0, b], lane_dphi[k, 1, b]


@_jit
def shape_functions(points, nodes, radius, code, size, neighbours, mask, gradients):
    """phi (n, n_max), dphi (n, n_max, 2) (empty unless gradients) and condition (n,).

    ``size`` is :func:`basis_size` of the degree.  Points whose Cholesky factorization
    breaks down get condition inf and phi = 0.  The points go through the kernel LANES
    at a time (:func:`_lane_group`).
    """
    n_points, n_max = neighbours.shape
    phi = np.zeros((n_points, n_max))  # 0 at padding and at rejected points
    dphi = np.zeros((n_points if gradients else 0, n_max, 2))
    condition = np.full(n_points, np.inf)
    # Per-group scratch on the heap, lane last.
    scratch = (
        np.empty((n_max, LANES)),  # w
        np.empty((n_max, 2, LANES)),  # dw
        np.zeros((n_max, 2, LANES)),  # offset (finite from the start)
        np.empty((n_max, LANES)),  # basis_gamma
        np.empty((n_max, LANES)),  # phi
        np.empty((n_max, 2, LANES)),  # dphi
        phi,
        dphi,
        condition,
    )
    for first in range(0, n_points, LANES):
        _lane_group(points, nodes, radius, code, size, neighbours, mask, gradients, first, scratch)
    return phi, dphi, condition
