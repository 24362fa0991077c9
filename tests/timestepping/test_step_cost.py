"""The per-step shortcuts: kept contact kinematics and the reused-factorization step.

Each shortcut must give the bits of the path it replaces: kinematics are compared with a
fresh product with the contact operator, and the reused-factorization step with SNES
taking every step (the shortcut switched off on an otherwise identical simulation).
"""

import subprocess
import sys

import numpy as np
import pytest
from conftest import mpi_env
from mpi4py import MPI
from petsc4py import PETSc

from parefg.run import prepare
from parefg.scene.numeric import CompiledField
from parefg.timestepping.step_solver import _reused_step_allowed

# square, m = 2, h = 1/8: contact on the bottom with sliding friction, 20 steps in which
# the active set changes (factorizations) and most steps are one reused-factorization step
OVERRIDES = ["discretization.h=0.125", "time.dt=0.0125", "time.T=0.25"]


def _fresh_kinematics(law, u):
    out = law.operator.createVecLeft()
    law.operator.mult(u, out)
    values = out.getArray().reshape(-1, 2)
    return values[:, 0].copy(), values[:, 1].copy()


def test_kept_kinematics_follow_every_change_of_the_vector():
    sim = prepare(MPI.COMM_WORLD, "square", OVERRIDES)
    law = sim.law
    u = sim.disc.create_vec()
    rng = np.random.default_rng(3 + MPI.COMM_WORLD.rank)
    u.setArray(rng.standard_normal(u.getLocalSize()))
    first = law.kinematics(u)
    assert law.kinematics(u) is first  # the same vector, unchanged: kept
    changes = [
        lambda: u.shift(0.5),
        lambda: u.setArray(rng.standard_normal(u.getLocalSize())),
        lambda: u.scale(-2.0),
    ]
    for change in changes:
        before = [a.copy() for a in law.kinematics(u)]
        change()
        after = law.kinematics(u)
        for value, fresh, old in zip(after, _fresh_kinematics(law, u), before, strict=True):
            assert np.array_equal(value, fresh)
            # a rank may hold no Gamma_C point (h = 1/8 on 2 ranks: both coarse-trace
            # groups of the bottom start on rank 0's segments)
            assert len(value) == 0 or not np.array_equal(value, old)
    # writes through a writable array view count once the view is released
    array = u.getArray()
    array *= 3.0
    del array
    for value, fresh in zip(law.kinematics(u), _fresh_kinematics(law, u), strict=True):
        assert np.array_equal(value, fresh)
    # a kept result is shared: it cannot be changed in place
    with pytest.raises(ValueError):
        law.kinematics(u)[0][0] = 1.0


def test_another_vector_with_other_values_is_not_served_the_kept_result():
    sim = prepare(MPI.COMM_WORLD, "square", OVERRIDES)
    law = sim.law
    a, b, c = (sim.disc.create_vec() for _ in range(3))
    for scale, vec in enumerate((a, b, c), start=1):
        vec.setArray(np.linspace(0.0, scale, vec.getLocalSize()) + MPI.COMM_WORLD.rank)
    for vec in (a, b, c, a, c, b):
        for value, fresh in zip(law.kinematics(vec), _fresh_kinematics(law, vec), strict=True):
            assert np.array_equal(value, fresh)


def _run(reuse):
    sim = prepare(MPI.COMM_WORLD, "square", OVERRIDES)
    if not reuse:
        sim.solver._reuse = False
    state = sim.start()
    for n in range(1, sim.scene.time.n_steps + 1):
        state = sim.step(state, n)
    return sim, state


def test_reused_factorization_steps_give_the_bits_of_snes():
    fast, fast_state = _run(reuse=True)
    snes, snes_state = _run(reuse=False)
    n_steps = fast.scene.time.n_steps
    # both paths are exercised: SNES took the steps that (re)built the Jacobian
    assert 0 < fast.solver.reused_steps < n_steps
    assert snes.solver.reused_steps == 0
    assert fast.solver.factorizations == snes.solver.factorizations > 1
    for name in ("u", "v", "a"):
        assert np.array_equal(
            getattr(fast_state, name).getArray(), getattr(snes_state, name).getArray()
        )
    assert fast.history == snes.history  # iterations, active points, energies
    assert np.array_equal(fast.law.slip, snes.law.slip)


class _CountingOperator:
    """The contact operator, counting its products with a DOF vector."""

    def __init__(self, operator):
        self.operator, self.products = operator, 0

    def mult(self, x, y):
        self.products += 1
        return self.operator.mult(x, y)

    def __getattr__(self, name):
        return getattr(self.operator, name)


def test_a_reused_step_forms_the_kinematics_of_each_vector_once():
    """The friction gate, the first residual and the energy row share the predictor's and
    the accepted u's kinematics: three products per reused step (the predictor, the Newton
    direction, the accepted u), not one per question."""
    sim = prepare(MPI.COMM_WORLD, "square", OVERRIDES)
    assert sim.law.has_friction  # the gate asks for the predictor's kinematics
    counter = _CountingOperator(sim.law.operator)
    sim.law.operator = counter
    state, reused = sim.start(), []
    for n in range(1, sim.scene.time.n_steps + 1):
        before, steps = counter.products, sim.solver.reused_steps
        state = sim.step(state, n)
        if sim.solver.reused_steps > steps:
            reused.append(counter.products - before)
    assert reused and set(reused) == {3}


