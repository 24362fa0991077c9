"""Coulomb friction (g = mu_f p, SPEC 1): closed forms, a manufactured solution, ranks, input.

Scenes (TOML in parefg.scene.library, written to a temporary directory):

* ``SLIDE``: an elastic 1 x 0.25 block (E = 1000, rho = 1) on the obstacle at y = 0,
  pressed by the body force f = (0, -G), thrown along it with v = (V0, 0), Coulomb
  coefficient MU.  Momentum balance of the whole block (K annihilates translations;
  every closed point slides forward, so its friction force is -MU p):
  m a_x = -MU int p,  m a_y = -m G + int p,  hence a_x + MU a_y = -MU G exactly, and the
  mean velocity decelerates at -MU G while it slides (a_y averages out).  It stops at
  t_stop = V0 / (MU G) and then sticks: nothing pulls it along any more.
* ``MMS``: the unit square, lam = mu = 1, with

      u_1 = (1 - cos t) [(1 + x) + y (0.9 e^x - 0.3)],   u_2 = -(1 - cos t) y e^x.

  On y = 0 (nu = (0, -1), tau = (1, 0)): u_nu = 0, -sigma_nu = -sigma_22 =
  (1 - cos t)(3 e^x - 1) > 0, sigma_12 = (1 - cos t)(0.9 e^x - 0.3) = 0.3 (-sigma_22)
  and u'_tau = sin t (1 + x) > 0: the exact solution slides with friction traction
  mu_f * pressure for mu_f = 0.3.  Loads, tractions and Dirichlet data are derived from
  [exact]; the friction bound is not (the Coulomb law makes it from the pressure).

Every in-process test runs serially and under ``mpirun -n 2`` (collective calls, per-point
checks reduced over ranks); the CLI tests are serial_only.
"""

import json

import h5py
import numpy as np
import pytest
from conftest import run_parefg
from mpi4py import MPI
from petsc4py import PETSc

from parefg.errors import InputError
from parefg.mechanics.contact import OPEN, STICK
from parefg.run import prepare
from parefg.scene.library import COULOMB_MMS, COULOMB_SLIDE, SLIDE_G, SLIDE_MU, SLIDE_V0
from parefg.scene.loader import load_scene
from parefg.timestepping.loop import time_loop
from parefg.timestepping.simulation import Simulation

COMM = MPI.COMM_WORLD
V0, MU, G = SLIDE_V0, SLIDE_MU, SLIDE_G
T_STOP = V0 / (MU * G)  # 1.6667: between the steps 1.66 and 1.68


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    """Paths of the two scene files (rank 0's directory, shared by every rank)."""
    directory = COMM.bcast(str(tmp_path_factory.mktemp("coulomb")) if COMM.rank == 0 else None)
    paths = {"slide": f"{directory}/slide.toml", "mms": f"{directory}/mms.toml"}
    if COMM.rank == 0:
        for key, text in (("slide", COULOMB_SLIDE), ("mms", COULOMB_MMS)):
            with open(paths[key], "w") as file:
                file.write(text)
    COMM.barrier()
    return paths


def simulation(source: str, overrides=()) -> Simulation:
    return prepare(COMM, source, overrides)


def mean_velocity(sim: Simulation, state) -> np.ndarray:
    """(1/|Omega|) int v dx, (2,).  Collective."""
    domain = sim.disc.domain
    v = domain.evaluate(state.v)
    sums = COMM.allreduce(np.array([*(domain.weights @ v), domain.weights.sum()]))
    return sums[:2] / sums[2]


def everywhere(flags) -> bool:
    return COMM.allreduce(bool(np.all(flags)), op=MPI.LAND)


def anywhere(flags) -> bool:
    return COMM.allreduce(bool(np.any(flags)), op=MPI.LOR)


@pytest.fixture(scope="module")
def slide(scenes):
    """The block run to T: per step (t, mean v_x, mean v_y, any point sticks, all closed
    points stick, the step's outer iterations, the dissipation increment)."""
    sim = simulation(scenes["slide"])
    state, rows = sim.start(), []
    for n in range(1, sim.scene.time.n_steps + 1):
        state = sim.step(state, n)
        law, row = sim.law, sim.history[-1]
        closed = law.step_status != OPEN
        dissipated = row["dissipated_energy"] - sim.history[-2]["dissipated_energy"]
        stick = law.step_status == STICK
        rows.append(
            (row["time"], *mean_velocity(sim, state), anywhere(stick), everywhere(stick[closed]))
            + (row["coulomb_iterations"], dissipated)
        )
    return sim, np.array(rows)


