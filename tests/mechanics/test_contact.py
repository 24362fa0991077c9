"""Verification of contact and friction: line search, robustness in alpha, friction, impact.

Scenes: "square" and "z" (SPEC 6, sliding at the Tresca bound), "stick" (a manufactured
solution below the bound: u = ((1 - cos t)(1 + x) y, -(1 - cos t) y e^x), g = 0.5) and
"impact" (a block thrown across a gap onto the obstacle).  Every test runs serially and
under ``mpirun -n 2``: all calls are collective, per-point checks are reduced over ranks.
"""

import numpy as np
import pytest
from conftest import run_parefg
from mpi4py import MPI

from parefg.errors import InputError
from parefg.mechanics.contact import OPEN, SLIP, STICK
from parefg.mechanics.friction import FRICTION_LAWS
from parefg.run import prepare
from parefg.scene.loader import load_scene
from parefg.timestepping.simulation import Simulation

COMM = MPI.COMM_WORLD


def simulation(scene_name: str, overrides=()) -> Simulation:
    return prepare(COMM, scene_name, overrides)


def advance(sim: Simulation, state, first: int, last: int):
    for n in range(first, last + 1):
        state = sim.step(state, n)
    return state


def everywhere(flags) -> bool:
    """True when the per-point condition holds at every point of every rank."""
    return COMM.allreduce(bool(np.all(flags)), op=MPI.LAND)


def global_max(values) -> float:
    return COMM.allreduce(float(np.max(values, initial=0.0)), op=MPI.MAX)


def record_line_searches(solver) -> list[tuple[float, float]]:
    """(J_n before, J_n after) of every later Newton step of ``solver``.  Collective.

    The solver's pre-check (its exact line search) is wrapped, so the energies are those
    of the iterate it starts from and of the update it hands to the SNES; so is the step
    it takes without SNES (the reused-factorization step, one Newton step).
    """
    log, trial = [], solver.a_const.createVecRight()
    line_search = solver._exact_line_search
    reused_step = solver._reused_step

    def recorded_step(u):
        before = solver.energy(u)
        iterations = reused_step(u)
        if iterations is not None and iterations[0] == 1:
            log.append((before, solver.energy(u)))
        return iterations

    solver._reused_step = recorded_step

    def recorded(x, y):
        before = solver.energy(x)
        changed = line_search(x, y)
        x.copy(trial)
        trial.axpy(-1.0, y)
        log.append((before, solver.energy(trial)))
        return changed

    solver.snes.setLineSearchPreCheck(recorded)
    return log


def mean_vertical_velocity(sim: Simulation, state) -> float:
    """(1/|Omega|) int v_y dx.  Collective."""
    domain = sim.disc.domain
    sums = np.array([np.dot(domain.weights, domain.evaluate(state.v)[:, 1]), domain.weights.sum()])
    sums = COMM.allreduce(sums)
    return float(sums[0] / sums[1])


# -- Newton and its line search --------------------------------------------------------------
@pytest.mark.parametrize(
    "scene_name, overrides",
    [
        ("square", ["discretization.degree=1", "discretization.h=0.125", "penalty.alpha=8e8"]),
        ("impact", ["time.T=0.3"]),
    ],
)
def test_line_search_never_increases_the_step_energy(scene_name, overrides):
    """Every line-search step has J_n(after) <= J_n(before) + 1e-12 |J_n(before)|."""
    sim = simulation(scene_name, overrides)
    records = record_line_searches(sim.solver)
    advance(sim, sim.start(), 1, sim.scene.time.n_steps)
    log = np.array(records)  # (n_newton, 2)
    # one entry per Newton iteration (a flying body's step has none: its predictor is exact)
    assert len(log) == sum(row["newton_iterations"] for row in sim.history) > 0
    before, after = log[:, 0], log[:, 1]
    assert np.all(after <= before + 1e-12 * np.abs(before)), np.max(after - before)
    assert np.any(after < before - 1e-9 * np.abs(before))  # the line search did real work


ALPHA_FACTORS = [1e2, 1e5, 1e8, 1e12]  # times E/h, for alpha_contact and alpha_friction alike
SHORT_RUNS = {
    "square": ["discretization.degree=1", "discretization.h=0.125", "time.T=0.2"],
    # 3 Gauss points per cell direction and per Gamma_C segment, as before issue 12: the
    # unstructured default of 6 doubles the contact points and, at alpha = 1e12 E/h, the
    # active-set changes (measured max Newton 58 with 6, 32 with 3)
    "z": [
        "discretization.degree=1",
        "discretization.h=0.125",
        "time.T=0.2",
        "discretization.quadrature=3",
    ],  # fmt: skip
    "impact": ["time.T=0.2"],
}


