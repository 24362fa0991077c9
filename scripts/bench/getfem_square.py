"""parefg's square scene (SPEC 6) in GetFEM's own terms: P1-P3 triangles, Newmark, penalty contact.

The continuous problem is the one parefg solves, read from the same :class:`Scene`
(``load_scene("square", overrides)``): material, Newmark beta and gamma, T, dt, penalty
factors (alpha_C = alpha_T = 1e4 E / h by default) and the exact solution, from which the
data are derived exactly as :mod:`parefg.scene.loader` derives them (sympy) and handed to
GetFEM as weak-form-language (GWFL) expressions of X, t and Normal, evaluated at GetFEM's
own quadrature points (no interpolation of the data):

    f = rho u_tt - div sigma(u)             body force on Omega  } assembled once per step
    p = sigma(u) nu                         traction on the      } (asm_generic) into an
                                            neumann parts        } explicit-rhs brick
    ubar = u                                Dirichlet data on top (strong: GetFEM's
                                            Dirichlet brick with simplification, nodal values)
    g = |tau . sigma(u) nu|                 Tresca bound on the contact part (bottom)
    u0 = u(., 0), v0 = u_t(., 0)            interpolated; a0 from M a0 = F0 - K u0 + ...

Per step n (t_n = n k), as parefg (SPEC 4): the Newmark predictor ut, vt; u_n solves

    rho/(beta k^2) (u - ut, w) + a(u, w) - l_n(w)
      + int_{Gamma_C} alpha_C (u.nu - s)^+ w.nu
      + int_{Gamma_C} clip(alpha_T (u.tau - xi_{n-1}), -g_n, g_n) w.tau = 0   for all w,

with the accumulated slip xi an internal variable at the Gamma_C quadrature points
(GetFEM im_data; xi_0 = u_tau(0)), updated by the return mapping after the step:
xi_n = u_tau - clip(u_tau - xi_{n-1}, -g_n/alpha_T, g_n/alpha_T).  Then
a_n = (u_n - ut)/(beta k^2), v_n = vt + gamma k a_n.  The contact and friction terms are
GWFL nonlinear terms (GetFEM differentiates them: pos_part -> Heaviside, min/max), the
rest are GetFEM's linear bricks (isotropic linearized elasticity, mass with rho/(beta k^2)),
assembled once; the step is solved by GetFEM's Newton (``Model.solve``, predictor as the
initial guess) with MUMPS.  The mesh is GetFEM's structured "regular_simplices" (1/h
squares a side, each cut in two): h is the element size, where parefg's h is the node
spacing, so compare by DOFs too.  GetFEM's own contact bricks
regularize Coulomb friction on the slip increment (which lets sticking points creep,
SPEC 4), so parefg's law is written in GWFL instead, as a GetFEM user writes a custom law.

The friction law of the contact part is honoured: "given" (the square's default: g acts on
all of Gamma_C) or "tresca" (g only where the predictor touches, u_nu >= s).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import getfem as gf
import numpy as np
import sympy
from sympy.printing.str import StrPrinter

from parefg.scene.expressions import SYMBOLS, parse_expression

# region ids of the square's parts and their outward normals
PARTS = {"bottom": (1, (0.0, -1.0)), "right": (2, (1.0, 0.0)), "top": (3, (0.0, 1.0)),
         "left": (4, (-1.0, 0.0))}  # fmt: skip
# Gauss rule per FEM degree (GetFEM's IM_TRIANGLE(k), exact to degree k): mass and
# stiffness of P2 need 4; the data are exponentials, so two orders more
INTEGRATION = {1: 4, 2: 6, 3: 8}
ERROR_INTEGRATION = 10  # error integrals: well beyond the FEM degree
NEWTON_MAX_RES = 1e-11  # GetFEM's residual target (its norm of the residual vector)
NEWTON_MAX_ITER = 30
# "auto" is GetFEM's default_linear_solver (getfem_model_solvers.h): MUMPS below 300000 DOFs
# in 2D, LDL^T when GetFEM deems the model symmetric, else LU.  Measured as fast as "mumps"
# (LU).  Declaring the GWFL terms symmetric and coercive doubled the Newton iterations
# (2 per step instead of ~1), so they are left undeclared.
LINEAR_SOLVER = "auto"
GATES = {"given": "1", "tresca": "Heaviside(ut.Normal - s)"}  # where g acts (friction law)


class _GwflPrinter(StrPrinter):
    """sympy -> GWFL: x, y -> X(1), X(2); nx, ny -> Normal(1), Normal(2); powers as pow()."""

    NAMES = {"x": "X(1)", "y": "X(2)", "t": "t", "nx": "Normal(1)", "ny": "Normal(2)"}

    def _print_Symbol(self, expr):
        return self.NAMES[expr.name]

    def _print_Pow(self, expr):
        base, exponent = expr.as_base_exp()
        return f"pow({self._print(base)}, {self._print(exponent)})"

    def _print_Float(self, expr):
        return repr(float(expr))

    def _print_Rational(self, expr):
        return f"({float(expr)!r})"

    def _print_Abs(self, expr):
        return f"abs({self._print(expr.args[0])})"


def gwfl(expr) -> str:
    """One sympy expression as a GWFL string."""
    return _GwflPrinter().doprint(sympy.sympify(expr))


def gwfl_vector(exprs) -> str:
    return "[" + "; ".join(gwfl(e) for e in exprs) + "]"


@dataclass
class GwflData:
    """The scene's data as GWFL strings (vectors as [a; b], matrices row by row)."""

    u: str  # exact displacement (Dirichlet data, u0 at t = 0)
    v: str  # exact velocity (v0 at t = 0)
    grad: str  # exact displacement gradient, [i, j] = d u_i / d x_j
    f: str  # body force
    traction: str  # sigma(u) Normal
    friction: str  # |tau . sigma(u) Normal|
    gap: str


