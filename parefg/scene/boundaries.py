"""The schema of the ``[boundary.NAME]`` tables: a kind, its data, a contact's friction law.

Read by :func:`parefg.scene.schema.validate`; the kinds are
:class:`parefg.boundary.BoundaryKind`, the friction laws
:data:`parefg.mechanics.friction.FRICTION_LAWS`.  Not collective.
"""

import copy

from parefg.boundary import BoundaryKind
from parefg.discretization.dirichlet import (
    CONTACT_METHODS,
    DEFAULT_CONTACT_METHOD,
    DEFAULT_DIRICHLET_METHOD,
    DIRICHLET_METHODS,
    NITSCHE_SAFETY,
)
from parefg.errors import InputError
from parefg.mechanics.friction import (
    DEFAULT_FRICTION_LAW,
    DERIVED_FRICTION_LAW,
    FRICTION_LAWS,
    PRESSURE_LAWS,
)
from parefg.scene.table import Table, as_nonnegative, as_number, as_vector, key_name, one_of, show

#: boundary type -> (key, converter, default without [exact], derived from [exact]?)
BOUNDARY_KEYS = {
    BoundaryKind.DIRICHLET: (("value", as_vector, [0, 0], True),),
    BoundaryKind.NEUMANN: (("traction", as_vector, [0, 0], True),),
    BoundaryKind.CONTACT: (
        ("gap", as_nonnegative, 0, False),
        ("friction", as_nonnegative, 0, True),
    ),
}


def read_boundaries(where: str, raw, part_names: list[str], has_exact: bool) -> dict:
    if not isinstance(raw, dict):
        raise InputError(f"{where}: boundary = {show(raw)}: must be a table of [boundary.NAME]")
    boundaries = {}
    for name, entry in raw.items():
        if name not in part_names:
            known = ", ".join(part_names)
            raise InputError(
                f"{where}: boundary.{key_name(name)}: unknown boundary part (allowed: {known})"
            )
        table = Table(where, f"boundary.{name}", entry)
        given = set(table.raw)
        kind = table.take("type", one_of(*BOUNDARY_KEYS))
        for key, convert, zero, derived in BOUNDARY_KEYS[kind]:
            table.take(key, convert, None if derived and has_exact else copy.deepcopy(zero))
        if kind == BoundaryKind.DIRICHLET:
            _read_dirichlet_method(table)
        if kind == BoundaryKind.CONTACT:
            _read_contact_method(table)
            _read_friction_law(table, has_exact)
            _read_friction_coefficient(table, given)
        boundaries[name] = table.finish()
    return boundaries


def _read_dirichlet_method(table: Table) -> None:
    """method: a name of DIRICHLET_METHODS (default "nitsche"); safety: Nitsche's only.

    safety > 1 scales the coercivity bound of each segment into beta (default
    NITSCHE_SAFETY); below 1 the Nitsche operator may be indefinite.  The penalty's
    alpha_D is [penalty] alpha_dirichlet, so safety is refused with it (not ignored).
    """
    method = table.take("method", one_of(*DIRICHLET_METHODS), DEFAULT_DIRICHLET_METHOD)
    if not DIRICHLET_METHODS[method].consistent:
        if "safety" in table.raw:
            raise table.fail(
                "safety",
                table.raw["safety"],
                f'only used with method = "nitsche" (the {method}\'s parameter is '
                "penalty.alpha_dirichlet)",
            )
        return
    _read_safety(table)


def _read_safety(table: Table) -> None:
    above_one = (lambda v: v > 1, "must be > 1 (the coercivity bound of Nitsche's method)")
    table.take("safety", as_number, NITSCHE_SAFETY, above_one)


def _read_contact_method(table: Table) -> None:
    """method: a name of CONTACT_METHODS (default "nitsche"); safety: Nitsche's only.

    Nitsche's gamma is safety times the coercivity bound of each segment, as for a
    Dirichlet part; the penalty's alpha_C is [penalty] alpha_contact.
    """
    method = table.take("method", one_of(*CONTACT_METHODS), DEFAULT_CONTACT_METHOD)
    if method == "penalty":
        if "safety" in table.raw:
            raise table.fail(
                "safety",
                table.raw["safety"],
                "only used with the Nitsche methods (the penalty's parameter is "
                "penalty.alpha_contact)",
            )
        return
    _read_safety(table)


def _read_friction_law(table: Table, has_exact: bool) -> None:
    """friction_law: a name of parefg.mechanics.friction.FRICTION_LAWS, by default "tresca".

    When the bound is derived from [exact] (friction not given), the default is "given":
    a manufactured solution such as the square's grazes the obstacle (u_nu = s with
    sigma_nu -> 0 as t -> 0), so under "tresca" the sign of the discretization error of
    u_nu - s would decide which points carry friction (measured on the z scene, m = 1,
    h = 1/16: L2 error 1.5e-4 with "given", 3.8e-3 with "tresca").  The effective scene
    shows the law chosen.
    """
    derived = has_exact and table.out.get("friction") is None
    default = DERIVED_FRICTION_LAW if derived else DEFAULT_FRICTION_LAW
    table.take("friction_law", one_of(*FRICTION_LAWS), default)


def _read_friction_coefficient(table: Table, given: set) -> None:
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
    table.take("friction_coefficient", as_number, check=nonnegative)
