"""Time schemes: generalized-alpha (Chung & Hulbert 1993) and the consistent initial state.

Generalized-alpha with spectral radius rho_inf at infinite frequency has

    alpha_m = (2 rho_inf - 1)/(rho_inf + 1),  alpha_f = rho_inf/(rho_inf + 1),
    gamma = 1/2 - alpha_m + alpha_f,          beta = (1 - alpha_m + alpha_f)^2 / 4,

and balances (1 - alpha_m) M a_n + alpha_m M a_{n-1} + (1 - alpha_f) r_n + alpha_f r_{n-1} = 0
with the Newmark update.  Checked here: the second-order rate on a smooth manufactured
solution, rho_inf = 1 equal to Newmark(1/4, 1/2), the amplification of single modes
against the scalar recurrence, a time-independent solution with u0 != 0 at rest to
round-off, bad input, and 1 rank == 2 ranks.
"""

import json

import numpy as np
import pytest
import scipy.linalg
from conftest import run_parefg
from mpi4py import MPI

from parefg.discretization.operators import build_discretization
from parefg.run import prepare
from parefg.scene.library import AT_REST, AT_REST_ON_OBSTACLE
from parefg.scene.loader import load_scene
from parefg.scene.schema import SCHEMES as SCHEMA_SCHEMES
from parefg.timestepping.loop import time_loop
from parefg.timestepping.schemes import SCHEMES, State, generalized_alpha_parameters
from parefg.timestepping.simulation import Simulation

COMM = MPI.COMM_WORLD
GENERALIZED_ALPHA = "time.scheme=generalized-alpha"

# The square's manufactured solution, clamped (penalty) at y = 0 and y = 1: no contact, so
# every step is one direct solve and the comparisons below are at round-off.
SMOOTH = """
[domain]
shape = "square"
[discretization]
h = 0.125
degree = 2
[time]
T = 1.0
dt = 0.1
[boundary.bottom]
type = "dirichlet"
[boundary.top]
type = "dirichlet"
[boundary.left]
type = "neumann"
[boundary.right]
type = "neumann"
[exact]
u = ["(1 - cos(t)) * (1 + x) * exp(y)", "-(1 - cos(t)) * y * exp(x)"]
"""

# Free square clamped at y = 0, no loads: the modes of (K + alpha_D G_D, M).
MODES = """
[domain]
shape = "square"
[discretization]
h = 0.25
degree = 1
[time]
T = 1.0
dt = 1.0
[boundary.bottom]
type = "dirichlet"
method = "penalty"  # its stiff clamp mode (omega k = 824) is the one damped to rho_inf
"""


def scene_file(tmp_path, text: str, name: str) -> str:
    path = tmp_path / f"{name}.toml"  # every rank writes its own identical copy
    path.write_text(text)
    return str(path)


def run(source: str, overrides=()) -> tuple[Simulation, State]:
    """Run a scene to T in-process; return the simulation and the final state.  Collective."""
    sim = prepare(COMM, source, overrides)
    state = sim.start()
    state = time_loop(sim, state, 1)
    return sim, state


def fitted_rate(sizes, errs) -> float:
    return float(np.polyfit(np.log(sizes), np.log(errs), 1)[0])


def test_registry_and_schema_name_the_same_schemes():
    assert set(SCHEMA_SCHEMES) == set(SCHEMES)


@pytest.mark.parametrize(
    "rho_inf, expected",
    [(1.0, (0.5, 0.5, 0.25, 0.5)), (0.5, (0.0, 1 / 3, 4 / 9, 5 / 6)), (0.0, (-1.0, 0.0, 1.0, 1.5))],
)
def test_parameters_follow_chung_hulbert(tmp_path, rho_inf, expected):
    """(alpha_m, alpha_f, beta, gamma) by hand from the formulas above; the effective scene
    shows the beta and gamma used."""
    p = generalized_alpha_parameters(rho_inf)
    got = (p["alpha_m"], p["alpha_f"], p["beta"], p["gamma"])
    assert got == pytest.approx(expected, abs=1e-15)
    scene = load_scene("square", [GENERALIZED_ALPHA, f"time.rho_inf={rho_inf}"])
    assert (scene.time.beta, scene.time.gamma) == pytest.approx(expected[2:], abs=1e-15)
    assert scene.params["time"]["rho_inf"] == rho_inf


