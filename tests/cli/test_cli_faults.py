"""Hostile command lines (SPEC 8, 9): unusable --out, bad PETSc options, the [solver] table.

Each bad input exits 2 with one ``parefg: error:`` line naming the culprit, on 1 and 2
ranks, and writes nothing: no output directory, no empty runs/<scene>-N left behind.
A misspelled PETSc option is a warning (the run goes on), as PETSc itself treats it.
serial_only where a test starts its own processes.
"""

import json
import os
import subprocess

import pytest
from conftest import PAREFG, QUICK, assert_bad_input, run_parefg
from mpi4py import MPI
from petsc4py import PETSc

from parefg.run import run_scene
from parefg.scene.loader import load_scene

WARNING = "parefg: warning:"


def _listing(root):
    return sorted(str(p.relative_to(root)) for p in root.rglob("*"))


def _unusable_outputs(tmp_path):
    """--out value -> words of the message; each path's parent exists and stays as it is."""
    (tmp_path / "afile").write_text("keep\n")
    (tmp_path / "dangling").symlink_to(tmp_path / "nowhere")
    return {
        "under /proc": ("/proc/parefg-out", ["/proc/parefg-out", "cannot create"]),
        "under a file": (str(tmp_path / "afile" / "sub"), ["afile", "not a directory"]),
        "a file": (str(tmp_path / "afile"), ["afile", "not a directory"]),
        "dangling link": (str(tmp_path / "dangling"), ["dangling", "symbolic link"]),
        "5000 characters": (str(tmp_path / ("a" * 5000)), ["characters", "File name too long"]),
        "300-byte name": (str(tmp_path / "x" / ("b" * 300) / "y"), ["300 bytes", "255"]),
    }


CASES = ["under /proc", "under a file", "a file", "dangling link", "5000 characters"]


@pytest.mark.serial_only
@pytest.mark.parametrize("case", [*CASES, "300-byte name"])
def test_unusable_out_is_one_line_and_creates_nothing(tmp_path, case):
    out, words = _unusable_outputs(tmp_path)[case]
    before = _listing(tmp_path)
    result = run_parefg(["run", "square", *QUICK, "--quiet", "--out", out])
    assert_bad_input(result, ["--out", *words])
    assert _listing(tmp_path) == before
    assert (tmp_path / "afile").read_text() == "keep\n"


@pytest.mark.serial_only
@pytest.mark.parametrize("case", ["under /proc", "under a file"])
def test_unusable_out_on_two_ranks(tmp_path, case):
    out, words = _unusable_outputs(tmp_path)[case]
    result = run_parefg(["run", "square", *QUICK, "--quiet", "--out", out], ranks=2, timeout=120)
    assert_bad_input(result, ["--out", *words])


@pytest.mark.serial_only
@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only directories")
def test_read_only_parent_is_refused(tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o500)
    result = run_parefg(["run", "square", *QUICK, "--quiet", "--out", str(locked / "run")])
    assert_bad_input(result, ["--out", "locked"])
    assert list(locked.iterdir()) == []


def _read_only_mount_works(directory) -> bool:
    probe = f"mount --bind {directory} {directory} && mount -o remount,ro,bind {directory}"
    command = ["unshare", "-m", "--propagation", "private", "sh", "-c", probe]
    try:
        return subprocess.run(command, capture_output=True, timeout=30).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        return False


