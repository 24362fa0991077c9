"""The numba kernels compiled ahead of time: their machine code without importing numba.

A process that calls a numba kernel first pays importing numba and loading its cached
code (~0.35 s), more than the whole build of a small problem.  ``make setup``
(scripts/setup/warm_kernels.py) therefore also compiles every kernel below, with numba's
own ahead-of-time compiler (``numba.pycc``), for each argument signature the JIT compiled
while it ran the warm-up scenes, into one extension module.  It imports in under a
millisecond, runs the same LLVM code as the JIT (the host CPU's features, the same
optimization: identical results, tested) and needs neither numba nor llvmlite at run time.

The module and its table of signatures live in ``<root>/<digest>/`` with ``root`` =
``$PAREFG_AOT_DIR`` (empty: none), by default ``share/parefg/kernels`` of the Python
installation, and ``digest`` hashing the kernels' sources, the interpreter, numpy and the
CPU's feature flags: an edit of a kernel, another numpy or a copy of the environment onto
another CPU finds no module, and the kernels run by numba's JIT as before.

A call is matched exactly on its arguments' types as numba would type them (dtype, number
of dimensions, layout, writability, alignment; scalars; tuples element by element): an
ahead-of-time function trusts its declared types, so a near miss would read memory
wrongly.  Any call without an exact match goes to the JIT, so the compiled module changes
speed, never results.  Nothing here is collective.
"""

import functools
import hashlib
import importlib
import importlib.machinery
import importlib.util
import json
import os
import platform
import sys
from pathlib import Path

import numpy as np

ENVIRONMENT = "PAREFG_AOT_DIR"
MODULE_NAME = "parefg_aot_kernels"
TABLE_NAME = "signatures.json"
PACKAGE = "parefg.discretization"
# The kernels called from Python, by module: everything else they call is compiled in.
EXPORTED = {
    "mls_kernels": ("shape_functions", "neighbour_lists"),
    "assembly_kernels": (
        "group_nodes",
        "touched_pairs",
        "pairs_to_csr",
        "gram_groups",
        "pair_positions",
        "interleave_blocks",
    ),
    "consistent_kernels": ("domain_sums", "boundary_sums", "correct"),
}
# Calls that found no compiled signature and went to the JIT (the tests read it).
misses: dict[str, int] = {}


def default_root() -> Path:
    """Where ``make setup`` compiles: inside the environment that runs parefg."""
    return Path(sys.prefix) / "share" / "parefg" / "kernels"


def root() -> Path | None:
    """The directory of compiled modules (``$PAREFG_AOT_DIR``; empty: none)."""
    return _root_of(os.environ.get(ENVIRONMENT))


def _root_of(setting: str | None) -> Path | None:
    """:func:`root` for one value of ``$PAREFG_AOT_DIR`` (None: unset)."""
    if setting is None:
        return default_root()
    return Path(setting) if setting else None


def _cpu_flags() -> str:
    """The CPU's feature flags (Linux), else the machine name: the code is compiled for them."""
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as stream:
            for line in stream:
                if line.startswith("flags"):
                    return " ".join(sorted(line.split(":", 1)[1].split()))
    except OSError:
        pass
    return platform.machine()


@functools.cache
def digest() -> str:
    """sha256 of what the compiled code depends on: the kernels' sources, Python, numpy, CPU."""
    hasher = hashlib.sha256()
    here = Path(__file__).resolve().parent
    for path in [here / f"{name}.py" for name in (*EXPORTED, "weights")]:
        hasher.update(path.name.encode())
        hasher.update(path.read_bytes())
    for part in (sys.version, np.__version__, _cpu_flags()):
        hasher.update(part.encode())
    return hasher.hexdigest()[:24]


def directory() -> Path | None:
    """This source's compiled module's directory, or None where there is no root."""
    base = root()
    return None if base is None else base / digest()


