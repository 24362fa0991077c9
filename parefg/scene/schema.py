"""The scene schema: every section of a scene's TOML read and checked key by key (SPEC 6).

Each section is a :class:`~parefg.scene.table.Table` read by one function below (the
``[boundary.NAME]`` tables by :mod:`parefg.scene.boundaries`).  The
allowed names of interchangeable parts are read from their registries, not listed here:
domain shapes and their keys from :data:`parefg.geometry.shapes.SHAPES`, weights from
:data:`parefg.discretization.weights.WEIGHTS`, friction laws from
:data:`parefg.mechanics.friction.FRICTION_LAWS`, contact forces from
:data:`parefg.mechanics.normal_force.CONTACT_FORCES`, penalty factors from
:data:`parefg.mechanics.penalty.PENALTY_KINDS`, time schemes from
:data:`parefg.timestepping.schemes.SCHEMES`, solver methods from
:data:`parefg.timestepping.linear_solver.SOLVER_METHODS`, boundary types from
:class:`parefg.boundary.BoundaryKind`.  :func:`validate` returns the effective params,
defaults written back, that :mod:`parefg.scene.loader` turns into a
:class:`~parefg.scene.sections.Scene`.
"""

import copy
import math
import re
from collections.abc import Sequence
from pathlib import Path

from parefg.discretization.weights import DEFAULT_WEIGHT, WEIGHTS
from parefg.errors import InputError
from parefg.geometry.cells import CELL_TYPES
from parefg.geometry.geo import load_geo
from parefg.geometry.jitter import MAX_JITTER
from parefg.geometry.shapes import DEFAULT_SHAPE, SHAPES, domain_part_names
from parefg.mechanics.normal_force import CONTACT_FORCES
from parefg.mechanics.penalty import PENALTY_KINDS
from parefg.scene.boundaries import read_boundaries
from parefg.scene.table import (
    POSITIVE,
    REQUIRED,
    Table,
    as_integer,
    as_names,
    as_number,
    as_pair,
    as_points,
    as_string,
    as_vector,
    between,
    key_name,
    one_of,
    show,
)
from parefg.timestepping.linear_solver import (
    DEFAULT_SOLVER_METHOD,
    SOLVER_METHODS,
    SYMMETRIC_KSPS,
    SYMMETRIC_PCS,
)
from parefg.timestepping.schemes import (
    SCHEMES,
    GeneralizedAlphaScheme,
    NewmarkScheme,
    generalized_alpha_parameters,
)

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
DEFAULT_SCHEME = next(iter(SCHEMES))
DEFAULT_RHO_INF = 0.8  # generalized-alpha: mild high-frequency damping, second order
#: [output] fields -> the result.h5 datasets each writes (parefg.io.observers)
OUTPUT_FIELDS = {
    "u": ("displacement",),
    "v": ("velocity",),
    "a": ("acceleration",),
    "von_mises": ("von_mises",),
    "contact": ("gap", "normal_pressure", "tangential_traction", "status"),
}
OUTPUT_FRAMES = 50  # default time series: about this many output steps per run
# dilation s per MLS degree m; measured: at m = 2, s = 3.2 cuts the H1 error at h = 1/32
# five-fold against s = 2.6 (README, accuracy section)
DEFAULT_SUPPORT = {1: 2.0, 2: 3.2, 3: 4.0}
# ... and with solver.method = "iterative": wide supports make the system ill-conditioned
# (CG + GAMG at m = 2: 413 iterations at h = 1/16 with s = 3.2, growing with 1 / h; 16, 17,
# 19 from h = 1/16 to 1/64 with s = 2.4; README, performance: iterative solver).  At m = 3
# 3.2 takes 4-5x fewer than 4.0 on the square's grid, but is not admissible on coarse
# unstructured cells (the Z at h = 1/8, graded .geo clouds: a moment matrix with 9-12
# neighbours for 10 basis functions), so other shapes keep 4.0 there.
ITERATIVE_SUPPORT = {1: 2.0, 2: 2.4, 3: 3.2}
ITERATIVE_UNSTRUCTURED_SUPPORT = {1: 2.0, 2: 2.4, 3: 4.0}
# Gauss points per cell direction by MLS degree m, on the structured grid of a box shape
# and on the unstructured cells of the others (the Z's re-entrant corner).  MLS shape
# functions are rational and their supports cut the cells, so Gauss rules converge
# slowly; with Nitsche's consistent boundary terms the quadrature error is what remains.
# Measured (static manufactured solution, h = 1/32, Nitsche; README, accuracy section):
# square m = 1: H1 8.5e-4 with 3 or 4 points (the 3 x 3 rule suffices on the grid);
# square m = 2: L2 1.3e-6 with 5 points, 5.1e-7 with 8; Z m = 1: H1 3.0e-3 (3 points),
# 1.2e-3 (6); Z m = 2: H1 6.8e-4 (5), 1.4e-4 (8), 8.2e-5 (10); Z m = 3, h = 1/16: H1
# 4.7e-4 (7), 1.7e-4 (9), 8.2e-5 (12); square m = 3, h = 1/16: H1 1.3e-5 (7), 4.8e-6 (9).
DEFAULT_QUADRATURE = {1: 3, 2: 8, 3: 9}
UNSTRUCTURED_QUADRATURE = {1: 6, 2: 10, 3: 12}
MAX_QUADRATURE = 16
# How K is integrated: "gauss" (the MLS gradients at the Gauss points) or "vci" (their
# variationally consistent correction, parefg.discretization.consistent_gradients).
INTEGRATIONS = ("gauss", "vci")
# Per degree, with the direct solver.  At m = 3 Gauss integration of the rational MLS
# gradients limits the error (static, h = 1/32: Z H1 1.69e-5 with 12 x 12 points, rate
# 1.2; square L2 2.55e-8), VCI restores the theory's rates (Z H1 1.10e-6, square L2
# 5.2e-9) with fewer points: its error is the same from 7 x 7 to 12 x 12 points (square,
# Z, h = 1/8 ... 1/32), so it runs with 7 (grid) / 8 (unstructured cells) and costs less
# than Gauss's 9 / 12.  VCI's K is nonsymmetric: the iterative solver (CG) keeps "gauss".
DEFAULT_INTEGRATION = {1: "gauss", 2: "gauss", 3: "vci"}
VCI_QUADRATURE = {3: 7}
VCI_UNSTRUCTURED_QUADRATURE = {3: 8}
STEP_TOLERANCE = 1e-9  # relative distance of T / dt from an integer
MAX_STEPS = 10**9  # beyond this T / dt is a typo, and is no longer checked as an integer

