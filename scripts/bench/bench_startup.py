"""Start-up cost: whole-process wall time of parefg commands and where it goes.

Tables, all from one run of this script (same machine load), for this tree and, with
``--baseline PYTHON``, for another checkout's interpreter (e.g. /work/main/.venv/bin/python)
or, with ``--baseline-env NAME=VALUE``, for this tree with one variable of the environment
set (``PAREFG_AOT_DIR=``: without the kernels compiled ahead of time), in interleaved
runs, with the ratio this / baseline:

1. Wall and CPU time of whole processes (median of --repeats): ``python -c pass``, the import
   floor of a run (numpy, scipy.sparse, sympy, numba, h5py, gmsh, petsc4py initialized,
   mpi4py), ``parefg --help``, ``parefg scenes``, ``parefg run square --quiet`` (default
   scene, one rank; the user caches of scene data and meshes warm, as on every run after
   the first), the same without a user cache (the data ``make setup`` prebuilt: what a
   user gets by default), with every cache off (``PAREFG_CACHE=0``: derived and meshed) and
   ``mpirun -n 2 parefg run square``.
2. ``python -X importtime`` of ``parefg run square``: cumulative import time by top-level
   package (self times summed over its modules), medians of --repeats.
3. The run's own phases (summary.json timings) and the time outside them (interpreter,
   imports, PETSc initialization, exit) = wall - timings.total.
4. The fixed costs, in CPU seconds of one fresh process each (robust to the load): the
   imports a run may need, importing gmsh and meshing the default square (the ``mesh``
   phase), and importing numba, its first cached kernel (numba's one-off
   initialization) and the next one (the ``neighbours`` phase is the first kernel call of
   a run by the JIT from parefg.discretization.backends.NUMBA_MIN_NODES nodes on), and
   loading the kernels compiled ahead of time (parefg.discretization.aot) with their first
   call, which replace all of numba's where ``make setup`` built them.
   This tree only.

The user cache of the measured runs is a temporary directory (warmed by one run per
tree before the timing).  Writes results/bench_startup.csv (one row per measured quantity
and tree).  The commands run as ``python -m parefg.cli`` of the given interpreter.

    .venv/bin/python scripts/bench/bench_startup.py [--repeats 5] \
        [--baseline /work/main/.venv/bin/python | --baseline-env PAREFG_AOT_DIR=]
"""

import collections
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import benchlib

RUN_SQUARE = ["run", "square", "--quiet"]
FLOOR = (
    "import numpy, scipy.sparse, sympy, numba, h5py, gmsh, petsc4py; "
    "petsc4py.init(); from petsc4py import PETSc; from mpi4py import MPI"
)
MPI_ENV = {
    "OMPI_ALLOW_RUN_AS_ROOT": "1",
    "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM": "1",
    "OMPI_MCA_rmaps_base_oversubscribe": "1",
}
RUN_LABEL = "parefg run square"  # the runs whose summary.json phases are read


def commands(python: str) -> dict[str, tuple[list[str], dict]]:
    """label -> (command, extra environment) of the processes timed for one interpreter."""
    parefg = [python, "-m", "parefg.cli"]  # the `parefg` script of that tree
    return {
        "python -c pass": ([python, "-c", "pass"], {}),
        "import floor of a run": ([python, "-c", "import parefg; " + FLOOR], {}),
        "parefg --help": ([*parefg, "--help"], {}),
        "parefg scenes": ([*parefg, "scenes"], {}),
        RUN_LABEL: ([*parefg, *RUN_SQUARE], {}),
        # what a user gets by default: no user cache, the data `make setup` prebuilt
        "parefg run square, no user cache": ([*parefg, *RUN_SQUARE], {"PAREFG_CACHE_DIR": ""}),
        # every cache off, the prebuilt data too: the run derives the scene and meshes
        "parefg run square, user caches off": ([*parefg, *RUN_SQUARE], {"PAREFG_CACHE": "0"}),
        "mpirun -n 2 parefg run square": (["mpirun", "-n", "2", *parefg, *RUN_SQUARE], {}),
    }