def test_a_sliding_block_decelerates_at_mu_times_the_pressing_acceleration(slide):
    """Fitted slope of the mean v_x while it slides: -MU G to 1e-3 (the closed form;
    measured -0.3000037);
    v_x + MU v_y = V0 - MU G t at every step to the step tolerance (momentum balance)."""
    sim, rows = slide
    t, vx, vy = rows[:, 0], rows[:, 1], rows[:, 2]
    sliding = (t >= 0.2) & (t <= T_STOP - 0.1)
    slope = np.polyfit(t[sliding], vx[sliding], 1)[0]
    assert slope == pytest.approx(-MU * G, rel=1e-3)
    before = t < T_STOP - 0.02
    assert np.allclose(vx[before] + MU * vy[before], V0 - MU * G * t[before], rtol=0, atol=1e-7)
    assert not np.any(rows[before, 3])  # nothing sticks while it slides
    assert np.all(rows[:, 6] >= 0)  # dissipation per step
    assert np.all(rows[:, 5] >= 1) and sim.coulomb_iterations == rows[:, 5].sum()


def test_the_block_stops_at_v0_over_mu_g_and_then_sticks(slide):
    """The sliding line reaches 0 at t_stop = V0/(MU G) (measured 1.666660 against
    1.666667), the first step with a sticking point is the first step after t_stop; from
    t_stop + 0.2 on |v_x| <= 1e-3 V0 (measured 2.3e-4); the last 0.2 s every closed point
    sticks and nothing is dissipated."""
    _, rows = slide
    t, vx = rows[:, 0], rows[:, 1]
    sliding = (t >= 0.2) & (t <= T_STOP - 0.1)
    slope, intercept = np.polyfit(t[sliding], vx[sliding], 1)
    assert -intercept / slope == pytest.approx(T_STOP, rel=1e-3)  # the fitted line's zero
    first_stick = t[np.argmax(rows[:, 3])]
    dt = t[1] - t[0]
    assert T_STOP <= first_stick < T_STOP + dt
    assert np.all(np.abs(vx[t >= T_STOP + 0.2]) <= 1e-3 * V0)
    assert np.all(rows[t >= t[-1] - 0.2, 4])
    assert np.all(rows[t >= t[-1] - 0.2, 6] <= 1e-9 * 0.5 * V0**2)  # no more slip dissipated


def test_a_flying_body_carries_no_coulomb_friction(scenes):
    """Thrown at the obstacle across a gap of 0.05 (v = (0.5, -1), no load): until it
    touches (t = 0.05) every point is open, p = 0 so g = 0: the mean v_x stays 0.5 to
    round-off and nothing is dissipated."""
    flight = ["boundary.bottom.gap=0.05", "initial.v=[0.5, -1.0]", "loads.f=[0, 0]"]
    sim = simulation(scenes["slide"], [*flight, "time.T=0.04"])
    state = sim.start()
    for n in range(1, sim.scene.time.n_steps + 1):
        state = sim.step(state, n)
        assert everywhere(sim.law.step_status == OPEN)
    assert mean_velocity(sim, state)[0] == pytest.approx(0.5, rel=1e-12, abs=0)
    assert abs(sim.history[-1]["dissipated_energy"]) <= 1e-12 * sim.history[0]["kinetic_energy"]
    assert sim.coulomb_iterations == sim.scene.time.n_steps  # one outer iteration: g stays 0


def coulomb_errors(source: str, overrides) -> dict[str, float]:
    sim = simulation(source, overrides)
    state = sim.start()
    state = time_loop(sim, state, 1)
    law = sim.law
    # at the final state every sliding point carries exactly mu_f p (the converged bound)
    un = law.kinematics(state.u)[0]
    slip = law.step_status == 2
    assert everywhere(np.isclose(np.abs(law.step_friction[slip]), 0.3 * law.pressure(un)[slip]))
    return sim.errors(state.u, sim.scene.time.T)


def fitted_rate(sizes, errs) -> float:
    return float(np.polyfit(np.log(sizes), np.log(errs), 1)[0])


