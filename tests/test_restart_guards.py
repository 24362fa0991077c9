"""Checkpoint/restart and the runtime guards (NaN stop, injected failure), via the CLI."""

import json

import h5py
import numpy as np
import pytest
from conftest import run_parefg

pytestmark = pytest.mark.serial_only


def _final_displacement(run_dir):
    with h5py.File(run_dir / "result.h5", "r") as handle:
        last = sorted(handle["fields/displacement"])[-1]
        return handle[f"fields/displacement/{last}"][...], handle["history/dissipated_energy"][-1]


def test_restart_matches_uninterrupted_run(tmp_path):
    """Checkpoint at step 14 of 20, restart on 1 and on 2 ranks: same final state."""
    full, again, parallel = tmp_path / "full", tmp_path / "again", tmp_path / "parallel"
    args = ["run", "square", "--quiet", "--set", "discretization.h=0.125"]
    assert run_parefg([*args, "--out", str(full), "--checkpoint-every", "7"]).returncode == 0
    checkpoint = str(full / "checkpoint.h5")
    with h5py.File(checkpoint, "r") as handle:
        assert handle.attrs["step"] == 14
    assert run_parefg([*args, "--out", str(again), "--restart", checkpoint]).returncode == 0
    result = run_parefg([*args, "--out", str(parallel), "--restart", checkpoint], ranks=2)
    assert result.returncode == 0, result.stderr
    reference, dissipated = _final_displacement(full)
    for run_dir, tolerance in ((again, 1e-12), (parallel, 1e-10)):
        restarted, restarted_dissipated = _final_displacement(run_dir)
        assert np.abs(restarted - reference).max() <= tolerance * np.abs(reference).max()
        assert restarted_dissipated == pytest.approx(dissipated, rel=1e-10)
        summary = json.loads((run_dir / "summary.json").read_text())
        assert summary["steps_done"] == 20


def test_restart_from_a_foreign_file_is_bad_input(tmp_path):
    bogus = tmp_path / "bogus.h5"
    bogus.write_text("not hdf5")
    result = run_parefg(
        ["run", "square", "--quiet", "--out", str(tmp_path / "r"), "--restart", str(bogus)]
    )
    assert result.returncode == 2
    assert "Traceback" not in result.stderr
    assert "checkpoint" in result.stderr.strip().splitlines()[-1]


def test_non_finite_state_stops_the_run_and_keeps_output(tmp_path):
    """A soft, light body (E = 1e-100, rho = 1e-200) loaded by 1e120 from t = 0.3 on:
    u = f / E = 1e220 overflows the elastic energy.  Exit 1, the steps before kept.

    (Data that are themselves not finite, sqrt(0.25 - t), are bad input: test_guards.py.)
    """
    scene = tmp_path / "overflow.toml"
    scene.write_text(
        '[domain]\nshape = "square"\n[discretization]\nh = 0.25\n'
        "[material]\nE = 1e-100\nrho = 1e-200\n[time]\nT = 0.5\ndt = 0.05\n"
        '[boundary.top]\ntype = "dirichlet"\n'
        '[loads]\nf = ["1e120 * heaviside(t - 0.275)", 0]\n[output]\nevery = 1\n'
    )
    out = tmp_path / "run"
    result = run_parefg(["run", str(scene), "--quiet", "--out", str(out)])
    assert result.returncode == 1, result.stderr
    assert "at step 6, t = 0.3: the time integration diverged" in result.stderr
    assert "Traceback" not in result.stderr and "Warning" not in result.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "failed"
    with h5py.File(out / "result.h5", "r") as handle:
        times = handle["steps/time"][...]
        assert times.max() == pytest.approx(0.25)  # every step before the overflow was written
