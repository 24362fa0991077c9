"""Run-time guards: bad scene data named with its point, singular static stiffness, divergence.

Scenes are small (h = 1/4, a few steps) and written here; every exact value asserted is
a property of the input (where the data are not finite, which motion is free), never an
output of the code.  In-process tests run serially and under ``mpirun -n 2``; CLI tests
start their own 1- and 2-rank jobs.
"""

import dataclasses
import json
import math
import re

import h5py
import numpy as np
import pytest
from conftest import run_parefg
from mpi4py import MPI
from petsc4py import PETSc

from parefg.discretization.operators import build_discretization
from parefg.errors import DataError, InputError, SolverError
from parefg.guards import DataGuard
from parefg.run import prepare
from parefg.scene.loader import load_scene
from parefg.timestepping.loop import time_loop
from parefg.timestepping.simulation import Simulation

COMM = MPI.COMM_WORLD

BODY = '[domain]\nshape = "square"\n[discretization]\nh = 0.25\n'
CLAMPED = '[boundary.top]\ntype = "dirichlet"\n'
# Static, held by contact alone: a gap 0.1 below the bottom and the top pulled up, so the
# contact never closes and nothing holds the body.
OPEN_CONTACT = (
    BODY + '[time]\nscheme = "static"\nT = 0.1\ndt = 0.05\n'
    '[boundary.bottom]\ntype = "contact"\ngap = 0.1\n'
    '[boundary.top]\ntype = "neumann"\ntraction = [0, 1]\n'
)
# Static, pressed onto the obstacle (gap 0) with friction: contact and friction hold it.
PRESSED = (
    BODY + '[time]\nscheme = "static"\nT = 0.1\ndt = 0.05\n'
    '[boundary.bottom]\ntype = "contact"\nfriction = 1.0\n'
    '[boundary.top]\ntype = "neumann"\ntraction = [0, -1]\n'
)


def scene_file(tmp_path, text, name="scene"):
    path = tmp_path / f"{name}.toml"
    path.write_text(text)
    return str(path)


def shared_tmp(tmp_path_factory):
    """One directory for all ranks (rank 0's), so that every rank reads the same scene."""
    path = tmp_path_factory.mktemp("guards") if COMM.rank == 0 else None
    return COMM.bcast(path, root=0)


def simulation(path, overrides=()):
    return prepare(COMM, path, overrides)


def one_error_line(done, code):
    """The single stderr line of a failed run with exit ``code``."""
    assert done.returncode == code, done.stderr
    # Under mpirun, mpirun adds its own report of the exit code.
    lines = [line for line in done.stderr.splitlines() if line.startswith("parefg: error: ")]
    assert len(lines) == 1, done.stderr
    assert "Traceback" not in done.stderr and "Warning" not in done.stderr
    return lines[0]


# ----------------------------------------------------------------------------- data


@pytest.mark.serial_only
@pytest.mark.parametrize("ranks", [1, 2])
@pytest.mark.parametrize(
    ("force", "shown"),
    [('"sqrt(x - 2)"', "'sqrt(x - 2)' is not finite (nan)"),
     ('"exp(1000 * (1 + x))"', "'exp(1000 * (1 + x))' is not finite (inf)")],
)  # fmt: skip
def test_non_finite_load_names_datum_and_point(tmp_path, force, shown, ranks):
    """sqrt(x - 2) is NaN on the unit square, exp(1000 (1 + x)) overflows: exit 2, no warning.

    (A constant such as exp(1000) is refused earlier, when the scene is parsed.)

    The point named is the smallest (x, y) among the quadrature points, whatever the ranks:
    the first Gauss point of the corner cell (0, 1/4)^2.
    """
    path = scene_file(tmp_path, BODY + CLAMPED + f"[loads]\nf = [{force}, 0]\n")
    done = run_parefg(["run", path, "--quiet", "--out", str(tmp_path / "r")], ranks=ranks)
    line = one_error_line(done, 2)
    assert f"loads.f[0] = {shown} at (x, y) = (0.0281754, 0.0281754), t = 0:" in line


