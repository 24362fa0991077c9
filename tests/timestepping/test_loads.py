"""The loads of a run from time-separable data equal the per-point evaluation (loads.py).

The reference is the same scene with every split removed (``separated = None``), which
takes the per-point path: the datum at every quadrature point, integrated against the
shape functions at each t.  Both must agree to round-off, and bad data must be reported
with the same message on both paths.  Serial and under ``mpirun -n 2``.
"""

from types import SimpleNamespace

import numpy as np
import pytest
from mpi4py import MPI

from parefg.discretization.operators import build_discretization
from parefg.errors import DataError
from parefg.guards import DataGuard, PointDatum
from parefg.scene.expressions import compile_field, parse_expression
from parefg.scene.fields import WITH_NORMAL
from parefg.scene.loader import load_scene
from parefg.scene.separable import with_separation, without_splits
from parefg.timestepping.simulation import Simulation

COMM = MPI.COMM_WORLD
TIMES = (0.0, 0.05, 0.3, 0.77, 1.0)
BODY = '[domain]\nshape = "square"\n[discretization]\nh = 0.25\n[time]\nT = 0.2\ndt = 0.05\n'


def pair(source, overrides=()):
    """Simulations of the scene on the separable path and on the per-point path."""
    scene = load_scene(source, list(overrides))
    disc = build_discretization(COMM, scene)
    return Simulation(COMM, scene, disc), Simulation(COMM, without_splits(scene), disc)


def relative(a, b):
    scale = max(np.linalg.norm(b), 1e-300)
    return np.linalg.norm(a - b) / scale


def _largest(values) -> float:
    """max |values|, 0 for none."""
    return float(np.max(np.abs(values), initial=0.0))


def _difference(a_vec, b_vec):
    """||a - b|| over all ranks."""
    difference = a_vec.copy()
    difference.axpy(-1.0, b_vec)
    return difference.norm()


def _dirichlet_load(sim, t):
    out = sim.disc.create_vec()
    out.set(0.0)
    sim._add_dirichlet_data(t, out)
    return out


# A time-independent manufactured solution: every datum is the one term 1 * f(x).
STEADY = 'exact.u=["0.01 * (1 + x) * exp(y)", "-0.01 * y * exp(x)"]'


@pytest.mark.parametrize(
    "scene_name, overrides", [("square", []), ("z", []), ("square", [STEADY])], ids=str
)
def test_separable_loads_equal_the_per_point_loads(scene_name, overrides):
    fast, slow = pair(scene_name, ["discretization.h=0.125", *overrides])
    # every datum of these scenes is separable: the fast path is really taken
    assert all(term.vectors for term in fast.loads.forces_terms)
    assert all(term.vectors for term in fast.loads.dirichlet.values())
    assert not any(term.vectors for term in slow.loads.forces_terms)
    assert fast.loads.forces_terms[0].datum.space is None  # f_k at the Gauss points: dropped
    # scales at t = 1: ubar(0) = 0 exactly for these solutions
    force_scale = slow.external_forces(1.0).norm()
    dirichlet_scale = _dirichlet_load(slow, 1.0).norm()
    for t in TIMES:
        assert _difference(fast.external_forces(t), slow.external_forces(t)) < 1e-12 * force_scale
        difference = _difference(_dirichlet_load(fast, t), _dirichlet_load(slow, t))
        assert difference < 1e-12 * dirichlet_scale
        for name in fast.dirichlet_names:  # this rank's points (none on some ranks)
            ubar = fast._dirichlet_value(name, t)
            scale = COMM.allreduce(_largest(slow._dirichlet_value(name, 1.0)), op=MPI.MAX)
            assert _largest(ubar - slow._dirichlet_value(name, t)) < 1e-12 * scale
            assert fast._dirichlet_value(name, t) is ubar  # evaluated once per t
    fast.guard.check(), slow.guard.check()