#: key of a [domain] table -> (converter, default, check); the keys of each shape are
#: Shape.keys, "file" is read by _geo_file (relative to the scene file)
DOMAIN_KEYS = {
    "size": (as_pair, REQUIRED, (lambda v: min(v) > 0, "must be two numbers > 0")),
    "origin": (as_pair, [0.0, 0.0], None),
    "vertices": (as_points, REQUIRED, None),
    "edge_names": (as_names, REQUIRED, None),
    "parts": (as_names, REQUIRED, (lambda v: 0 < len(v) == len(set(v)),
                                   "must be a non-empty list of distinct names")),
}  # fmt: skip


def _geo_file(source_dir: Path):
    """Converter of ``domain.file``: a .geo file relative to the scene file, made absolute."""

    def convert(table: Table, key: str, value) -> str:
        given = as_string(table, key, value)
        path = (source_dir / given).resolve()
        if not path.is_file():
            raise table.fail(key, given, f"no such file ({path})")
        try:  # checked here too, so that a hostile file fails before anything is created
            load_geo(str(path))
        except InputError as exc:
            raise table.fail(key, given, str(exc)) from None
        return str(path)

    return convert


def _read_domain(table: Table, source_dir: Path) -> list[str]:
    """The shape, its keys (Shape.keys) and their joint check; returns the part names."""
    shape = SHAPES[table.take("shape", one_of(*SHAPES), DEFAULT_SHAPE)]
    readers = {**DOMAIN_KEYS, "file": (_geo_file(source_dir), REQUIRED, None)}
    for key in shape.keys:
        convert, default, check = readers[key]
        # A fresh default for each scene (REQUIRED is a sentinel, kept as is).
        table.take(key, convert, default if default is REQUIRED else copy.deepcopy(default), check)
    problem = shape.check(table.out) if shape.check is not None else None
    if problem is not None:
        key, why = problem
        raise table.fail(key, table.out[key], why)
    return domain_part_names(table.out)


