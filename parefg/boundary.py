"""The kinds of boundary condition a boundary part can carry (SPEC 6: ``[boundary.NAME] type``).

Defined here, below every subpackage, because every layer dispatches on them: the scene
reads them, the discretization assembles a penalty matrix per kind, mechanics and the
time loop pick their parts by kind.
"""

from enum import StrEnum


class BoundaryKind(StrEnum):
    """``[boundary.NAME] type``: each member equals (and hashes as) its TOML string."""

    DIRICHLET = "dirichlet"  # prescribed displacement ubar, by penalty
    NEUMANN = "neumann"  # prescribed traction p
    CONTACT = "contact"  # unilateral contact with a rigid obstacle at gap s, Tresca bound g

    # Hash as the plain string (Enum hashes by member name): sets and dict keys holding
    # "contact" and BoundaryKind.CONTACT then agree, as == does.
    __hash__ = str.__hash__