@pytest.mark.serial_only
def test_data_turning_non_finite_stops_at_that_step_and_keeps_output(tmp_path):
    """f = sqrt(0.25 - t) is finite up to t = 0.25: steps 1-5 are written, t = 0.3 refused."""
    path = scene_file(
        tmp_path,
        BODY + "[time]\nT = 0.5\ndt = 0.05\n" + CLAMPED
        + '[loads]\nf = ["sqrt(0.25 - t)", 0]\n[output]\nevery = 1\n',
    )  # fmt: skip
    out = tmp_path / "run"
    line = one_error_line(run_parefg(["run", path, "--quiet", "--out", str(out)]), 2)
    assert "loads.f[0] = 'sqrt(0.25 - t)' is not finite (nan) at" in line
    assert line.endswith("t = 0.3: scene data must be finite at every point and time of the run")
    assert json.loads((out / "summary.json").read_text())["status"] == "failed"
    with h5py.File(out / "result.h5", "r") as handle:
        assert handle["steps/time"][...].max() == pytest.approx(0.25)


@pytest.mark.parametrize(
    ("key", "text", "name"),
    [("initial.u", '["sqrt(x - 2)", 0]', "initial.u[0]"),
     ("boundary.top.value", '[0, "log(y - 1)"]', "boundary.top.value[1]"),
     ("boundary.right.traction", '["1/(x - 1)", 0]', "boundary.right.traction[0]"),
     ("boundary.bottom.gap", '"sqrt(-1 - x)"', "boundary.bottom.gap")],
)  # fmt: skip
def test_every_datum_is_guarded_and_named(tmp_path_factory, key, text, name):
    directory = shared_tmp(tmp_path_factory)
    scene = (
        BODY + "[time]\nT = 0.1\ndt = 0.05\n" + CLAMPED
        + '[boundary.right]\ntype = "neumann"\n[boundary.bottom]\ntype = "contact"\n'
    )  # fmt: skip
    path = scene_file(directory, scene) if COMM.rank == 0 else None
    path = COMM.bcast(path, root=0)
    # InputError: a load-time check that samples the data may find it first.
    with pytest.raises(InputError, match=re.escape(f": {name} = ")) as raised:
        sim = simulation(path, [f"{key}={text}"])
        state = sim.start()
        sim.step(state, 1)
    assert "not finite" in str(raised.value) and raised.value.exit_code == 2


def test_friction_negative_at_run_time_is_refused(tmp_path_factory):
    # g = 0.5 - x - t is negative on part of the bottom edge from t = 0 on.  The bound is
    # installed after loading, as data that only the run evaluates.
    directory = shared_tmp(tmp_path_factory)
    text = BODY + "[time]\nT = 0.1\ndt = 0.05\n" + CLAMPED
    text += '[boundary.bottom]\ntype = "contact"\nfriction = 0.5\n'
    path = COMM.bcast(scene_file(directory, text) if COMM.rank == 0 else None, root=0)
    scene = load_scene(path)
    bottom = scene.boundaries["bottom"]
    bottom.friction = lambda x, y, t, nx, ny: 0.5 - x - t
    sim = Simulation(COMM, scene, build_discretization(COMM, scene))
    with pytest.raises(DataError, match=r"boundary\.bottom\.friction = 0\.5 is negative \(-0\.0"):
        sim.start()


def test_round_off_negative_friction_reads_as_zero(tmp_path_factory):
    # sin^2 + cos^2 - 1 is zero up to ~1e-16 (sign depends on the CPU): accepted, read as 0.
    directory = shared_tmp(tmp_path_factory)
    text = BODY + "[time]\nT = 0.1\ndt = 0.05\n" + CLAMPED
    text += '[boundary.bottom]\ntype = "contact"\nfriction = 0.5\n'
    path = COMM.bcast(scene_file(directory, text) if COMM.rank == 0 else None, root=0)
    scene = load_scene(path)
    scene.boundaries["bottom"].friction = lambda x, y, t, nx, ny: np.full(len(x), -1e-16)
    sim = Simulation(COMM, scene, build_discretization(COMM, scene))
    sim.step(sim.start(), 1)
    assert np.all(sim.law.bound == 0.0)


