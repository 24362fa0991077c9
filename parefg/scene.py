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
the effective scene again gives the same scene.
"""

import copy
import math
import tomllib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import sympy

from parefg.errors import InputError
from parefg.expressions import SYMBOLS, compile_field, parse_expression
from parefg.geometry import MAX_JITTER

SCENES_DIR = Path(__file__).with_name("scenes")

Field = Callable[..., np.ndarray]


@dataclass
class BoundaryCondition:
    """The data of one boundary part; callables not used by ``kind`` are None.

    ``value(x, y, t) -> (2, n)`` (dirichlet ubar), ``traction(x, y, t, nx, ny)
    -> (2, n)`` (neumann p), ``gap(x, y) -> (n,)`` and ``friction(x, y, t, nx,
    ny) -> (n,)`` (contact s and Tresca bound g); ``friction_is_zero`` is True
    when g is identically zero, so the solver can skip tangential terms.
    """

    name: str
    kind: str
    value: Field | None = None
    traction: Field | None = None
    gap: Field | None = None
    friction: Field | None = None
    friction_is_zero: bool = True


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
    n_steps: int
    alpha_dirichlet: float
    alpha_contact: float
    alpha_friction: float
    boundaries: dict[str, BoundaryCondition]
    body_force: Field
    initial_u: Field
    initial_v: Field
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
    params, part_names = _validate(where, raw, name, source_dir)
    return _build(where, params, part_names, source_dir)


def _read_source(source: str) -> tuple[str, dict, Path]:
    """(name, raw TOML dict, directory) of a built-in name or a TOML path."""
    builtin = SCENES_DIR / f"{source}.toml"
    looks_like_path = source.endswith(".toml") or "/" in source
    path = builtin if not looks_like_path and builtin.is_file() else Path(source)
    if not path.is_file():
        known = ", ".join(builtin_scenes())
        raise InputError(f"scene {source!r}: no such built-in scene or file (built-in: {known})")
    name = path.stem
    try:
        with path.open("rb") as stream:
            raw = tomllib.load(stream)
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"scene {name}: TOML syntax error in {path}: {exc}") from None
    except OSError as exc:
        raise InputError(f"scene {name}: cannot read {path}: {exc.strerror}") from None
    return name, raw, path.resolve().parent


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
    E, nu, lam, mu = _elastic_constants(params["material"])
    rho = params["material"]["rho"]
    mechanics = None
    if "exact" in params:
        exact_u = _fields(where, "exact.u", params["exact"]["u"])
        mechanics = _Mechanics(exact_u, lam, mu, rho, time["scheme"])
    return Scene(
        name=params["name"],
        params=params,
        source_dir=source_dir,
        domain=_cloud_description(params),
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
        n_steps=_step_count(where, time),
        **{f"alpha_{kind}": penalty[f"alpha_{kind}"] for kind in PENALTY_KINDS},
        boundaries={
            name: _boundary(where, name, table, mechanics)
            for name, table in params.get("boundary", {}).items()
        },
        body_force=_vector_field(where, "loads.f", params["loads"].get("f"), mechanics, "f"),
        initial_u=_initial(where, "u", params["initial"].get("u"), mechanics),
        initial_v=_initial(where, "v", params["initial"].get("v"), mechanics),
        exact=mechanics.solution() if mechanics else None,
        output_every=params["output"]["every"],
        output_fields=list(params["output"]["fields"]),
        solver_options=dict(params["solver"]),
    )


def _cloud_description(params: dict) -> dict:
    """The [domain] table, plus the node jitter and its seed when jitter > 0 (geometry's input)."""
    domain = copy.deepcopy(params["domain"])
    disc = params["discretization"]
    if disc.get("jitter", 0.0) > 0:
        domain.update(jitter=disc["jitter"], seed=disc.get("seed", 0))
    return domain


class _Mechanics:
    """Symbolic elasticity of an exact solution u(x, y, t) (plane strain)."""

    def __init__(self, u: list[sympy.Expr], lam: float, mu: float, rho: float, scheme: str):
        x, y, t, nx, ny = (SYMBOLS[s] for s in ("x", "y", "t", "nx", "ny"))
        self.u = u
        self.grad = sympy.Matrix(2, 2, lambda i, j: sympy.diff(u[i], (x, y)[j]))
        eps = (self.grad + self.grad.T) / 2
        sigma = sympy.Float(lam) * eps.trace() * sympy.eye(2) + 2 * sympy.Float(mu) * eps
        div_sigma = [sympy.diff(sigma[i, 0], x) + sympy.diff(sigma[i, 1], y) for i in range(2)]
        inertia = [sympy.Float(rho) * sympy.diff(ui, t, 2) for ui in u]
        if scheme == "static":
            inertia = [0, 0]
        traction = sigma * sympy.Matrix([nx, ny])
        self.derived = {
            "f": [inertia[i] - div_sigma[i] for i in range(2)],
            "value": list(u),
            "traction": list(traction),
            "friction": [sympy.Abs(-ny * traction[0] + nx * traction[1])],
            "u": [ui.subs(t, 0) for ui in u],
            "v": [sympy.diff(ui, t).subs(t, 0) for ui in u],
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
            v=compile_field([sympy.diff(ui, SYMBOLS["t"]) for ui in self.u]),
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


def _boundary(where: str, name: str, table: dict, mechanics) -> BoundaryCondition:
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
    gap = compile_field([_expr(where, f"{prefix}.gap", table["gap"], ("x", "y"))], ("x", "y"))
    given = table.get("friction")
    friction = (
        [_expr(where, f"{prefix}.friction", given)]
        if given is not None
        else mechanics.derived["friction"]
    )
    friction_field = compile_field(friction, with_normal)
    return BoundaryCondition(
        name,
        kind,
        gap=lambda x, y: gap(x, y)[0],
        friction=lambda x, y, t, nx, ny: friction_field(x, y, t, nx, ny)[0],
        friction_is_zero=_is_zero(friction[0], friction_field),
    )


def _is_zero(expr: sympy.Expr, field: Field) -> bool:
    """Whether ``expr`` is identically zero, the same answer on every rank.

    A nonzero value at a few fixed sample points settles "no" cheaply; only an
    expression that vanishes there is simplified symbolically.
    """
    samples = np.random.default_rng(seed=12345).uniform(0.05, 0.95, size=(4, 7))
    angle = 2 * np.pi * samples[3]
    with np.errstate(all="ignore"):
        values = field(samples[0], samples[1], samples[2], np.cos(angle), np.sin(angle))
    if np.any(np.isfinite(values) & (values != 0)):
        return False
    return sympy.simplify(expr) == 0


# ---------------------------------------------------------------------------
# Schema: every section is read key by key; leftover keys are unknown.

SECTIONS = (
    "domain",
    "discretization",
    "material",
    "time",
    "penalty",
    "boundary",
    "initial",
    "loads",
    "exact",
    "output",
    "solver",
)
TOP_LEVEL_KEYS = ("name", "description")
WEIGHTS = ("cubic", "quartic", "gaussian")
CELLS = ("quad", "tri")
SCHEMES = ("newmark", "static")
OUTPUT_FIELDS = ("u", "v", "a", "von_mises", "contact")
# dilation s per MLS degree m; measured: at m = 2, s = 3.2 cuts the H1 error at h = 1/32
# five-fold against s = 2.6 (README, accuracy section)
DEFAULT_SUPPORT = {1: 2.0, 2: 3.2, 3: 4.0}
# Gauss points per cell direction: MLS shape functions are rational, so m >= 2 needs more
DEFAULT_QUADRATURE = {1: 3, 2: 5, 3: 7}
PENALTY_KINDS = ("dirichlet", "contact", "friction")
STEP_TOLERANCE = 1e-9  # relative distance of T / dt from an integer
MAX_STEPS = 10**9  # beyond this T / dt is a typo, and is no longer checked as an integer

_REQUIRED = object()


def _show(value) -> str:
    """A value as it appears in an error message: repr, one line, at most 60 characters."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _name(key: str) -> str:
    """A key as it appears in an error message: as is if printable, else its repr (one line)."""
    return key if key.isprintable() and len(key) <= 60 else _show(key)


class _Table:
    """One TOML table under validation: ``take`` each key, then ``finish``."""

    def __init__(self, where: str, path: str, raw):
        if not isinstance(raw, dict):
            raise InputError(f"{where}: {path} = {_show(raw)}: must be a table")
        self.where, self.path = where, path
        self.raw = dict(raw)
        self.out: dict = {}
        self.allowed: list[str] = []

    def fail(self, key: str, value, why: str) -> InputError:
        return InputError(f"{self.where}: {self.path}.{_name(key)} = {_show(value)}: {why}")

    def take(self, key: str, convert, default=_REQUIRED, check=None):
        """Convert and check ``key``; a missing key gets ``default`` (None: stays absent)."""
        self.allowed.append(key)
        if key not in self.raw:
            if default is _REQUIRED:
                raise InputError(f"{self.where}: {self.path}.{key} is required")
            if default is not None:
                self.out[key] = default
            return default
        given = self.raw.pop(key)
        value = convert(self, key, given)
        if check is not None and not check[0](value):
            raise self.fail(key, given, check[1])
        self.out[key] = value
        return value

    def finish(self) -> dict:
        """The effective table; any key not taken is an error listing the allowed ones."""
        for key in self.raw:
            allowed = ", ".join(self.allowed)
            raise InputError(
                f"{self.where}: {self.path}.{_name(key)}: unknown key (allowed: {allowed})"
            )
        return self.out


def _number(table: _Table, key: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise table.fail(key, value, "must be a finite number")
    try:
        number = float(value)
    except OverflowError:  # TOML integers have no size limit in tomllib
        number = math.inf
    if not math.isfinite(number):
        raise table.fail(key, value, "must be a finite number")
    return number


def _integer(table: _Table, key: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise table.fail(key, value, "must be an integer")
    return value


def _choice(*options: str):
    def convert(table: _Table, key: str, value) -> str:
        if not isinstance(value, str) or value not in options:
            raise table.fail(key, value, "must be one of " + ", ".join(map(repr, options)))
        return value

    return convert


def _string(table: _Table, key: str, value) -> str:
    if not isinstance(value, str) or not value:
        raise table.fail(key, value, "must be a non-empty string")
    return value


def _names(table: _Table, key: str, value) -> list[str]:
    """A list of names; a leading '_' is reserved for parefg's own parts."""
    if not isinstance(value, list) or not all(isinstance(v, str) and v for v in value):
        raise table.fail(key, value, "must be a list of non-empty strings")
    if any(v.startswith("_") for v in value):
        raise table.fail(key, value, "names must not start with '_'")
    return list(value)


def _expression(table: _Table, key: str, value):
    if isinstance(value, bool) or not isinstance(value, int | float | str):
        raise table.fail(key, value, "must be a number or an expression string in x, y, t")
    return value


def _vector(table: _Table, key: str, value) -> list:
    if not isinstance(value, list) or len(value) != 2:
        raise table.fail(key, value, "must be a list of two numbers or expression strings")
    return [_expression(table, f"{key}[{i}]", v) for i, v in enumerate(value)]


def _pair(table: _Table, key: str, value) -> list[float]:
    if not isinstance(value, list) or len(value) != 2:
        raise table.fail(key, value, "must be a list of two numbers")
    return [_number(table, key, v) for v in value]


def _points(table: _Table, key: str, value) -> list[list[float]]:
    if not isinstance(value, list) or len(value) < 3:
        raise table.fail(key, value, "must be a list of at least 3 points [x, y]")
    return [_pair(table, key, v) for v in value]


POSITIVE = (lambda v: v > 0, "must be > 0")


def _between(low, high):
    return (lambda v: low <= v <= high, f"must be in {low}..{high}")


def _square_parts(table: _Table, source_dir: Path) -> list[str]:
    return ["bottom", "right", "top", "left"]


def _rectangle_parts(table: _Table, source_dir: Path) -> list[str]:
    table.take("size", _pair, _REQUIRED, (lambda v: min(v) > 0, "must be two numbers > 0"))
    table.take("origin", _pair, [0.0, 0.0])
    return ["bottom", "right", "top", "left"]


def _z_parts(table: _Table, source_dir: Path) -> list[str]:
    return ["bottom", "top", "sides"]


def _polygon_parts(table: _Table, source_dir: Path) -> list[str]:
    """Edge i runs from vertex i to i+1; equal edge names merge into one part."""
    vertices = table.take("vertices", _points)
    names = table.take("edge_names", _names)
    if len(names) != len(vertices):
        raise table.fail("edge_names", names, f"needs one name per edge ({len(vertices)})")
    xy = np.array(vertices)  # (n_vertices, 2)
    # Shoelace formula: positive signed area <=> counter-clockwise.
    area = 0.5 * np.sum(xy[:, 0] * np.roll(xy[:, 1], -1) - np.roll(xy[:, 0], -1) * xy[:, 1])
    if not area > 0:
        raise table.fail("vertices", vertices, "must run counter-clockwise (positive area)")
    return list(dict.fromkeys(names))


def _geo_parts(table: _Table, source_dir: Path) -> list[str]:
    """A .geo file (relative to the scene file) and its physical curve names."""
    given = table.take("file", _string)
    path = (source_dir / given).resolve()
    if not path.is_file():
        raise table.fail("file", given, f"no such file ({path})")
    table.out["file"] = str(path)
    distinct = (lambda v: 0 < len(v) == len(set(v)), "must be a non-empty list of distinct names")
    return table.take("parts", _names, _REQUIRED, distinct)


#: domain shape -> reader of its keys, returning the names of its boundary parts
DOMAIN_SHAPES = {
    "square": _square_parts,
    "rectangle": _rectangle_parts,
    "z": _z_parts,
    "polygon": _polygon_parts,
    "geo": _geo_parts,
}


def _read_domain(table: _Table, source_dir: Path) -> list[str]:
    shape = table.take("shape", _choice(*DOMAIN_SHAPES), "square")
    return DOMAIN_SHAPES[shape](table, source_dir)


def _read_discretization(table: _Table) -> None:
    table.take("h", _number, 0.1, POSITIVE)
    degree = table.take("degree", _integer, 1, _between(1, 3))
    table.take("weight", _choice(*WEIGHTS), "cubic")
    table.take("support", _number, DEFAULT_SUPPORT[degree], (lambda v: v > 1, "must be > 1"))
    table.take("quadrature", _integer, DEFAULT_QUADRATURE.get(degree, 5), _between(1, 10))
    table.take("cells", _choice(*CELLS), "quad")
    # Absent stays absent (no jitter): the effective scene of an unjittered run is unchanged.
    table.take("jitter", _number, None, _between(0.0, MAX_JITTER))
    table.take("seed", _integer, None, (lambda v: 0 <= v < 2**63, "must be in 0..2**63 - 1"))


def _read_material(table: _Table) -> None:
    """(E > 0, -1 < nu < 0.5) or (mu > 0, lam > -2 mu / 3), never both; default E = 1, nu = 0.3."""
    lame = {"lam", "mu"} & table.raw.keys()
    if lame and {"E", "nu"} & table.raw.keys():
        raise InputError(f"{table.where}: material: give E and nu, or lam and mu, not both")
    if lame:
        mu = table.take("mu", _number, _REQUIRED, POSITIVE)
        # lam > -2 mu / 3 <=> E > 0 and nu > -1, the same range as the (E, nu) pair.
        table.take("lam", _number, _REQUIRED, (lambda v: 3 * v > -2 * mu, "must be > -2 mu / 3"))
    else:
        table.take("E", _number, 1.0, POSITIVE)
        table.take("nu", _number, 0.3, (lambda v: -1 < v < 0.5, "must be in (-1, 0.5)"))
    table.take("rho", _number, 1.0, POSITIVE)
    table.allowed = ["E", "nu", "lam", "mu", "rho"]
    if not all(map(math.isfinite, _elastic_constants(table.out))):
        raise InputError(f"{table.where}: material: {table.out} gives non-finite E, nu, lam or mu")


def _elastic_constants(material: dict) -> tuple[float, float, float, float]:
    """(E, nu, lam, mu), plane strain: lam = E nu / ((1 + nu)(1 - 2 nu)), mu = E / (2 (1 + nu))."""
    if "lam" in material:
        lam, mu = material["lam"], material["mu"]
        return mu * (3 * lam + 2 * mu) / (lam + mu), lam / (2 * (lam + mu)), lam, mu
    E, nu = material["E"], material["nu"]
    return E, nu, E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))


