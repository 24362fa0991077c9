"""Scenes: TOML problem descriptions, validated and completed (SPEC 6, 9).

:func:`load_scene` reads a built-in scene or a TOML file, applies
``section.key=value`` overrides, checks every section and key against the
schema (one-line :class:`InputError` naming the key), writes the defaults back
so that ``Scene.params`` is the effective scene, and turns expressions into
vectorized callables.  Given ``[exact] u``, whatever boundary, initial and load
data the scene leaves out are derived from it by symbolic differentiation:

    eps = sym grad u,  sigma = lam tr(eps) I + 2 mu eps,
    f = rho u_tt - div sigma (newmark) or -div sigma (static),
    ubar = u,  p = sigma n,  g = |tau . sigma n| with tau = (-n_y, n_x),
    u0 = u(., 0),  v0 = u_t(., 0).

Derived data stay out of ``params`` (they follow from ``[exact]``), so loading
the effective scene again gives the same scene.  The schema (sections, keys,
defaults, checks) lives in :mod:`parefg.scene.schema`; its public names are
re-exported here.
"""

import copy
import tomllib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import sympy

from parefg.errors import InputError
from parefg.mechanics.friction import PRESSURE_LAWS
from parefg.scene.checks import SignChecks
from parefg.scene.expressions import SYMBOLS, compile_field, parse_expression
from parefg.scene.schema import (
    BOUNDARY_KEYS,
    CELLS,
    DEFAULT_QUADRATURE,
    DEFAULT_SUPPORT,
    DOMAIN_SHAPES,
    MAX_STEPS,
    OUTPUT_FIELDS,
    PENALTY_KINDS,
    POSITIVE,
    SCHEMES,
    SECTIONS,
    STEP_TOLERANCE,
    TOP_LEVEL_KEYS,
    WEIGHTS,
    elastic_constants,
    plain_name,
    step_count,
    validate,
)
from parefg.scene.symbolic import DerivativeBudget, is_identically_zero

__all__ = [
    "BOUNDARY_KEYS",
    "CELLS",
    "DEFAULT_QUADRATURE",
    "DEFAULT_SUPPORT",
    "DOMAIN_SHAPES",
    "MAX_STEPS",
    "OUTPUT_FIELDS",
    "PENALTY_KINDS",
    "POSITIVE",
    "SCENES_DIR",
    "SCHEMES",
    "SECTIONS",
    "STEP_TOLERANCE",
    "TOP_LEVEL_KEYS",
    "WEIGHTS",
    "BoundaryCondition",
    "ExactSolution",
    "Field",
    "Scene",
    "builtin_scenes",
    "elastic_constants",
    "load_scene",
    "step_count",
    "validate",
]

SCENES_DIR = Path(__file__).with_name("builtin")
MAX_SCENE_BYTES = 2**24  # a scene is a few hundred bytes; a long polygon a few hundred KB

Field = Callable[..., np.ndarray]


@dataclass
class BoundaryCondition:
    """The data of one boundary part; callables not used by ``kind`` are None.

    ``value(x, y, t) -> (2, n)`` (dirichlet ubar), ``traction(x, y, t, nx, ny)
    -> (2, n)`` (neumann p), ``gap(x, y) -> (n,)`` and ``friction(x, y, t, nx,
    ny) -> (n,)`` (contact s and Tresca bound g); ``friction_is_zero`` is True
    when g is identically zero, so the solver can skip tangential terms;
    ``friction_law`` names the contact part's law in parefg.mechanics.friction.FRICTION_LAWS.
    A Coulomb part (friction_law in PRESSURE_LAWS) has the coefficient mu_f
    ``friction_coefficient``, a zero ``friction`` field (its bound mu_f p is set by the
    step), and ``friction_is_zero`` iff mu_f = 0.
    """

    name: str
    kind: str
    value: Field | None = None
    traction: Field | None = None
    gap: Field | None = None
    friction: Field | None = None
    friction_is_zero: bool = True
    friction_law: str = "tresca"
    friction_coefficient: float = 0.0


@dataclass
class ExactSolution:
    """A manufactured solution: ``u(x, y, t) -> (2, n)``, ``v`` = du/dt ``-> (2, n)``,
    ``grad(x, y, t) -> (2, 2, n)`` with ``[i, j] = d u_i / d x_j``; ``exprs`` in sympy."""

    exprs: list[sympy.Expr]
    u: Field
    v: Field
    grad: Field