def _read_discretization(table: Table, shape: str, solver: dict) -> None:
    """h, m, weight, support, integration and quadrature.  The defaults of support and
    integration depend on the linear solver (CG wants a well-conditioned, symmetric K),
    the quadrature's on the integration and on ``shape`` (a grid or unstructured cells)."""
    table.take("h", as_number, 0.1, POSITIVE)
    degree = table.take("degree", as_integer, 1, between(1, 3))
    table.take("weight", one_of(*WEIGHTS), DEFAULT_WEIGHT)
    structured = SHAPES[shape].box is not None
    if solver["method"] == "iterative":
        support = (ITERATIVE_SUPPORT if structured else ITERATIVE_UNSTRUCTURED_SUPPORT)[degree]
    else:
        support = DEFAULT_SUPPORT[degree]
    table.take("support", as_number, support, (lambda v: v > 1, "must be > 1"))
    integration = "gauss" if wants_symmetric(solver) else DEFAULT_INTEGRATION[degree]
    integration = table.take("integration", one_of(*INTEGRATIONS), integration)
    if integration == "vci" and degree in VCI_QUADRATURE:
        points = (VCI_QUADRATURE if structured else VCI_UNSTRUCTURED_QUADRATURE)[degree]
    else:
        points = (DEFAULT_QUADRATURE if structured else UNSTRUCTURED_QUADRATURE)[degree]
    table.take("quadrature", as_integer, points, between(1, MAX_QUADRATURE))
    table.take("cells", one_of(*CELL_TYPES), CELL_TYPES[0])
    # Absent stays absent (no jitter): the effective scene of an unjittered run is unchanged.
    table.take("jitter", as_number, None, between(0.0, MAX_JITTER))
    table.take("seed", as_integer, None, (lambda v: 0 <= v < 2**63, "must be in 0..2**63 - 1"))


def _read_material(table: Table) -> None:
    """(E > 0, -1 < nu < 0.5) or (mu > 0, lam > -2 mu / 3), never both; default E = 1, nu = 0.3."""
    lame = {"lam", "mu"} & table.raw.keys()
    if lame and {"E", "nu"} & table.raw.keys():
        raise InputError(f"{table.where}: material: give E and nu, or lam and mu, not both")
    if lame:
        mu = table.take("mu", as_number, REQUIRED, POSITIVE)
        # lam > -2 mu / 3 <=> E > 0 and nu > -1, the same range as the (E, nu) pair.
        table.take("lam", as_number, REQUIRED, (lambda v: 3 * v > -2 * mu, "must be > -2 mu / 3"))
    else:
        table.take("E", as_number, 1.0, POSITIVE)
        table.take("nu", as_number, 0.3, (lambda v: -1 < v < 0.5, "must be in (-1, 0.5)"))
    table.take("rho", as_number, 1.0, POSITIVE)
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