@pytest.mark.parametrize(
    "scene_name, overrides", [("square", []), ("z", []), ("square", [STEADY])], ids=str
)
def test_separable_friction_bound_equals_the_per_point_bound(scene_name, overrides):
    fast, slow = pair(scene_name, ["discretization.h=0.125", *overrides])
    assert all(datum.space is not None for _, datum in _friction_data(fast))
    for t in TIMES:
        fast.law.set_time(t)
        slow.law.set_time(t)
        assert relative(fast.law.bound_data, slow.law.bound_data) <= 1e-12
    assert np.all(fast.law.bound_data >= 0.0)
    assert not any(datum.space is not None for _, datum in _friction_data(slow))
    fast.guard.check(), slow.guard.check()


def _friction_data(sim):
    sim.law.set_time(0.0)
    return sim.law._friction_data


def test_a_scene_with_non_separable_data_runs_like_its_per_point_twin(tmp_path):
    """f mixes x and t inside functions (not split), the Dirichlet value is split."""
    path = tmp_path / f"mixed{COMM.rank}.toml"
    path.write_text(
        BODY + '[boundary.top]\ntype = "dirichlet"\nvalue = ["0.01*sin(pi*x)*t", 0]\n'
        '[loads]\nf = ["sin(x*t)", "exp(x + t) - 1"]\n'
    )
    fast, slow = pair(str(path))
    assert fast.scene.loads.f.separated is None
    assert fast.scene.boundaries["top"].value.separated is not None
    states = [sim.start() for sim in (fast, slow)]
    for n in range(1, 5):
        states = [sim.step(state, n) for sim, state in zip((fast, slow), states, strict=True)]
    assert _difference(states[0].u, states[1].u) < 1e-12 * states[1].u.norm()
    assert states[1].u.norm() > 0


def message(sim, steps):
    """The DataError message of the first of ``steps`` whose data are bad."""
    with pytest.raises(DataError) as raised:
        state = sim.start()
        for n in range(1, steps + 1):
            state = sim.step(state, n)
    return str(raised.value)


@pytest.mark.parametrize(
    ("table", "shown"),
    [('[loads]\nf = ["(1 + x)*sqrt(0.12 - t)", 0]\n',
      "loads.f[0] = '(1 + x)*sqrt(0.12 - t)' is not finite (nan)"),
     ('[boundary.top]\ntype = "dirichlet"\nvalue = [0, "y*log(0.12 - t)"]\n',
      "boundary.top.value[1] = 'y*log(0.12 - t)' is not finite"),
     ('[boundary.right]\ntype = "neumann"\ntraction = ["x*exp(3000*t)", 0]\n',
      "boundary.right.traction[0] = 'x*exp(3000*t)' is too large")],
)  # fmt: skip
def test_data_turning_bad_are_reported_as_on_the_per_point_path(tmp_path, table, shown):
    """Good at t = 0, 0.05 and 0.1, bad from t = 0.15 on (exp(450) > DATA_BOUND)."""
    path = tmp_path / f"bad{COMM.rank}.toml"
    text = BODY.replace("T = 0.2", "T = 0.3")
    if "dirichlet" not in table:
        text += '[boundary.top]\ntype = "dirichlet"\n'
    path.write_text(text + table)
    fast, slow = pair(str(path))
    # the bad datum is split: its F_k were integrated once (finite at the points)
    terms = fast.loads.forces_terms + list(fast.loads.dirichlet.values())
    (bad,) = [term for term in terms if ".".join(term.datum.key) in shown]
    assert bad.vectors
    got, want = message(fast, 6), message(slow, 6)
    assert got == want
    assert shown in got
    assert "t = 0.15:" in got


