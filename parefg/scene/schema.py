"""The scene schema: every section of a scene's TOML read and checked key by key (SPEC 6).

Each section is a :class:`_Table`; its reader ``take``s every allowed key with a
converter, a default and a check, and ``finish`` reports any leftover key as
unknown.  Errors are one-line :class:`InputError` messages naming the key
(``scene NAME: section.key = value: what is wrong``).  :func:`validate` returns
the effective params, defaults written back, that :mod:`parefg.scene.loader` turns into
a :class:`~parefg.scene.loader.Scene`.
"""

import copy
import math
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from parefg.errors import InputError
from parefg.geometry.domains import BOX_PART_NAMES, Z_EDGE_NAMES, Z_VERTICES, polygon_defect
from parefg.geometry.geo import load_geo
from parefg.geometry.jitter import MAX_JITTER
from parefg.mechanics.friction import DEFAULT_FRICTION_LAW, FRICTION_LAWS, PRESSURE_LAWS

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
#: a scene name is a directory name under runs/: no separator, no leading '.' or '-'
PLAIN_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9._-]{0,99}")
PLAIN_NAME_RULE = (
    "a plain name: letters, digits, '.', '_', '-', not starting with '.' or '-', "
    "at most 100 characters"
)
WEIGHTS = ("cubic", "quartic", "gaussian")
CELLS = ("quad", "tri")
#: the names of parefg.timestepping.schemes.SCHEMES (not imported: PETSc is not started here)
SCHEMES = ("newmark", "generalized-alpha", "static")
DEFAULT_RHO_INF = 0.8  # generalized-alpha: mild high-frequency damping, second order
OUTPUT_FIELDS = ("u", "v", "a", "von_mises", "contact")
OUTPUT_FRAMES = 50  # default time series: about this many output steps per run
# dilation s per MLS degree m; measured: at m = 2, s = 3.2 cuts the H1 error at h = 1/32
# five-fold against s = 2.6 (README, accuracy section)
DEFAULT_SUPPORT = {1: 2.0, 2: 3.2, 3: 4.0}
# Gauss points per cell direction: MLS shape functions are rational, so m >= 2 needs more
DEFAULT_QUADRATURE = {1: 3, 2: 5, 3: 7}
PENALTY_KINDS = ("dirichlet", "contact", "friction")
STEP_TOLERANCE = 1e-9  # relative distance of T / dt from an integer
MAX_STEPS = 10**9  # beyond this T / dt is a typo, and is no longer checked as an integer
AREA_TOLERANCE = 1e-12  # relative to the size squared: a polygon with less area is degenerate

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


def _nonnegative(table: _Table, key: str, value):
    """An expression whose value must be >= 0: numbers are checked here, strings at load."""
    value = _expression(table, key, value)
    if isinstance(value, int | float) and not value >= 0:
        raise table.fail(key, value, "must be >= 0")
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
    defect = polygon_defect(vertices)
    if defect is not None:
        raise table.fail("vertices", vertices, f"must be a simple polygon: {defect}")
    xy = np.array(vertices) - vertices[0]  # (n_vertices, 2), shifted: less cancellation
    # Shoelace formula: positive signed area <=> counter-clockwise.  An area at round-off
    # of the polygon's size squared (collinear vertices) has no sign to trust.
    area = 0.5 * np.sum(xy[:, 0] * np.roll(xy[:, 1], -1) - np.roll(xy[:, 0], -1) * xy[:, 1])
    if not area > AREA_TOLERANCE * np.max(np.ptp(xy, axis=0)) ** 2:
        raise table.fail("vertices", vertices, "must run counter-clockwise (positive area)")
    return list(dict.fromkeys(names))


def _geo_parts(table: _Table, source_dir: Path) -> list[str]:
    """A .geo file (relative to the scene file) and its physical curve names."""
    given = table.take("file", _string)
    path = (source_dir / given).resolve()
    if not path.is_file():
        raise table.fail("file", given, f"no such file ({path})")
    try:  # checked here too, so that a hostile file fails before anything is created
        load_geo(str(path))
    except InputError as exc:
        raise table.fail("file", given, str(exc)) from None
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