def _read_time(table: Table) -> None:
    """Newmark is unconditionally stable iff 2 beta >= gamma >= 1/2; the rest is refused."""
    scheme = table.take("scheme", one_of(*SCHEMES), DEFAULT_SCHEME)
    T = table.take("T", as_number, 1.0, POSITIVE)
    table.take("dt", as_number, 0.1, (lambda v: 0 < v <= T, f"must be > 0 and <= time.T = {T}"))
    beta = table.take("beta", as_number, 0.5, (lambda v: 0 < v <= 1, "must be in (0, 1]"))
    gamma = table.take("gamma", as_number, 0.5, (lambda v: 0.5 <= v <= 1, "must be in [0.5, 1]"))
    _read_rho_inf(table, scheme)
    table.take("contact_force", one_of(*CONTACT_FORCES), next(iter(CONTACT_FORCES)))
    if SCHEMES[scheme] is NewmarkScheme and 2 * beta < gamma:
        raise table.fail(
            "beta",
            beta,
            f"Newmark with beta < gamma / 2 = {gamma / 2:g} is only conditionally stable "
            "(its explicit range is not supported): need 2 beta >= gamma, "
            "e.g. beta = 0.25, gamma = 0.5",
        )
    step_count(table.where, table.out)


def _read_rho_inf(table: Table, scheme: str) -> None:
    """rho_inf in [0, 1]: generalized-alpha's spectral radius at infinite frequency.

    Only generalized-alpha reads it (refused with another scheme, where it would do
    nothing).  Its beta and gamma follow from rho_inf (Chung & Hulbert 1993) and replace
    any given ones, so that ``--set time.scheme=generalized-alpha`` works on a scene that
    sets Newmark's; the effective scene shows the values used.
    """
    if SCHEMES[scheme] is not GeneralizedAlphaScheme:
        if "rho_inf" in table.raw:
            raise table.fail(
                "rho_inf",
                table.raw["rho_inf"],
                f'only with time.scheme = "{GeneralizedAlphaScheme.name}"',
            )
        return
    unit = (lambda v: 0 <= v <= 1, "must be in [0, 1] (1: no numerical damping)")
    rho_inf = table.take("rho_inf", as_number, DEFAULT_RHO_INF, unit)
    parameters = generalized_alpha_parameters(rho_inf)
    table.out["gamma"], table.out["beta"] = parameters["gamma"], parameters["beta"]


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


def _read_penalty(table: Table, E: float, h: float) -> None:
    """alpha defaults to 1e4 E / h; the three specific factors default to alpha.

    Measured (static square, m = 1, 2, h = 1/8 .. 1/32): the error is flat for alpha h / E
    in 1e3 .. 1e5 and grows above ~1e6, where the Dirichlet penalty over-constrains the
    MLS trace (README, accuracy section).
    """
    default = 1e4 * E / h
    if "alpha" not in table.raw and not math.isfinite(default):
        raise table.fail("alpha", default, "the default 1e4 E / h overflows: give penalty.alpha")
    alpha = table.take("alpha", as_number, default, POSITIVE)
    for kind in PENALTY_KINDS:
        table.take(f"alpha_{kind}", as_number, alpha, POSITIVE)


def _read_vectors(table: Table, keys: Sequence[str], has_exact: bool) -> None:
    """2-vector expressions defaulting to zero, or (absent) to data derived from [exact]."""
    for key in keys:
        table.take(key, as_vector, None if has_exact else [0, 0])


def default_output_every(n_steps: int) -> int:
    """Steps between outputs for about OUTPUT_FRAMES frames of a run of ``n_steps`` steps."""
    return max(1, round(n_steps / OUTPUT_FRAMES))


def _read_output(table: Table, time: dict) -> None:
    """every: steps between outputs (0: only the final step), by default about
    OUTPUT_FRAMES frames over the run; written back, so the effective scene shows it."""
    n_steps = step_count(table.where, time)
    within = (lambda v: 0 <= v <= MAX_STEPS, f"must be in 0..{MAX_STEPS} (0: final step only)")
    table.take("every", as_integer, default_output_every(n_steps), within)
    known = (lambda v: set(v) <= set(OUTPUT_FIELDS), "allowed: " + ", ".join(OUTPUT_FIELDS))
    table.take("fields", as_names, list(OUTPUT_FIELDS), known)


