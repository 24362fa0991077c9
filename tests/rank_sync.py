"""pytest plugin: a test that fails on some ranks only must not hang the MPI run.

Under ``mpirun -n 2`` every test must reach the same collective calls on every rank.  A
test that raises on one rank before a collective (a file written on rank 0 only, a
rank-dependent branch) leaves that rank free to run on, while the other rank waits in
the collective for ever: the job then hangs until mpirun's timeout, and the failure's
traceback is never printed.

After each test every rank joins a non-blocking allreduce on a private communicator.  A
rank on which the test failed waits at most ``PAREFG_TEST_RANK_TIMEOUT`` seconds (60 by
default) for the other ranks to finish the same test; if they do not, it prints its
failure and calls MPI Abort, which ends every rank.  A rank on which the test passed
waits without limit: only a failure can justify aborting, and a slow but correct rank
is not one.  Serial runs are untouched.
"""

import os
import sys
import time

import numpy as np
import pytest
from mpi4py import MPI

TIMEOUT_VARIABLE = "PAREFG_TEST_RANK_TIMEOUT"
DEFAULT_TIMEOUT = 60.0  # seconds a failed rank waits for the others
POLL_INTERVAL = 0.01  # seconds between tests of the pending allreduce

_state: dict = {}
_FAILURES = pytest.StashKey[list]()  # the failed reports (setup, call, teardown) of a test


def pytest_configure(config):
    if MPI.COMM_WORLD.size > 1:
        # Private: a pending collective of a test on COMM_WORLD must not match ours.
        _state["comm"] = MPI.COMM_WORLD.Dup()
        _state["timeout"] = float(os.environ.get(TIMEOUT_VARIABLE, DEFAULT_TIMEOUT))


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    report = outcome.get_result()
    if report.failed:
        item.stash.setdefault(_FAILURES, []).append(report)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    yield
    comm = _state.get("comm")
    if comm is None:
        return
    failures = item.stash.get(_FAILURES, [])
    failed = np.array([len(failures) > 0], dtype=np.int32)
    any_failed = np.zeros(1, dtype=np.int32)  # both buffers live until the request completes
    request = comm.Iallreduce(failed, any_failed, MPI.MAX)
    deadline = time.monotonic() + _state["timeout"]
    while not request.Test():
        if failures and time.monotonic() > deadline:
            _abort(item, failures, comm.rank)
        time.sleep(POLL_INTERVAL)


def _abort(item, failures, rank: int) -> None:
    """Print this rank's failure (pytest's summary would never come) and end every rank."""
    for report in failures:
        sys.stderr.write(f"\n[rank {rank}] {report.when} of {item.nodeid} failed:\n")
        sys.stderr.write(report.longreprtext + "\n")
    sys.stderr.write(
        f"[rank {rank}] {item.nodeid} failed on this rank and the other ranks did not "
        f"finish it within {_state['timeout']:g} s (waiting in a collective the failed "
        "rank skipped?): MPI Abort\n"
    )
    sys.stderr.flush()
    MPI.COMM_WORLD.Abort(1)