def derive_data(scene) -> GwflData:
    """f, p, ubar, g, u0, v0 of the scene's exact solution, as parefg.scene.loader derives them."""
    x, y, t, nx, ny = (SYMBOLS[name] for name in ("x", "y", "t", "nx", "ny"))
    u = [parse_expression(value, "exact.u") for value in scene.exact.given]
    grad = sympy.Matrix(2, 2, lambda i, j: sympy.diff(u[i], (x, y)[j]))
    eps = (grad + grad.T) / 2
    sigma = (
        sympy.Float(scene.material.lam) * eps.trace() * sympy.eye(2)
        + 2 * sympy.Float(scene.material.mu) * eps
    )
    div_sigma = [sympy.diff(sigma[i, 0], x) + sympy.diff(sigma[i, 1], y) for i in range(2)]
    f = [scene.material.rho * sympy.diff(ui, t, 2) - div_sigma[i] for i, ui in enumerate(u)]
    traction = sigma * sympy.Matrix([nx, ny])
    contact = [bc for bc in scene.boundaries.values() if bc.kind == "contact"]
    (bottom,) = contact
    gap = scene.params["boundary"][bottom.name]["gap"]
    given = scene.params["boundary"][bottom.name].get("friction")
    friction = sympy.Abs(-ny * traction[0] + nx * traction[1]) if given is None else given
    rows = "; ".join(", ".join(gwfl(grad[i, j]) for j in range(2)) for i in range(2))
    return GwflData(
        u=gwfl_vector(u),
        v=gwfl_vector([sympy.diff(ui, t) for ui in u]),
        grad=f"[{rows}]",
        f=gwfl_vector(f),
        traction=gwfl_vector(traction),
        friction=gwfl(friction),
        gap=gwfl(gap),
    )


@dataclass
class _Square:
    """The GetFEM objects of one discretization of the square."""

    mesh: object
    mf: object  # displacement FEM, P1/P2 Lagrange, 2 components
    mim: object  # integration on Omega (and, through its faces, the boundary)
    mimd: object  # the Gamma_C quadrature points, home of the slip xi
    model: object
    loads: list  # (GWFL expression, region): the step's right-hand side l_n + M ut / (beta k^2)
    rhs_brick: int  # GetFEM's explicit-rhs brick that carries it

    def assemble_loads(self) -> None:
        """Assemble the right-hand side at the model's t and ut, once per step.

        An explicit-rhs brick, not source-term bricks: GetFEM reassembles those at every
        residual evaluation of its Newton, though they do not depend on u (measured 5-10 %
        of the run at h = 1/16; the factorizations dominate).
        """
        rhs = sum(
            gf.asm_generic(self.mim, 1, expr, region, self.model) for expr, region in self.loads
        )
        self.model.set_private_rhs(self.rhs_brick, rhs)


def _mesh(n: int):
    """Structured triangles of the unit square (n x n squares, each cut in two), parts tagged."""
    nodes = np.linspace(0.0, 1.0, n + 1)
    mesh = gf.Mesh("regular_simplices", nodes, nodes)
    for region, normal in PARTS.values():
        mesh.set_region(region, mesh.outer_faces_with_direction(list(normal), 0.01))
    return mesh


