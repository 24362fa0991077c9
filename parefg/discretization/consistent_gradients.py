"""Variationally consistent integration (VCI) of the stiffness: corrected shape gradients.

Why: Gauss rules on background cells integrate the rational MLS shape functions inexactly,
so the discrete stiffness misses the integration by parts that a Galerkin method of degree
m relies on.  On a grid of squares the error is small; on unstructured cells (user
polygons, the Z) it limits the convergence at m >= 2 (m = 3, h = 1/16: H1 7.1e-5 against
4.8e-6 on the grid, README accuracy section).  Chen, Hillman and Rueter (2013, Int. J.
Numer. Meth. Engng 95, "An arbitrary order variationally consistent integration for
Galerkin meshfree methods") restore it by correcting each node's gradient,

    g_I(x) = grad phi_I(x) + sum_c xi_{I,c} p_c((x - x_I) / R_I),   p a basis of P_{m-1},

with the coefficients xi_I (one per gradient component a and basis function c) chosen so
that the quadrature itself satisfies the divergence theorem against every p in P_{m-1}:

    sum_q w_q g_{I,a} p = sum_b w_b phi_I p n_a - sum_q w_q phi_I d_a p,

the sums over the domain's Gauss points q and the boundary's Gauss points b in I's
support.  That is one small system per node, G_I xi_{I,a} = r_{I,a} with
G_I = sum_q w_q p p^T.  The corrected gradients replace grad phi in the test slot of the
stiffness only, K_IJ = sum_q w_q g_I : C grad phi_J (Petrov-Galerkin, as in the paper):
then for u in P_m, which MLS reproduces, row I of K u equals the boundary and body-force
terms of the same quadrature exactly, so the discrete problem passes the patch test of
degree m.  Correcting both slots keeps K symmetric but loses that (grad of u_h is then
no longer exact for u in P_m): measured, it stalls the L2 error at h = 1/32 (square,
m = 2: 5.0e-6 against 5.1e-7 with Gauss).  K is therefore not symmetric: the runs use LU
(the direct solver's default), and refuse CG.  The mass matrix, the loads, the boundary
terms and every output use the MLS gradients themselves.

The sums of a node collect points of every rank whose cells its support reaches:
:func:`node_corrections` adds them in a PETSc vector owned by the node's rank, which
solves G_I xi_I = r_I and sends xi_I to the ranks that use it.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from petsc4py import PETSc

from parefg.discretization.mls import ShapeValues, basis_exponents
from parefg.errors import InputError

# Padded (point, neighbour) entries per chunk of the sums: bounds their basis arrays.
CHUNK_ENTRIES = 1 << 17


def _local_basis(offsets: np.ndarray, radius: np.ndarray, degree: int):
    """p((x - x_I) / R_I) and its x-gradient for offsets x - x_I of shape (n, 2).

    Returns (n, n_p) values and (n, n_p, 2) gradients of the Pascal basis of ``degree``.
    """
    exponents = basis_exponents(degree)  # (n_p, 2)
    scaled = offsets / radius[:, None]  # (n, 2)
    # powers[k][:, e] = scaled_k^e by repeated products (float ** is ~20x slower)
    powers = np.ones((2, len(scaled), degree + 1))
    for power in range(1, degree + 1):
        powers[:, :, power] = powers[:, :, power - 1] * scaled.T
    x_power, y_power = powers[0][:, exponents[:, 0]], powers[1][:, exponents[:, 1]]
    lowered = np.maximum(exponents - 1, 0)
    gradients = np.empty((len(scaled), len(exponents), 2))
    gradients[..., 0] = exponents[:, 0] * powers[0][:, lowered[:, 0]] * y_power
    gradients[..., 1] = exponents[:, 1] * x_power * powers[1][:, lowered[:, 1]]
    return x_power * y_power, gradients / radius[:, None, None]


def _kernels():
    """The compiled kernels: ahead of time where installed, else numba's JIT (imported on
    first use: numba's import costs ~0.2 s)."""
    from parefg.discretization import aot

    return aot.kernels("consistent_kernels")


def _entries(shape: ShapeValues, start: int, stop: int):
    """(point, neighbour) rows and nodes of the support entries of points start:stop."""
    point, slot = np.nonzero(shape.mask[start:stop])
    point += start
    return point, slot, shape.neighbours[point, slot]