@pytest.mark.parametrize("scene_name", sorted(SHORT_RUNS))
def test_newton_converges_for_alpha_from_1e2_to_1e12(scene_name):
    """No step fails for alpha_C = alpha_T = 1e2 .. 1e12 E/h (short runs).

    Measured max Newton iterations per step (T = 0.2, dt = 0.05, h = 1/8, m = 1) at alpha =
    1e2, 1e6, 1e9, 1e12 E/h: square 3, 8, 14, 25; z 3, 13, 23, 32 (Nitsche clamp; 3, 11, 19, 15
    with the penalty clamp).
    A failing step raises SolverError.
    """
    h = {"impact": 0.1}.get(scene_name, 0.125)
    worst = []
    for factor in ALPHA_FACTORS:
        alpha = factor / h  # E = 1 in all three scenes
        sets = ["boundary.bottom.method=penalty", f"penalty.alpha_contact={alpha}"]
        sets += [f"penalty.alpha_friction={alpha}"]
        sim = simulation(scene_name, SHORT_RUNS[scene_name] + sets)
        advance(sim, sim.start(), 1, sim.scene.time.n_steps)
        assert len(sim.history) == sim.scene.time.n_steps + 1
        worst.append(max(row["newton_iterations"] for row in sim.history))
    assert max(worst) < 50, worst  # SNES max_it is 200: far from cycling


# -- friction ------------------------------------------------------------------------------
def test_square_slides_at_the_bound_like_the_exact_solution():
    """At T every Gamma_C point is closed, slides forward (u'_tau = sin t (1 + x) > 0) and
    carries |f| = g = mu (1 - cos t)(1 + x) to round-off; g is derived from [exact]."""
    sim = simulation("square")
    n_steps = sim.scene.time.n_steps
    state = advance(sim, sim.start(), 1, n_steps - 1)
    law = sim.law
    slip_before = law.slip.copy()
    state = advance(sim, state, n_steps, n_steps)
    un, ut = law.kinematics(state.u)
    _, friction = law.forces(un, ut)
    x = law.points[:, 0]
    g_exact = sim.scene.material.mu * (1 - np.cos(sim.scene.time.T)) * (1 + x)
    assert everywhere(un > law.gap)
    assert everywhere(np.abs(law.bound - g_exact) <= 1e-12)
    assert everywhere(np.abs(np.abs(friction) - law.bound) <= 1e-9 * law.bound)
    assert everywhere(law.slip - slip_before > 0.0)  # the slip increment has the sign of u'_tau
    # the status the step converged on (slip of t_{n-1}): sliding everywhere
    slip_after, law.slip = law.slip, slip_before
    status = law.status(un, ut)
    law.slip = slip_after
    assert everywhere(status == SLIP)


def stick_run(friction_bound: float):
    """The "stick" scene (m = 2, h = 1/16); returns (sim, final state, xi_0, stuck at every step).

    m = 2 because the penalty traction of m = 1 at h = 1/8 is too rough (measured errors in
    f of 170 % of max |sigma_tau| near the corners) to keep the points below g = 0.5.
    """
    sim = simulation("stick", [f"boundary.bottom.friction={friction_bound}"])
    state = sim.start()
    xi_0 = sim.law.slip.copy()
    stuck_throughout = True
    for n in range(1, sim.scene.time.n_steps + 1):
        state = sim.step(state, n)
        un, ut = sim.law.kinematics(state.u)
        stuck_throughout &= everywhere(sim.law.status(un, ut) == STICK)
    return sim, state, xi_0, stuck_throughout


def test_manufactured_stick_solution_does_not_slip():
    """u_tau = 0 on y = 0 and |sigma_tau| = mu (1 - cos t)(1 + x) <= 0.354 < g = 0.5.

    Asserted: every Gamma_C point sticks at every step, so the return mapping never moves
    xi (xi_n == xi_0 exactly) and |u_tau - xi_0| = |f| / alpha_T <= g / alpha_T: the
    discrete slip is bounded by the penalty's elastic slip alone, with no discretization
    term because xi_0 is the discrete u_tau(0) (= 0 here).  The sustained tangential force
    f = -sigma_tau matches mu (1 - cos T)(1 + x) to 5 % of its maximum (measured 1.7 %),
    and the displacement is right (relative L2 < 1e-2; measured 4.3e-4).
    """
    sim, state, xi_0, stuck_throughout = stick_run(0.5)
    law = sim.law
    un, ut = law.kinematics(state.u)
    _, friction = law.forces(un, ut)
    f_exact = sim.scene.material.mu * (1 - np.cos(sim.scene.time.T)) * (1 + law.points[:, 0])
    assert stuck_throughout
    assert everywhere(law.slip == xi_0)
    assert global_max(np.abs(ut - xi_0)) <= 0.5 / law.alpha_t
    assert global_max(np.abs(friction - f_exact)) <= 0.05 * 2 * f_exact.max(initial=0.0) + 1e-12
    assert sim.errors(state.u, sim.scene.time.T)["l2_rel"] < 1e-2


