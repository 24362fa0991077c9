"""The rank_sync plugin: a test failing on one rank ends a 2-rank pytest run instead of hanging it.

serial_only: each test starts its own ``mpirun -n 2 pytest`` on a small test file.
"""

import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import mpi_env

pytestmark = pytest.mark.serial_only

TESTS = Path(__file__).resolve().parents[1]  # where rank_sync.py lives
WAIT = 3  # PAREFG_TEST_RANK_TIMEOUT of the child runs [s]
LIMIT = 120  # mpirun --timeout: a hang ends here, far above WAIT [s]

# Rank 1 fails before the barrier rank 0 waits in: without the plugin the job hangs.
HANGING = """
from mpi4py import MPI

def test_fails_on_rank_1_before_a_collective():
    if MPI.COMM_WORLD.rank == 1:
        raise AssertionError("only rank 1 fails")
    MPI.COMM_WORLD.Barrier()

def test_never_reached():
    MPI.COMM_WORLD.Barrier()
"""

# Rank 1 fails but no rank is left in a collective: the run must go on to the end.
NOT_HANGING = """
from mpi4py import MPI

def test_fails_on_rank_1_only():
    assert MPI.COMM_WORLD.rank == 0

def test_after_the_failure():
    MPI.COMM_WORLD.Barrier()
"""


def _run_child(tmp_path, source: str):
    test_file = tmp_path / "test_child.py"
    test_file.write_text(source)
    env = mpi_env()
    env.update(PYTHONPATH=str(TESTS), PAREFG_TEST_RANK_TIMEOUT=str(WAIT))
    command = ["mpirun", "--timeout", str(LIMIT), "-n", "2", sys.executable, "-m", "pytest"]
    command += ["-p", "rank_sync", "-p", "no:cacheprovider", "-q", "-rA", "--color=no"]
    command.append(str(test_file))
    start = time.monotonic()
    result = subprocess.run(
        command, capture_output=True, text=True, env=env, cwd=tmp_path, timeout=LIMIT + 60
    )
    return result, time.monotonic() - start


def test_a_failure_on_one_rank_before_a_collective_aborts_every_rank(tmp_path):
    result, elapsed = _run_child(tmp_path, HANGING)
    output = result.stdout + result.stderr
    assert result.returncode != 0, output
    assert elapsed < LIMIT / 2, (elapsed, output)  # ended by the plugin, not by mpirun
    assert "only rank 1 fails" in output  # the failure's traceback is printed
    assert "MPI Abort" in output and "[rank 1]" in output, output
    assert "test_never_reached PASSED" not in output


def test_a_failure_on_one_rank_without_a_hang_lets_the_run_finish(tmp_path):
    result, _ = _run_child(tmp_path, NOT_HANGING)
    output = result.stdout + result.stderr
    assert result.returncode == 1, output  # pytest's "tests failed", not an abort
    assert "MPI Abort" not in output
    assert output.count("PASSED test_child.py::test_after_the_failure") == 2, output
