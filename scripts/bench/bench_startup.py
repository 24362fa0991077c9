"""Start-up cost: whole-process wall time of parefg commands and where it goes.

Three tables, all from one run of this script (same machine load):

1. Wall and CPU time of whole processes (median of --repeats): ``python -c pass``, the import
   floor of a run (numpy, scipy.sparse, sympy, numba, h5py, gmsh, petsc4py initialized,
   mpi4py: the modules ``parefg run square`` cannot do without), ``parefg --help``,
   ``parefg scenes`` and ``parefg run square --quiet`` (default scene, one rank).
2. ``python -X importtime`` of ``parefg run square``: cumulative import time by top-level
   package (self times summed over its modules), medians of --repeats.
3. The run's own phases (summary.json timings) and the time outside them (interpreter,
   imports, PETSc initialization, exit) = wall - timings.total.

4. The fixed costs, in CPU seconds of one fresh process each (robust to the load): the
   imports a run cannot do without, importing gmsh and meshing the default square (the
   ``mesh`` phase), and importing numba, its first cached kernel (numba's one-off
   initialization) and the next one (the ``neighbours`` phase is the first kernel call).

Writes results/bench_startup.csv (one row per measured quantity).  The commands run as
``python -m parefg.cli``, so PYTHONPATH=OTHER_TREE measures another checkout (before/after).

    .venv/bin/python scripts/bench/bench_startup.py [--repeats 5]
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

PYTHON = sys.executable
# `python -m parefg.cli` is the `parefg` script; it honours PYTHONPATH (compare two trees)
PAREFG = [PYTHON, "-m", "parefg.cli"]
RUN_SQUARE = ["run", "square", "--quiet"]
FLOOR = (
    "import numpy, scipy.sparse, sympy, numba, h5py, gmsh, petsc4py; "
    "petsc4py.init(); from petsc4py import PETSc; from mpi4py import MPI"
)
COMMANDS = {
    "python -c pass": [PYTHON, "-c", "pass"],
    "import floor of a run": [PYTHON, "-c", "import parefg; " + FLOOR],
    "parefg --help": [*PAREFG, "--help"],
    "parefg scenes": [*PAREFG, "scenes"],
    "parefg run square": [*PAREFG, *RUN_SQUARE],
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
radius = np.full(len(cloud.coords), 3.2 * 0.0625)
cells = mls_kernels.build_cells(cloud.coords, radius.max())
arguments = (cloud.coords, cloud.coords, radius, radius.max(), cells)
tic = clock()
mls_kernels.count_neighbours(*arguments)
print("numba: first cached kernel (initialization)", clock() - tic)
tic = clock()
mls_kernels.fill_neighbours(*arguments, 64)
print("numba: next cached kernel", clock() - tic)
"""


def timed_run(command: list[str], out_dir: Path | None = None) -> tuple[float, float, str]:
    """Wall and CPU (user + sys) seconds of one process (its --out in a fresh directory)
    and its stderr.  CPU time is what the process needs on an idle core: it hardly
    depends on the machine's load, the wall time does."""
    extra = ["--out", str(out_dir)] if out_dir is not None else []
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    tic = time.perf_counter()
    done = subprocess.run(
        command + extra, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
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


def measure(repeats: int, workdir: Path):
    """Wall times per command, import times per package, run phases: lists of samples."""
    walls = collections.defaultdict(list)
    cpus = collections.defaultdict(list)
    imports = collections.defaultdict(list)
    phases = collections.defaultdict(list)
    pieces = collections.defaultdict(list)
    for r in range(repeats):
        for label, command in COMMANDS.items():
            out = workdir / f"wall-{r}" if label == "parefg run square" else None
            wall, cpu, _ = timed_run(command, out)
            walls[label].append(wall)
            cpus[label].append(cpu)
            if out is not None:
                timings = json.loads((out / "summary.json").read_text())["timings"]
                for key, value in timings.items():
                    phases[key].append(value)
                phases["outside the run (wall - total)"].append(wall - timings["total"])
        _, _, stderr = timed_run(
            [PYTHON, "-X", "importtime", *PAREFG[1:], *RUN_SQUARE], workdir / f"i{r}"
        )
        per_package = import_times(stderr)
        for package, seconds in per_package.items():
            imports[package].append(seconds)
        imports["(all imports)"].append(sum(per_package.values()))
        for line in subprocess.run(
            [PYTHON, "-c", PIECES], check=True, capture_output=True, text=True
        ).stdout.splitlines():
            label, seconds = line.rsplit(" ", 1)
            pieces[label].append(float(seconds))
    return walls, cpus, imports, phases, pieces


def table(title: str, samples: dict, limit: int | None = None) -> list[dict]:
    """Print a markdown table of medians (largest first when limited); return its rows."""
    rows = [
        {"table": title, "what": k, "median_s": statistics.median(v)} for k, v in samples.items()
    ]
    if limit is not None:
        rows = sorted(rows, key=lambda row: -row["median_s"])[:limit]
    print(f"\n| {title} | median [s] |\n|---|---|")
    for row in rows:
        print(f"| {row['what']} | {row['median_s']:.3f} |")
    return rows


def main():
    parser = benchlib.parser(__doc__, repeats=5)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        walls, cpus, imports, phases, pieces = measure(args.repeats, Path(tmp))
    print(f"load average {os.getloadavg()[0]:.2f}; medians of {args.repeats}")
    rows = table("process, wall", walls)
    rows += table("process, CPU (user + sys)", cpus)
    rows += table("imports of `parefg run square`, by package", imports, limit=14)
    rows += table("phases of `parefg run square` (summary.json)", phases)
    rows += table("fixed costs, CPU of one fresh process", pieces)
    print(f"\nwrote {benchlib.write_csv(args.out, 'bench_startup.csv', rows)}")


if __name__ == "__main__":
    main()