def _model(scene, data: GwflData, mesh, degree: int) -> _Square:
    """The per-step problem of Newmark: linear bricks, GWFL sources and contact terms."""
    mf = gf.MeshFem(mesh, 2)
    mf.set_classical_fem(degree)
    mim = gf.MeshIm(mesh, gf.Integ(f"IM_TRIANGLE({INTEGRATION[degree]})"))
    bottom = PARTS["bottom"][0]
    mimd = gf.MeshImData(mim, bottom)
    md = gf.Model("real")
    md.add_fem_variable("u", mf)
    k = scene.time.dt
    material, penalty = scene.material, scene.penalty
    constants = {"t": 0.0, "lambda": material.lam, "mu": material.mu, "rho": material.rho,
                 "cM": material.rho / (scene.time.beta * k**2), "alpha_C": penalty.alpha_contact,
                 "alpha_T": penalty.alpha_friction}  # fmt: skip
    for name, value in constants.items():
        md.add_initialized_data(name, [value])
    md.add_macro("s", data.gap)
    md.add_macro("Tg", "[-Normal(2); Normal(1)]")  # tau = (-nu_2, nu_1)
    md.add_isotropic_linearized_elasticity_brick(mim, "u", "lambda", "mu")
    md.add_mass_brick(mim, "u", "cM")
    md.add_fem_data("ut", mf)  # Newmark predictor
    loads = [(f"(cM*ut + {data.f}).Test_u", -1)]
    md.add_fem_data("ubar", mf)
    for name, bc in scene.boundaries.items():
        region = PARTS[name][0]
        if bc.kind == "neumann":
            loads.append((f"{data.traction}.Test_u", region))
        elif bc.kind == "dirichlet":
            md.add_Dirichlet_condition_with_simplification("u", region, "ubar")
        else:
            md.add_macro("g", f"({GATES[bc.friction_law]})*({data.friction})")
            md.add_im_data("xi", mimd)
            md.add_nonlinear_term(mim, "alpha_C*pos_part(u.Normal - s)*(Test_u.Normal)", region)
            md.add_nonlinear_term(mim, "max(min(alpha_T*(u.Tg - xi), g), -g)*(Test_u.Tg)", region)
    rhs_brick = md.add_explicit_rhs("u", np.zeros(mf.nbdof()))
    return _Square(mesh, mf, mim, mimd, md, loads, rhs_brick)


def _initial_acceleration(scene, data: GwflData, square: _Square, u0: np.ndarray) -> np.ndarray:
    """a0 from M a0 = F0 - K u0 + int_{Gamma_N} p0 - contact(u0), as parefg (SPEC 4).

    The friction force at t = 0 vanishes: xi_0 = u_tau(0).
    """
    mf, mim = square.mf, square.mim
    md = gf.Model("real")
    md.add_fem_variable("a", mf)
    for name in ("t", "lambda", "mu", "rho", "alpha_C"):
        md.add_initialized_data(name, [0.0 if name == "t" else square.model.variable(name)[0]])
    md.add_initialized_fem_data("u0", mf, u0)
    md.add_macro("s", data.gap)
    md.add_mass_brick(mim, "a", "rho")
    stress = "(lambda*Div_u0*Id(2) + 2*mu*Sym(Grad_u0))"
    md.add_source_term(mim, f"{data.f}.Test_a - {stress}:Grad_Test_a")
    for name, bc in scene.boundaries.items():
        region = PARTS[name][0]
        if bc.kind == "neumann":
            md.add_source_term(mim, f"{data.traction}.Test_a", region)
        elif bc.kind == "contact":
            md.add_source_term(mim, "-alpha_C*pos_part(u0.Normal - s)*(Test_a.Normal)", region)
    md.solve("lsolver", LINEAR_SOLVER)
    return md.variable("a")


