"""The command-line contract (SPEC 7, 8, 9), each test a `parefg` subprocess.

Bad input exits 2 with one line on stderr naming the problem, no traceback, and
writes nothing; a solver failure exits 1 and leaves readable output; a good run
under ``mpirun -n 2`` exits 0 with every summary.json contract key.
serial_only: these tests start their own processes and MPI jobs.
"""

import json
import re

import h5py
import pytest
from conftest import QUICK, assert_bad_input, run_parefg

pytestmark = pytest.mark.serial_only

SUMMARY_KEYS = {
    "scene",
    "params",
    "mpi_ranks",
    "n_nodes",
    "n_dofs",
    "n_steps",
    "timings",
    "newton_iterations",
    "linear_iterations",
    "errors",
}
TIMING_KEYS = {"total", "mesh", "mls", "assembly", "solve", "output"}

# --set override -> words the one-line message must contain.
BAD_OVERRIDES = {
    "unknown key": ("discretization.hh=0.1", ["discretization.hh", "unknown key"]),
    "wrong type": ('discretization.h="coarse"', ["discretization.h", "number"]),
    "h negative": ("discretization.h=-0.1", ["discretization.h", "> 0"]),
    "dt zero": ("time.dt=0", ["time.dt", "> 0"]),
    "nu incompressible": ("material.nu=0.5", ["material.nu", "0.5"]),
    "unknown boundary": ('boundary.nowhere.type="dirichlet"', ["nowhere", "bottom"]),
    "degree 4": ("discretization.degree=4", ["discretization.degree", "1..3"]),
    "python internals": ('exact.u=["().__class__", "0"]', ["exact.u[0]", "not allowed"]),
    "python builtins": ('loads.f=["__import__(\'os\')", "0"]', ["loads.f[0]", "not allowed"]),
}


@pytest.mark.parametrize("case", BAD_OVERRIDES)
def test_bad_override_exits_2_with_one_line(tmp_path, case):
    override, words = BAD_OVERRIDES[case]
    out = tmp_path / "never"
    result = run_parefg(["run", "square", "--set", override, "--out", str(out), "--quiet"])
    assert_bad_input(result, words)
    assert result.stderr.strip().count("\n") == 0
    assert not out.exists()


def test_toml_syntax_error_exits_2(tmp_path):
    scene = tmp_path / "broken.toml"
    scene.write_text('[domain\nshape = "square"\n')
    result = run_parefg(["run", str(scene), "--out", str(tmp_path / "never")])
    assert_bad_input(result, ["TOML syntax error", "line 1"])


def test_support_too_small_names_point_and_fix(tmp_path):
    """s = 1.05 leaves corner points with too few neighbours for m = 2 (6 basis terms)."""
    args = ["run", "square", *QUICK, "--set", "discretization.support=1.05"]
    result = run_parefg([*args, "--out", str(tmp_path / "run"), "--quiet"])
    line = assert_bad_input(result, ["point", "neighbours", "discretization.support"])
    assert re.search(r"point \(\s*-?[0-9.e+-]+,\s*-?[0-9.e+-]+\)", line), line


def test_existing_output_directory_untouched(tmp_path):
    out = tmp_path / "taken"
    out.mkdir()
    keep = out / "notes.txt"
    keep.write_text("mine\n")
    result = run_parefg(["run", "square", *QUICK, "--out", str(out), "--quiet"])
    assert_bad_input(result, [str(out), "--out"])
    assert [path.name for path in out.iterdir()] == ["notes.txt"]
    assert keep.read_text() == "mine\n"


def test_bad_input_under_two_ranks_exits_2_without_hang(tmp_path):
    args = ["run", "square", "--set", "material.nu=0.7", "--out", str(tmp_path / "never")]
    result = run_parefg(args, ranks=2, timeout=120)
    assert_bad_input(result, ["material.nu"])


def test_scenes_lists_square_and_z():
    result = run_parefg(["scenes"])
    assert result.returncode == 0, result.stderr
    names = {line.split()[0] for line in result.stdout.splitlines() if line.strip()}
    assert {"square", "z"} <= names


def test_info_prints_petsc_version():
    from petsc4py import PETSc

    result = run_parefg(["info"])
    assert result.returncode == 0, result.stderr
    version = ".".join(map(str, PETSc.Sys.getVersion()))
    assert re.search(rf"^petsc\s+{re.escape(version)}\b", result.stdout, re.M), result.stdout


