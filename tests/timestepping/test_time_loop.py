"""The time loop's observers: the default time series, [output] fields, progress, Ctrl-C.

In-process runs use a tiny scene (h = 1/4, m = 1: 25 nodes) so that a thousand steps
take about a second; the Ctrl-C and progress tests start the CLI as a subprocess.
"""

import json
import os
import select
import signal
import subprocess
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import h5py
import numpy as np
import pytest
from conftest import PAREFG, mpi_env

from parefg.io.observers import output_fields as _output_fields
from parefg.run import prepare, run_scene
from parefg.scene.loader import load_scene

TINY = ["discretization.h=0.25", "discretization.degree=1"]
FREE = ['boundary.bottom.type="dirichlet"']  # no Gamma_C: one linear solve per step


@pytest.fixture
def run_dir(comm, tmp_path):
    """One directory shared by all ranks (rank 0's tmp_path)."""
    return Path(comm.bcast(str(tmp_path), root=0)) / "run"


def output_steps(run_dir: Path) -> np.ndarray:
    with h5py.File(run_dir / "result.h5", "r") as f:
        return f["steps/step"][()]


def test_default_output_is_a_series_of_about_50_frames_from_t0(comm, run_dir):
    """1000 steps, no [output] every: t = 0, every 20th step and T (51 frames)."""
    scene = load_scene("square", [*TINY, *FREE, "time.dt=0.001"])
    assert scene.params["output"]["every"] == 20  # the effective scene shows the choice
    run_scene(comm, scene, out=str(run_dir), quiet=True)
    np.testing.assert_array_equal(output_steps(run_dir), 20 * np.arange(51))
    root = ET.parse(run_dir / "result.xdmf").getroot()
    times = [float(g.find("Time").get("Value")) for g in root.find("Domain/Grid")]
    np.testing.assert_allclose(times, 0.02 * np.arange(51), rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("n_steps, every", [(7, 1), (130, 3), (10**6, 20000)])
def test_default_every_gives_about_50_frames(n_steps, every):
    scene = load_scene("square", [*TINY, "time.T=1", f"time.dt={1 / n_steps!r}"])
    assert scene.time.n_steps == n_steps and scene.output.every == every


def test_every_zero_writes_the_final_step_only(comm, run_dir):
    scene = load_scene("square", [*TINY, *FREE, "time.dt=0.25", "output.every=0"])
    run_scene(comm, scene, out=str(run_dir), quiet=True)
    np.testing.assert_array_equal(output_steps(run_dir), [4])


@pytest.mark.parametrize(
    "fields, node, contact",
    [
        (["u"], ["displacement"], []),
        ([], [], []),
        (["contact", "a"], ["acceleration"], ["gap", "normal_pressure", "status"]),
    ],
)
def test_output_fields_selects_the_datasets(comm, run_dir, fields, node, contact):
    """[output] fields = [...] writes only those; history, mesh and steps always."""
    scene = load_scene("square", [*TINY, "time.dt=0.25", f"output.fields={fields!r}"])
    run_scene(comm, scene, out=str(run_dir), quiet=True)
    with h5py.File(run_dir / "result.h5", "r") as f:
        assert sorted(f.get("fields", {})) == node
        assert set(contact) <= set(f.get("contact_fields", {}))
        assert bool(contact) == ("contact_fields" in f)
        assert f["mesh/coordinates"].shape[0] == 25
        assert len(f["history/time"]) == 5 and len(f["steps/step"]) == 5
    root = ET.parse(run_dir / "result.xdmf").getroot()
    names = {a.get("Name") for a in root.iter("Attribute")}
    assert names == set(node) | (
        {"gap", "normal_pressure", "status", "tangential_traction"} if contact else set()
    )


def test_unrequested_von_mises_builds_no_gradient_operator(comm):
    sim = prepare(comm, "square", [*TINY, "time.dt=0.25", "output.fields=['u', 'contact']"])
    node_fields, contact_fields = _output_fields(sim, sim.start())
    assert sorted(node_fields) == ["displacement"] and "status" in contact_fields
    assert sim.disc.nodes.gradients.kept is None  # the nodal shape gradients were never built


def start_cli(args, ranks=1):
    command = [PAREFG, "run", "square", *args]
    if ranks > 1:
        command = ["mpirun", "-n", str(ranks), *command]
    return subprocess.Popen(
        command,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=mpi_env(),
        start_new_session=True,
    )


def wait_for_progress(job, timeout: float) -> str:
    """The first progress line ("  step n/N ..."), read within ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    descriptor, text = job.stdout.fileno(), b""
    while time.monotonic() < deadline and job.poll() is None:
        if select.select([descriptor], [], [], 0.1)[0]:
            text += os.read(descriptor, 65536)
        lines = [line for line in text.decode().splitlines() if line.startswith("  step ")]
        if lines:
            return lines[0]
    raise AssertionError(f"no progress line within {timeout} s:\n{text.decode()}")


@pytest.mark.serial_only
def test_progress_within_seconds_and_ctrl_c_exits_130_with_readable_output(tmp_path):
    """1e9 steps: a progress line comes within seconds (not at 10 % of the run); SIGINT
    ends the run with exit 130, summary.json "interrupted", both files readable."""
    out = tmp_path / "run"
    job = start_cli([*[f"--set={s}" for s in (*TINY, "time.dt=1e-9")], "--out", str(out)])
    try:
        line = wait_for_progress(job, timeout=60)
        assert "/1000000000" in line
        job.send_signal(signal.SIGINT)
        _, stderr = job.communicate(timeout=60)
    finally:
        if job.poll() is None:
            os.killpg(job.pid, signal.SIGKILL)
    assert job.returncode == 130, stderr
    assert stderr.count("\n") == 1 and "interrupted by SIGINT after step" in stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "interrupted"
    done = summary["steps_done"]
    with h5py.File(out / "result.h5", "r") as f:
        assert len(f["history/time"]) == done + 1  # row 0 is t = 0
        assert f["steps/step"][-1] == done  # the step it stopped at is written
        assert f.attrs["summary_json"]
    snapshots = ET.parse(out / "result.xdmf").getroot().find("Domain/Grid").findall("Grid")
    assert snapshots[-1].find("Information").get("Value") == str(done)


@pytest.mark.serial_only
def test_ctrl_c_under_mpirun_stops_every_rank_after_the_same_step(tmp_path):
    """Open MPI turns Ctrl-C (SIGINT to mpirun) into SIGTERM to every rank: they agree
    on one step, write it, close result.h5 and summary.json ("interrupted")."""
    out = tmp_path / "run"
    args = [*[f"--set={s}" for s in (*TINY, "time.dt=1e-6")], "--out", str(out)]
    job = start_cli(args, ranks=2)
    try:
        wait_for_progress(job, timeout=120)
        job.send_signal(signal.SIGINT)
        job.communicate(timeout=60)
    finally:
        if job.poll() is None:
            os.killpg(job.pid, signal.SIGKILL)
    assert job.returncode != 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "interrupted" and summary["mpi_ranks"] == 2
    with h5py.File(out / "result.h5", "r") as f:
        assert len(f["history/time"]) == summary["steps_done"] + 1
        assert f["steps/step"][-1] == summary["steps_done"]
    ET.parse(out / "result.xdmf")
