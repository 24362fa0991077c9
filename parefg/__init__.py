"""parefg: PETSc-parallel element-free Galerkin solver for dynamic contact with friction."""

from parefg import _env  # noqa: F401  (sets PETSC_DIR before any petsc4py import)

__version__ = "0.1.0"