def test_info_names_the_kernels_a_run_uses():
    from parefg.discretization import aot

    result = run_parefg(["info"])
    assert result.returncode == 0, result.stderr
    (line,) = [row for row in result.stdout.splitlines() if row.startswith("kernels")]
    assert "compiled ahead of time" in line and str(aot.directory()) in line, line


def test_two_rank_run_writes_contract_summary(tmp_path):
    out = tmp_path / "run"
    result = run_parefg(["run", "square", "--set", "time.dt=0.1", "--out", str(out)], ranks=2)
    assert result.returncode == 0, result.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert SUMMARY_KEYS <= summary.keys()
    assert TIMING_KEYS <= summary["timings"].keys()
    assert summary["mpi_ranks"] == 2 and summary["n_steps"] == 10
    assert summary["n_dofs"] == 2 * summary["n_nodes"]
    assert summary["params"]["time"]["dt"] == 0.1
    # SPEC 6 solution at h = 1/16, m = 2: measured L2 2.8e-3, H1 4.8e-3.
    assert 0 < summary["errors"]["l2_rel"] < 1e-2
    assert 0 < summary["errors"]["h1_rel"] < 1e-2
    assert (out / "result.h5").is_file() and (out / "result.xdmf").is_file()


def test_injected_failure_exits_1_and_keeps_output(tmp_path):
    out = tmp_path / "run"
    args = ["run", "square", *QUICK, "--fail-at-step", "3", "--out", str(out), "--quiet"]
    result = run_parefg(args)
    assert result.returncode == 1, result.stderr
    assert "Traceback" not in result.stderr
    assert "step 3" in result.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "failed"
    assert summary["steps_done"] == 2
    with h5py.File(out / "result.h5", "r") as result_file:
        # rows for t = 0 and the two completed steps of dt = 0.25
        assert list(result_file["history/time"][:]) == pytest.approx([0.0, 0.25, 0.5])


def test_petsc_option_is_honoured(tmp_path):
    args = ["run", "square", *QUICK, "--out", str(tmp_path / "run"), "--quiet"]
    result = run_parefg([*args, "-snes_monitor"])
    assert result.returncode == 0, result.stderr
    assert "SNES Function norm" in result.stdout
    quiet = run_parefg(["run", "square", *QUICK, "--out", str(tmp_path / "plain"), "--quiet"])
    assert "SNES Function norm" not in quiet.stdout


@pytest.mark.serial_only
def test_bare_parefg_under_mpirun_runs_the_default_scene(tmp_path):
    """`mpirun -n 2 parefg` (no arguments) runs "square" into runs/square and prints errors."""
    result = run_parefg([], ranks=2, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert "errors at T" in result.stdout
    summary = json.loads((tmp_path / "runs" / "square" / "summary.json").read_text())
    assert summary["scene"] == "square" and summary["mpi_ranks"] == 2
    assert summary["errors"]["h1_rel"] < 1e-2


def test_command_line_symmetric_solver_chooses_gauss_at_degree_3(tmp_path):
    """The command line's -pc_type cholesky / -ksp_type cg decide the defaults like the
    scene's [solver] options: at m = 3 the run integrates with Gauss (VCI's nonsymmetric
    K would be solved by Cholesky or CG otherwise), and an explicit vci is refused."""
    base = ["run", "square", *QUICK, "--set", "discretization.degree=3", "--quiet"]
    result = run_parefg([*base, "--out", str(tmp_path / "cholesky"), "-pc_type", "cholesky"])
    assert result.returncode == 0, result.stderr
    params = json.loads((tmp_path / "cholesky" / "summary.json").read_text())["params"]
    assert params["discretization"]["integration"] == "gauss"
    plain = run_parefg([*base, "--out", str(tmp_path / "lu")])
    assert plain.returncode == 0, plain.stderr
    params = json.loads((tmp_path / "lu" / "summary.json").read_text())["params"]
    assert params["discretization"]["integration"] == "vci"
    explicit = [*base, "--set", "discretization.integration=vci", "-ksp_type", "cg"]
    refused = run_parefg([*explicit, "--out", str(tmp_path / "refused")])
    assert_bad_input(refused, ["nonsymmetric"])
    assert not (tmp_path / "refused").exists()