@pytest.mark.parametrize("rho_inf", [0.8, 0.0])
def test_generalized_alpha_is_second_order_in_time(tmp_path, rho_inf):
    """L2 error at T = 1 vs dt = 0.1, 0.05, 0.025 (m = 2, h = 1/8): fitted rate >= 1.8.

    Measured: rho_inf = 0.8: 1.0e-3, 2.5e-4, 6.8e-5 (rate 1.95); rho_inf = 0: 4.5e-3,
    1.2e-3, 3.1e-4 (1.92).
    """
    source = scene_file(tmp_path, SMOOTH, "smooth")
    steps = [0.1, 0.05, 0.025]
    overrides = [GENERALIZED_ALPHA, f"time.rho_inf={rho_inf}"]
    l2 = []
    for dt in steps:
        sim, state = run(source, [*overrides, f"time.dt={dt}"])
        l2.append(sim.errors(state.u, 1.0)["l2_rel"])
    assert fitted_rate(steps, l2) >= 1.8, l2
    assert l2[-1] < 4e-4, l2


def test_rho_inf_one_is_newmark_average_acceleration(tmp_path):
    """rho_inf = 1 (alpha_m = alpha_f = 1/2) solves the mean of Newmark(1/4, 1/2)'s balances
    at t_{n-1} and t_n; Newmark's holds at t_{n-1}, so the states agree to round-off.

    alpha_D = 1e2 E/h: the round-off of the history term grows with the penalty (measured
    relative differences u, v, a: 6e-13, 4e-11, 5e-9 here; 1.8e-11, 8e-10, 9e-8 at the
    default 1e4 E/h).  rho_inf = 0.99 moves u by 1.1e-7, 1e4 times the tolerance: the check
    is sharp.
    """
    source = scene_file(tmp_path, SMOOTH, "smooth")
    penalty = "penalty.alpha=800"
    _, newmark = run(source, ["time.beta=0.25", "time.gamma=0.5", penalty])
    _, alpha = run(source, [GENERALIZED_ALPHA, "time.rho_inf=1", penalty])
    _, damped = run(source, [GENERALIZED_ALPHA, "time.rho_inf=0.99", penalty])
    for field, tolerance in (("u", 1e-11), ("v", 1e-9), ("a", 1e-7)):
        reference = getattr(newmark, field)
        for state, bound in ((alpha, tolerance), (damped, None)):
            difference = getattr(state, field).copy()
            difference.axpy(-1.0, reference)
            relative = difference.norm() / reference.norm()
            if bound is not None:
                assert relative <= bound, field
            elif field == "u":
                assert relative > 1e3 * tolerance


def amplification(rho_inf: float, omega_k: float) -> np.ndarray:
    """3x3 matrix (u, k v, k^2 a)_{n-1} -> _n of generalized-alpha on u'' + omega^2 u = 0.

    Written from the scheme's equations, independently of parefg: the balance
    (1 - am) a_n + am a_{n-1} + omega^2 ((1 - af) u_n + af u_{n-1}) = 0 with
    u_n = u_{n-1} + k v_{n-1} + k^2 ((1/2 - beta) a_{n-1} + beta a_n),
    v_n = v_{n-1} + k ((1 - gamma) a_{n-1} + gamma a_n); time unit k = 1.
    """
    p = generalized_alpha_parameters(rho_inf)
    am, af, beta, gamma = p["alpha_m"], p["alpha_f"], p["beta"], p["gamma"]
    w2 = omega_k**2
    columns = []
    for u0, v0, a0 in np.eye(3):
        predicted = u0 + v0 + (0.5 - beta) * a0
        a1 = -(am * a0 + w2 * ((1 - af) * predicted + af * u0)) / ((1 - am) + (1 - af) * w2 * beta)
        columns.append([predicted + beta * a1, v0 + (1 - gamma) * a0 + gamma * a1, a1])
    return np.array(columns).T


