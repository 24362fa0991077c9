"""Compile parefg's numba kernels into their on-disk cache, so no user run pays for it.

The numba kernels (MLS, neighbour search, assembly, VCI sums) are compiled on first use
and cached next to their sources (``cache=True``): without this, the first run after an
install or an edit of a kernel spends ~7 s per MLS degree and ~10 s more on the rest
compiling (a 0.5 s run took 21 s).  `make setup` runs this script once per change of the
discretization sources.  It runs tiny scenes that take every kernel path with the types
of a real run: the square at m = 1, 2, 3 (Gauss, VCI, Nitsche), the Z domain (unstructured
cells) and the impact scene (a body in flight), with numba forced
(``PAREFG_KERNELS=numba``, the tiny clouds would otherwise use the numpy kernels) and by
its JIT (``PAREFG_AOT_DIR`` empty).  Then it compiles every signature the JIT compiled
into one extension module ahead of time (:mod:`parefg.discretization.aot`), which later
runs load without importing numba (~15 s, once per change of the kernels' sources).

    .venv/bin/python scripts/setup/warm_kernels.py
"""

import os

os.environ["PAREFG_KERNELS"] = "numba"
os.environ["PAREFG_AOT_DIR"] = ""  # the JIT: its signatures are what gets compiled ahead
os.environ.setdefault("OMP_NUM_THREADS", "1")

import importlib  # noqa: E402
import json  # noqa: E402
import shutil  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import petsc4py  # noqa: E402

import parefg  # noqa: E402, F401  (PETSC_DIR)

petsc4py.init(sys.argv[:1])
from mpi4py import MPI  # noqa: E402

from parefg.discretization import aot  # noqa: E402
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
    tic = time.perf_counter()
    target = compile_ahead(aot.default_root(), aot.digest())
    seconds = time.perf_counter() - tic
    print(f"setup: kernels compiled ahead of time (or found) in {target} ({seconds:.1f} s)")


def compile_ahead(root: Path, digest: str) -> Path:
    """Every signature the JIT compiled, into ``root/digest`` (other digests removed).

    Nothing to do when that directory holds these signatures already: it is written whole
    (renamed into place) or not at all.
    """
    target = root / digest
    dispatchers, table = [], {}
    for module_name, names in aot.EXPORTED.items():
        module = importlib.import_module(f"{aot.PACKAGE}.{module_name}")
        for name in names:
            dispatcher = getattr(module, name)
            for index, (arguments, overload) in enumerate(dispatcher.overloads.items()):
                exported = f"{module_name}__{name}__{index}"
                dispatchers.append((exported, overload.signature, dispatcher.py_func))
                key = [aot.type_key(kind) for kind in arguments]
                table.setdefault(f"{module_name}.{name}", []).append([key, exported])
    try:
        if json.loads((target / aot.TABLE_NAME).read_text()) == json.loads(json.dumps(table)):
            return target
    except (OSError, ValueError):
        pass
    from numba.core import codegen
    from numba.pycc import CC

    # pycc compiles for a named CPU; on a virtual machine LLVM names the host "generic",
    # and without the host's feature flags (which the JIT passes) the code would lose
    # AVX and run ~1.4x slower.  The digest holds the flags: another CPU finds no module.
    codegen.AOTCPUCodegen._customize_tm_features = lambda self: self._get_host_cpu_features()
    building = Path(tempfile.mkdtemp(prefix=f".{digest}.", dir=_made(root)))
    compiler = CC(aot.MODULE_NAME)
    compiler.output_dir, compiler.target_cpu = str(building), "host"
    for exported, signature, function in dispatchers:
        compiler.export(exported, signature)(function)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # pycc's pending-deprecation notice
        compiler.compile()
    (building / aot.TABLE_NAME).write_text(json.dumps(table))
    building.chmod(0o755)  # mkdtemp's 0700: every user of the environment reads it
    for old in root.iterdir():  # earlier sources' (or signatures') modules
        if old.is_dir() and old != building:
            shutil.rmtree(old, ignore_errors=True)
    building.rename(target)
    return target


def _made(path: Path) -> Path:
    path.mkdir(parents=True, exist_ok=True)
    return path


if __name__ == "__main__":
    main()