def test_a_fault_on_one_rank_is_raised_on_every_rank():
    """Only the last rank has a bad point; every rank raises the same message."""
    scene = load_scene("square", ["discretization.h=0.25"])
    guard = DataGuard(COMM, scene)
    points = np.array([[0.5, 0.5 + COMM.rank]])  # (1, 2), different on each rank
    bad = COMM.rank == COMM.size - 1
    guard.evaluate(("loads", "f"), lambda: np.array([[1.0], [np.nan if bad else 0.0]]), points, 0.5)
    with pytest.raises(DataError) as raised:
        guard.check()
    message = str(raised.value)
    y = 0.5 + COMM.size - 1
    point = f"at (x, y) = (0.5, {y:g}), t = 0.5"
    assert f"loads.f[1] (derived from exact.u) is not finite (nan) {point}" in message
    assert COMM.allgather(message) == [message] * COMM.size


# ----------------------------------------------------------------------------- static


@pytest.mark.serial_only
@pytest.mark.parametrize("ranks", [1, 2])
def test_static_scene_without_dirichlet_or_contact_is_refused(tmp_path, ranks):
    text = BODY + '[time]\nscheme = "static"\nT = 0.1\ndt = 0.05\n'
    text += '[boundary.right]\ntype = "neumann"\ntraction = [1, 0]\n'
    done = run_parefg(["run", scene_file(tmp_path, text), "--quiet", "--out", str(tmp_path / "r")],
                      ranks=ranks)  # fmt: skip
    line = one_error_line(done, 2)
    assert 'time.scheme = "static" needs a dirichlet or contact boundary part' in line


@pytest.mark.serial_only
@pytest.mark.parametrize("ranks", [1, 2])
def test_static_scene_held_by_open_contact_is_a_singular_stiffness(tmp_path, ranks):
    out = tmp_path / "r"
    done = run_parefg(["run", scene_file(tmp_path, OPEN_CONTACT), "--quiet", "--out", str(out)],
                      ranks=ranks)  # fmt: skip
    line = one_error_line(done, 1)
    assert (
        "singular stiffness at t = 0.05: the rigid motions of the body (translations and " in line
    )
    assert "not constrained (static scene without Dirichlet part and without closed contact" in line
    assert json.loads((out / "summary.json").read_text())["status"] == "failed"


def test_frictionless_closed_contact_leaves_the_sliding_translation_free(tmp_path_factory):
    """Every bottom point closed, no friction: the contact holds u_y and the rotation only."""
    directory = shared_tmp(tmp_path_factory)
    path = COMM.bcast(scene_file(directory, PRESSED) if COMM.rank == 0 else None, root=0)
    sim = simulation(path)
    closed = sim.law.weights * sim.law.alpha_c
    with pytest.raises(SolverError, match=re.escape("translation of the body along (1, 0) is not")):
        sim.rigid_modes.check(0.05, closed, np.zeros_like(closed))
    sim.rigid_modes.check(0.05, closed, sim.law.weights * sim.law.alpha_t)  # friction holds it


def test_static_scene_pressed_on_the_obstacle_with_friction_runs(tmp_path_factory):
    """The body starts at u = 0 on the obstacle (s = 0): every point sits on the kink.

    The Jacobian takes the kink as closed; open, J = K + friction left two rigid motions
    free and the first Newton direction came from round-off pivots (it failed without
    AVX-512).  Physics from the input: the contact reaction carries the load (traction 1
    on the unit top edge, nothing sideways), and the second step under the same load
    keeps the body where the first put it (|u| of the elastic scale t L / E = 1).
    """
    directory = shared_tmp(tmp_path_factory)
    path = COMM.bcast(scene_file(directory, PRESSED) if COMM.rank == 0 else None, root=0)
    sim = simulation(path)
    state = sim.start()
    levels = []
    for n in (1, 2):
        state = sim.step(state, n)
        levels.append(state.u.copy())
    assert sim.history[-1]["active_contact_points"] > 0
    pressure, friction = sim.law.forces(*sim.law.kinematics(state.u))
    reaction = COMM.allreduce(np.array([sim.law.weights @ friction, sim.law.weights @ pressure]))
    assert np.allclose(reaction, [0.0, 1.0], rtol=0.0, atol=1e-6)
    levels[1].axpy(-1.0, levels[0])
    assert levels[0].norm(PETSc.NormType.INFINITY) <= 2.0
    assert levels[1].norm(PETSc.NormType.INFINITY) <= 1e-2 * levels[0].norm(PETSc.NormType.INFINITY)