def test_negative_separable_friction_bound_is_reported_as_on_the_per_point_path(tmp_path):
    """g = (1 + x)(0.05 - t) >= 0 until t = 0.05, negative at t = 0.1 (installed after load)."""
    path = tmp_path / f"friction{COMM.rank}.toml"
    path.write_text(
        BODY + '[boundary.top]\ntype = "dirichlet"\n'
        '[boundary.bottom]\ntype = "contact"\nfriction = 0.5\n'
    )
    expr = parse_expression("(1 + x)*(0.05 - t)", "test")
    scene = load_scene(str(path))
    bottom = scene.boundaries["bottom"]
    bottom.friction = with_separation(compile_field([expr], WITH_NORMAL, ()), [expr])
    assert bottom.friction.separated is not None
    disc = build_discretization(COMM, scene)
    fast = Simulation(COMM, scene, disc)
    slow = Simulation(COMM, without_splits(scene), disc)
    got, want = message(fast, 3), message(slow, 3)
    assert got == want
    assert "boundary.bottom.friction = 0.5 is negative" in got and "t = 0.1:" in got


# ----------------------------------------------------------- what the rewriting must not hide


@pytest.mark.parametrize(
    ("value", "when", "split"),
    [("x*(t + 1/x)", "t = 0:", False),  # x t + 1 if split: finite at x = 0
     ("(t - 0.1)*(x + 1/(t - 0.1))", "t = 0.1:", False),  # (t - 0.1) x + 1: finite at 0.1
     ("t*(x + 1/x) - t/x", "t = 0:", True)],  # split to t x; the datum decides at t = 0
)  # fmt: skip
def test_a_singularity_the_split_cancels_is_reported_as_on_the_per_point_path(
    tmp_path, value, when, split
):
    """NaN at x = 0 (the left edge's points) for all t, or at t = 0.1 at every point.

    Products that cancel a denominator are not split; a sum that cancels one is split,
    and the datum as written, not finite at t = 0, keeps the per-point path.
    """
    path = tmp_path / f"cancel{COMM.rank}.toml"
    path.write_text(BODY + f'[boundary.left]\ntype = "dirichlet"\nvalue = ["{value}", 0]\n')
    fast, slow = pair(str(path))
    assert (fast.scene.boundaries["left"].value.separated is not None) is split
    got, want = message(fast, 3), message(slow, 3)
    assert got == want
    assert f"boundary.left.value[0] = '{value}' is not finite (nan)" in got and when in got


def test_data_whose_time_terms_all_cancel_run_like_their_per_point_twin(tmp_path):
    """t (x + 1) - t x - t is 0: no split (K = 0), the same run as the per-point path."""
    path = tmp_path / f"zero{COMM.rank}.toml"
    path.write_text(
        BODY + '[boundary.top]\ntype = "dirichlet"\n[loads]\nf = ["t*(x + 1) - t*x - t", 0]\n'
    )
    fast, slow = pair(str(path))
    states = []
    for sim in (fast, slow):
        state = sim.start()
        for n in range(1, 4):
            state = sim.step(state, n)
        states.append(state)
    assert _difference(states[0].u, states[1].u) <= 1e-12 * states[1].u.norm()


def test_round_off_negatives_of_a_distributed_square_are_no_negative_bound():
    """g = 1e5 (x - t)^2 >= 0 as written; distributed, x^2 - 2 x t + t^2 rounds below zero.

    Contact points x_q = q / 40 and times t_n = n / 40 meet; with E = 1 the round-off
    (~1e-12) is beyond the guard's floor of zero, so a check of the split's values would
    call the bound negative where the square is not.
    """
    scene = SimpleNamespace(
        name="s", material=SimpleNamespace(E=1.0), params={"boundary": {"c": {"friction": "g"}}}
    )
    expr = parse_expression("1e5*(x - t)**2", "test")
    field = with_separation(compile_field([expr], WITH_NORMAL, ()), [expr])
    assert field.separated is not None
    points = np.column_stack([np.linspace(0.0, 1.0, 41), np.zeros(41)])
    x, y = points.T
    arguments = {"x": x, "y": y, "nx": np.zeros_like(x), "ny": -np.ones_like(x)}
    guard = DataGuard(COMM, scene)
    datum = PointDatum(guard, ("boundary", "c", "friction"), field, points, arguments, True)
    assert datum.space is not None  # the split is used
    for n in range(41):
        values = datum.values(n * 0.025)
        guard.check()  # raised "... is negative (-1.82e-12) ..." when the split decided
        assert np.all(values >= 0.0)