def _read_solver(where: str, raw) -> dict[str, str]:
    """``method`` (SOLVER_METHODS, default "direct") and PETSc options (name without '-')
    -> value as on a command line ("" for a bare flag)."""
    table = Table(where, "solver", raw)
    options = {"method": table.take("method", one_of(*SOLVER_METHODS), DEFAULT_SOLVER_METHOD)}
    for key, value in table.raw.items():
        name = key.lstrip("-")
        if not name or not all(c.isalnum() or c == "_" for c in name):
            raise InputError(f"{where}: solver.{key_name(key)}: not a PETSc option name")
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


def validate(
    where: str, raw: dict, name: str, source_dir: Path, command_line: dict | None = None
) -> tuple[dict, list[str]]:
    """The effective params (defaults filled) and the domain's boundary part names.

    A top-level ``name`` names the default output directory runs/<name>, so it
    must be plain (PLAIN_NAME): "/abs/path" or "../../x" would point elsewhere.
    ``command_line``: the step solver's PETSc options given on the command line
    (parefg.petsc_options.step_solver_options), which choose the defaults a symmetric
    solver needs.
    """
    for key, value in raw.items():
        if key in TOP_LEVEL_KEYS and not isinstance(value, str):
            raise InputError(f"{where}: {key} = {show(value)}: must be a string")
        if key == "name" and not PLAIN_NAME.fullmatch(value):
            raise InputError(f"{where}: name = {show(value)}: must be {PLAIN_NAME_RULE}")
        if key not in SECTIONS and key not in TOP_LEVEL_KEYS:
            allowed = ", ".join(SECTIONS)
            raise InputError(f"{where}: [{key_name(key)}]: unknown section (allowed: {allowed})")
    params: dict = {"name": name, **{key: raw[key] for key in TOP_LEVEL_KEYS if key in raw}}
    has_exact = "exact" in raw

    def section(key: str, reader, *args):
        table = Table(where, key, raw.get(key, {}))
        result = reader(table, *args)
        params[key] = table.finish()
        return result

    part_names = section("domain", _read_domain, source_dir)
    solver = _read_solver(where, raw.get("solver", {}))  # the discretization's defaults need it
    # the command line's PETSc options win over the scene's (e.g. -ksp_type cg): they
    # decide, with it, whether the linear solver needs a symmetric K
    linear_solver = {**solver, **(command_line or {})}
    section("discretization", _read_discretization, params["domain"]["shape"], linear_solver)
    section("material", _read_material)
    section("time", _read_time)
    E = elastic_constants(params["material"])[0]
    section("penalty", _read_penalty, E, params["discretization"]["h"])
    params["boundary"] = read_boundaries(where, raw.get("boundary", {}), part_names, has_exact)
    section("initial", _read_vectors, ("u", "v"), has_exact)
    section("loads", _read_vectors, ("f",), has_exact)
    if has_exact:
        section("exact", lambda table: table.take("u", as_vector))
    section("output", _read_output, params["time"])
    params["solver"] = solver
    _check_integration_solver(where, params["discretization"], linear_solver)
    return params, part_names


def wants_symmetric(solver: dict) -> bool:
    """Whether the linear solver needs a symmetric K: CG + GAMG, or PETSc options (of the
    scene's [solver] table, or of the command line over them) naming a Krylov method or a
    (sub-)preconditioner that assumes symmetry, or a symmetric matrix format."""
    symmetric_pc = {solver.get("pc_type"), solver.get("sub_pc_type")} & set(SYMMETRIC_PCS)
    return (
        solver["method"] == "iterative"
        or solver.get("ksp_type") in SYMMETRIC_KSPS
        or bool(symmetric_pc)
        or "sbaij" in str(solver.get("mat_type", ""))
    )


def _check_integration_solver(where: str, discretization: dict, solver: dict) -> None:
    """VCI makes K nonsymmetric: CG and the symmetric factorizations would be wrong."""
    if discretization["integration"] == "vci" and wants_symmetric(solver):
        raise InputError(
            f'{where}: discretization.integration = "vci" makes the stiffness nonsymmetric, '
            "but the linear solver (solver.method, [solver] or the command line's -ksp_type /"
            ' -pc_type) assumes symmetry; use the direct solver with LU or integration = "gauss"'
        )