def test_dynamic_scenes_skip_the_rigid_mode_check():
    # The impact block has no Dirichlet part; its mass term makes J definite.
    assert simulation("impact", ["discretization.h=0.25"]).rigid_modes is None


# ----------------------------------------------------------------------------- divergence


def test_unstable_newmark_is_stopped_with_the_step(tmp_path_factory):
    """beta = 1e-4 < gamma/2 with dt = 0.1 (set after loading): unstable, stopped early.

    Without the guard it ends at T = 2 with |u| = 3e70, exit 0.
    """
    directory = shared_tmp(tmp_path_factory)
    text = BODY.replace("0.25", "0.125") + "[time]\nT = 2.0\ndt = 0.1\n" + CLAMPED
    text += "[loads]\nf = [0, -1]\n"
    scene = load_scene(COMM.bcast(scene_file(directory, text) if COMM.rank == 0 else None))
    scene = dataclasses.replace(scene, time=dataclasses.replace(scene.time, beta=1e-4))
    sim = Simulation(COMM, scene, build_discretization(COMM, scene))
    state = sim.start()
    with pytest.raises(
        SolverError, match=r"at step \d+, t = [\d.]+: the time integration diverged"
    ):
        state = time_loop(sim, state, 1)
    assert len(sim.history) < scene.time.n_steps  # before T
    assert all(math.isfinite(v) for row in sim.history for v in row.values())


# A soft, light body (E = 1e-100, rho = 1e-200) loaded from t = 0.3 on by 1e120: every
# datum is finite and below DATA_BOUND, but u = f / E = 1e220 makes u^T K u overflow.
SOFT = (
    BODY + "[material]\nE = 1e-100\nrho = 1e-200\n[time]\nT = 0.5\ndt = 0.05\n" + CLAMPED
    + '[loads]\nf = ["1e120 * heaviside(t - 0.275)", 0]\n[output]\nevery = 1\n'
)  # fmt: skip


@pytest.mark.serial_only
@pytest.mark.parametrize("ranks", [1, 2])
def test_overflowing_state_is_a_solver_failure_and_keeps_output(tmp_path, ranks):
    """Without the guard: exit 0, energies inf/NaN, numpy overflow warnings."""
    out = tmp_path / "r"
    done = run_parefg(["run", scene_file(tmp_path, SOFT), "--quiet", "--out", str(out)],
                      ranks=ranks)  # fmt: skip
    line = one_error_line(done, 1)
    assert "energy is nan at step 6, t = 0.3: the time integration diverged" in line
    assert json.loads((out / "summary.json").read_text())["status"] == "failed"
    with h5py.File(out / "result.h5", "r") as handle:
        assert handle["steps/time"][...].max() == pytest.approx(0.25)


@pytest.mark.serial_only
def test_data_too_large_to_square_are_bad_input(tmp_path):
    """f = exp(1000 t) passes 1e150 between t = 0.30 and 0.35 (e^345 = 1e150)."""
    text = BODY + "[time]\nT = 0.5\ndt = 0.05\n" + CLAMPED + '[loads]\nf = ["exp(1000*t)", 0]\n'
    path = scene_file(tmp_path, text)
    line = one_error_line(run_parefg(["run", path, "--quiet", "--out", str(tmp_path / "r")]), 2)
    assert "loads.f[0] = 'exp(1000*t)' is too large (1.01e+152) at (x, y) = (" in line
    assert "t = 0.35: scene data beyond 1e+150 in size overflow the energies" in line


def test_non_finite_output_field_names_the_field():
    sim = simulation("square", ["discretization.h=0.25", "discretization.degree=1"])
    von_mises = np.full(3, np.inf if COMM.rank == 0 else 1.0)
    with pytest.raises(SolverError, match="non-finite output field von_mises at step 4, t = 0.2"):
        sim.check_fields(4, {"displacement": np.zeros((3, 2)), "von_mises": von_mises})


def test_non_finite_energy_names_the_energy():
    sim = simulation("square", ["discretization.h=0.25", "discretization.degree=1"])
    sim.start()
    row = dict(sim.history[0], kinetic_energy=math.nan)
    with pytest.raises(SolverError, match="kinetic energy is nan at step 3, t = 0.15"):
        sim._check_row(row, 3)