def test_stick_solution_slides_when_the_bound_is_below_the_traction():
    """Control for the test above: with g = 0.1 < max |sigma_tau| the same loads make it slide."""
    sim, state, xi_0, stuck_throughout = stick_run(0.1)
    assert not stuck_throughout
    assert global_max(np.abs(sim.law.slip - xi_0)) > 100 * 0.1 / sim.law.alpha_t


# -- impact --------------------------------------------------------------------------------
def test_impact_closes_rebounds_and_opens():
    """The block hits the obstacle (active points > 0), bounces back (mean v_y > 0) and
    leaves it (no active point at T); with beta = gamma = 1/2 and penalty contact the
    energy balance is not exact: kinetic + elastic + stored + dissipated stays within 10 %
    of the initial kinetic energy (measured +5.7 %; beta = 1/4 gains 350 % here)."""
    sim = simulation("impact")
    state = sim.start()
    velocities = []
    for n in range(1, sim.scene.time.n_steps + 1):
        state = sim.step(state, n)
        velocities.append(mean_vertical_velocity(sim, state))
    active = np.array([row["active_contact_points"] for row in sim.history])
    first_contact = int(np.argmax(active > 0))
    assert active.max() > 0 and first_contact > 0  # opens across the gap, then closes
    assert velocities[0] == pytest.approx(-1.0, abs=0.02)
    assert active[-1] == 0 and velocities[-1] > 0.5
    rows = sim.history
    energy = [
        r["kinetic_energy"] + r["elastic_energy"] + r["penalty_energy"] + r["dissipated_energy"]
        for r in (rows[0], rows[-1])
    ]
    assert energy[1] <= 1.1 * energy[0]
    assert rows[-1]["dissipated_energy"] > 0.0


def test_frictionless_impact_reaching_the_gap_exactly_at_a_step():
    """With g = 0 the rigid approach puts every bottom point at u_nu = s (to round-off) at
    t = 0.05, where the active set flips on round-off; Newton must still converge (the
    update falls below -snes_stol: the iterate sits on the kink)."""
    sim = simulation("impact", ["boundary.bottom.friction=0", "time.T=0.06"])
    advance(sim, sim.start(), 1, sim.scene.time.n_steps)


def test_status_after_a_sliding_step_reports_slip():
    """After the return mapping |alpha_T (u_tau - xi_n)| = g only to round-off, so the status
    written to the output (step_status) is taken with the slip the step was solved with:
    on the square every point slides, so every point must report SLIP."""
    sim = simulation("square")
    advance(sim, sim.start(), 1, sim.scene.time.n_steps)
    assert everywhere(sim.law.step_status == SLIP)


# -- friction laws (SPEC 1): "tresca" acts only where the body touches, "given" everywhere --
BEFORE_CONTACT = ["time.T=0.045"]  # the block reaches the gap s = 0.05 at t = 0.05


def mean_velocity(sim: Simulation, state) -> np.ndarray:
    """(1/|Omega|) int v dx, both components.  Collective."""
    domain = sim.disc.domain
    values = domain.evaluate(state.v)
    sums = np.array([*(domain.weights @ values), domain.weights.sum()])
    sums = COMM.allreduce(sums)
    return sums[:2] / sums[2]


def flight(law_overrides):
    """The impact block in flight (every Gamma_C point open): simulation, final state."""
    sim = simulation("impact", BEFORE_CONTACT + law_overrides)
    state = advance(sim, sim.start(), 1, sim.scene.time.n_steps)
    assert everywhere(sim.law.step_status == OPEN)
    return sim, state