# Prints "label seconds" lines of process CPU time around each piece of the first phases.
PIECES = """
import time
clock = time.process_time
tic = clock()
import numpy as np
print("numpy import", clock() - tic)
tic = clock()
import petsc4py
import parefg
petsc4py.init([])
from petsc4py import PETSc
from mpi4py import MPI
print("petsc4py + mpi4py import and PETSc initialization", clock() - tic)
tic = clock()
import scipy.sparse, scipy.special
print("scipy.sparse + scipy.special import", clock() - tic)
tic = clock()
import sympy
print("sympy import", clock() - tic)
tic = clock()
import h5py
print("h5py import", clock() - tic)
from parefg.geometry import gmsh_mesh
tic = clock()
import gmsh
print("gmsh import", clock() - tic)
tic = clock()
cloud = gmsh_mesh.mesh_domain({"shape": "square"}, 0.0625)
print("gmsh: initialize, mesh h = 1/16, finalize", clock() - tic)
tic = clock()
import numba
print("numba import", clock() - tic)
from parefg.discretization import mls_kernels
from parefg.discretization.mls import basis_size
from parefg.discretization.neighbours import build_cells, radius_classes
radius = np.full(len(cloud.coords), 3.2 * 0.0625)
cells = build_cells(cloud.coords, radius, *radius_classes(radius))
tic = clock()
neighbours, mask = mls_kernels.neighbour_lists(cloud.coords, cells, 64)
print("numba: first cached kernel (initialization)", clock() - tic)
tic = clock()
size = basis_size(2)
mls_kernels.shape_functions(cloud.coords, cloud.coords, radius, 0, size, neighbours, mask, True)
print("numba: next cached kernel", clock() - tic)
tic = clock()
from parefg.discretization import aot
compiled = aot.kernels("mls_kernels")
compiled.neighbour_lists(cloud.coords, cells, 64)
print("kernels compiled ahead of time: load and first call", clock() - tic)
assert aot.available() and not aot.misses, "no kernels compiled ahead of time: make setup"
"""


def timed_run(
    command: list[str], out_dir: Path | None = None, env: dict | None = None
) -> tuple[float, float, str]:
    """Wall and CPU (user + sys) seconds of one process (its --out in a fresh directory)
    and its stderr.  CPU time is what the process needs on an idle core: it hardly
    depends on the machine's load, the wall time does."""
    extra = ["--out", str(out_dir)] if out_dir is not None else []
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    tic = time.perf_counter()
    done = subprocess.run(
        command + extra,
        check=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, **MPI_ENV, **(env or {})},
        cwd=tempfile.gettempdir(),  # not a checkout: `-m parefg.cli` imports the tree's own
    )
    wall = time.perf_counter() - tic
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime
    return wall, cpu, done.stderr


def import_times(stderr: str) -> dict[str, float]:
    """Seconds of import by top-level package, from ``-X importtime`` lines (self times)."""
    totals: dict[str, float] = collections.defaultdict(float)
    for line in stderr.splitlines():
        if not line.startswith("import time:") or "self [us]" in line:
            continue
        self_us, _, name = line.removeprefix("import time:").split("|")
        totals[name.strip().split(".")[0]] += int(self_us) * 1e-6
    return dict(totals)


def samples():
    return collections.defaultdict(list)


