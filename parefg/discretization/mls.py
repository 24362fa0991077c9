"""Moving least-squares (MLS) shape functions and their analytic gradients (SPEC 2).

For an evaluation point x with neighbours I (the nodes whose support covers x,
|x - x_I| < d_I) the MLS shape functions are

    phi_I(x) = p(0)^T A(x)^-1 w_I(x) p_I,    A(x) = sum_I w_I(x) p_I p_I^T,

with w_I(x) = W(|x - x_I| / d_I) and p_I = p((x_I - x) / R) the complete Pascal
basis of degree m, shifted to x and scaled by R (the largest support radius
among the neighbours of x) so that A is well conditioned at any length scale.

Gradients are analytic.  MLS is invariant under an affine change of the
polynomial basis, so the shift centre c may be frozen at c = x while
differentiating: with p_c(y) = p((y - c) / R),

    gamma = A^-1 p(0),   A gamma_k = dp/dxi_k(0) / R - A_k gamma,
    A_k = sum_I dw_I/dx_k p_I p_I^T,
    dphi_I/dx_k = (gamma_k^T p_I) w_I + (gamma^T p_I) dw_I/dx_k.

Two interchangeable backends compute the same numbers (see :data:`BACKENDS`):
``"numba"`` runs the compiled per-point kernels of :mod:`parefg.discretization.mls_kernels`
(Cholesky of A); ``"numpy"`` is vectorized over points (padded neighbour lists,
batched dense linear algebra), serves as the reference and is the default of small
problems, which it spares numba's start-up (:mod:`parefg.discretization.backends`), and
the fallback when numba or a compiled weight is missing.  The neighbour lists come from
:mod:`parefg.discretization.neighbours` (cell list or k-d tree, the same lists).
"""

import math
from dataclasses import dataclass

import numpy as np

from parefg.discretization import backends
from parefg.discretization.neighbours import NeighbourSearch, RegionSearch
from parefg.discretization.weights import DEFAULT_WEIGHT, get_weight
from parefg.errors import InputError
from parefg.geometry.cloud import DIM

# Dilations beyond this are advised down, not up, when A(x) is singular with enough neighbours.
LARGE_SUPPORT = 20.0
# Moment matrices less well conditioned than this are rejected.
MAX_CONDITION = 1e12
# Rejected matrices whose condition estimate exceeds this are reported as singular.  Both
# backends share it, so the verdict does not depend on round-off: an exactly singular A
# comes out of either factorization (LU, Cholesky, any SIMD path) with an estimate >= 4e16
# or a breakdown (inf), while an estimate below 1e14 is accurate to kappa eps < 2 %.
SINGULAR_CONDITION = 1e14
# Points per batch of the numpy backend's dense linear algebra (a few MB per array): batches
# that stay in cache and reuse the same memory are ~3x faster in a fresh process than
# 20000-point ones, which fault in tens of MB per temporary (default scene: mls 0.32 -> 0.10 s).
CHUNK_POINTS = 2048
# Backends by name; the default is the first one usable for the chosen weight.
BACKENDS = ("numba", "numpy")


class MLSError(InputError):
    """A point whose moment matrix A(x) is singular or badly conditioned."""


@dataclass
class ShapeValues:
    """MLS shape functions at a set of points, on padded neighbour lists.

    Attributes
    ----------
    neighbours : ndarray of int64, shape (n_points, n_max)
        Node indices; padding entries hold a valid index with mask False.
    mask : ndarray of bool, shape (n_points, n_max)
        True where the node's support covers the point.
    phi : ndarray, shape (n_points, n_max)
        Shape function values, 0 at padding.
    dphi : ndarray, shape (n_points, n_max, 2), or None
        Shape function gradients, 0 at padding; None when not requested.
    condition : ndarray, shape (n_points,)
        Condition number of the scaled moment matrix A(x): ||A||_F ||A^-1||_F, an upper
        bound of the 2-norm condition number that exceeds it by at most a factor n_basis.
    """

    neighbours: np.ndarray
    mask: np.ndarray
    phi: np.ndarray
    dphi: np.ndarray | None
    condition: np.ndarray


def n_basis(degree: int, dim: int = 2) -> int:
    """Number of Pascal monomials of total degree <= m in d dimensions: C(m + d, d)."""
    return math.comb(degree + dim, dim)