def measured_amplification(sim: Simulation, mode: np.ndarray, k: float) -> np.ndarray:
    """The same matrix measured by one parefg step from (u, v, a) = mode times e_j.

    The step is linear and maps span(mode) into itself (M- and K-orthogonal modes).
    """
    mass = sim.disc.owned["mass"]
    columns = []
    for j in range(3):
        state = sim.start()
        sim._energy_budget = [np.inf, 0.0]  # the divergence guard measures from the zero start
        scales = np.eye(3)[j] / np.array([1.0, k, k * k])
        for vec, scale in zip((state.u, state.v, state.a), scales, strict=True):
            vec.setArray(scale * mode)
        new = sim.step(state, 1)
        coords = [
            mode @ (mass @ vec.getArray()) / (mode @ (mass @ mode)) for vec in (new.u, new.v, new.a)
        ]
        columns.append(np.array(coords) * np.array([1.0, k, k * k]))
    return np.array(columns).T


@pytest.mark.skipif(COMM.size > 1, reason="dense eigenmodes of the serial matrices")
@pytest.mark.parametrize("rho_inf", [0.0, 0.5, 0.8, 1.0])
def test_mode_amplification_matches_the_scalar_recurrence(tmp_path, rho_inf):
    """Stiffest and softest mode of a clamped square: parefg's step equals the recurrence,
    and the stiffest (omega k = 824) is damped to the spectral radius rho_inf (+ 0.02),
    the softest (omega k < 2) by less than 5 % (4.2 % at rho_inf = 0)."""
    scene = load_scene(
        scene_file(tmp_path, MODES, "modes"), [GENERALIZED_ALPHA, f"time.rho_inf={rho_inf}"]
    )
    sim = Simulation(COMM, scene, build_discretization(COMM, scene))
    owned = sim.disc.owned
    stiffness = (owned["stiffness"] + owned["dirichlet"]).toarray()
    omega2, modes = scipy.linalg.eigh(stiffness, owned["mass"].toarray())
    for index, (low, high) in ((0, (0.0, 2.0)), (-1, (500.0, np.inf))):
        omega_k = np.sqrt(omega2[index]) * scene.time.dt
        assert low < omega_k < high
        expected = amplification(rho_inf, omega_k)
        measured = measured_amplification(sim, modes[:, index], scene.time.dt)
        assert np.max(np.abs(measured - expected)) <= 1e-8 * np.max(np.abs(expected))
        radius = np.max(np.abs(np.linalg.eigvals(measured)))
        if index == -1:
            assert rho_inf <= radius + 1e-9 and radius <= rho_inf + 0.02, radius
        else:
            assert radius >= 0.95, radius


def kinetic_and_elastic(sim: Simulation) -> tuple[float, float]:
    kinetic = max(row["kinetic_energy"] for row in sim.history)
    elastic = min(row["elastic_energy"] for row in sim.history)
    return kinetic, elastic