def _read_time(table: _Table) -> None:
    table.take("scheme", _choice(*SCHEMES), "newmark")
    T = table.take("T", _number, 1.0, POSITIVE)
    table.take("dt", _number, 0.1, (lambda v: 0 < v <= T, f"must be > 0 and <= time.T = {T}"))
    table.take("beta", _number, 0.5, (lambda v: 0 < v <= 1, "must be in (0, 1]"))
    table.take("gamma", _number, 0.5, (lambda v: 0.5 <= v <= 1, "must be in [0.5, 1]"))
    _step_count(table.where, table.out)


def _step_count(where: str, time: dict) -> int:
    """n_steps = T / dt, which must be an integer to within STEP_TOLERANCE."""
    ratio = time["T"] / time["dt"]
    if not ratio <= MAX_STEPS:
        raise InputError(
            f"{where}: time.dt = {time['dt']}: T / dt = {ratio:.6g} steps (at most {MAX_STEPS:.0e})"
        )
    if abs(ratio - round(ratio)) > STEP_TOLERANCE * ratio:
        raise InputError(
            f"{where}: time.dt = {time['dt']}: T / dt = {ratio:.6g} must be an integer"
        )
    return round(ratio)


def _read_penalty(table: _Table, E: float, h: float) -> None:
    """alpha defaults to 1e4 E / h; the three specific factors default to alpha.

    Measured (static square, m = 1, 2, h = 1/8 .. 1/32): the error is flat for alpha h / E
    in 1e3 .. 1e5 and grows above ~1e6, where the Dirichlet penalty over-constrains the
    MLS trace (README, accuracy section).
    """
    default = 1e4 * E / h
    if "alpha" not in table.raw and not math.isfinite(default):
        raise table.fail("alpha", default, "the default 1e4 E / h overflows: give penalty.alpha")
    alpha = table.take("alpha", _number, default, POSITIVE)
    for kind in PENALTY_KINDS:
        table.take(f"alpha_{kind}", _number, alpha, POSITIVE)


