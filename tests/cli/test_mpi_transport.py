"""Open MPI's transport defaults (parefg/_env.py): ob1 asked for directly where all ranks
share one machine, the singleton daemon skipped, nothing the user set overridden, and
nothing changed for ranks spread over several machines.  Whether the runs still agree on
1 and 2 ranks is the business of tests/parallel; here, the choice and that it reaches a
real process before MPI_Init."""

import subprocess
import sys
from pathlib import Path

import pytest
from conftest import mpi_env

from parefg._env import one_machine_transport


def test_a_singleton_asks_for_ob1_and_no_daemon():
    assert one_machine_transport({}) == {
        "OMPI_MCA_pml": "ob1",
        "OMPI_MCA_ess_singleton_isolated": "1",
    }


def test_ranks_on_one_machine_ask_for_ob1():
    launched = {"OMPI_COMM_WORLD_SIZE": "2", "OMPI_COMM_WORLD_LOCAL_SIZE": "2"}
    assert one_machine_transport(launched) == {"OMPI_MCA_pml": "ob1"}


def test_ranks_on_several_machines_keep_open_mpis_choice():
    spread = {"OMPI_COMM_WORLD_SIZE": "8", "OMPI_COMM_WORLD_LOCAL_SIZE": "4"}
    assert one_machine_transport(spread) == {}


def test_what_the_user_set_wins():
    chosen = {"OMPI_MCA_pml": "ucx", "OMPI_MCA_ess_singleton_isolated": "0"}
    assert one_machine_transport(chosen) == {}


@pytest.mark.serial_only
def test_the_choice_is_made_before_mpi_starts_and_mpi_runs_with_it():
    """A fresh interpreter importing parefg then MPI: the variables are set and Open MPI
    came up with them (a wrong value would fail MPI_Init)."""
    result = _fresh_singleton("print(os.environ['OMPI_MCA_pml'], MPI.COMM_WORLD.size)")
    assert result.stdout.split() == ["ob1", "1"]


def _fresh_singleton(line: str) -> subprocess.CompletedProcess:
    """A new interpreter that imports parefg, starts MPI, then runs ``line`` (os and MPI
    imported); none of the settings under test inherited.  Asserts it succeeded."""
    env = {key: value for key, value in mpi_env().items() if key != "OMPI_MCA_pml"}
    env.pop("OMPI_MCA_ess_singleton_isolated", None)
    probe = f"import os, parefg\nfrom mpi4py import MPI\nMPI.COMM_WORLD.barrier()\n{line}\n"
    result = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, env=env, timeout=120
    )
    assert result.returncode == 0, result.stderr
    return result


@pytest.mark.serial_only
def test_a_singleton_keeps_its_session_directory_to_itself_and_removes_it():
    """Isolated singletons all name their session directory jf.0: each parefg singleton
    gets its own base for it (two processes starting at once raced to create the shared
    one), used by Open MPI and removed when the process ends."""
    line = "base = os.environ['OMPI_MCA_orte_tmpdir_base']; print(base, *os.listdir(base))"
    bases = []
    for _ in range(2):
        base, used = _fresh_singleton(line).stdout.split()
        assert used.startswith("ompi."), used  # Open MPI's session directory is in it
        assert not Path(base).exists()  # removed at exit
        bases.append(base)
    assert bases[0] != bases[1]


def test_a_base_the_user_chose_is_kept():
    env = {"OMPI_MCA_orte_tmpdir_base": "/scratch"}
    probe = "import os, parefg; print(os.environ['OMPI_MCA_orte_tmpdir_base'])"
    result = subprocess.run(
        [sys.executable, "-c", probe],
        capture_output=True,
        text=True,
        env={**{k: v for k, v in mpi_env().items() if not k.startswith("OMPI_MCA_ess")}, **env},
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "/scratch"