def test_manufactured_coulomb_solution_converges_in_h(scenes):
    """m = 1, dt = 0.0125, h = 1/4, 1/8, 1/16: H1 rate >= 0.9, L2 >= 1.8 (the thresholds of
    the Tresca scenes in test_dynamics).  Measured: H1 0.096, 0.026, 0.0067 (1.92);
    L2 9.6e-3, 1.4e-3, 2.0e-4 (2.79); the given-friction run with the exact bound derived
    from [exact] has the same errors to 0.3 %."""
    sizes = [0.25, 0.125, 0.0625]
    runs = [coulomb_errors(scenes["mms"], [f"discretization.h={h}"]) for h in sizes]
    h1, l2 = [e["h1_rel"] for e in runs], [e["l2_rel"] for e in runs]
    assert fitted_rate(sizes, h1) >= 0.9, h1
    assert fitted_rate(sizes, l2) >= 1.8, l2
    assert h1[-1] < 0.01 and l2[-1] < 1e-3


def test_manufactured_coulomb_solution_is_second_order_in_time(scenes):
    """m = 2, h = 1/16: L2 vs dt = 0.1, 0.05, 0.025 has rate >= 1.8.
    Measured: 2.30e-3, 5.75e-4, 1.42e-4 (rate 2.01)."""
    steps = [0.1, 0.05, 0.025]
    fine = ["discretization.degree=2", "discretization.h=0.0625"]
    l2 = [coulomb_errors(scenes["mms"], [*fine, f"time.dt={dt}"])["l2_rel"] for dt in steps]
    assert fitted_rate(steps, l2) >= 1.8, l2


def test_coulomb_matches_given_friction_with_the_exact_bound(scenes):
    """Independent check of the law: the paper's given friction with g = |sigma_tau| of
    the exact solution (derived from [exact]) is the same continuous problem, so the two
    discrete solutions differ by the discretization error of the pressure only."""
    coulomb = coulomb_errors(scenes["mms"], [])
    raw = COULOMB_MMS.replace('friction_law = "coulomb"', 'friction_law = "given"')
    raw = raw.replace("friction_coefficient = 0.3\n", "")
    path = scenes["mms"].replace("mms.toml", "mms_given.toml")
    if COMM.rank == 0:
        with open(path, "w") as file:
            file.write(raw)
    COMM.barrier()
    sim = simulation(path)
    state = sim.start()
    state = time_loop(sim, state, 1)
    given = sim.errors(state.u, sim.scene.time.T)
    for key in ("l2_rel", "h1_rel"):
        assert coulomb[key] == pytest.approx(given[key], rel=0.01)


# -- bad input --------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "overrides, message",
    [
        ([], "boundary.bottom.friction_coefficient is required with friction_law = 'coulomb'"),
        (["boundary.bottom.friction_coefficient=-0.1"], "must be >= 0"),
        (["boundary.bottom.friction_coefficient=0.3", "boundary.bottom.friction=0.1"], "not used"),
    ],
)
def test_bad_coulomb_parts_are_refused(overrides, message):
    with pytest.raises(InputError) as error:
        load_scene("square", ['boundary.bottom.friction_law="coulomb"', *overrides])
    assert message in str(error.value)


def test_a_friction_coefficient_needs_the_coulomb_law():
    with pytest.raises(InputError) as error:
        load_scene("stick", ["boundary.bottom.friction_coefficient=0.3"])
    assert "boundary.bottom.friction_coefficient" in str(error.value)
    assert "only used with friction_law = 'coulomb'" in str(error.value)


@pytest.mark.serial_only
@pytest.mark.parametrize("ranks", [1, 2])
def test_a_negative_friction_coefficient_on_the_command_line_exits_2(tmp_path, ranks):
    out = tmp_path / "never"
    sets = ["boundary.bottom.friction_law=coulomb", "boundary.bottom.friction_coefficient=-1"]
    args = ["run", "square", "--out", str(out), "--quiet"]
    result = run_parefg([*args, "--set", sets[0], "--set", sets[1]], ranks)
    assert result.returncode == 2
    lines = [line for line in result.stderr.splitlines() if line.startswith("parefg: ")]
    assert lines and set(lines) == {lines[0]} and lines[0].startswith("parefg: error: ")
    assert "boundary.bottom.friction_coefficient" in lines[0] and ">= 0" in lines[0]
    assert "Traceback" not in result.stderr
    assert not out.exists()