def part_segments(domain: dict) -> dict[str, np.ndarray] | None:
    """Boundary part name -> (n, 2, 2) segments [start, end] of a validated domain's outline.

    None for a .geo domain, whose curves only gmsh knows.
    """
    shape = domain["shape"]
    if shape == "geo":
        return None
    if shape == "polygon":
        vertices, names = domain["vertices"], domain["edge_names"]
    elif shape == "z":
        vertices, names = Z_VERTICES, Z_EDGE_NAMES
    else:
        (x0, y0), (lx, ly) = domain.get("origin", (0, 0)), domain.get("size", (1, 1))
        vertices = [(x0, y0), (x0 + lx, y0), (x0 + lx, y0 + ly), (x0, y0 + ly)]
        names = BOX_PART_NAMES
    start = np.asarray(vertices, dtype=float)  # (n_edges, 2); edge i runs to vertex i + 1
    segments = np.stack([start, np.roll(start, -1, axis=0)], axis=1)  # (n_edges, 2, 2)
    return {name: segments[[n == name for n in names]] for name in dict.fromkeys(names)}


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
    if not all(map(math.isfinite, elastic_constants(table.out))):
        raise InputError(f"{table.where}: material: {table.out} gives non-finite E, nu, lam or mu")


def elastic_constants(material: dict) -> tuple[float, float, float, float]:
    """(E, nu, lam, mu), plane strain: lam = E nu / ((1 + nu)(1 - 2 nu)), mu = E / (2 (1 + nu))."""
    if "lam" in material:
        lam, mu = material["lam"], material["mu"]
        return mu * (3 * lam + 2 * mu) / (lam + mu), lam / (2 * (lam + mu)), lam, mu
    E, nu = material["E"], material["nu"]
    return E, nu, E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))


def _read_time(table: _Table) -> None:
    """Newmark is unconditionally stable iff 2 beta >= gamma >= 1/2; the rest is refused."""
    scheme = table.take("scheme", _choice(*SCHEMES), "newmark")
    T = table.take("T", _number, 1.0, POSITIVE)
    table.take("dt", _number, 0.1, (lambda v: 0 < v <= T, f"must be > 0 and <= time.T = {T}"))
    beta = table.take("beta", _number, 0.5, (lambda v: 0 < v <= 1, "must be in (0, 1]"))
    gamma = table.take("gamma", _number, 0.5, (lambda v: 0.5 <= v <= 1, "must be in [0.5, 1]"))
    _read_rho_inf(table, scheme)
    if scheme == "newmark" and 2 * beta < gamma:
        raise table.fail(
            "beta",
            beta,
            f"Newmark with beta < gamma / 2 = {gamma / 2:g} is only conditionally stable "
            "(its explicit range is not supported): need 2 beta >= gamma, "
            "e.g. beta = 0.25, gamma = 0.5",
        )
    step_count(table.where, table.out)


def _read_rho_inf(table: _Table, scheme: str) -> None:
    """rho_inf in [0, 1]: generalized-alpha's spectral radius at infinite frequency.

    Only generalized-alpha reads it (refused with another scheme, where it would do
    nothing).  Its beta and gamma follow from rho_inf (Chung & Hulbert 1993) and replace
    any given ones, so that ``--set time.scheme=generalized-alpha`` works on a scene that
    sets Newmark's; the effective scene shows the values used.
    """
    if scheme != "generalized-alpha":
        if "rho_inf" in table.raw:
            raise table.fail(
                "rho_inf", table.raw["rho_inf"], 'only with time.scheme = "generalized-alpha"'
            )
        return
    unit = (lambda v: 0 <= v <= 1, "must be in [0, 1] (1: no numerical damping)")
    rho_inf = table.take("rho_inf", _number, DEFAULT_RHO_INF, unit)
    alpha_m, alpha_f = (2 * rho_inf - 1) / (rho_inf + 1), rho_inf / (rho_inf + 1)
    table.out["gamma"] = 0.5 - alpha_m + alpha_f
    table.out["beta"] = 0.25 * (1 - alpha_m + alpha_f) ** 2


def step_count(where: str, time: dict) -> int:
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
    "contact": (("gap", _nonnegative, 0, False), ("friction", _nonnegative, 0, True)),
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
        given = set(table.raw)
        kind = table.take("type", _choice(*BOUNDARY_KEYS))
        for key, convert, zero, derived in BOUNDARY_KEYS[kind]:
            table.take(key, convert, None if derived and has_exact else copy.deepcopy(zero))
        if kind == "contact":
            _read_friction_law(table, has_exact)
            _read_friction_coefficient(table, given)
        boundaries[name] = table.finish()
    return boundaries