@pytest.mark.parametrize("text", [AT_REST, AT_REST_ON_OBSTACLE], ids=["clamped", "on-obstacle"])
@pytest.mark.parametrize(
    "overrides",
    [["time.beta=0.25"], ["time.beta=0.5"], [GENERALIZED_ALPHA, "time.rho_inf=0.8"]],
    ids=["beta-1/4", "beta-1/2", "generalized-alpha"],
)
def test_time_independent_solution_with_u0_stays_at_rest(tmp_path, text, overrides):
    """A t-independent exact solution with u0 != 0: the discrete solution must not move.

    clamped: u = 0.1 ((1 + x) e^y, -y e^x); on-obstacle: u = (0.02 x, -0.05 y) pressed on
    Gamma_C.  Before the elliptic projection of u0 (L2 projection only) the penalty modes
    oscillated: with beta = 1/2 the kinetic energy alternated 5.6e-3 / 1.5e-7 against the
    elastic 0.032 (max |a| = 121), on the obstacle 9.0e-5 / 2e-10 against 1.4e-3.  Now the
    kinetic energy is <= 1e-12 of the elastic one at every step (measured <= 1e-21), and the
    H1 error equals that of the static solution (the discrete equilibrium) to 1e-6.
    """
    source = scene_file(tmp_path, text, "at_rest")
    sim, state = run(source, overrides)
    kinetic, elastic = kinetic_and_elastic(sim)
    assert elastic > 1e-3
    assert kinetic <= 1e-12 * elastic, (kinetic, elastic)
    static, static_state = run(source, ['time.scheme="static"'])
    reference = static.errors(static_state.u, 0.5)["h1_rel"]
    assert sim.errors(state.u, 0.5)["h1_rel"] <= reference * (1 + 1e-6)


@pytest.mark.serial_only
@pytest.mark.parametrize(
    "overrides, key",
    [
        ([GENERALIZED_ALPHA, "time.rho_inf=1.5"], "time.rho_inf"),
        ([GENERALIZED_ALPHA, 'time.rho_inf="x"'], "time.rho_inf"),
        (["time.rho_inf=0.5"], "time.rho_inf"),  # newmark has no rho_inf: refused
    ],
)
def test_bad_rho_inf_exits_2_with_one_line(tmp_path, overrides, key):
    out = tmp_path / "out"
    args = ["run", "square", "--out", str(out), "--quiet"]
    for text in overrides:
        args += ["--set", text]
    result = run_parefg(args)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("parefg: error: ") and key in lines[0]
    assert not out.exists()


@pytest.mark.serial_only
def test_generalized_alpha_one_rank_equals_two_ranks(tmp_path):
    """Square (h = 1/8) with sliding contact, generalized-alpha rho_inf = 0.5, 10 steps."""
    summaries = []
    for ranks in (1, 2):
        out = tmp_path / f"run{ranks}"
        args = ["run", "square", "--out", str(out), "--quiet"]
        for text in (
            GENERALIZED_ALPHA,
            "time.rho_inf=0.5",
            "time.dt=0.1",
            "discretization.h=0.125",
        ):
            args += ["--set", text]
        result = run_parefg(args, ranks=ranks, timeout=300)
        assert result.returncode == 0, result.stderr
        summaries.append(json.loads((out / "summary.json").read_text()))
    serial, parallel = summaries
    assert serial["params"] == parallel["params"]
    assert serial["newton_iterations"] == parallel["newton_iterations"]
    for norm in ("l2_rel", "h1_rel"):
        one, two = serial["errors"][norm], parallel["errors"][norm]
        assert 0 < one < 0.05
        assert two == pytest.approx(one, rel=1e-8, abs=0), norm


@pytest.mark.serial_only
def test_generalized_alpha_restart_equals_uninterrupted_run(tmp_path):
    """The previous level's forces are recomputed from the checkpointed u, v, a and slip:
    a restart at step 5 of 10 gives the errors of the uninterrupted run (measured: equal)."""
    common = [GENERALIZED_ALPHA, "time.rho_inf=0.5", "time.dt=0.1", "discretization.h=0.125"]

    def cli(out, *extra, overrides=()):
        args = ["run", "square", "--out", str(tmp_path / out), "--quiet", *extra]
        for text in [*common, *overrides]:
            args += ["--set", text]
        result = run_parefg(args)
        assert result.returncode == 0, result.stderr
        return json.loads((tmp_path / out / "summary.json").read_text())

    full = cli("full")
    cli("half", "--checkpoint-every", "5", overrides=["time.T=0.5"])
    restarted = cli("restarted", "--restart", str(tmp_path / "half" / "checkpoint.h5"))
    for norm in ("l2_rel", "h1_rel"):
        assert restarted["errors"][norm] == pytest.approx(full["errors"][norm], rel=1e-12)
