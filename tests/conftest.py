"""Shared test fixtures.

The suite runs twice: serially and under ``mpirun -n 2``.  Every test must
reach the same collective calls on every rank.  Tests that start their own MPI
jobs (CLI runs, 1-rank vs 2-rank comparisons) are marked ``serial_only`` and
skipped inside an MPI run, where nested mpirun is not possible.
"""

import os
import subprocess
import sys
from pathlib import Path

import pytest
from mpi4py import MPI

REPO = Path(__file__).resolve().parents[1]
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


def mpi_env():
    """Environment for child MPI jobs (Open MPI refuses root otherwise)."""
    env = dict(os.environ)
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