@dataclass
class Scene:
    """A validated scene: the effective ``params`` and everything derived from them."""

    name: str
    params: dict
    source_dir: Path
    domain: dict
    part_names: list[str]
    h: float
    degree: int
    weight: str
    support: float
    quadrature: int
    cells: str
    jitter: float
    seed: int
    E: float
    nu: float
    lam: float
    mu: float
    rho: float
    scheme: str
    T: float
    dt: float
    beta: float
    gamma: float
    rho_inf: float | None
    n_steps: int
    alpha_dirichlet: float
    alpha_contact: float
    alpha_friction: float
    boundaries: dict[str, BoundaryCondition]
    body_force: Field
    initial_u: Field
    initial_v: Field
    # grad u0 (x, y) -> (2, 2, n) and div sigma(u0) (x, y) -> (2, n); None where u0 = 0
    initial_grad: Field | None
    initial_div_stress: Field | None
    exact: ExactSolution | None
    output_every: int
    output_fields: list[str]
    solver_options: dict[str, str]


def builtin_scenes() -> dict[str, str]:
    """Built-in scene names -> their description (``description`` key or first comment line)."""
    scenes = {}
    for path in sorted(SCENES_DIR.glob("*.toml")):
        text = path.read_text()
        first = text.lstrip().splitlines()[0] if text.strip() else ""
        described = tomllib.loads(text).get("description")
        scenes[path.stem] = described or first.lstrip("#").strip()
    return scenes


def load_scene(source: str, overrides: Sequence[str] = ()) -> Scene:
    """Read, override, validate and complete a scene.

    Not collective (every rank may call it; the result is the same).

    Parameters
    ----------
    source
        A built-in scene name (see :func:`builtin_scenes`) or a path to a TOML file.
    overrides
        ``"section.key=value"`` strings, e.g. ``"discretization.h=0.05"`` or
        ``"boundary.bottom.friction=0"``; value is read as a TOML value, else as a string.

    Raises
    ------
    InputError
        One line, ``scene NAME: key ...: what is wrong``, for a missing file, a
        TOML syntax error, a bad override or any schema violation.
    """
    name, raw, source_dir = _read_source(source)
    where = f"scene {name}"
    for text in overrides:
        _apply_override(raw, text, where)
    params, part_names = validate(where, raw, name, source_dir)
    return _build(where, params, part_names, source_dir)


def _read_source(source: str) -> tuple[str, dict, Path]:
    """(name, raw TOML dict, directory) of a built-in name or a TOML path."""
    builtin = SCENES_DIR / f"{source}.toml"
    looks_like_path = source.endswith(".toml") or "/" in source
    path = builtin if not looks_like_path and builtin.is_file() else Path(source)
    if not path.is_file():
        known = ", ".join(builtin_scenes())
        raise InputError(f"scene {source!r}: no such built-in scene or file (built-in: {known})")
    name = plain_name(path.stem)  # the default output directory is runs/<name>
    try:
        if path.stat().st_size > MAX_SCENE_BYTES:
            size = path.stat().st_size
            raise InputError(f"scene {name}: {path} has {size} bytes (at most {MAX_SCENE_BYTES})")
        with path.open("rb") as stream:
            raw = tomllib.load(stream)
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"scene {name}: TOML syntax error in {path}: {exc}") from None
    except (RecursionError, MemoryError, ValueError) as exc:
        raise InputError(f"scene {name}: cannot parse {path}: {_toml_failure(exc)}") from None
    except OSError as exc:
        raise InputError(f"scene {name}: cannot read {path}: {exc.strerror}") from None
    return name, raw, path.resolve().parent


def _toml_failure(exc: Exception) -> str:
    """Why tomllib failed other than by a syntax error, in one line."""
    if isinstance(exc, RecursionError):
        return "arrays or tables nested too deeply"
    if isinstance(exc, MemoryError):
        return "out of memory"
    # Python refuses to convert integers of more than 4300 digits
    return str(exc).split(";")[0].split(":")[0]


def _apply_override(raw: dict, text: str, where: str) -> None:
    """Set ``raw[section][...][key] = value`` from ``"section.key=value"``."""
    path, equals, value_text = text.partition("=")
    keys = path.strip().split(".")
    if not equals or len(keys) < 2 or not all(keys):
        raise InputError(f"{where}: --set {text!r}: expected section.key=value")
    try:
        value = tomllib.loads("v = " + value_text)["v"]
    except tomllib.TOMLDecodeError:
        value = value_text.strip()
    except (RecursionError, MemoryError, ValueError) as exc:
        shown = repr(text) if len(text) <= 60 else repr(text[:57] + "...")
        raise InputError(f"{where}: --set {shown}: {_toml_failure(exc)}") from None
    table = raw
    for depth, key in enumerate(keys[:-1]):
        table = table.setdefault(key, {})
        if not isinstance(table, dict):
            inner = ".".join(keys[: depth + 1])
            raise InputError(f"{where}: --set {text!r}: {inner} is not a table")
    table[keys[-1]] = value


