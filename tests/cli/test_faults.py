"""Faults under mpirun (SPEC 7, 9): a killed rank or an exception on one rank ends the job
promptly, and the output written so far stays readable.

Both tests start their own ``mpirun -n 2`` jobs, so they run in the serial pass only.
"""

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
from conftest import PAREFG, mpi_env

pytestmark = pytest.mark.serial_only

PROMPT_END = 10.0  # seconds within which the whole job must end after the fault
OUTPUT_EVERY = 5


def rank_processes(mpirun_pid: int) -> dict[int, int]:
    """{MPI rank: pid} of the processes mpirun started, read from /proc (no psutil)."""
    listing = subprocess.run(
        ["ps", "--ppid", str(mpirun_pid), "-o", "pid="], capture_output=True, text=True
    )
    ranks = {}
    for pid in map(int, listing.stdout.split()):
        try:
            environ = Path(f"/proc/{pid}/environ").read_bytes().split(b"\0")
        except OSError:  # already gone
            continue
        for entry in environ:
            if entry.startswith(b"OMPI_COMM_WORLD_RANK="):
                ranks[int(entry.split(b"=")[1])] = pid
    return ranks


def is_running(pid: int) -> bool:
    """Alive and not a zombie."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def wait_for_progress(job: subprocess.Popen, timeout: float, past_step: int = 0) -> list[str]:
    """Rank 0's stdout lines up to the first 'step n/N' progress line with n > past_step."""
    lines, deadline = [], time.monotonic() + timeout
    while time.monotonic() < deadline:
        line = job.stdout.readline()
        if not line:
            break
        lines.append(line)
        words = line.split()
        if words and words[0] == "step" and int(words[1].split("/")[0]) > past_step:
            return lines
    raise AssertionError(f"no progress line past step {past_step} within {timeout} s: {lines}")


@pytest.fixture
def job_cleanup():
    """Kill (by process group) whatever job a test leaves behind."""
    jobs = []
    yield jobs.append
    for job in jobs:
        if job.poll() is None:
            os.killpg(job.pid, signal.SIGKILL)
            job.wait()


def test_killed_rank_ends_job_and_output_stays_readable(tmp_path, job_cleanup):
    """SIGKILL rank 1 mid-run: mpirun and rank 0 end within 10 s, and result.h5 opens
    read-only with every output step up to the last one flushed before the kill."""
    out = tmp_path / "run"
    settings = ["discretization.h=0.03125", "time.dt=0.005", "time.T=2"]
    settings += [f"output.every={OUTPUT_EVERY}"]
    command = ["mpirun", "-n", "2", PAREFG, "run", "square", "--out", str(out)]
    command += [arg for s in settings for arg in ("--set", s)]
    job = subprocess.Popen(
        command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=mpi_env(),
        start_new_session=True,
    )  # fmt: skip
    job_cleanup(job)
    # two output steps written (and flushed: the step after an output step is running),
    # counted from the progress rather than waited for, so that a loaded machine is no matter
    wait_for_progress(job, timeout=120, past_step=2 * OUTPUT_EVERY)
    ranks = rank_processes(job.pid)
    assert sorted(ranks) == [0, 1], ranks

    os.kill(ranks[1], signal.SIGKILL)
    killed_at = time.monotonic()
    code = job.wait(timeout=PROMPT_END)
    deadline = killed_at + PROMPT_END
    while is_running(ranks[0]) and time.monotonic() < deadline:
        time.sleep(0.05)
    ended_after = time.monotonic() - killed_at
    print(f"\n[faults] SIGKILL of rank 1: mpirun exit {code}, job ended in {ended_after:.2f} s")
    assert code != 0
    assert not is_running(ranks[0]), "rank 0 outlived the job"

    with h5py.File(out / "result.h5", "r", locking=False) as h5:
        steps = h5["steps/step"][:]  # (n_out,)
        times = h5["steps/time"][:]
        n_nodes = h5["mesh/coordinates"].shape[0]
        print(f"[faults] result.h5 readable: {len(steps)} output steps, last step {steps[-1]}")
        # t = 0 and every output step from the first one on, none missing, at t = n dt
        expected = OUTPUT_EVERY * np.arange(len(steps))
        np.testing.assert_array_equal(steps, expected)
        np.testing.assert_allclose(times, 0.005 * expected, rtol=1e-12)
        assert len(steps) >= 2
        # each field holds exactly the outputs 0000 .. n_out - 1, all finite
        names = [f"fields/{name}" for name in h5["fields"]]
        names += [f"contact_fields/{name}" for name in h5.get("contact_fields", {})]
        assert "fields/displacement" in names
        for name in names:
            assert sorted(h5[name]) == [f"{k:04d}" for k in range(len(steps))], name
            assert all(np.all(np.isfinite(h5[name][k][:])) for k in h5[name]), name
        for k in range(len(steps)):
            assert h5[f"fields/displacement/{k:04d}"].shape == (n_nodes, 2)
        # the per-step table was flushed with the last output step
        assert len(h5["history/time"]) >= steps[-1] + 1


ONE_RANK_RAISES = textwrap.dedent(
    """
    from mpi4py import MPI
    from parefg import cli

    {install_hook}
    comm = MPI.COMM_WORLD
    if comm.rank == 1:
        raise RuntimeError("failure on rank 1 only")
    comm.Barrier()  # rank 0 would wait here forever without the abort hook
    print("rank 0 passed the barrier", flush=True)
    """
)


def test_exception_on_one_rank_ends_all_ranks(tmp_path):
    """An uncaught exception on rank 1 while rank 0 waits in a barrier: both end within
    10 s (the abort hook calls MPI Abort) with a nonzero exit code."""
    script = tmp_path / "one_rank_raises.py"
    script.write_text(ONE_RANK_RAISES.format(install_hook="cli._install_abort_hook()"))
    start = time.monotonic()
    # generous timeout: startup (imports) is not part of the fault; the check is below
    result = subprocess.run(
        ["mpirun", "-n", "2", sys.executable, str(script)],
        capture_output=True, text=True, env=mpi_env(), timeout=60,
    )  # fmt: skip
    seconds = time.monotonic() - start
    print(f"\n[faults] exception on rank 1: exit {result.returncode} after {seconds:.2f} s")
    assert result.returncode != 0
    assert "failure on rank 1 only" in result.stderr
    assert "passed the barrier" not in result.stdout
    assert seconds < PROMPT_END + 5.0  # + interpreter and mpi4py start-up


def test_without_the_abort_hook_the_job_hangs(tmp_path, job_cleanup):
    """Control for the test above: the same script without the hook is still running
    after 10 s (rank 1 waits in MPI_Finalize, rank 0 in the barrier), so that test
    detects a missing or broken hook."""
    script = tmp_path / "one_rank_raises_no_hook.py"
    script.write_text(ONE_RANK_RAISES.format(install_hook="pass"))
    job = subprocess.Popen(
        ["mpirun", "-n", "2", sys.executable, str(script)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=mpi_env(),
        start_new_session=True,
    )  # fmt: skip
    job_cleanup(job)
    with pytest.raises(subprocess.TimeoutExpired):
        job.wait(timeout=PROMPT_END)
