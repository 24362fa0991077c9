"""`parefg run --solver` and `[solver] method`: one switch, validated, failures kept failures.

serial_only: each test starts `parefg` subprocesses.
"""

import json

import pytest
from conftest import QUICK, assert_bad_input, run_parefg

pytestmark = pytest.mark.serial_only
NO_CONTACT = ["--set", "boundary.bottom.type=neumann"]  # each step one linear solve


def test_unknown_method_is_bad_input(tmp_path):
    out = tmp_path / "never"
    args = ["run", "square", *QUICK, "--solver", "gauss", "--out", str(out), "--quiet"]
    result = run_parefg(args)
    assert_bad_input(result, ["solver.method", "gauss", "'direct', 'iterative'"])
    assert not out.exists()


def test_the_command_line_method_wins_and_petsc_options_still_apply(tmp_path):
    out = tmp_path / "run"
    args = ["run", "square", *QUICK, "--set", "solver.method=direct", "--solver", "iterative"]
    result = run_parefg([*args, "--out", str(out), "--quiet", "-pc_type", "jacobi", "-ksp_view"])
    assert result.returncode == 0, result.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["params"]["solver"]["method"] == "iterative"
    assert summary["linear_iterations"] > summary["newton_iterations"]  # CG
    assert "type: cg" in result.stdout and "type: jacobi" in result.stdout
    assert "type: gamg" not in result.stdout  # -pc_type beat the method's GAMG
    assert "never used" not in result.stderr


@pytest.mark.parametrize("scene", [[], NO_CONTACT], ids=["contact step", "linear step"])
def test_a_ksp_that_does_not_converge_fails_the_run(tmp_path, scene):
    """-ksp_max_it 2: exit 1 naming the KSP reason, output kept, status "failed"."""
    out = tmp_path / "run"
    args = ["run", "square", *QUICK, *scene, "--solver", "iterative", "-ksp_max_it", "2"]
    result = run_parefg([*args, "--out", str(out), "--quiet"])
    assert result.returncode == 1, result.stderr
    assert "Traceback" not in result.stderr
    assert "DIVERGED_MAX_IT" in result.stderr and "t = 0.25" in result.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "failed" and summary["steps_done"] == 0
    assert "errors" not in summary