def _expr(where: str, key: str, value, args=("x", "y", "t")) -> sympy.Expr:
    """Parse one scene value whose free symbols must be among ``args``."""
    expr = parse_expression(value, f"{where}: {key}")
    extra = expr.free_symbols - {SYMBOLS[a] for a in args}
    if extra:
        used = ", ".join(sorted(str(s) for s in extra))
        raise InputError(f"{where}: {key}: must not depend on {used}")
    return expr


def _fields(where: str, key: str, values: list, args=("x", "y", "t")) -> list[sympy.Expr]:
    """Parse a list of scene values, each error naming ``key[i]``."""
    return [_expr(where, f"{key}[{i}]", value, args) for i, value in enumerate(values)]


def _build(where: str, params: dict, part_names: list[str], source_dir: Path) -> Scene:
    """Turn validated params into a Scene with callables."""
    disc, time, penalty = params["discretization"], params["time"], params["penalty"]
    E, nu, lam, mu = elastic_constants(params["material"])
    rho = params["material"]["rho"]
    mechanics = None
    if "exact" in params:
        exact_u = _fields(where, "exact.u", params["exact"]["u"])
        budget = DerivativeBudget(where, "exact.u")
        mechanics = _Mechanics(exact_u, lam, mu, rho, time["scheme"], budget)
    checks = SignChecks(where, params, E)
    initial_grad, initial_div_stress = _initial_elasticity(
        where, params["initial"].get("u"), mechanics, lam, mu, rho
    )
    return Scene(
        name=params["name"],
        params=params,
        source_dir=source_dir,
        domain=copy.deepcopy(params["domain"]),
        part_names=list(part_names),
        **{key: disc[key] for key in ("h", "degree", "weight", "support", "quadrature", "cells")},
        jitter=disc.get("jitter", 0.0),
        seed=disc.get("seed", 0),
        E=E,
        nu=nu,
        lam=lam,
        mu=mu,
        rho=rho,
        **{key: time[key] for key in ("scheme", "T", "dt", "beta", "gamma")},
        rho_inf=time.get("rho_inf"),
        n_steps=step_count(where, time),
        **{f"alpha_{kind}": penalty[f"alpha_{kind}"] for kind in PENALTY_KINDS},
        boundaries={
            name: _boundary(where, name, table, mechanics, checks)
            for name, table in params.get("boundary", {}).items()
        },
        body_force=_vector_field(where, "loads.f", params["loads"].get("f"), mechanics, "f"),
        initial_u=_initial(where, "u", params["initial"].get("u"), mechanics),
        initial_v=_initial(where, "v", params["initial"].get("v"), mechanics),
        initial_grad=initial_grad,
        initial_div_stress=initial_div_stress,
        exact=mechanics.solution() if mechanics else None,
        output_every=params["output"]["every"],
        output_fields=list(params["output"]["fields"]),
        solver_options=dict(params["solver"]),
    )


class _Mechanics:
    """Symbolic elasticity of an exact solution u(x, y, t) (plane strain).

    Every derivative goes through ``budget``, which refuses an exact solution whose
    derived data would be too large to compute, compile or evaluate.
    """

    def __init__(
        self,
        u: list[sympy.Expr],
        lam: float,
        mu: float,
        rho: float,
        scheme: str,
        budget: DerivativeBudget,
    ):
        x, y, t, nx, ny = (SYMBOLS[s] for s in ("x", "y", "t", "nx", "ny"))
        diff = budget.diff
        self.u = u
        self.grad = sympy.Matrix(2, 2, lambda i, j: diff(u[i], (x, y)[j]))
        self.velocity = [diff(ui, t) for ui in u]
        eps = (self.grad + self.grad.T) / 2
        sigma = sympy.Float(lam) * eps.trace() * sympy.eye(2) + 2 * sympy.Float(mu) * eps
        div_sigma = [diff(sigma[i, 0], x) + diff(sigma[i, 1], y) for i in range(2)]
        self.div_sigma = div_sigma
        inertia = [sympy.Float(rho) * diff(vi, t) for vi in self.velocity]
        if scheme == "static":
            inertia = [0, 0]
        traction = sigma * sympy.Matrix([nx, ny])
        tangential = -ny * traction[0] + nx * traction[1]
        budget.charge(*traction, tangential)
        self.derived = {
            "f": [inertia[i] - div_sigma[i] for i in range(2)],
            "value": list(u),
            "traction": list(traction),
            "friction": [sympy.Abs(tangential)],
            "u": [ui.subs(t, 0) for ui in u],
            "v": [vi.subs(t, 0) for vi in self.velocity],
        }

    def solution(self) -> ExactSolution:
        """Vectorized u, v and grad u."""
        gradient = compile_field([self.grad[i, j] for i in range(2) for j in range(2)])

        def grad(x, y, t):
            rows = gradient(x, y, t)  # (4, n), row 2 i + j = d u_i / d x_j
            return rows.reshape(2, 2, *rows.shape[1:])

        return ExactSolution(
            exprs=list(self.u),
            u=compile_field(self.u),
            v=compile_field(self.velocity),
            grad=grad,
        )