def measure(trees: dict[str, tuple[str, dict]], repeats: int, workdir: Path) -> dict:
    """Samples by table, tree and row: tree label -> (interpreter, environment), runs
    interleaved."""
    tables = ("process, wall", "process, CPU (user + sys)", "imports", "phases", "pieces")
    result = {table: {tree: samples() for tree in trees} for table in tables}
    for tree, (python, tree_env) in trees.items():  # warm the scene cache of each tree
        timed_run([python, "-m", "parefg.cli", *RUN_SQUARE], workdir / f"warm-{tree}", tree_env)
    for r in range(repeats):
        for tree, (python, tree_env) in trees.items():
            for i, (label, (command, env)) in enumerate(commands(python).items()):
                out = workdir / f"{tree}-{r}-{i}" if "run square" in label else None
                wall, cpu, _ = timed_run(command, out, {**tree_env, **env})
                result["process, wall"][tree][label].append(wall)
                result["process, CPU (user + sys)"][tree][label].append(cpu)
                if label == RUN_LABEL:
                    timings = json.loads((out / "summary.json").read_text())["timings"]
                    phases = result["phases"][tree]
                    for key, value in timings.items():
                        phases[key].append(value)
                    phases["outside the run (wall - total)"].append(wall - timings["total"])
            _, _, stderr = timed_run(
                [python, "-X", "importtime", "-m", "parefg.cli", *RUN_SQUARE],
                workdir / f"i-{tree}-{r}",
                tree_env,
            )
            per_package = import_times(stderr)
            for package, seconds in per_package.items():
                result["imports"][tree][package].append(seconds)
            result["imports"][tree]["(all imports)"].append(sum(per_package.values()))
        for line in subprocess.run(
            [sys.executable, "-c", PIECES], check=True, capture_output=True, text=True
        ).stdout.splitlines():
            label, seconds = line.rsplit(" ", 1)
            result["pieces"]["this tree"][label].append(float(seconds))
    return result


def table(title: str, by_tree: dict, limit: int | None = None) -> list[dict]:
    """Print a markdown table of medians, one column per tree (and this / baseline);
    rows largest first (of the last tree) when limited.  Return its rows."""
    trees = [tree for tree in by_tree if by_tree[tree]]
    names = list(dict.fromkeys(name for tree in trees for name in by_tree[tree]))
    medians = {
        tree: {name: statistics.median(by_tree[tree][name]) for name in by_tree[tree]}
        for tree in trees
    }
    if limit is not None:
        names = sorted(names, key=lambda name: -medians[trees[-1]].get(name, 0.0))[:limit]
    ratio = len(trees) == 2
    header = " | ".join(f"{tree} [s]" for tree in trees) + (" | ratio" if ratio else "")
    print(f"\n| {title} | {header} |\n|---|" + "---|" * (len(trees) + ratio))
    rows = []
    for name in names:
        values = [medians[tree].get(name) for tree in trees]
        cells = ["-" if v is None else f"{v:.3f}" for v in values]
        if ratio:
            both = None not in values and values[0] > 0
            cells.append(f"{values[1] / values[0]:.2f}" if both else "-")
        print(f"| {name} | " + " | ".join(cells) + " |")
        rows += [
            {"table": title, "tree": tree, "what": name, "median_s": value}
            for tree, value in zip(trees, values, strict=True)
            if value is not None
        ]
    return rows


def main():
    parser = benchlib.parser(__doc__, repeats=5)
    baseline = parser.add_mutually_exclusive_group()
    baseline.add_argument("--baseline", help="python of the checkout to compare with")
    baseline.add_argument(
        "--baseline-env", metavar="NAME=VALUE", help="compare with this tree run with NAME=VALUE"
    )
    args = parser.parse_args()
    trees: dict[str, tuple[str, dict]] = {}
    if args.baseline:
        trees["baseline"] = (args.baseline, {})
    elif args.baseline_env:
        name, _, value = args.baseline_env.partition("=")
        trees[args.baseline_env] = (sys.executable, {name: value})
    trees["this tree"] = (sys.executable, {})
    with tempfile.TemporaryDirectory() as tmp:
        os.environ["PAREFG_CACHE_DIR"] = str(Path(tmp) / "cache")  # the runs' scene cache
        os.environ.pop("PAREFG_SCENE_CACHE", None)
        result = measure(trees, args.repeats, Path(tmp))
    print(f"load average {os.getloadavg()[0]:.2f}; medians of {args.repeats}")
    rows = table("process, wall", result["process, wall"])
    rows += table("process, CPU (user + sys)", result["process, CPU (user + sys)"])
    rows += table("imports of `parefg run square`, by package", result["imports"], limit=14)
    rows += table("phases of `parefg run square` (summary.json)", result["phases"])
    rows += table("fixed costs, CPU of one fresh process", result["pieces"])
    print(f"\nwrote {benchlib.write_csv(args.out, 'bench_startup.csv', rows)}")


if __name__ == "__main__":
    main()