def test_an_outer_iteration_limit_below_one_is_refused(scenes):
    """-coulomb_max_it 0 would leave the fixed point without a single solve."""
    options = PETSc.Options()
    options.setValue("coulomb_max_it", 0)
    try:
        with pytest.raises(InputError, match="-coulomb_max_it 0: must be at least 1"):
            simulation(scenes["mms"])
    finally:
        options.delValue("coulomb_max_it")


# -- 1 rank == 2 ranks ------------------------------------------------------------------------
def run_cli(tmp_path, source: str, ranks: int, overrides=()) -> tuple[dict, np.ndarray]:
    """summary.json and the final displacement u_h at the nodes of `parefg run`."""
    out = tmp_path / f"run{ranks}"
    args = ["run", source, "--out", str(out), "--quiet"]
    for text in overrides:
        args += ["--set", text]
    result = run_parefg(args, ranks=ranks, timeout=300)
    assert result.returncode == 0, result.stderr
    with h5py.File(out / "result.h5", "r") as file:
        last = sorted(file["fields/displacement"])[-1]
        displacement = file["fields/displacement"][last][()]
        assert np.all(np.isfinite(file["history/coulomb_iterations"][()]))
    return json.loads((out / "summary.json").read_text()), displacement


@pytest.mark.serial_only
@pytest.mark.parametrize("case", ["mms", "slide"])
def test_one_rank_equals_two_ranks(tmp_path, scenes, case):
    """Same errors (1e-8), displacement (1e-8 of its size), Newton and outer counts."""
    overrides = ["time.T=1.76", "time.dt=0.04"] if case == "slide" else []  # through the stop
    serial, u1 = run_cli(tmp_path, scenes[case], 1, overrides)
    parallel, u2 = run_cli(tmp_path, scenes[case], 2, overrides)
    assert (serial["mpi_ranks"], parallel["mpi_ranks"]) == (1, 2)
    assert serial["params"] == parallel["params"]
    for key in ("newton_iterations", "coulomb_iterations", "max_coulomb_per_step"):
        assert serial[key] == parallel[key], key
    assert serial["coulomb_iterations"] >= serial["n_steps"]
    assert np.max(np.abs(u1 - u2)) <= 1e-8 * np.max(np.abs(u1))
    if case == "mms":
        for norm in ("l2_rel", "h1_rel"):
            assert parallel["errors"][norm] == pytest.approx(serial["errors"][norm], rel=1e-8)


@pytest.mark.serial_only
def test_a_fixed_point_that_does_not_converge_fails_with_exit_1(tmp_path, scenes):
    """Two outer iterations cannot converge the first step (g^(0) = 0 from the predictor
    at rest): one line naming the residual and the limit, exit 1, the output kept."""
    out = tmp_path / "failed"
    args = ["run", scenes["mms"], "--out", str(out), "--quiet", "-coulomb_max_it", "2"]
    result = run_parefg(args)
    assert result.returncode == 1
    lines = [line for line in result.stderr.splitlines() if line.startswith("parefg: ")]
    assert len(lines) == 1 and "Coulomb friction failed at t = 0.0125" in lines[0]
    assert "after 2 outer iterations (-coulomb_max_it 2)" in lines[0]
    assert json.loads((out / "summary.json").read_text())["status"] == "failed"


@pytest.mark.serial_only
def test_a_restarted_coulomb_run_repeats_the_uninterrupted_one(tmp_path, scenes):
    """The restart starts the fixed point from the checkpointed pressure, like the
    uninterrupted run (from the predictor's instead, the errors differed at 1e-8)."""
    full, part, rest = (tmp_path / name for name in ("full", "part", "rest"))
    assert run_parefg(["run", scenes["mms"], "--out", str(full), "--quiet"]).returncode == 0
    args = ["--fail-at-step", "41", "--checkpoint-every", "40"]
    failed = run_parefg(["run", scenes["mms"], "--out", str(part), "--quiet", *args])
    assert failed.returncode == 1
    args = ["--restart", str(part / "checkpoint.h5")]
    assert run_parefg(["run", scenes["mms"], "--out", str(rest), "--quiet", *args]).returncode == 0
    errors = [json.loads((out / "summary.json").read_text())["errors"] for out in (full, rest)]
    assert errors[0] == errors[1]
