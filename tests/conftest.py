"""Shared test fixtures.

The suite runs twice: serially and under ``mpirun -n 2``.  Every test must
reach the same collective calls on every rank.  Tests that start their own MPI
jobs (CLI runs, 1-rank vs 2-rank comparisons) are marked ``serial_only`` and
skipped inside an MPI run, where nested mpirun is not possible.

Layout: one folder per subpackage of parefg (scene/, geometry/, discretization/,
mechanics/, timestepping/, io/), cli/ for the command line and its faults,
verification/ for rates and balances against exact solutions, parallel/ for
1 rank == 2 ranks.  The folders have no ``__init__.py``: pytest puts this folder on
``sys.path`` (so ``from conftest import ...`` works everywhere) and imports each
test module by its basename, which must therefore be unique across the folders.
"""

import os
import subprocess
import sys
from pathlib import Path

import pytest
from mpi4py import MPI

pytest_plugins = ["rank_sync"]  # a test failing on one rank only aborts the MPI run

REPO = Path(__file__).resolve().parents[1]
# The tests count derivations and meshings, so they run without the entries `make setup`
# prebuilt for the built-in scenes (tests/scene/test_prebuilt.py tests those); their child
# processes inherit this.
os.environ["PAREFG_PREBUILT_DIR"] = ""
PAREFG = str(Path(sys.executable).with_name("parefg"))


def pytest_collection_modifyitems(config, items):
    if MPI.COMM_WORLD.size == 1:
        return
    skip = pytest.mark.skip(reason="starts its own MPI jobs; runs in the serial pass")
    for item in items:
        if "serial_only" in item.keywords:
            item.add_marker(skip)


@pytest.fixture
def comm():
    return MPI.COMM_WORLD


# Set by Open MPI in a process that initialized MPI as a singleton (a pytest-xdist worker
# does): inherited by a child `mpirun`, they make it join the parent's session and fail.
SINGLETON_PREFIXES = ("PMIX_", "OMPI_MCA_ess", "OMPI_MCA_orte_", "OMPI_MCA_pmix", "OMPI_APP_CTX")


def mpi_env():
    """Environment for child MPI jobs (Open MPI refuses root otherwise)."""
    env = {key: val for key, val in os.environ.items() if not key.startswith(SINGLETON_PREFIXES)}
    env.update(
        OMPI_ALLOW_RUN_AS_ROOT="1",
        OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
        OMPI_MCA_rmaps_base_oversubscribe="1",
    )
    return env


def run_parefg(args, ranks=1, timeout=600, cwd=None):
    """Run the parefg CLI (under mpirun when ranks > 1); return CompletedProcess."""
    cmd = [PAREFG, *args]
    if ranks > 1:
        cmd = ["mpirun", "--timeout", str(timeout), "-n", str(ranks), *cmd]
    return subprocess.run(
        cmd, capture_output=True, text=True, timeout=timeout, env=mpi_env(), cwd=cwd
    )


# A quick run: 81 nodes, 4 steps.
QUICK = ["--set", "time.dt=0.25", "--set", "discretization.h=0.125"]


def assert_bad_input(result, words: list[str]) -> str:
    """Exit 2, exactly one `parefg: error:` line containing ``words``, no traceback."""
    assert result.returncode == 2, (result.returncode, result.stderr)
    assert "Traceback" not in result.stderr and "Traceback" not in result.stdout
    lines = [line for line in result.stderr.splitlines() if line.startswith("parefg: error:")]
    assert len(lines) == 1, result.stderr
    for word in words:
        assert word in lines[0], (word, lines[0])
    return lines[0]