@pytest.mark.serial_only
def test_read_only_file_system_is_refused(tmp_path):
    """Root writes into any directory, but not into a read-only mount (a private one here)."""
    base = tmp_path / "ro"
    base.mkdir()
    if not _read_only_mount_works(base):
        pytest.skip("no private read-only bind mount here (needs unshare and CAP_SYS_ADMIN)")
    run = " ".join([PAREFG, "run", "square", *QUICK, "--quiet", "--out", str(base / "run")])
    script = f"mount --bind {base} {base} && mount -o remount,ro,bind {base} && {run}"
    result = subprocess.run(
        ["unshare", "-m", "--propagation", "private", "sh", "-c", script],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert_bad_input(result, ["--out", "read-only file system"])
    assert list(base.iterdir()) == []


# input found bad only after the scene loaded -> words of the message
LATE_FAILURES = {
    "meshing/MLS": (["--set", "discretization.support=1.05"], ["discretization.support"]),
    "PETSc option": (["-ksp_type", "bogus"], ["-ksp_type bogus"]),
}


@pytest.mark.serial_only
@pytest.mark.parametrize("case", LATE_FAILURES)
def test_late_bad_input_leaves_no_default_output_directory(tmp_path, case):
    """Without --out the run would use runs/square; a failed run must not create it."""
    extra, words = LATE_FAILURES[case]
    for _ in range(2):  # a second failure must not leave runs/square-2 either
        result = run_parefg(["run", "square", *QUICK, "--quiet", *extra], cwd=tmp_path)
        assert_bad_input(result, words)
    assert _listing(tmp_path) == []


@pytest.mark.serial_only
@pytest.mark.parametrize("case", LATE_FAILURES)
def test_late_bad_input_of_a_sweep_leaves_nothing(tmp_path, case):
    """A sweep creates its directory after validating the cases; a bad input found by its
    first case (meshing, a PETSc option) removes it again, with or without --out."""
    extra, words = LATE_FAILURES[case]
    vary = ["--vary", "discretization.h=0.25,0.125", "--set", "time.dt=0.25"]
    result = run_parefg(["sweep", "square", *vary, *extra], cwd=tmp_path)
    assert_bad_input(result, words)
    result = run_parefg(["sweep", "square", *vary, "--out", "D", *extra], cwd=tmp_path)
    assert_bad_input(result, words)
    assert _listing(tmp_path) == []


# PETSc option -> words of the message
BAD_PETSC = {
    "ksp type": (["-ksp_type", "bogus"], ["-ksp_type bogus", "KSP type bogus"]),
    "pc type": (["-pc_type", "nopc"], ["-pc_type nopc"]),
    "factor package": (["-pc_factor_mat_solver_type", "nope"], ["solver_type nope"]),
    "mass ksp type": (["-mass_ksp_type", "bogus"], ["-mass_ksp_type bogus"]),
    "mass factor package": (["-mass_pc_factor_mat_solver_type", "nope"], ["mass_pc_factor"]),
}


@pytest.mark.serial_only
@pytest.mark.parametrize("case", BAD_PETSC)
def test_bad_petsc_option_is_one_line_naming_it(tmp_path, case):
    option, words = BAD_PETSC[case]
    out = tmp_path / "never"
    result = run_parefg(["run", "square", *QUICK, "--quiet", "--out", str(out), *option])
    assert_bad_input(result, words)
    assert not out.exists()


@pytest.mark.serial_only
@pytest.mark.parametrize("case", ["ksp type", "factor package", "mass ksp type"])
def test_bad_petsc_option_on_two_ranks(tmp_path, case):
    option, words = BAD_PETSC[case]
    out = tmp_path / "never"
    args = ["run", "square", *QUICK, "--quiet", "--out", str(out), *option]
    result = run_parefg(args, ranks=2, timeout=120)
    assert_bad_input(result, words)
    assert not out.exists()


@pytest.mark.serial_only
@pytest.mark.parametrize("ranks", [1, 2])
def test_misspelled_petsc_option_is_one_warning(tmp_path, ranks):
    out = tmp_path / "run"
    args = ["run", "square", *QUICK, "--quiet", "--out", str(out), "-ksp_tpye", "cg"]
    result = run_parefg([*args, "-snes_rtol", "1e-11"], ranks=ranks, timeout=300)
    assert result.returncode == 0, result.stderr
    warnings = [line for line in result.stderr.splitlines() if line.startswith(WARNING)]
    assert len(warnings) == 1, result.stderr
    assert "-ksp_tpye" in warnings[0] and "snes_rtol" not in warnings[0]
    assert (out / "summary.json").is_file()


@pytest.mark.serial_only
def test_used_petsc_options_give_no_warning(tmp_path):
    args = ["run", "square", *QUICK, "--quiet", "--out", str(tmp_path / "run")]
    result = run_parefg([*args, "-ksp_type", "preonly", "-snes_rtol", "1e-12"])
    assert result.returncode == 0, result.stderr
    assert WARNING not in result.stderr


SOLVER_SCENE = """
[domain]
shape = "square"
[discretization]
h = 0.125
[time]
T = 0.5
dt = 0.25
[boundary.top]
type = "dirichlet"
[boundary.bottom]
type = "neumann"
traction = [0, -0.1]
"""


def _scene_file(tmp_path, solver: str):
    path = tmp_path / "scene.toml"
    path.write_text(SOLVER_SCENE + solver)
    return str(path)


@pytest.mark.serial_only
def test_solver_table_is_applied_and_a_bogus_value_refused(tmp_path):
    """A direct solve takes 1 linear iteration a step; CG + Jacobi takes many."""
    runs = {}
    for name, table in {
        "direct": "",
        "cg": '[solver]\nksp_type = "cg"\npc_type = "jacobi"\n',
    }.items():
        out = tmp_path / name
        result = run_parefg(["run", _scene_file(tmp_path, table), "--quiet", "--out", str(out)])
        assert result.returncode == 0, result.stderr
        runs[name] = json.loads((out / "summary.json").read_text())["linear_iterations"]
    assert runs["direct"] == 2  # 2 steps, one preonly application each
    assert runs["cg"] > 10 * runs["direct"]
    bogus = _scene_file(tmp_path, '[solver]\nksp_type = "bogus"\n')
    result = run_parefg(["run", bogus, "--quiet", "--out", str(tmp_path / "never")])
    assert_bad_input(result, ["solver.ksp_type", "bogus"])
    assert not (tmp_path / "never").exists()


@pytest.mark.serial_only
def test_command_line_option_wins_over_the_solver_table(tmp_path):
    scene = _scene_file(tmp_path, '[solver]\nksp_type = "cg"\npc_type = "jacobi"\n')
    out = tmp_path / "run"
    options = ["-ksp_type", "preonly", "-pc_type", "lu"]
    result = run_parefg(["run", scene, "--quiet", "--out", str(out), *options])
    assert result.returncode == 0, result.stderr
    # the command line's direct solve instead of the scene's CG + Jacobi: one solve per step
    # (preonly with the scene's Jacobi alone is no solve: the step's residual check fails it)
    assert json.loads((out / "summary.json").read_text())["linear_iterations"] == 2


def test_solver_table_does_not_leak_into_the_next_run(tmp_path):
    """In one process: the [solver] options are gone after the run, PETSc's and ours."""
    comm = MPI.COMM_WORLD
    root = comm.bcast(str(tmp_path), root=0)
    table = '[solver]\nksp_type = "cg"\npc_type = "jacobi"\nksp_rtol = 1e-10\n'
    scene = load_scene(comm.bcast(_scene_file(tmp_path, table) if comm.rank == 0 else None))
    before = PETSc.Options().getAll()
    summary = run_scene(comm, scene, out=f"{root}/first", quiet=True)
    assert summary["linear_iterations"] > 20
    assert PETSc.Options().getAll() == before
    plain = load_scene(comm.bcast(_scene_file(tmp_path, "") if comm.rank == 0 else None))
    # a leaked ksp_type = cg would take > 20 iterations again; the direct solve takes 2
    assert run_scene(comm, plain, out=f"{root}/second", quiet=True)["linear_iterations"] == 2


# command line argparse refuses -> words of the message
BAD_ARGUMENTS = {
    "no scene": (["run"], ["run:", "scene"]),
    "negative checkpoint interval": (["run", "square", "--checkpoint-every", "-3"], ["-3"]),
    "unknown argument": (["run", "square", "--bogus"], ["--bogus"]),
    "unknown command": (["frob"], ["frob"]),
}


@pytest.mark.serial_only
@pytest.mark.parametrize("ranks", [1, 2])
@pytest.mark.parametrize("case", BAD_ARGUMENTS)
def test_bad_arguments_are_one_line(tmp_path, case, ranks):
    args, words = BAD_ARGUMENTS[case]
    result = run_parefg(args, ranks=ranks, timeout=60, cwd=tmp_path)
    assert_bad_input(result, words)
    assert result.stderr.count("parefg: error:") == 1 and "usage:" not in result.stderr
    assert _listing(tmp_path) == []