def _vector_field(where, key, values, mechanics, derived_key, args=("x", "y", "t")) -> Field:
    """The given expressions, or the ones derived from the exact solution."""
    exprs = _fields(where, key, values, args) if values is not None else None
    if exprs is None:
        exprs = mechanics.derived[derived_key]
    return compile_field(exprs, args)


def _initial(where: str, key: str, values, mechanics) -> Field:
    """u0 or v0 as a function of (x, y); a given t is read as t = 0."""
    t = SYMBOLS["t"]
    if values is not None:
        exprs = [e.subs(t, 0) for e in _fields(where, f"initial.{key}", values)]
    else:
        exprs = mechanics.derived[key]
    return compile_field(exprs, ("x", "y"))


def _initial_elasticity(
    where: str, values, mechanics, lam, mu, rho
) -> tuple[Field | None, Field | None]:
    """grad u0 and div sigma(u0) as functions of (x, y), for the consistent start.

    Both None when u0 vanishes identically (decided on the expressions, not on floats).
    """
    x, y, t = (SYMBOLS[s] for s in ("x", "y", "t"))
    if values is not None:
        exprs = [e.subs(t, 0) for e in _fields(where, "initial.u", values)]
    else:
        exprs = mechanics.derived["u"]
    if all(is_identically_zero(e, [x, y]) for e in exprs):
        return None, None
    initial = _Mechanics(exprs, lam, mu, rho, "static", DerivativeBudget(where, "initial.u"))
    gradient = compile_field([initial.grad[i, j] for i in range(2) for j in range(2)], ("x", "y"))

    def grad(x, y):
        rows = gradient(x, y)  # (4, n), row 2 i + j = d u0_i / d x_j
        return rows.reshape(2, 2, *rows.shape[1:])

    return grad, compile_field(initial.div_sigma, ("x", "y"))


def _boundary(where: str, name: str, table: dict, mechanics, checks) -> BoundaryCondition:
    """BoundaryCondition of one [boundary.NAME] table."""
    kind, prefix = table["type"], f"boundary.{name}"
    with_normal = ("x", "y", "t", "nx", "ny")
    if kind == "dirichlet":
        value = _vector_field(where, f"{prefix}.value", table.get("value"), mechanics, "value")
        return BoundaryCondition(name, kind, value=value)
    if kind == "neumann":
        traction = _vector_field(
            where, f"{prefix}.traction", table.get("traction"), mechanics, "traction", with_normal
        )
        return BoundaryCondition(name, kind, traction=traction)
    gap_expr = _expr(where, f"{prefix}.gap", table["gap"], ("x", "y"))
    checks.nonnegative(name, "gap", table["gap"], gap_expr)
    gap = compile_field([gap_expr], ("x", "y"))
    if table["friction_law"] in PRESSURE_LAWS:
        return _coulomb_boundary(name, table, lambda x, y: gap(x, y)[0])
    given = table.get("friction")
    if given is not None:
        friction = [_expr(where, f"{prefix}.friction", given)]
        checks.nonnegative(name, "friction", given, friction[0])
    else:  # |tau . sigma n| >= 0
        friction = mechanics.derived["friction"]
    friction_field = compile_field(friction, with_normal)
    return BoundaryCondition(
        name,
        kind,
        gap=lambda x, y: gap(x, y)[0],
        friction=lambda x, y, t, nx, ny: friction_field(x, y, t, nx, ny)[0],
        # derived friction is homogeneous in (nx, ny): zero for all normals iff for unit ones
        friction_is_zero=is_identically_zero(friction[0], [SYMBOLS[s] for s in with_normal]),
        friction_law=table["friction_law"],
    )


def _coulomb_boundary(name: str, table: dict, gap: Field) -> BoundaryCondition:
    """A Coulomb contact part: no given bound (zero field), the coefficient mu_f."""
    coefficient = table["friction_coefficient"]
    return BoundaryCondition(
        name,
        "contact",
        gap=gap,
        friction=lambda x, y, t, nx, ny: np.zeros(np.shape(x)),
        friction_is_zero=coefficient == 0,  # the scene's number, not a computed float
        friction_law=table["friction_law"],
        friction_coefficient=coefficient,
    )
