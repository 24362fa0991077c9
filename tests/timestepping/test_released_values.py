"""The domain's value operator is dropped for the time loop, and nothing changes.

S[q, I] = phi_I(x_q) at the domain's Gauss points is the largest point operator (12 KB per
DOF at m = 2 with 8 x 8 points); once the load vectors and the initial state exist, only
the error norms at the end use it (and a body force that is integrated at every step).
Large operators are released by Simulation.start; the norms then take u_h from MLS values
block by block, and so does an integration (S^T w f: PointGradients.integrate_values);
S is built again on the build's blocks only for a body force integrated at every step.  A
domain whose S would be large (size_estimate.BUILT_VALUE_BYTES) never builds it: its
load vectors and initial state come from MLS values block by block too.  These tests
force both on small clouds (the thresholds set to 0).
"""

import numpy as np
import pytest
from mpi4py import MPI

from parefg.discretization import domain_assembly, operators
from parefg.run import prepare
from parefg.timestepping import simulation

COMM = MPI.COMM_WORLD
# Coarse square, m = 2 and m = 3 (VCI): Nitsche Dirichlet and contact, friction, loads.
CASES = {
    "m2": ["discretization.h=0.25", "discretization.degree=2", "time.dt=0.05", "time.T=0.2"],
    "m3-vci": ["discretization.h=0.25", "discretization.degree=3", "time.dt=0.05", "time.T=0.2"],
}
# exp(x t) is not a sum of products a(t) f(x): the body force is integrated at every step.
NOT_SEPARABLE = 'exact.u=["exp(x * t) - 1", "0.1 * t**2 * y"]'


def run(overrides, keep_below, monkeypatch):
    """(values kept during the loop?, final u, errors) of a short run."""
    monkeypatch.setattr(simulation, "RELEASE_VALUE_BYTES", keep_below)
    sim = prepare(COMM, "square", overrides)
    state = sim.start()
    held = sim.disc.domain.values is not None
    for n in range(1, sim.scene.time.n_steps + 1):
        state = sim.step(state, n)
    u = state.u.getArray(readonly=True).copy()
    return held, u, sim.errors(state.u, sim.scene.time.T), sim


@pytest.mark.parametrize("kernels", ["numpy", "numba"])
@pytest.mark.parametrize("case", sorted(CASES))
def test_released_values_change_nothing(case, kernels, monkeypatch):
    monkeypatch.setenv("PAREFG_KERNELS", kernels)  # large clouds run numba's
    kept, u_kept, errors_kept, _ = run(CASES[case], 10**15, monkeypatch)
    released, u_released, errors_released, sim = run(CASES[case], 0, monkeypatch)
    assert kept and not released  # the threshold decides, on every rank alike
    np.testing.assert_array_equal(u_released, u_kept)  # the loop never used S
    if COMM.size == 1:  # MLS values summed as PETSc's product of S sums a row
        assert errors_released == errors_kept
    for name, value in errors_kept.items():  # on 2 ranks S's product is split into two
        assert errors_released[name] == pytest.approx(value, rel=1e-12)


@pytest.mark.parametrize("block_points", [65536, 300], ids=["one-block", "blocks"])
def test_the_rebuilt_operator_is_the_built_one(block_points, monkeypatch):
    monkeypatch.setattr(simulation, "RELEASE_VALUE_BYTES", 0)
    monkeypatch.setattr(domain_assembly, "BLOCK_POINTS", block_points)  # 1024 points here
    sim = prepare(COMM, "square", CASES["m2"])
    domain = sim.disc.domain
    built = [array.copy() for array in domain.values.getValuesCSR()]
    points, weights = domain.points, domain.weights
    sim.start()
    assert domain.values is None and domain.points is None and domain.weights is None
    assert domain.gradients.points is None  # no reference left to the released points
    rebuilt = domain.rebuild(domain.restore_points()[0]).getValuesCSR()
    for before, after in zip(built, rebuilt, strict=True):
        np.testing.assert_array_equal(after, before)
    np.testing.assert_array_equal(domain.points, points)  # the same rule, computed again
    np.testing.assert_array_equal(domain.weights, weights)
    assert domain.gradients.points is domain.points


def test_a_body_force_evaluated_as_written_gets_the_points_back(monkeypatch):
    """A step whose a_k(t) are not usable evaluates f point by point at the Gauss points,
    which the release dropped: the datum computes them again (and the run goes on)."""
    monkeypatch.setattr(simulation, "RELEASE_VALUE_BYTES", 0)
    sim = prepare(COMM, "square", CASES["m2"])
    datum = sim.loads.forces_terms[0].datum
    assert datum.scale is not None and datum.points is None  # split usable: points dropped
    built = sim.disc.domain.points.copy()
    sim.start()
    assert sim.disc.domain.points is None
    values = datum._checked(0.1)  # the path of a step without usable a_k(t)
    expected = datum._direct({"x": built[:, 0], "y": built[:, 1]}, 0.1)
    np.testing.assert_array_equal(values, expected)  # at the points the run was built on
    vector = sim.disc.create_vec()
    sim.loads.forces_terms[0].integrate(values, vector)  # MLS values block by block
    assert np.isfinite(vector.norm())


