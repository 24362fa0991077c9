"""Dirichlet boundary methods: the paper's penalty and symmetric Nitsche (SPEC 2, issue 12).

Both impose u = ubar on Gamma_D through one constant symmetric operator D, added to the
stiffness, and a load L^T (w ubar(t)) that follows the data each step::

    penalty:  D = alpha_D int phi_I phi_J,                       L = alpha_D phi
    nitsche:  D = int beta phi_I phi_J - int phi_I sigma(phi_J) n
                  - int sigma(phi_I) n phi_J,                   L = beta phi - sigma(phi) n

The Nitsche form is consistent (the exact solution satisfies it for every beta), so its
error does not depend on a user-tuned number; beta = safety x 2 x C_e x (segments of the
cell), C_e the trace-inverse constant of the segment's cell
(:mod:`parefg.discretization.trace_inverse`), which makes K + D coercive.  The default
"nitsche" (also "nitsche-coarse") applies these terms to the projections P of the trace
and the traction onto a coarse trace space (:mod:`parefg.discretization.coarse_trace`:
V -> P V, T -> P T, beta constant per group), which keeps its error flat in beta;
"nitsche-pointwise" is the textbook form at every Gauss point.  A method is chosen per
part (``[boundary.NAME] method``) from :data:`DIRICHLET_METHODS`.

Both derive from the boundary energy per point, whose u-gradient the step balances and
whose ubar-gradient is the work of moving data::

    e(u, ubar) = beta / 2 |u - ubar|^2 - [sigma(u) n] . (u - ubar)   (penalty: no sigma term)

Nothing here is collective except where a docstring says so.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import scipy.sparse as sp

from parefg.discretization.coarse_trace import project_rows
from parefg.discretization.structure import structural_sum, weighted_product

if TYPE_CHECKING:  # the scene schema reads the registry without loading PETSc or numba
    from petsc4py import PETSc

    from parefg.discretization.mls import ShapeValues


@dataclass
class DirichletPart:
    """The operators of one Dirichlet part on this rank's points of it.

    ``load`` is L (2 n_points x n_dofs), ``traction`` sigma(u_h) n at the points (2 n_points
    x n_dofs, None for the penalty; projected for the coarse trace), ``beta`` (n_points,)
    the penalty or stabilization, ``projection`` the coarse trace's P on point fields
    (n_points x n_points, this rank's points) or None.
    """

    method: str
    weights: np.ndarray  # (n_points,) quadrature weights
    beta: np.ndarray  # (n_points,)
    load: PETSc.Mat
    traction: PETSc.Mat | None
    projection: sp.csr_matrix | None = None
    # work vectors at the points, created on first use and reused (no PETSc object per step)
    _point_vec: PETSc.Vec | None = field(default=None, init=False, repr=False)
    _traction_vec: PETSc.Vec | None = field(default=None, init=False, repr=False)

    def add_load(self, ubar: np.ndarray, out: PETSc.Vec) -> None:
        """out += L^T (w ubar), ubar (n_points, 2): the data's share of the load.  Collective."""
        if self._point_vec is None:
            self._point_vec = self.load.createVecLeft()
        self._point_vec.setArray((ubar * self.weights[:, None]).ravel())
        self.load.multTransposeAdd(self._point_vec, out, out)

    def point_traction(self, u: PETSc.Vec) -> np.ndarray:
        """sigma(u_h) n at the points, (n_points, 2); zeros for the penalty.  Collective."""
        if self.traction is None:
            return np.zeros((len(self.weights), 2))
        if self._traction_vec is None:
            self._traction_vec = self.traction.createVecLeft()
        self.traction.mult(u, self._traction_vec)
        return self._traction_vec.getArray().reshape(-1, 2).copy()

    def energy_and_force(self, trace: np.ndarray, traction: np.ndarray, ubar: np.ndarray):
        """Per-point e(u, ubar) (n_points,) and f = -de/dubar = beta (u - ubar) - sigma n.

        With the coarse trace, u - ubar is projected (the traction already is): the
        densities then integrate to the form's boundary energy.
        """
        diff = trace - ubar
        if self.projection is not None:
            diff = self.projection @ diff
        energy = 0.5 * self.beta * np.sum(diff**2, axis=1) - np.sum(traction * diff, axis=1)
        return energy, self.beta[:, None] * diff - traction


def traction_operator(shape: ShapeValues, normals: np.ndarray, n_nodes, lam, mu) -> sp.csr_matrix:
    """(2 n_points x 2 n_nodes) sigma(u_h) n at the points, from the gradient operator.

    With G[q, i, j] = d u_i / d x_j: (sigma n)_i = lam tr(G) n_i + mu (G_ij + G_ji) n_j.
    """
    from parefg.discretization.assembly import gradient_operator  # numba: not at import

    gradients = gradient_operator(shape, n_nodes)  # rows 4q + 2i + j
    n_points = len(normals)
    nx, ny = normals[:, 0], normals[:, 1]
    # (n_points, 2, 4) coefficients of (G_00, G_01, G_10, G_11) in (sigma n)_0 and _1
    block = np.zeros((n_points, 2, 4))
    block[:, 0] = np.column_stack([(lam + 2 * mu) * nx, mu * ny, mu * ny, lam * nx])
    block[:, 1] = np.column_stack([lam * ny, mu * nx, mu * nx, (lam + 2 * mu) * ny])
    rows = np.repeat(np.arange(2 * n_points), 4)
    columns = (4 * np.arange(n_points)[:, None, None] + np.arange(4)[None, None, :]).repeat(2, 1)
    combine = sp.csr_matrix(
        (block.ravel(), (rows, columns.ravel())), shape=(2 * n_points, 4 * n_points)
    )
    return (combine @ gradients).tocsr()


@dataclass(frozen=True)
class DirichletMethod:
    """A registered Dirichlet method: its name, Nitsche's traction terms, the coarse trace."""

    name: str
    consistent: bool  # Nitsche: -int sigma(u) n . v - int sigma(v) n . (u - ubar)
    coarse: bool = False  # the terms act on the coarse trace space's projections


#: ``[boundary.NAME] method`` of a Dirichlet part -> the method; the first is the default
DIRICHLET_METHODS = {
    "nitsche": DirichletMethod("nitsche", consistent=True, coarse=True),
    "nitsche-coarse": DirichletMethod("nitsche-coarse", consistent=True, coarse=True),
    "nitsche-pointwise": DirichletMethod("nitsche-pointwise", consistent=True),
    "penalty": DirichletMethod("penalty", consistent=False),
}
DEFAULT_DIRICHLET_METHOD = next(iter(DIRICHLET_METHODS))
#: beta = NITSCHE_SAFETY x the coercivity bound 2 C_e (segments per cell) by default
NITSCHE_SAFETY = 2.0
#: ``[boundary.NAME] method`` of a contact part; the first is the default.  "nitsche" is
#: Chouly & Hild's symmetric Nitsche contact (parefg.mechanics.contact), gamma = safety x
#: the same coercivity bound: consistent, so no penalty error (m = 2 dynamic L2 rate 2.86
#: against the penalty's 2.03, README Accuracy), with the law on the coarse trace as the
#: Dirichlet parts' (P u, P sigma_nu, P s; also "nitsche-coarse"): flat in the safety,
#: where the law at every Gauss point ("nitsche-pointwise") over-constrains the MLS
#: trace as gamma grows.  "nitsche-hat" puts the law on P u with P the projection onto
#: continuous piecewise-linear functions (coarse_trace.hat_projection): flat too and
#: sharper at a contact zone's edge, but its traction is only O(h^2) there, which costs
#: m = 3 its rates.  "penalty" is the paper's alpha_C (u_nu - s)^+.
CONTACT_METHODS = ("nitsche", "nitsche-coarse", "nitsche-hat", "nitsche-pointwise", "penalty")
NITSCHE_CONTACT_METHODS = CONTACT_METHODS[:-1]
COARSE_CONTACT_METHODS = ("nitsche", "nitsche-coarse")
HAT_CONTACT_METHODS = ("nitsche-hat",)
DEFAULT_CONTACT_METHOD = CONTACT_METHODS[0]


def local_operators(
    method: DirichletMethod,
    shape: ShapeValues,
    weights: np.ndarray,
    normals: np.ndarray,
    beta: np.ndarray,
    n_nodes: int,
    lam: float,
    mu: float,
    projection: sp.csr_matrix | None = None,
) -> tuple[sp.csr_matrix, sp.csr_matrix, sp.csr_matrix | None]:
    """This rank's contributions to D (2n x 2n), and its rows of L and of sigma(u_h) n.

    D = V^T W_beta V - V^T W T - T^T W V with V the values and T the tractions at the
    points (T = 0 for the penalty), W the quadrature weights; with a coarse-trace
    ``projection`` P (n_points x n_points, beta constant on its groups), V and T are
    replaced by P V and P T.
    """
    from parefg.discretization.assembly import value_operator  # numba: not at import

    # kron(S, I_2) of the scalar values: row 2q + c, column 2I + c = phi_I(x_q)
    values = sp.kron(value_operator(shape, n_nodes), sp.identity(2), format="csr")
    if projection is not None:
        values = project_rows(projection, values)
    weight_rows = np.repeat(weights, 2)
    beta_rows = np.repeat(beta, 2)
    # the patterns are structural (parefg.discretization.structure): phi and T are signed
    terms = [(1.0, weighted_product(values, weight_rows * beta_rows, values))]
    load = sp.diags(beta_rows) @ values
    traction = None
    if method.consistent:
        traction = traction_operator(shape, normals, n_nodes, lam, mu)
        if projection is not None:
            traction = project_rows(projection, traction)
        cross = weighted_product(values, weight_rows, traction)
        terms += [(-1.0, cross), (-1.0, cross.T)]
        load = load - traction
    return structural_sum(terms, (2 * n_nodes, 2 * n_nodes)), load.tocsr(), traction
