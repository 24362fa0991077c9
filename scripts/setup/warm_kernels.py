"""Compile parefg's numba kernels into their on-disk cache, so no user run pays for it.

The numba kernels (MLS, neighbour search, assembly, VCI sums) are compiled on first use
and cached next to their sources (``cache=True``): without this, the first run after an
install or an edit of a kernel spends ~7 s per MLS degree and ~10 s more on the rest
compiling (a 0.5 s run took 21 s).  `make setup` runs this script once per change of the
discretization sources.  It runs tiny scenes that take every kernel path with the types
of a real run: the square at m = 1, 2, 3 (Gauss, VCI, Nitsche), the Z domain (unstructured
cells) and the impact scene (a body in flight), with numba forced
(``PAREFG_KERNELS=numba``, the tiny clouds would otherwise use the numpy kernels).

    .venv/bin/python scripts/setup/warm_kernels.py
"""

import os

os.environ["PAREFG_KERNELS"] = "numba"
os.environ.setdefault("OMP_NUM_THREADS", "1")

import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import petsc4py  # noqa: E402

import parefg  # noqa: E402, F401  (PETSC_DIR)

petsc4py.init(sys.argv[:1])
from mpi4py import MPI  # noqa: E402

from parefg.run import run_scene  # noqa: E402
from parefg.scene.loader import load_scene  # noqa: E402

TWO_STEPS = ["time.T=0.1", "time.dt=0.05", "output.every=0"]
COARSE = "discretization.h=0.25"
# (scene, overrides): each a few hundred points, two steps
CASES = [
    ("square", [COARSE, "discretization.degree=1"]),
    ("square", [COARSE, "discretization.degree=2"]),
    ("square", [COARSE, "discretization.degree=3"]),
    ("square", [COARSE, "discretization.degree=3", "discretization.integration=gauss"]),
    ("z", [COARSE]),
    ("impact", []),
]


def main() -> None:
    tic = time.perf_counter()
    for name, overrides in CASES:
        scene = load_scene(name, overrides + TWO_STEPS)
        with tempfile.TemporaryDirectory() as tmp:
            run_scene(MPI.COMM_WORLD, scene, out=str(Path(tmp) / "run"), quiet=True)
    seconds = time.perf_counter() - tic
    print(f"setup: numba kernels compiled or found in their cache ({seconds:.1f} s)")


if __name__ == "__main__":
    main()