def test_options_that_snes_would_act_on_refuse_the_reused_step():
    assert _reused_step_allowed({"snes_rtol": "1e-12", "ksp_type": "preonly", "pc_type": "lu"})
    for option in ("snes_monitor", "snes_converged_reason", "snes_lag_jacobian", "snes_view",
                   "ksp_monitor", "ksp_view", "ksp_converged_reason", "pc_view"):  # fmt: skip
        assert not _reused_step_allowed({option: None})


def test_snes_monitor_is_honoured_at_every_step():
    options = PETSc.Options()
    options.setValue("snes_monitor", "")
    try:
        sim = prepare(MPI.COMM_WORLD, "square", OVERRIDES)
    finally:
        options.delValue("snes_monitor")
    assert not sim.solver._reuse


# An observer that reads u on rank 0 only, through petsc4py's default (writable) view:
# releasing it raises u's PETSc state on rank 0 alone.
ONE_RANK_READER = """
from mpi4py import MPI
from parefg.run import prepare
from parefg.scene.numeric import CompiledField
comm = MPI.COMM_WORLD
sim = prepare(comm, "stick", ["time.T=0.15"])
state = sim.start()
for n in range(1, 4):
    state = sim.step(state, n)
    if comm.rank == 0:
        state.u.getArray()[0]
print("rank", comm.rank, "done", flush=True)
"""


@pytest.mark.serial_only
def test_a_view_taken_on_one_rank_does_not_split_the_ranks_on_the_kept_kinematics(tmp_path):
    """Both ranks compute the kinematics when one of them saw u's state change.

    With the kept result taken per rank, rank 0 entered the collective product while rank 1
    went on with its kept one: the job hung (here: killed by the timeout).
    """
    script = tmp_path / "reader.py"
    script.write_text(ONE_RANK_READER)
    cmd = ["mpirun", "--timeout", "120", "-n", "2", sys.executable, str(script)]
    try:
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=150, env=mpi_env())
    except subprocess.TimeoutExpired:
        pytest.fail("the 2-rank job hung")
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.count("done") == 2


def test_kept_contact_forces_follow_the_law_state_and_their_arguments():
    """ContactLaw.forces keeps its last answer for read-only (u_nu, u_tau): every change of
    the law's state it reads (start level, level force, slip, bound, normal force) and
    every writable argument gives the forces computed afresh."""
    sim = prepare(MPI.COMM_WORLD, "square", OVERRIDES)
    law, state = sim.law, sim.start()
    for n in (1, 2):
        state = sim.step(state, n)
    un, ut = law.kinematics(state.u)
    first = law.forces(un, ut)
    assert law.forces(un, ut) is first  # the same arrays and state: kept

    def check(un, ut):
        fresh = law.step_pressure(un), law.friction_force(ut)
        for value, expected in zip(law.forces(un, ut), fresh, strict=True):
            assert np.array_equal(value, expected)

    changes = [
        lambda: setattr(law, "start_penetration", law.start_penetration - 1e-3),
        lambda: setattr(law, "level_pressure", law.level_pressure + 1.0),
        lambda: setattr(law, "slip", law.slip + 1e-3),
        lambda: law.set_time(0.6),
    ]
    for change in changes:
        change()
        check(un, ut)
    with law.endpoint_force():
        check(un, ut)
    check(un, ut)
    # writable arguments are not kept: a write into them gives new forces
    un_copy, ut_copy = un.copy(), ut.copy()
    law.forces(un_copy, ut_copy)
    un_copy += 1e-3
    ut_copy -= 1e-3
    check(un_copy, ut_copy)


def test_a_reused_step_forms_the_step_pressure_twice():
    """The residual at u_0 and the line search's start share the forces at u_0, and the
    slip update needs only the friction force: the step pressure is formed for the first
    residual and for C_n at the accepted u (end_level), two evaluations per reused step
    (four before)."""
    sim = prepare(MPI.COMM_WORLD, "square", OVERRIDES)
    law, calls = sim.law, [0]
    step_pressure = law.step_pressure

    def counted(un):
        calls[0] += 1
        return step_pressure(un)

    law.step_pressure = counted
    state, reused = sim.start(), []
    for n in range(1, sim.scene.time.n_steps + 1):
        before, steps = calls[0], sim.solver.reused_steps
        state = sim.step(state, n)
        if sim.solver.reused_steps > steps:
            reused.append(calls[0] - before)
    assert reused and set(reused) == {2}


def test_a_step_evaluates_each_distinct_time_part_once(monkeypatch):
    """The square scene's split data (body force, tractions, Dirichlet data, friction bound)
    share their time parts: three distinct ones, each evaluated once per step (five
    evaluations, one per datum, before)."""
    sim = prepare(MPI.COMM_WORLD, "square", OVERRIDES)
    parts = {
        tuple(field.separated.time.texts)
        for field in (
            sim.scene.loads.f,
            *(
                getattr(bc, key)
                for bc in sim.scene.boundaries.values()
                for key in ("value", "traction", "friction")
            ),
        )
        if field is not None and field.separated is not None
    }
    assert len(parts) == 3
    evaluations = []
    call = CompiledField.__call__

    def counted(self, *values):
        if self.args == ("t",):
            evaluations.append(tuple(self.texts))
        return call(self, *values)

    state = sim.start()
    monkeypatch.setattr(CompiledField, "__call__", counted)
    for n in range(1, 4):
        evaluations.clear()
        state = sim.step(state, n)
        assert sorted(evaluations) == sorted(parts)