def test_a_body_force_integrated_per_step_keeps_the_operator(monkeypatch):
    held, _, errors, sim = run([*CASES["m2"], NOT_SEPARABLE], 0, monkeypatch)
    assert sim.loads.integrates_domain
    assert held
    assert np.isfinite(errors["h1_rel"])


def test_small_operators_are_kept_by_default():
    sim = prepare(COMM, "square", CASES["m2"])
    sim.start()
    assert sim.disc.domain.values is not None  # a few KB: not worth an MLS pass


def _unbuilt_run(overrides, build: bool, monkeypatch):
    """(the domain's S after prepare, final u, errors, sim) with S built or not; the sim
    records whether the Gauss points were released for the loop."""
    monkeypatch.setattr(operators, "BUILT_VALUE_BYTES", 10**15 if build else 0)
    sim = prepare(COMM, "square", overrides)
    built = sim.disc.domain.values
    state = sim.start()
    sim.points_released = sim.disc.domain.points is None
    for n in range(1, sim.scene.time.n_steps + 1):
        state = sim.step(state, n)
    u = state.u.getArray(readonly=True).copy()
    return built, u, sim.errors(state.u, sim.scene.time.T), sim


@pytest.mark.parametrize("case", sorted(CASES))
def test_a_domain_without_its_value_operator_gives_the_same_run(case, monkeypatch):
    """Load vectors and the initial state from MLS values block by block instead of S^T:
    the same sums in another order, so the run agrees to round-off."""
    built, u_built, errors_built, _ = _unbuilt_run(CASES[case], True, monkeypatch)
    unbuilt, u_unbuilt, errors_unbuilt, sim = _unbuilt_run(CASES[case], False, monkeypatch)
    assert built is not None and unbuilt is None
    assert sim.points_released  # for the loop, as with a released S
    scale = COMM.allreduce(float(np.abs(u_built).max()), op=MPI.MAX)
    assert COMM.allreduce(float(np.abs(u_unbuilt - u_built).max()), op=MPI.MAX) <= 1e-11 * scale
    for name, value in errors_built.items():
        assert errors_unbuilt[name] == pytest.approx(value, rel=1e-9)


def test_block_integration_is_s_transpose(monkeypatch):
    """PointSet.integrate without S equals S^T (w density) to round-off, ghost nodes (other
    ranks' nodes that this rank's points reach) included."""
    sim = prepare(COMM, "square", CASES["m2"])
    domain = sim.disc.domain
    points, weights = domain.points, domain.weights
    density = np.column_stack([np.sin(3 * points[:, 0]) * points[:, 1], np.cos(points[:, 1])])
    with_s, without_s = sim.disc.create_vec(), sim.disc.create_vec()
    domain.integrate(density, with_s)
    domain.gradients.integrate_values((density * weights[:, None])[None], [without_s])
    without_s.axpy(-1.0, with_s)
    assert without_s.norm() <= 1e-13 * with_s.norm()


def test_a_body_force_integrated_per_step_builds_the_operator(monkeypatch):
    """A force that is not time-separable is integrated at every step: S is built for it
    before the loop, not evaluated by MLS at every step."""
    built, _, errors, sim = _unbuilt_run([*CASES["m2"], NOT_SEPARABLE], False, monkeypatch)
    assert sim.loads.integrates_domain
    assert built is not None  # built at Simulation construction, from the points
    assert sim.disc.domain.values is not None
    assert np.isfinite(errors["h1_rel"])


def test_the_load_vectors_of_a_separable_force_take_one_mls_pass(monkeypatch):
    """The square's body force has two space parts f_k: without S, their F_k come from one
    MLS pass over the Gauss points, not one each."""
    from parefg.discretization import point_gradients

    monkeypatch.setattr(operators, "BUILT_VALUE_BYTES", 0)
    passes = []
    integrate = point_gradients.PointGradients.integrate_values

    def counted(self, weighted, outs):
        passes.append(len(outs))
        integrate(self, weighted, outs)

    monkeypatch.setattr(point_gradients.PointGradients, "integrate_values", counted)
    sim = prepare(COMM, "square", CASES["m2"])
    assert len(sim.loads.forces_terms[0].vectors) == 2
    assert passes == [2]