def _read_friction_law(table: _Table, has_exact: bool) -> None:
    """friction_law: a name of parefg.mechanics.friction.FRICTION_LAWS, by default "tresca".

    When the bound is derived from [exact] (friction not given), the default is "given":
    a manufactured solution such as the square's grazes the obstacle (u_nu = s with
    sigma_nu -> 0 as t -> 0), so under "tresca" the sign of the discretization error of
    u_nu - s would decide which points carry friction (measured on the z scene, m = 1,
    h = 1/16: L2 error 1.5e-4 with "given", 3.8e-3 with "tresca").  The effective scene
    shows the law chosen.
    """
    derived = has_exact and table.out.get("friction") is None
    default = "given" if derived else DEFAULT_FRICTION_LAW
    table.take("friction_law", _choice(*FRICTION_LAWS), default)


def _read_friction_coefficient(table: _Table, given: set) -> None:
    """friction_coefficient mu_f >= 0: required by, and only allowed with, a Coulomb part.

    Coulomb's bound is mu_f times the contact pressure, so a given bound ``friction``
    would have no effect: it is refused rather than ignored (and not written back).
    """
    law = table.out["friction_law"]
    if law not in PRESSURE_LAWS:
        if "friction_coefficient" in table.raw:
            value = table.raw["friction_coefficient"]
            raise table.fail(
                "friction_coefficient",
                value,
                f"only used with friction_law = {', '.join(map(repr, PRESSURE_LAWS))} "
                f"(this part's law {law!r} takes the bound 'friction')",
            )
        return
    if "friction" in given:
        raise table.fail(
            "friction",
            table.out["friction"],
            f"not used with friction_law = {law!r}, whose bound is friction_coefficient "
            "times the contact pressure: give friction_coefficient instead",
        )
    table.out.pop("friction", None)
    if "friction_coefficient" not in table.raw:
        raise InputError(
            f"{table.where}: {table.path}.friction_coefficient is required with "
            f"friction_law = {law!r} (Coulomb's mu_f >= 0)"
        )
    nonnegative = (lambda v: v >= 0, "must be >= 0 (Coulomb's mu_f)")
    table.take("friction_coefficient", _number, check=nonnegative)


def _read_vectors(table: _Table, keys: Sequence[str], has_exact: bool) -> None:
    """2-vector expressions defaulting to zero, or (absent) to data derived from [exact]."""
    for key in keys:
        table.take(key, _vector, None if has_exact else [0, 0])


def default_output_every(n_steps: int) -> int:
    """Steps between outputs for about OUTPUT_FRAMES frames of a run of ``n_steps`` steps."""
    return max(1, round(n_steps / OUTPUT_FRAMES))


def _read_output(table: _Table, time: dict) -> None:
    """every: steps between outputs (0: only the final step), by default about
    OUTPUT_FRAMES frames over the run; written back, so the effective scene shows it."""
    n_steps = step_count(table.where, time)
    within = (lambda v: 0 <= v <= MAX_STEPS, f"must be in 0..{MAX_STEPS} (0: final step only)")
    table.take("every", _integer, default_output_every(n_steps), within)
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


def plain_name(text: str) -> str:
    """``text`` made a plain name (PLAIN_NAME): other characters become '_'; "scene" if empty."""
    plain = re.sub(r"[^A-Za-z0-9._-]", "_", text).lstrip(".-")[:100]
    return plain or "scene"


def validate(where: str, raw: dict, name: str, source_dir: Path) -> tuple[dict, list[str]]:
    """The effective params (defaults filled) and the domain's boundary part names.

    A top-level ``name`` names the default output directory runs/<name>, so it
    must be plain (PLAIN_NAME): "/abs/path" or "../../x" would point elsewhere.
    """
    for key, value in raw.items():
        if key in TOP_LEVEL_KEYS and not isinstance(value, str):
            raise InputError(f"{where}: {key} = {_show(value)}: must be a string")
        if key == "name" and not PLAIN_NAME.fullmatch(value):
            raise InputError(f"{where}: name = {_show(value)}: must be {PLAIN_NAME_RULE}")
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
    E = elastic_constants(params["material"])[0]
    section("penalty", _read_penalty, E, params["discretization"]["h"])
    params["boundary"] = _read_boundaries(where, raw.get("boundary", {}), part_names, has_exact)
    section("initial", _read_vectors, ("u", "v"), has_exact)
    section("loads", _read_vectors, ("f",), has_exact)
    if has_exact:
        section("exact", lambda table: table.take("u", _vector))
    section("output", _read_output, params["time"])
    params["solver"] = _read_solver(where, raw.get("solver", {}))
    return params, part_names
