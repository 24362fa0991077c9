"""Manufactured solutions: the data a scene derives from its ``[exact] u`` (SPEC 6, 9).

Given ``[exact] u``, whatever boundary, initial and load data the scene leaves out are
derived from it by symbolic differentiation:

    eps = sym grad u,  sigma = lam tr(eps) I + 2 mu eps,
    f = rho u_tt - div sigma (dynamic schemes) or -div sigma (static),
    ubar = u,  p = sigma n,  g = |tau . sigma n| with tau = (-n_y, n_x),
    u0 = u(., 0),  v0 = u_t(., 0).

Not collective.
"""

import sympy

from parefg.scene.expressions import SYMBOLS, compile_field
from parefg.scene.fields import scene_expressions
from parefg.scene.numeric import CompiledField, ExactSolution
from parefg.scene.symbolic import DerivativeBudget, is_identically_zero


class ManufacturedSolution:
    """Symbolic elasticity of an exact solution u(x, y, t) (plane strain).

    ``derived`` holds the data a scene may leave out, as sympy expressions by key:
    "f" (body force rho u_tt - div sigma, or -div sigma when not ``dynamic``), "value"
    (ubar = u), "traction" (sigma n), "friction" (|tau . sigma n|), "u" and "v" (the
    initial u(., 0) and u_t(., 0)).

    Every derivative goes through ``budget``, which refuses an exact solution whose
    derived data would be too large to compute, compile or evaluate.
    """

    def __init__(
        self,
        u: list[sympy.Expr],
        lam: float,
        mu: float,
        rho: float,
        dynamic: bool,
        budget: DerivativeBudget,
    ):
        x, y, t, nx, ny = (SYMBOLS[s] for s in ("x", "y", "t", "nx", "ny"))
        coordinates = (x, y)
        d = len(coordinates)  # the dimension: only the traction below is planar
        diff = budget.diff
        self.u = u
        self.grad = sympy.Matrix(d, d, lambda i, j: diff(u[i], coordinates[j]))
        self.velocity = [diff(ui, t) for ui in u]
        eps = (self.grad + self.grad.T) / 2
        sigma = sympy.Float(lam) * eps.trace() * sympy.eye(d) + 2 * sympy.Float(mu) * eps
        div_sigma = [
            sympy.Add(*(diff(sigma[i, j], coordinates[j]) for j in range(d))) for i in range(d)
        ]
        self.div_sigma = div_sigma
        inertia = [sympy.Float(rho) * diff(vi, t) for vi in self.velocity]
        if not dynamic:  # a static scheme: no inertia
            inertia = [0] * d
        traction = sigma * sympy.Matrix([nx, ny])
        tangential = -ny * traction[0] + nx * traction[1]
        budget.charge(*traction, tangential)
        self.derived = {
            "f": [inertia[i] - div_sigma[i] for i in range(d)],
            "value": list(u),
            "traction": list(traction),
            "friction": [sympy.Abs(tangential)],
            "u": [ui.subs(t, 0) for ui in u],
            "v": [vi.subs(t, 0) for vi in self.velocity],
        }

    def solution(self, given: list) -> ExactSolution:
        """Vectorized u, v and grad u; ``given``: the scene's ``[exact] u`` values."""
        d = self.grad.shape[0]
        gradient = [self.grad[i, j] for i in range(d) for j in range(d)]
        return ExactSolution(
            given=list(given),
            u=compile_field(self.u),
            v=compile_field(self.velocity),
            grad=compile_field(gradient, components=(d, d)),
        )


def initial_elasticity(
    where: str, values, manufactured, lam: float, mu: float, rho: float
) -> tuple[CompiledField | None, CompiledField | None]:
    """grad u0 and div sigma(u0) as functions of (x, y), for the consistent start.

    ``values`` are the scene's ``[initial] u`` (None: u0 of ``manufactured``, the exact
    solution at t = 0).  Both None when u0 vanishes identically (decided on the
    expressions, not on floats).
    """
    x, y, t = (SYMBOLS[s] for s in ("x", "y", "t"))
    if values is not None:
        exprs = [e.subs(t, 0) for e in scene_expressions(where, "initial.u", values)]
    else:
        exprs = manufactured.derived["u"]
    if all(is_identically_zero(e, [x, y]) for e in exprs):
        return None, None
    derivatives = DerivativeBudget(where, "initial.u")
    initial = ManufacturedSolution(exprs, lam, mu, rho, False, derivatives)
    d = initial.grad.shape[0]
    gradient = [initial.grad[i, j] for i in range(d) for j in range(d)]
    return (
        compile_field(gradient, ("x", "y"), components=(d, d)),
        compile_field(initial.div_sigma, ("x", "y")),
    )
