"""The parallel layer (parefg.parallel): failures raised on every rank, rows, PETSc options.

Runs serially and under ``mpirun -n 2``; every test reaches the same collectives on every
rank.  On one rank "the last rank" is rank 0 itself.
"""

import pytest
from petsc4py import PETSc

from parefg.errors import InputError, SolverError
from parefg.parallel import (
    call_on_root,
    default_options,
    raise_everywhere,
    raise_unless_everywhere,
    run_on_root,
    same_everywhere,
    set_from_options,
    wait_for_all,
)


def test_a_failure_on_the_last_rank_is_raised_on_every_rank(comm):
    last = comm.size - 1
    error = SolverError("diverged on the last rank") if comm.rank == last else None
    with pytest.raises(SolverError, match="diverged on the last rank"):
        raise_everywhere(comm, error)


def test_the_first_failing_rank_decides_the_message(comm):
    error = InputError(f"bad on rank {comm.rank}")  # every rank fails
    with pytest.raises(InputError, match="bad on rank 0"):
        raise_everywhere(comm, error)


def test_the_deciding_rank_raises_its_own_exception_object(comm):
    """Rank 0 keeps its traceback; another rank raises a copy of rank 0's failure."""
    error = InputError(f"found on rank {comm.rank}")
    with pytest.raises(InputError, match="found on rank 0") as raised:
        raise_everywhere(comm, error)
    assert (raised.value is error) == (comm.rank == 0)


def test_with_a_root_only_its_verdict_counts(comm):
    # every rank but the root sees a failure; the root's verdict (none) is what counts
    error = None if comm.rank == 0 else InputError("not the root's verdict")
    raise_everywhere(comm, error, root=0)
    last = comm.size - 1
    error = InputError("the root refuses") if comm.rank == last else None
    with pytest.raises(InputError, match="the root refuses"):
        raise_everywhere(comm, error, root=last)


def test_no_failure_returns_on_every_rank(comm):
    raise_everywhere(comm, None)
    raise_unless_everywhere(comm, True, ValueError("never"))
    assert comm.allreduce(1) == comm.size  # every rank is still in step


def test_a_check_failing_on_one_rank_fails_everywhere(comm):
    ok = comm.rank != comm.size - 1
    with pytest.raises(ValueError, match="rows overlap"):
        raise_unless_everywhere(comm, ok, ValueError("rows overlap"))


def test_same_everywhere_compares_every_rank_with_rank_0(comm):
    assert same_everywhere(comm, ("u", (2,), "<f8"))
    assert same_everywhere(comm, comm.rank) == (comm.size == 1)


def test_call_on_root_runs_once_and_broadcasts_the_result(comm):
    calls = []

    def task(value):
        calls.append(value)
        return {"path": "runs/square", "value": value}

    assert call_on_root(comm, task, 7) == {"path": "runs/square", "value": 7}
    assert len(calls) == (1 if comm.rank == 0 else 0)


def test_run_on_root_keeps_the_result_on_the_root(comm):
    result = run_on_root(comm, lambda value: [value], 7)
    assert result == ([7] if comm.rank == 0 else None)


@pytest.mark.parametrize("on_root", [call_on_root, run_on_root])
def test_call_on_root_raises_an_expected_failure_everywhere(comm, on_root):
    def task():
        raise InputError("--out runs: exists and is not a directory")

    with pytest.raises(InputError, match="exists and is not a directory"):
        on_root(comm, task)


@pytest.mark.parametrize("on_root", [call_on_root, run_on_root])
def test_call_on_root_ends_every_rank_on_a_defect(comm, on_root):
    """A defect on the root is raised there as it is; the other ranks do not wait forever."""

    def task():
        raise KeyError("u")

    expected = KeyError if comm.rank == 0 else RuntimeError
    with pytest.raises(expected, match="u"):
        on_root(comm, task)


def test_wait_for_all_returns_when_every_rank_arrives(comm):
    wait_for_all(comm, patience=None, abort_code=1)
    wait_for_all(comm, patience=30.0, abort_code=1)
    assert comm.allreduce(1) == comm.size


def test_defaults_apply_only_where_no_option_was_given_and_leave_no_trace(comm):
    options = PETSc.Options()
    options.setValue("layer_test_pc_type", "jacobi")  # as if given on the command line
    try:
        with default_options("layer_test_", {"ksp_type": "cg", "pc_type": "none"}) as inserted:
            assert inserted == ["layer_test_ksp_type"]
            assert options.getString("layer_test_ksp_type") == "cg"
            assert options.getString("layer_test_pc_type") == "jacobi"
        assert not options.hasName("layer_test_ksp_type")
        assert options.getString("layer_test_pc_type") == "jacobi"
    finally:
        options.delValue("layer_test_pc_type")


def test_set_from_options_reads_the_object_s_prefix_only(comm):
    """A prefixed KSP takes its default, ignores an unprefixed option, and obeys its own."""
    options = PETSc.Options()
    options.setValue("ksp_type", "bcgs")  # for the step solver, not for this object
    ksp = PETSc.KSP().create(comm)
    try:
        set_from_options(ksp, "layer_test_", {"ksp_type": "cg"})
        assert ksp.getOptionsPrefix() == "layer_test_"
        assert ksp.getType() == "cg"
        options.setValue("layer_test_ksp_type", "gmres")
        set_from_options(ksp, "layer_test_", {"ksp_type": "cg"})
        assert ksp.getType() == "gmres"
    finally:
        ksp.destroy()
        options.delValue("ksp_type")
        options.delValue("layer_test_ksp_type")
    assert not options.hasName("layer_test_ksp_type")