#: boundary type -> (key, converter, default without [exact], derived from [exact]?)
BOUNDARY_KEYS = {
    "dirichlet": (("value", _vector, [0, 0], True),),
    "neumann": (("traction", _vector, [0, 0], True),),
    "contact": (("gap", _expression, 0, False), ("friction", _expression, 0, True)),
}


def _read_boundaries(where: str, raw, part_names: list[str], has_exact: bool) -> dict:
    if not isinstance(raw, dict):
        raise InputError(f"{where}: boundary = {_show(raw)}: must be a table of [boundary.NAME]")
    boundaries = {}
    for name, entry in raw.items():
        if name not in part_names:
            known = ", ".join(part_names)
            raise InputError(
                f"{where}: boundary.{_name(name)}: unknown boundary part (allowed: {known})"
            )
        table = _Table(where, f"boundary.{name}", entry)
        kind = table.take("type", _choice(*BOUNDARY_KEYS))
        for key, convert, zero, derived in BOUNDARY_KEYS[kind]:
            table.take(key, convert, None if derived and has_exact else copy.deepcopy(zero))
        boundaries[name] = table.finish()
    return boundaries


def _read_vectors(table: _Table, keys: Sequence[str], has_exact: bool) -> None:
    """2-vector expressions defaulting to zero, or (absent) to data derived from [exact]."""
    for key in keys:
        table.take(key, _vector, None if has_exact else [0, 0])


