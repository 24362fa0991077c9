"""Make Debian's petsc4py importable without extra environment variables.

Debian's petsc4py finds its PETSc build through PETSC_DIR unless the
``petsc-dev`` alternative is installed; point it at Debian's PETSc 3.18 build
when the user has not chosen one.
"""

import os

DEBIAN_PETSC_DIR = "/usr/lib/petscdir/petsc3.18/x86_64-linux-gnu-real"

if "PETSC_DIR" not in os.environ and os.path.isdir(DEBIAN_PETSC_DIR):
    os.environ["PETSC_DIR"] = DEBIAN_PETSC_DIR
