"""Scene data as vectorized fields: given expressions, or data derived from ``[exact]``.

Each value of a scene (loads, initial data, boundary data) is a number or an expression
string; here it becomes a callable over point arrays, or, when the scene leaves it out,
the one derived from its manufactured solution
(:class:`~parefg.scene.manufactured.ManufacturedSolution`).  Not collective.
"""

import sympy

from parefg.boundary import BoundaryKind
from parefg.errors import InputError
from parefg.mechanics.friction import PRESSURE_LAWS
from parefg.scene.expressions import SYMBOLS, compile_field, parse_expression
from parefg.scene.numeric import BoundaryCondition, CompiledField
from parefg.scene.separable import with_separation
from parefg.scene.symbolic import is_identically_zero


def scene_expression(where: str, key: str, value, args=("x", "y", "t")) -> sympy.Expr:
    """Parse one scene value whose free symbols must be among ``args``."""
    expr = parse_expression(value, f"{where}: {key}")
    extra = expr.free_symbols - {SYMBOLS[a] for a in args}
    if extra:
        used = ", ".join(sorted(str(s) for s in extra))
        raise InputError(f"{where}: {key}: must not depend on {used}")
    return expr


def scene_expressions(where: str, key: str, values: list, args=("x", "y", "t")) -> list[sympy.Expr]:
    """Parse a list of scene values, each error naming ``key[i]``."""
    return [scene_expression(where, f"{key}[{i}]", value, args) for i, value in enumerate(values)]


def vector_field(
    where, key, values, manufactured, derived_key, args=("x", "y", "t")
) -> CompiledField:
    """The given expressions, or the ones derived from the exact solution.

    With its time-separable form (parefg.scene.separable) when it has one.
    """
    exprs = scene_expressions(where, key, values, args) if values is not None else None
    if exprs is None:
        exprs = manufactured.derived[derived_key]
    return with_separation(compile_field(exprs, args), exprs)


def initial_field(where: str, key: str, values, manufactured) -> CompiledField:
    """u0 or v0 as a function of (x, y); a given t is read as t = 0."""
    t = SYMBOLS["t"]
    if values is not None:
        exprs = [e.subs(t, 0) for e in scene_expressions(where, f"initial.{key}", values)]
    else:
        exprs = manufactured.derived[key]
    return compile_field(exprs, ("x", "y"))


WITH_NORMAL = ("x", "y", "t", "nx", "ny")  # arguments of data that depend on the normal


def _dirichlet(where: str, name: str, table: dict, manufactured, checks) -> BoundaryCondition:
    """ubar(x, y, t): given, or u of the exact solution."""
    prefix = f"boundary.{name}"
    value = vector_field(where, f"{prefix}.value", table.get("value"), manufactured, "value")
    return BoundaryCondition(
        name,
        BoundaryKind.DIRICHLET,
        value=value,
        method=table["method"],
        safety=table.get("safety", 0.0),
    )


def _neumann(where: str, name: str, table: dict, manufactured, checks) -> BoundaryCondition:
    """p(x, y, t, nx, ny): given, or sigma n of the exact solution."""
    prefix = f"boundary.{name}"
    traction = vector_field(
        where, f"{prefix}.traction", table.get("traction"), manufactured, "traction", WITH_NORMAL
    )
    return BoundaryCondition(name, BoundaryKind.NEUMANN, traction=traction)


def _contact(where: str, name: str, table: dict, manufactured, checks) -> BoundaryCondition:
    """Gap s(x, y) >= 0 and Tresca bound g >= 0: given, or |tau . sigma n| of the exact one."""
    prefix = f"boundary.{name}"
    gap_expr = scene_expression(where, f"{prefix}.gap", table["gap"], ("x", "y"))
    checks.nonnegative(name, "gap", table["gap"], gap_expr)
    gap = compile_field([gap_expr], ("x", "y"), components=())
    if table["friction_law"] in PRESSURE_LAWS:
        return _coulomb_boundary(name, table, gap)
    given = table.get("friction")
    if given is not None:
        friction = [scene_expression(where, f"{prefix}.friction", given)]
        checks.nonnegative(name, "friction", given, friction[0])
    else:  # |tau . sigma n| >= 0
        friction = manufactured.derived["friction"]
    return BoundaryCondition(
        name,
        BoundaryKind.CONTACT,
        gap=gap,
        friction=with_separation(compile_field(friction, WITH_NORMAL, components=()), friction),
        # derived friction is homogeneous in (nx, ny): zero for all normals iff for unit ones
        friction_is_zero=is_identically_zero(friction[0], [SYMBOLS[s] for s in WITH_NORMAL]),
        friction_law=table["friction_law"],
        method=table["method"],
        safety=table.get("safety", 0.0),
    )


def _coulomb_boundary(name: str, table: dict, gap: CompiledField) -> BoundaryCondition:
    """A Coulomb contact part: no given bound (zero field), the coefficient mu_f."""
    coefficient = table["friction_coefficient"]
    return BoundaryCondition(
        name,
        BoundaryKind.CONTACT,
        gap=gap,
        friction=CompiledField(["0"], WITH_NORMAL, components=()),
        friction_is_zero=coefficient == 0,  # the scene's number, not a computed float
        friction_law=table["friction_law"],
        friction_coefficient=coefficient,
        method=table["method"],
        safety=table.get("safety", 0.0),
    )


#: boundary kind -> builder of its BoundaryCondition from a validated [boundary.NAME] table
BOUNDARY_BUILDERS = {
    BoundaryKind.DIRICHLET: _dirichlet,
    BoundaryKind.NEUMANN: _neumann,
    BoundaryKind.CONTACT: _contact,
}


def boundary_condition(
    where: str, name: str, table: dict, manufactured, checks
) -> BoundaryCondition:
    """BoundaryCondition of one validated [boundary.NAME] table.

    ``manufactured`` is the scene's ManufacturedSolution (None without [exact]); ``checks``
    its :class:`~parefg.scene.checks.SignChecks`.
    """
    return BOUNDARY_BUILDERS[BoundaryKind(table["type"])](where, name, table, manufactured, checks)