def _read_output(table: _Table) -> None:
    table.take("every", _integer, 0, (lambda v: v >= 0, "must be >= 0"))
    known = (lambda v: set(v) <= set(OUTPUT_FIELDS), "allowed: " + ", ".join(OUTPUT_FIELDS))
    table.take("fields", _names, list(OUTPUT_FIELDS), known)


def _read_solver(where: str, raw) -> dict[str, str]:
    """PETSc options (name without '-') -> value as on a command line ("" for a bare flag)."""
    table = _Table(where, "solver", raw)
    options = {}
    for key, value in table.raw.items():
        name = key.lstrip("-")
        if not name or not all(c.isalnum() or c == "_" for c in name):
            raise InputError(f"{where}: solver.{_name(key)}: not a PETSc option name")
        if isinstance(value, bool):
            # A bare "-ksp_monitor" is PETSc's "true"; "-ksp_monitor true" would name a viewer.
            options[name] = "" if value else "false"
        elif isinstance(value, int | float | str):
            options[name] = str(value)
        else:
            raise table.fail(key, value, "must be a string, number or boolean")
    return options


def _validate(where: str, raw: dict, name: str, source_dir: Path) -> tuple[dict, list[str]]:
    """The effective params (defaults filled) and the domain's boundary part names."""
    for key, value in raw.items():
        if key in TOP_LEVEL_KEYS and not isinstance(value, str):
            raise InputError(f"{where}: {key} = {_show(value)}: must be a string")
        if key not in SECTIONS and key not in TOP_LEVEL_KEYS:
            allowed = ", ".join(SECTIONS)
            raise InputError(f"{where}: [{_name(key)}]: unknown section (allowed: {allowed})")
    params: dict = {"name": name, **{key: raw[key] for key in TOP_LEVEL_KEYS if key in raw}}
    has_exact = "exact" in raw

    def section(key: str, reader, *args):
        table = _Table(where, key, raw.get(key, {}))
        result = reader(table, *args)
        params[key] = table.finish()
        return result

    part_names = section("domain", _read_domain, source_dir)
    section("discretization", _read_discretization)
    section("material", _read_material)
    section("time", _read_time)
    E = _elastic_constants(params["material"])[0]
    section("penalty", _read_penalty, E, params["discretization"]["h"])
    params["boundary"] = _read_boundaries(where, raw.get("boundary", {}), part_names, has_exact)
    section("initial", _read_vectors, ("u", "v"), has_exact)
    section("loads", _read_vectors, ("f",), has_exact)
    if has_exact:
        section("exact", lambda table: table.take("u", _vector))
    section("output", _read_output)
    params["solver"] = _read_solver(where, raw.get("solver", {}))
    return params, part_names