class ConsistencySums:
    """This rank's terms of G_I and r_I (module docstring), by node.  Not collective.

    ``moments[I]`` holds G_I (n_p x n_p) and ``rhs[I]`` r_I (2 x n_p) for the nodes this
    rank's points reach (``touched``); other rows stay zero.
    """

    def __init__(self, nodes: np.ndarray, radius: np.ndarray, degree: int, compiled: bool):
        self.nodes, self.radius, self.compiled = nodes, radius, compiled
        self.degree = degree - 1  # the correction's basis: P_{m-1}
        self.exponents = basis_exponents(self.degree).astype(np.int64)
        n_p = len(basis_exponents(self.degree))
        self.moments = np.zeros((len(nodes), n_p, n_p))
        self.rhs = np.zeros((len(nodes), 2, n_p))
        self.touched = np.zeros(len(nodes), dtype=bool)

    def _chunks(self, shape: ShapeValues, points: np.ndarray):
        """(entry rows, nodes, p, grad p) of the support entries, chunk by chunk."""
        per_chunk = max(1, CHUNK_ENTRIES // max(1, shape.mask.shape[1]))
        for start in range(0, len(points), per_chunk):
            point, slot, node = _entries(shape, start, min(start + per_chunk, len(points)))
            offsets = points[point] - self.nodes[node]
            values, gradients = _local_basis(offsets, self.radius[node], self.degree)
            self.touched[node] = True
            yield point, slot, node, values, gradients

    def _summed(self, node: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """sum of rows[e] over the entries e of each node, (n_nodes, k): one sparse
        product (no np.add.at)."""
        entries = np.arange(len(node))
        ones = np.ones(len(node))
        scatter = sp.csr_matrix((ones, (node, entries)), shape=(len(self.nodes), len(node)))
        return scatter @ rows.reshape(len(node), -1)

    def _add(self, target: np.ndarray, node: np.ndarray, weights, terms: np.ndarray) -> None:
        """target[node[e]] += weights[e] terms[e]."""
        weighted = weights[:, None] * terms.reshape(len(node), -1)
        target.reshape(len(target), -1)[...] += self._summed(node, weighted)

    def add_domain(self, shape: ShapeValues, points: np.ndarray, weights: np.ndarray) -> None:
        """The domain points' terms: G_I and -sum w (phi_I d_a p + d_a phi_I p) of r_I."""
        assert shape.dphi is not None
        if self.compiled:
            self.touched[shape.neighbours[shape.mask]] = True
            arguments = (points, weights, shape.neighbours, shape.mask, shape.phi, shape.dphi)
            _kernels().domain_sums(
                *arguments, self.nodes, self.radius, self.exponents, self.moments, self.rhs
            )
            return
        n_p = self.moments.shape[1]
        upper = np.triu_indices(n_p)  # G_I is symmetric: its upper triangle suffices
        n_upper = len(upper[0])
        for point, slot, node, p, dp in self._chunks(shape, points):
            w = weights[point]
            # every entry's weighted terms as one row: w p p^T (upper) and w r-terms
            columns = np.empty((len(node), n_upper + 2 * n_p))
            np.multiply((p * w[:, None])[:, upper[0]], p[:, upper[1]], out=columns[:, :n_upper])
            terms = columns[:, n_upper:].reshape(-1, 2, n_p)
            phi, dphi = shape.phi[point, slot] * w, shape.dphi[point, slot] * w[:, None]
            np.multiply(phi[:, None, None], dp.transpose(0, 2, 1), out=terms)
            terms += dphi[:, :, None] * p[:, None, :]
            sums = self._summed(node, columns)  # (n_nodes, n_upper + 2 n_p)
            self.moments[:, upper[0], upper[1]] += sums[:, :n_upper]
            self.rhs -= sums[:, n_upper:].reshape(-1, 2, n_p)

    def symmetric_moments(self) -> np.ndarray:
        """G_I of every node from the upper triangles summed by :meth:`add_domain`."""
        moments = self.moments
        return moments + np.triu(moments, 1).transpose(0, 2, 1)

    def add_boundary(
        self, shape: ShapeValues, points: np.ndarray, weights: np.ndarray, normals: np.ndarray
    ) -> None:
        """The boundary points' terms sum w phi_I p n_a of r_I."""
        if self.compiled:
            self.touched[shape.neighbours[shape.mask]] = True
            arguments = (points, weights, normals, shape.neighbours, shape.mask, shape.phi)
            _kernels().boundary_sums(*arguments, self.nodes, self.radius, self.exponents, self.rhs)
            return
        for point, slot, node, p, _ in self._chunks(shape, points):
            terms = normals[point][:, :, None] * p[:, None, :]
            self._add(self.rhs, node, weights[point] * shape.phi[point, slot], terms)


def node_corrections(
    comm, sums: ConsistencySums, node_ranges: np.ndarray, node_ids: np.ndarray | None = None
) -> np.ndarray:
    """xi_I (n_nodes, 2, n_p) for this rank's touched nodes (zero elsewhere).  Collective.

    Each node's terms are added over all ranks in the rows of its owner, which solves
    G_I xi_I = r_I; the coefficients then go back to every rank that touched the node.
    ``node_ids``: the global number of each node of ``sums`` (None: they are global).
    Raises InputError on every rank when some G_I is singular (a support with too few
    Gauss points for P_{m-1}: a cell coarser than the nodes).
    """
    n_nodes, n_p = len(sums.moments), sums.moments.shape[1]
    width = n_p * n_p + 2 * n_p
    start, stop = int(node_ranges[comm.rank]), int(node_ranges[comm.rank + 1])
    touched = np.flatnonzero(sums.touched)
    touched_ids = (touched if node_ids is None else node_ids[touched]).astype(PETSc.IntType)
    moments = sums.symmetric_moments()[touched]
    local = np.concatenate(
        [moments.reshape(len(touched), -1), sums.rhs[touched].reshape(len(touched), -1)], axis=1
    )
    totals = PETSc.Vec().createMPI(
        ((stop - start) * width, PETSc.DETERMINE), bsize=width, comm=comm
    )
    totals.setValuesBlocked(touched_ids, local.ravel(), addv=PETSc.InsertMode.ADD_VALUES)
    totals.assemble()
    owned = totals.getArray(readonly=True).reshape(stop - start, width)
    moments = owned[:, : n_p * n_p].reshape(-1, n_p, n_p)
    rhs = owned[:, n_p * n_p :].reshape(-1, 2, n_p)
    # Nodes no rank's points reach (none in a valid cloud) keep xi = 0.
    used = np.abs(moments).sum(axis=(1, 2)) > 0
    coefficients = np.zeros((stop - start, 2, n_p))
    singular = False
    if used.any():
        scale = np.abs(moments[used]).max(axis=(1, 2))[:, None, None]
        scaled = moments[used] / scale  # scale-aware: G_I ~ support area
        condition = np.linalg.cond(scaled)
        singular = bool((~np.isfinite(condition) | (condition > 1e12)).any())
        if not singular:
            solved = np.linalg.solve(scaled, (rhs[used] / scale).transpose(0, 2, 1))
            coefficients[used] = solved.transpose(0, 2, 1)
    totals.destroy()
    if comm.allreduce(singular):
        raise InputError(
            "discretization.integration = 'vci': a node's support holds too few Gauss points "
            "for the gradient correction; refine the cells or raise discretization.quadrature"
        )
    result = PETSc.Vec().createMPI(
        ((stop - start) * 2 * n_p, PETSc.DETERMINE), bsize=2 * n_p, comm=comm
    )
    result.setArray(coefficients.ravel())
    gathered = PETSc.Vec().createSeq(len(touched) * 2 * n_p, bsize=2 * n_p)
    wanted = PETSc.IS().createBlock(2 * n_p, touched_ids, comm=PETSc.COMM_SELF)
    scatter = PETSc.Scatter().create(result, wanted, gathered, None)
    scatter.scatter(result, gathered, PETSc.InsertMode.INSERT_VALUES, PETSc.ScatterMode.FORWARD)
    out = np.zeros((n_nodes, 2, n_p))
    out[touched] = gathered.getArray(readonly=True).reshape(-1, 2, n_p)
    for obj in (scatter, wanted, gathered, result):
        obj.destroy()
    return out


def corrected_gradients(
    shape: ShapeValues, points, nodes, radius, coefficients, degree: int, compiled: bool
) -> np.ndarray:
    """grad phi_I + xi_I . p((x - x_I) / R_I) at every padded entry, (n_points, n_max, 2)."""
    assert shape.dphi is not None
    if compiled:
        out = np.empty_like(shape.dphi)
        exponents = basis_exponents(degree - 1).astype(np.int64)
        arguments = (points, shape.neighbours, shape.mask, shape.dphi, nodes, radius)
        _kernels().correct(*arguments, exponents, coefficients, out)
        return out
    out = shape.dphi.copy()
    per_chunk = max(1, CHUNK_ENTRIES // max(1, shape.mask.shape[1]))
    for start in range(0, len(points), per_chunk):
        point, slot, node = _entries(shape, start, min(start + per_chunk, len(points)))
        p, _ = _local_basis(points[point] - nodes[node], radius[node], degree - 1)
        out[point, slot] += np.einsum("eac,ec->ea", coefficients[node], p)
    return out
