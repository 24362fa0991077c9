"""The background cell types of a node cloud (SPEC 6: ``[discretization] cells``).

The one place that names them: the schema reads :data:`CELL_TYPES`, meshing and the size
estimate compare against :class:`CellType` members.
"""

from enum import StrEnum


class CellType(StrEnum):
    """``[discretization] cells``: each member equals (and hashes as) its TOML string."""

    QUAD = "quad"  # recombined quadrilaterals (a few triangles may remain on unstructured meshes)
    TRI = "tri"  # triangles

    # Hash as the plain string (Enum hashes by member name): dict keys holding "quad" and
    # CellType.QUAD then agree, as == does.
    __hash__ = str.__hash__


#: the registry of cell types, as the plain strings of a scene file (the first is the default)
CELL_TYPES = tuple(member.value for member in CellType)

# Unstructured gmsh meshes at target size h have about this many nodes per h^2 of area
# (measured on polygons, z and .geo domains; 1.16 ~ 2 / sqrt 3: equilateral triangles).
# The size estimate and the meshing's choice of refinements read it.
UNSTRUCTURED_DENSITY = 1.16