def solve(scene, data: GwflData, degree: int = 2) -> dict:
    """Run the scene with GetFEM P``degree`` at the scene's h (1/h squares a side); time it.

    Returns errors at T (relative L2 and H1 seminorm, as parefg's summary), DOFs, steps,
    Newton iterations and the wall time of everything after the data strings: mesh, FEM,
    model, initial state, time loop and the error integrals.
    """
    n = round(1.0 / scene.discretization.h)
    if abs(n * scene.discretization.h - 1.0) > 1e-9:
        raise ValueError(f"h = {scene.discretization.h}: GetFEM's square needs 1/h an integer")
    tic = time.perf_counter()
    square = _model(scene, data, _mesh(n), degree)
    md, mf, mimd = square.model, square.mf, square.mimd
    bottom, top = PARTS["bottom"][0], PARTS["top"][0]
    u = md.interpolation(data.u, mf)  # t = 0
    v = md.interpolation(data.v, mf)
    a = _initial_acceleration(scene, data, square, u)
    md.set_variable("u", u)
    md.set_variable("xi", md.interpolation("u.Tg", mimd, bottom))
    k, beta, gamma = scene.time.dt, scene.time.beta, scene.time.gamma
    newton = 0
    for step in range(1, scene.time.n_steps + 1):
        ut = u + k * v + k**2 * (0.5 - beta) * a
        vt = v + k * (1.0 - gamma) * a
        md.set_variable("t", [step * k])
        md.set_variable("ut", ut)
        md.set_variable("ubar", md.interpolation(data.u, mf, top))
        md.set_variable("u", ut)  # initial guess: the predictor, as parefg
        square.assemble_loads()
        iterations, converged = md.solve(
            "max_res", NEWTON_MAX_RES, "max_iter", NEWTON_MAX_ITER, "lsolver", LINEAR_SOLVER
        )
        if not converged:
            raise RuntimeError(f"GetFEM Newton did not converge at step {step}")
        newton += iterations
        u = md.variable("u")
        a = (u - ut) / (beta * k**2)
        v = vt + gamma * k * a
        slip = "u.Tg - max(min(u.Tg - xi, g/alpha_T), -g/alpha_T)"  # return mapping
        md.set_variable("xi", md.interpolation(slip, mimd, bottom))
    errors = relative_errors(square, data)
    seconds = time.perf_counter() - tic
    return {"dofs": mf.nbdof(), "steps": scene.time.n_steps, "newton": newton, "seconds": seconds,
            **errors}  # fmt: skip


def relative_errors(square: _Square, data: GwflData) -> dict:
    """Relative L2 and H1-seminorm errors of u at the model's time t (parefg's definitions)."""
    mim = gf.MeshIm(square.mesh, gf.Integ(f"IM_TRIANGLE({ERROR_INTEGRATION})"))
    md = square.model

    def integral(expr):
        return gf.asm_generic(mim, 0, expr, -1, md)

    l2 = integral(f"Norm_sqr(u - {data.u})") / integral(f"Norm_sqr({data.u})")
    h1 = integral(f"Norm_sqr(Grad_u - {data.grad})") / integral(f"Norm_sqr({data.grad})")
    return {"l2_rel": float(np.sqrt(l2)), "h1_rel": float(np.sqrt(h1))}


def data_mismatch(scene, data: GwflData, n_points: int = 20, seed: int = 0) -> float:
    """Largest relative difference between the GWFL data and parefg's own data callables.

    Evaluated by GetFEM (the strings as it parses them) and by parefg (scene.loads.f,
    the boundary callables, exact u and grad u, u0, v0) at random points and times, with
    Normal replaced by a random unit vector: the check that both codes solve the same
    continuous problem.
    """
    rng = np.random.default_rng(seed)
    x, y = rng.random(n_points), rng.random(n_points)
    t, angle = rng.uniform(0.1, scene.time.T), rng.uniform(0.0, 2.0 * np.pi)
    nx, ny = np.cos(angle), np.sin(angle)
    mesh = _mesh(1)
    md = gf.Model("real")
    md.add_initialized_data("t", [t])
    md.add_macro("Nrm", f"[{nx!r}; {ny!r}]")  # GetFEM's Normal exists on faces only

    def getfem_values(expr, shape):
        values = md.interpolation(expr.replace("Normal", "Nrm"), np.vstack([x, y]), mesh)
        # per point, GetFEM stores a tensor column-major
        return np.reshape(values, (n_points, *shape[::-1])).transpose(0, *range(len(shape), 0, -1))

    bcs = {bc.kind: bc for bc in scene.boundaries.values()}
    pairs = [
        (getfem_values(data.f, (2,)), scene.loads.f(x, y, t).T),
        (getfem_values(data.u, (2,)), bcs["dirichlet"].value(x, y, t).T),
        (getfem_values(data.traction, (2,)), bcs["neumann"].traction(x, y, t, nx, ny).T),
        (getfem_values(data.friction, ()), bcs["contact"].friction(x, y, t, nx, ny)),
        (getfem_values(data.grad, (2, 2)), np.moveaxis(scene.exact.grad(x, y, t), -1, 0)),
    ]
    md.set_variable("t", [0.0])
    pairs += [
        (getfem_values(data.u, (2,)), scene.initial.u(x, y).T),
        (getfem_values(data.v, (2,)), scene.initial.v(x, y).T),
    ]
    return max(float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300)) for a, b in pairs)