def _compositions(total: int, dim: int):
    """Exponent tuples of ``dim`` entries summing to ``total``, the first entry descending."""
    if dim == 1:
        yield (total,)
        return
    for first in range(total, -1, -1):
        for rest in _compositions(total - first, dim - 1):
            yield (first, *rest)


def basis_exponents(degree: int, dim: int = 2) -> np.ndarray:
    """Exponents of the monomials of total degree <= m, ordered by total degree.

    Within one total degree the first exponent descends: in 2D the rows are (a, b) of
    xi^a eta^b, row 0 is (0, 0), rows 1 and 2 are (1, 0) and (0, 1), then degree 2, ...

    Returns
    -------
    ndarray of int, shape (n_basis, dim)
    """
    rows = [row for total in range(degree + 1) for row in _compositions(total, dim)]
    return np.array(rows, dtype=int).reshape(-1, dim)


def basis_size(degree):
    """Tuple of n_basis zeros: the kernels' compile-time stand-in for the degree.

    numba types a tuple with its length, so ``len(size)`` is a constant inside the
    kernel; it compiles one kernel per degree with the small loops over basis terms
    unrolled (about three times faster than a run-time n_basis).
    """
    return (0.0,) * ((degree + 1) * (degree + 2) // 2)


def pascal_basis(xi: np.ndarray, degree: int) -> np.ndarray:
    """Complete Pascal basis p(xi) = [prod_k xi_k^(a_k)], sum a_k <= m, for xi of shape (..., d).

    Returns
    -------
    ndarray, shape (..., n_basis(degree, d))
    """
    dim = xi.shape[-1]
    exponents = basis_exponents(degree, dim)
    # Powers xi_k^0..xi_k^m by repeated products (cheaper than **), [axis][power] (...,).
    powers = []
    for axis in range(dim):
        coordinate = xi[..., axis]
        powers.append([np.ones(xi.shape[:-1]), coordinate])
        for power in range(2, degree + 1):
            powers[axis].append(powers[axis][power - 1] * coordinate)
    # Column j = prod_k xi_k^(a_jk), multiplied in axis order; one column at a time (a
    # gather of the powers along the last axis costs several times more).
    basis = np.empty((*xi.shape[:-1], len(exponents)))
    for j, row in enumerate(exponents):
        column = powers[0][row[0]]
        for axis in range(1, dim):
            column = column * powers[axis][row[axis]]
        basis[..., j] = column
    return basis


class MLS:
    """MLS shape functions of one node cloud (not collective: each rank evaluates its own points).

    Parameters
    ----------
    nodes : array_like, shape (n_nodes, 2)
        Node coordinates x_I.
    support_radius : array_like, shape (n_nodes,) or scalar
        Support radius d_I of each node (dilation s times local spacing c_I).
    degree : int
        Degree m of the Pascal basis: 1, 2 or 3.
    weight : str
        Name of a registered weight (see :data:`parefg.discretization.weights.WEIGHTS`).
    support_factor : float, optional
        The dilation s, only quoted in error messages.
    backend : {"numba", "numpy"}, optional
        How to compute (see :data:`BACKENDS`); by default numba for large problems when
        it is installed and knows the weight, else numpy
        (:func:`parefg.discretization.backends.choose`).
    region : array_like, shape (2, 2), optional
        Lower and upper corners of the box the evaluation points are expected in (a
        rank's part): the neighbour search then holds only the nodes that reach it
        (:class:`~parefg.discretization.neighbours.RegionSearch`; the same lists, points
        elsewhere grow it).  By default it holds every node.
    node_ids : array_like of int, shape (n_nodes,), optional
        The global number of each node, ascending, where ``nodes`` are only some of the
        cloud's (a rank's own and ghost nodes, :mod:`parefg.discretization.ghosts`):
        ``region`` must then hold every point evaluated.  Neighbour lists always hold
        positions in ``nodes``.  None: ``nodes`` are the whole cloud.
    n_global : int, optional
        The cloud's node count, by which the default backend is chosen, the same on
        every rank (default: len(nodes)).
    """

    def __init__(
        self,
        nodes,
        support_radius,
        degree: int,
        weight: str = DEFAULT_WEIGHT,
        support_factor: float | None = None,
        backend: str | None = None,
        region=None,
        node_ids=None,
        n_global: int | None = None,
    ):
        if degree not in (1, 2, 3):
            raise InputError(f"discretization.degree: must be 1, 2 or 3, got {degree!r}")
        self.nodes = np.ascontiguousarray(nodes, dtype=float).reshape(-1, DIM)  # (n_nodes, d)
        self.support_radius = np.broadcast_to(
            np.asarray(support_radius, dtype=float), (len(self.nodes),)
        ).copy()  # (n_nodes,)
        if len(self.nodes) == 0 or not np.all(self.support_radius > 0):
            raise InputError("MLS needs at least one node and positive support radii")
        self.degree = int(degree)
        self.n_basis = n_basis(self.degree)
        self.weight = get_weight(weight)
        self.support_factor = support_factor
        self.node_ids = None if node_ids is None else np.asarray(node_ids, dtype=np.int64)
        if self.node_ids is not None and region is None:
            raise ValueError("MLS of some of the nodes needs the region of its points")
        self.n_global = len(self.nodes) if n_global is None else int(n_global)
        self.backend = self._choose_backend(backend)
        self.search: NeighbourSearch | RegionSearch = (
            NeighbourSearch(self.nodes, self.support_radius, self.backend)
            if region is None
            else RegionSearch(
                self.nodes,
                self.support_radius,
                self.backend,
                region,
                complete=self.node_ids is None,
            )
        )

    def global_ids(self, positions: np.ndarray) -> np.ndarray:
        """The global node numbers of ``positions`` in ``nodes`` (neighbour-list entries)."""
        positions = np.asarray(positions, dtype=np.int64)
        return positions if self.node_ids is None else self.node_ids[positions]

    def _choose_backend(self, backend):
        """The backend to use: the requested one, or the one of :func:`backends.choose`."""
        compiled = backends.numba_installed() and self.weight.code is not None
        if backend is None:
            return backends.choose(self.n_global, compiled)
        if backend not in BACKENDS:
            raise InputError(f"MLS backend must be one of {BACKENDS}, got {backend!r}")
        if backend == "numba" and not compiled:
            raise InputError(f"MLS backend 'numba' is unavailable for weight {self.weight.name!r}")
        return backend

    def evaluate(self, points: np.ndarray, gradients: bool = True, neighbours=None) -> ShapeValues:
        """Shape functions (and gradients) at ``points`` of shape (n_points, 2). Not collective.

        ``neighbours`` may pass the (neighbours, mask) of :meth:`find_neighbours` for these
        points (so that the search can be timed on its own); by default it is computed here.

        Raises
        ------
        MLSError
            At the first point whose moment matrix has fewer neighbours than basis
            terms or a condition number above ``MAX_CONDITION``.
        """
        points = np.ascontiguousarray(points, dtype=float).reshape(-1, DIM)  # (n_points, d)
        neighbours, mask = self.find_neighbours(points) if neighbours is None else neighbours
        if self.backend == "numba":
            return self._evaluate_compiled(points, neighbours, mask, gradients)
        phi = np.zeros(neighbours.shape)  # (n_points, n_max)
        dphi = np.zeros((*neighbours.shape, DIM)) if gradients else None  # (n_points, n_max, d)
        condition = np.zeros(len(points))  # (n_points,)
        for start in range(0, len(points), CHUNK_POINTS):
            chunk = slice(start, start + CHUNK_POINTS)
            phi[chunk], chunk_dphi, condition[chunk] = self._evaluate_chunk(
                points[chunk], neighbours[chunk], mask[chunk], gradients
            )
            if dphi is not None:
                dphi[chunk] = chunk_dphi
        return ShapeValues(neighbours, mask, phi, dphi, condition)

    def find_neighbours(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Padded lists of the nodes I with |x - x_I| < d_I, nearest first.

        See :meth:`parefg.discretization.neighbours.NeighbourSearch.find`.

        Returns
        -------
        neighbours : ndarray of int64, shape (n_points, n_max)
        mask : ndarray of bool, shape (n_points, n_max)
        """
        return self.search.find(points)

    def _weights(self, points, neighbours, mask):
        """Weights w_I(x), their gradients dw_I/dx, offsets x_I - x and the basis scale R."""
        # x_I - x, (n, n_max, 2), one coordinate at a time: two gathers from 1-D arrays
        # cost a fifth of one gather of (x, y) rows
        offset = np.empty((*neighbours.shape, DIM))
        for axis in range(DIM):
            coordinate = np.take(self.nodes[:, axis], neighbours)
            np.subtract(coordinate, points[:, axis, None], out=offset[..., axis])
        distance = np.sqrt(np.einsum("nkd,nkd->nk", offset, offset))  # (n, n_max)
        radius = self.support_radius[neighbours]  # (n, n_max)
        r = distance / radius
        w = np.where(mask, self.weight.value(r), 0.0)  # (n, n_max)
        # dw/dx = W'(r) dr/dx with dr/dx = (x - x_I) / (|x - x_I| d_I); W'(0) = 0 at r = 0.
        slope = np.where(mask, self.weight.derivative(r), 0.0)
        safe_distance = np.where(distance > 0.0, distance, 1.0)
        dw = (-slope / (safe_distance * radius))[..., None] * offset  # (n, n_max, 2)
        scale = np.max(np.where(mask, radius, 0.0), axis=1)  # (n,) R
        return w, dw, offset, np.where(scale > 0.0, scale, 1.0)

    def _check_conditioning(self, points, mask, condition):
        """Raise MLSError at the first point with too few neighbours or an ill-conditioned A."""
        counts = mask.sum(axis=1)
        bad = (counts < self.n_basis) | ~(condition <= MAX_CONDITION)
        if not bad.any():
            return
        i = int(np.argmax(bad))
        x, y = points[i]
        if counts[i] < self.n_basis or not condition[i] <= SINGULAR_CONDITION:
            problem = "singular"
        else:
            # One significant digit: the estimate is only accurate to kappa eps.
            problem = (
                f"badly conditioned (condition number {condition[i]:.0e} > {MAX_CONDITION:.0e})"
            )
        now = "" if self.support_factor is None else f" (now {self.support_factor:g})"
        advice = f"increase discretization.support{now}"
        huge = self.support_factor is not None and self.support_factor > LARGE_SUPPORT
        if huge and counts[i] >= self.n_basis:
            # Enough neighbours, but the scaled basis p((x_I - x) / r) is ~ (c / r)^m small:
            # a far larger support only loses digits.
            advice = (
                f"decrease discretization.support{now}: supports far wider than the node "
                "spacing leave A(x) without significant digits (2 to 4 is typical)"
            )
        raise MLSError(
            f"MLS moment matrix {problem} at point ({x:.6g}, {y:.6g}): {counts[i]} neighbours "
            f"for {self.n_basis} basis functions (degree {self.degree}); {advice}"
        )

    @staticmethod
    def _invert(moment):
        """A^-1 (n, n_basis, n_basis) and the condition estimate ||A||_F ||A^-1||_F (n,).

        The Frobenius estimate bounds the 2-norm condition number from above, by at
        most a factor n_basis, at the price of the inverse that is needed anyway.  As the
        numba kernel (step 3 of mls_kernels._lane_group, the same
        operations in the same order), vectorized over the points: A = L L^T by Cholesky,
        A^-1 column by column by forward and back substitution.  A matrix whose Cholesky
        breaks down (a pivot not positive) gets an infinite condition (singular) and an
        unspecified inverse, without changing the other matrices' results.  (np.linalg.inv
        calls LAPACK once per 6 x 6 matrix, ~10 us each: most of a small run's MLS time.)
        """
        n_basis = moment.shape[1]
        entries = moment.transpose(1, 2, 0)  # (n_basis, n_basis, n): [i][j] a vector over points
        factor = [[np.zeros(0)] * n_basis for _ in range(n_basis)]  # lower triangle used
        valid = np.ones(len(moment), dtype=bool)
        for j in range(n_basis):
            pivot = entries[j, j].copy()
            for k in range(j):
                pivot -= factor[j][k] * factor[j][k]
            valid &= pivot > 0.0
            factor[j][j] = np.sqrt(np.where(valid, pivot, 1.0))  # broken rows: any value
            for i in range(j + 1, n_basis):
                entry = entries[i, j].copy()
                for k in range(j):
                    entry -= factor[i][k] * factor[j][k]
                factor[i][j] = entry / factor[j][j]
        inverse = np.empty((n_basis, n_basis, len(moment)))
        for column in range(n_basis):
            for i in range(n_basis):  # L y = e_column
                value = np.full(len(moment), 1.0 if i == column else 0.0)
                for k in range(i):
                    value -= factor[i][k] * inverse[k, column]
                inverse[i, column] = value / factor[i][i]
            for i in range(n_basis - 1, -1, -1):  # L^T z = y
                value = inverse[i, column].copy()
                for k in range(i + 1, n_basis):
                    value -= factor[k][i] * inverse[k, column]
                inverse[i, column] = value / factor[i][i]
        moment_sum, inverse_sum = np.zeros(len(moment)), np.zeros(len(moment))
        for i in range(n_basis):
            for j in range(n_basis):
                moment_sum += entries[i, j] * entries[i, j]
                inverse_sum += inverse[i, j] * inverse[i, j]
        condition = np.where(valid, np.sqrt(moment_sum) * np.sqrt(inverse_sum), np.inf)
        return np.ascontiguousarray(inverse.transpose(2, 0, 1)), condition

    def _evaluate_compiled(self, points, neighbours, mask, gradients):
        """:meth:`evaluate` by the numba kernel, all points at once.

        Errors are raised as the chunked numpy path raises them: in the first chunk
        holding a bad point, neighbour counts before condition numbers.
        """
        from parefg.discretization import aot

        phi, dphi, condition = aot.kernels("mls_kernels").shape_functions(
            points,
            self.nodes,
            self.support_radius,
            self.weight.code,
            basis_size(self.degree),
            neighbours,
            mask,
            gradients,
        )
        bad = (mask.sum(axis=1) < self.n_basis) | ~(condition <= MAX_CONDITION)
        if bad.any():
            start = int(np.argmax(bad)) // CHUNK_POINTS * CHUNK_POINTS
            chunk = slice(start, start + CHUNK_POINTS)
            self._check_conditioning(points[chunk], mask[chunk], np.zeros(len(points[chunk])))
            self._check_conditioning(points[chunk], mask[chunk], condition[chunk])
        return ShapeValues(neighbours, mask, phi, dphi if gradients else None, condition)

    def _evaluate_chunk(self, points, neighbours, mask, gradients):
        """phi (n, n_max), dphi (n, n_max, 2) or None and condition (n,) for one chunk of points.

        The numpy backend: vectorized over points with batched dense linear algebra.
        """
        w, dw, offset, scale = self._weights(points, neighbours, mask)
        basis = pascal_basis(offset / scale[:, None, None], self.degree)  # (n, n_max, n_basis)
        basis_t = basis.transpose(0, 2, 1)  # (n, n_basis, n_max)
        moment = (basis_t * w[:, None, :]) @ basis  # (n, n_basis, n_basis) A
        self._check_conditioning(points, mask, np.zeros(len(points)))  # neighbour counts first
        inverse, condition = self._invert(moment)
        self._check_conditioning(points, mask, condition)

        gamma = inverse[:, :, 0]  # (n, n_basis): A^-1 p(0), p(0) = e_0
        basis_gamma = np.einsum("nki,ni->nk", basis, gamma)  # (n, n_max): gamma^T p_I
        phi = w * basis_gamma
        if not gradients:
            return phi, None, condition
        dphi = np.empty((*phi.shape, DIM))  # (n, n_max, d)
        for k in range(DIM):
            moment_k = (basis_t * dw[:, None, :, k]) @ basis  # (n, n_basis, n_basis) A_k
            # A gamma_k = dp/dxi_k(0) / R - A_k gamma; dp/dxi_k(0) = e_{1+k}.
            rhs = -np.einsum("nij,nj->ni", moment_k, gamma)
            rhs[:, 1 + k] += 1.0 / scale
            gamma_k = np.einsum("nij,nj->ni", inverse, rhs)  # (n, n_basis)
            dphi[..., k] = w * np.einsum("nki,ni->nk", basis, gamma_k) + dw[..., k] * basis_gamma
        return phi, dphi, condition