def value_key(value) -> tuple | str:
    """The type of an argument as numba's typeof would give it, as a hashable key."""
    if isinstance(value, np.ndarray):
        flags = value.flags
        layout = "C" if flags.c_contiguous else ("F" if flags.f_contiguous else "A")
        return ("array", value.dtype.str, value.ndim, layout, flags.writeable, flags.aligned)
    if isinstance(value, tuple):
        return ("tuple", *(value_key(item) for item in value))
    if isinstance(value, bool | np.bool_):
        return "bool"
    if isinstance(value, np.generic):
        return value.dtype.name
    if isinstance(value, int):
        return "int64"
    if isinstance(value, float):
        return "float64"
    return ("other", type(value).__name__)


def type_key(kind) -> tuple | str:
    """:func:`value_key` of a numba type (the build side; imports numba)."""
    from numba import types
    from numba.np import numpy_support

    if isinstance(kind, types.Array):
        dtype = numpy_support.as_dtype(kind.dtype).str
        return ("array", dtype, kind.ndim, kind.layout, kind.mutable, kind.aligned)
    if isinstance(kind, types.BaseTuple):
        return ("tuple", *(type_key(item) for item in kind.types))
    if isinstance(kind, types.Literal):
        return type_key(kind.literal_type)
    if isinstance(kind, types.Boolean):
        return "bool"
    if isinstance(kind, types.Integer | types.Float):
        return str(kind)
    return ("other", str(kind))


def _freeze(key) -> tuple | str:
    """A key read back from JSON (lists) as the tuples :func:`value_key` makes."""
    return tuple(_freeze(item) for item in key) if isinstance(key, list) else key


def _compiled() -> dict[str, dict]:
    """{"module.kernel": {argument key: compiled function}}; empty where there is no module.

    Looked up by the environment's setting (a string: cheap to hash on every kernel call,
    unlike the Path it names).
    """
    return _loaded(os.environ.get(ENVIRONMENT))


@functools.cache
def _loaded(setting: str | None) -> dict[str, dict]:
    """:func:`_compiled` for one value of ``$PAREFG_AOT_DIR``, loaded once per process."""
    base = _root_of(setting)
    return {} if base is None else _load(base / digest())


def _load(path: Path) -> dict[str, dict]:
    """The table of the module in ``path``; empty where it is missing or damaged."""
    try:
        table = json.loads((path / TABLE_NAME).read_text())
        (library,) = path.glob(f"{MODULE_NAME}.*")
        loader = importlib.machinery.ExtensionFileLoader(MODULE_NAME, str(library))
        spec = importlib.util.spec_from_file_location(MODULE_NAME, library, loader=loader)
        if spec is None:
            return {}
        module = importlib.util.module_from_spec(spec)
        loader.exec_module(module)
        return {
            kernel: {_freeze(key): getattr(module, exported) for key, exported in variants}
            for kernel, variants in table.items()
        }
    except (OSError, ValueError, ImportError, AttributeError, TypeError):
        # none, unreadable, or a table that does not fit the module: the JIT runs all
        return {}


def available() -> bool:
    """Whether this source's compiled module is installed (and loads)."""
    return bool(_compiled())


class Kernel:
    """One exported kernel: its compiled function for the arguments' types, else the JIT's."""

    def __init__(self, module: str, name: str):
        self.module, self.name = module, name
        self.qualified = f"{module}.{name}"

    def __call__(self, *args):
        variants = _compiled().get(self.qualified)
        if variants:
            function = variants.get(tuple(value_key(arg) for arg in args))
            if function is not None:
                return function(*args)
        misses[self.qualified] = misses.get(self.qualified, 0) + 1
        jit = importlib.import_module(f"{PACKAGE}.{self.module}")  # imports numba
        return getattr(jit, self.name)(*args)


class Kernels:
    """The exported kernels of one module, as attributes (a module's stand-in)."""

    def __init__(self, module: str):
        self.module = module

    def __getattr__(self, name: str) -> Kernel:
        if name not in EXPORTED[self.module]:
            raise AttributeError(f"{self.module} exports no kernel {name!r}")
        kernel = Kernel(self.module, name)
        setattr(self, name, kernel)  # found as an attribute from now on
        return kernel


@functools.cache
def kernels(module: str) -> Kernels:
    """The kernels of ``module`` (a key of :data:`EXPORTED`), e.g.
    ``kernels("mls_kernels").shape_functions``."""
    return Kernels(module)