def test_a_flying_body_keeps_its_velocity_under_tresca():
    """Default law: no friction force on open points, so no tangential traction, no
    dissipation, and the mean v_x = 0.5 is kept to round-off (main: 0.49575, 1.0e-3
    dissipated, as g = 0.05 acted on the open points)."""
    sim, state = flight([])
    assert mean_velocity(sim, state)[0] == pytest.approx(0.5, rel=1e-12, abs=0)
    assert global_max(np.abs(sim.law.step_friction)) <= 1e-12 * 0.05
    kinetic = sim.history[0]["kinetic_energy"]
    assert abs(sim.history[-1]["dissipated_energy"]) <= 1e-12 * kinetic
    assert sim.scene.boundaries["bottom"].friction_law == "tresca"


def test_given_friction_acts_on_a_flying_body_as_in_the_paper():
    """friction_law = "given" keeps the paper's model: g acts on all of Gamma_C, so the
    open points carry |f| = g and the block slows (measured mean v_x 0.49575 at t = 0.045)."""
    sim, state = flight(['boundary.bottom.friction_law="given"'])
    assert everywhere(np.isclose(np.abs(sim.law.step_friction), 0.05, rtol=1e-12, atol=0))
    assert mean_velocity(sim, state)[0] == pytest.approx(0.49575, rel=1e-6)
    assert sim.history[-1]["dissipated_energy"] > 1e-4


def test_manufactured_scenes_default_to_the_papers_given_friction():
    """A bound derived from [exact] defaults to "given" (the square's solution grazes the
    obstacle); a given bound defaults to "tresca" (stick, impact)."""
    assert load_scene("square").boundaries["bottom"].friction_law == "given"
    assert load_scene("z").boundaries["bottom"].friction_law == "given"
    assert load_scene("stick").boundaries["bottom"].friction_law == "tresca"
    tresca = load_scene("square", ['boundary.bottom.friction_law="tresca"'])
    assert tresca.boundaries["bottom"].friction_law == "tresca"


def test_square_errors_are_the_given_friction_errors():
    """The square's default law reproduces today's (given-friction) errors exactly; on the
    degree-2 square, where every point stays closed, "tresca" gives the same errors."""
    short = ["time.T=0.3", "discretization.h=0.125"]
    errors = {}
    for law in ("given", "tresca"):
        sim = simulation("square", [*short, f'boundary.bottom.friction_law="{law}"'])
        state = advance(sim, sim.start(), 1, sim.scene.time.n_steps)
        errors[law] = sim.errors(state.u, sim.scene.time.T)
    sim = simulation("square", short)
    state = advance(sim, sim.start(), 1, sim.scene.time.n_steps)
    default = sim.errors(state.u, sim.scene.time.T)
    for key in ("l2_rel", "h1_rel"):
        assert default[key] == pytest.approx(errors["given"][key], rel=1e-12)
        assert errors["tresca"][key] == pytest.approx(errors["given"][key], rel=1e-9)


def test_an_unknown_friction_law_is_refused_listing_the_laws():
    with pytest.raises(InputError) as error:
        load_scene("impact", ['boundary.bottom.friction_law="sticky"'])
    message = str(error.value)
    assert "boundary.bottom.friction_law" in message
    assert "'tresca'" in message and "'given'" in message and "'coulomb'" in message


@pytest.mark.serial_only
@pytest.mark.parametrize("ranks", [1, 2])
def test_an_unknown_friction_law_on_the_command_line_exits_2(tmp_path, ranks):
    out = tmp_path / "never"
    bad = "boundary.bottom.friction_law=sticky"
    result = run_parefg(["run", "impact", "--set", bad, "--out", str(out), "--quiet"], ranks)
    assert result.returncode == 2
    lines = [line for line in result.stderr.splitlines() if line.startswith("parefg: ")]
    assert lines and set(lines) == {lines[0]} and lines[0].startswith("parefg: error: ")
    assert "boundary.bottom.friction_law" in lines[0] and "'tresca', 'given'" in lines[0]
    assert not out.exists()


def test_the_tresca_gate_is_not_decided_by_round_off():
    """A rigid approach puts the impact block's points at u_nu = s only to round-off at
    t = 0.05; a bare u_nu >= s made 1 and 2 ranks disagree there (final mean v_x 0.47626 vs
    0.47660).  Within 1e-9 relative the point touches; 1e-6 below the obstacle it does not."""
    gate = FRICTION_LAWS["tresca"]
    gap = np.full(3, 0.05)
    below_by_round_off = gap * (1 - np.array([1e-16, 4e-16, 1e-12]))
    assert np.all(gate(below_by_round_off, gap))
    assert not np.any(gate(gap - 1e-6 * gap, gap))
    assert np.all(gate(np.zeros(2), np.zeros(2)))  # the manufactured scenes at t = 0
    assert np.all(FRICTION_LAWS["given"](gap - 0.01, gap))
