"""Nitsche contact (Chouly & Hild, symmetric) against the paper's penalty contact.

Penalty contact lets the body sink by u_nu - s = sigma_nu / alpha_C into the obstacle: an
O(h) consistency error with alpha_C ~ E / h that stalls the dynamic L2 error near 1e-6 at
m >= 2.  Nitsche's p = [gamma (u_nu - s) - sigma_nu(u_h)]^+ is consistent (the exact
solution satisfies the discrete equations), with gamma from the coercivity bound of the
MLS space, not from the user.  Every test runs serially and under ``mpirun -n 2``.
"""

import numpy as np
import pytest
from test_dynamics import TIME_EXACT, errors, run

from parefg.sweep import fitted_rate

NITSCHE = "boundary.bottom.method=nitsche"
PENALTY = "boundary.bottom.method=penalty"


def test_nitsche_contact_lifts_the_penalty_floor_at_degree_2():
    """Time-exact motion, m = 2, dt = 0.05, h = 1/8, 1/16, 1/32: L2 rate in [2.5, 3.7].

    Measured L2: Nitsche 1.45e-5, 1.48e-6, 2.75e-7 (fitted rate 2.86); penalty 1.70e-5,
    2.55e-6, 1.02e-6 (2.03: its O(h) consistency error), which fails the window.
    """
    sizes = [0.125, 0.0625, 0.03125]
    fixed = [TIME_EXACT, "discretization.degree=2", "time.dt=0.05", NITSCHE]
    runs = [errors("square", [*fixed, f"discretization.h={h}"]) for h in sizes]
    l2 = [e["l2_rel"] for e in runs]
    assert 2.5 <= fitted_rate(sizes, l2) <= 3.7, l2
    assert 1.6 <= fitted_rate(sizes, [e["h1_rel"] for e in runs]) <= 2.6, runs
    assert l2[-1] < 5e-7, l2  # below the penalty's floor (1.0e-6 at h = 1/32)


def test_nitsche_contact_at_degree_3_is_an_order_of_magnitude_more_accurate():
    """Time-exact motion, m = 3, h = 1/16, dt = 0.05: Nitsche's L2 below 1/10 of the penalty's.

    Measured L2 7.0e-8 (Nitsche) and 1.89e-6 (penalty); H1 3.3e-6 and 5.5e-6.
    """
    fixed = [TIME_EXACT, "discretization.degree=3", "discretization.h=0.0625", "time.dt=0.05"]
    nitsche, penalty = (errors("square", [*fixed, method]) for method in (NITSCHE, PENALTY))
    assert nitsche["l2_rel"] < 0.1 * penalty["l2_rel"], (nitsche, penalty)
    assert nitsche["h1_rel"] < penalty["h1_rel"], (nitsche, penalty)
    assert nitsche["l2_rel"] < 2e-7, nitsche


BAR = [  # the frictionless nu = 0 bar of scripts/bench/bench_impact.py, thrown at the wall
    "domain.size=[0.4, 1.0]",
    "discretization.h=0.1",
    "material.nu=0.0",
    "boundary.bottom.friction=0.0",
    "boundary.bottom.gap=0.05",
    "initial.v=[0.0, -0.1]",
    "time.T=2.56",
    "time.dt=0.02",
    "time.beta=0.25",
    NITSCHE,
]


def stored_energy(row: dict) -> float:
    names = ("kinetic_energy", "elastic_energy", "penalty_energy", "dissipated_energy")
    return sum(row[name] for name in names) - row["external_work"]


@pytest.mark.parametrize("method", ["nitsche", "nitsche-pointwise", "nitsche-hat"])
def test_nitsche_contact_conserves_energy_through_an_impact(method):
    """The bar hits the wall, stays 2 L / c, rebounds: energy conserved at beta = 1/4.

    The Nitsche term -||sigma_nu||^2 / (2 gamma) belongs to the conserved energy (it is in
    penalty_energy); the discrete-gradient force does the contact work exactly.  Measured:
    max |E / E_0 - 1| = 2.5e-9 (penalty 2.8e-9); rebound velocity 0.984 v0 (penalty 0.987);
    with the law on the coarse trace (P u, P sigma_nu, P s: the default), at every point
    or on the hats' P u the same balance holds.
    """
    sim, state = run("impact", [*BAR, f"boundary.bottom.method={method}"])
    energy = np.array([stored_energy(row) for row in sim.history])
    closed = np.array([row["active_contact_points"] > 0 for row in sim.history])
    assert closed.any() and not closed[-1]  # it touched and left again
    assert np.max(np.abs(energy / energy[0] - 1.0)) <= 1e-7, energy / energy[0]
    # the rebound: mean vertical velocity reversed to about +v0
    ones = sim.disc.create_vec()
    ones.setArray(np.tile([0.0, 1.0], ones.getLocalSize() // 2))
    sim.disc.mass.mult(state.v, sim._product)
    velocity = sim._product.dot(ones) / sim._quadratic(sim.disc.mass, ones)
    assert 0.95 * 0.1 <= velocity <= 1.01 * 0.1, velocity


def test_energy_at_degree_3_stays_bounded_with_the_nonsymmetric_stiffness():
    """m = 3 (VCI, its default: K has a skew part of ~1e-5 |K|), the same bar and impact:
    the energy is no longer conserved to the solver tolerance but to the skew part (bounded:
    K's spectrum is real, tests/discretization/test_consistent_gradients.py).  Measured
    max |E / E_0 - 1|: 3.7e-6 over T = 2.56 (129 steps), 3.6e-5 over T = 25.6 (1281
    steps, oscillating in sign); Gauss integration 6.8e-9."""
    sim, _ = run("impact", [*BAR, "discretization.degree=3"])
    assert sim.scene.params["discretization"]["integration"] == "vci"
    energy = np.array([stored_energy(row) for row in sim.history])
    assert any(row["active_contact_points"] > 0 for row in sim.history)
    drift = np.abs(energy / energy[0] - 1.0).max()
    assert drift <= 2e-5, drift


def _contact_safety_errors(method: str) -> dict[str, np.ndarray]:
    fixed = [TIME_EXACT, "discretization.degree=2", "discretization.h=0.0625", "time.dt=0.0125"]
    fixed.append(f"boundary.bottom.method={method}")
    runs = [errors("square", [*fixed, f"boundary.bottom.safety={s}"]) for s in (1.1, 2.0, 2e4)]
    return {norm: np.array([run[norm] for run in runs]) for norm in ("l2_rel", "h1_rel")}


def test_contact_errors_stay_within_a_factor_2_over_four_decades_of_the_safety():
    """Time-exact motion, m = 2, h = 1/16, dt = 0.0125, contact safety 1.1, 2 and 2e4.

    The default "nitsche" imposes the law on the coarse trace's polynomials, "nitsche-hat"
    on the projection of u onto continuous piecewise-linear functions (parefg.
    discretization.coarse_trace.hat_projection): their errors agree to 4 digits (measured
    L2 1.486e-6 / 1.487e-6, H1 8.743e-5 / 8.744e-5 at each safety).  The law at
    every Gauss point ("nitsche-pointwise") grows with gamma (L2 1.488e-6 -> 3.924e-6,
    H1 8.75e-5 -> 1.154e-4), towards the penalty's over-constrained MLS trace; at the
    default safety the three agree to 1 %."""
    coarse = _contact_safety_errors("nitsche")
    hats = _contact_safety_errors("nitsche-hat")
    pointwise = _contact_safety_errors("nitsche-pointwise")
    for norm in ("l2_rel", "h1_rel"):
        for flat in (hats, coarse):
            assert flat[norm].max() <= 1.1 * flat[norm].min(), (norm, flat)
            assert flat[norm][1] <= 1.01 * pointwise[norm][1], (norm, flat, pointwise)
    assert pointwise["l2_rel"][2] > 2 * pointwise["l2_rel"][1], pointwise


def test_coarse_contact_with_friction_runs_at_lambda_zero():
    """nu = 0 (lambda = 0): sigma_nu = 2 mu eps_nu has no u_x part, so the coarse law's
    Nitsche matrix lacks the (u_x, u_x) couplings that P brings into the tangential rows
    of the friction Jacobian.  The contact pattern must hold them (it did not: PETSc's
    "new nonzero caused a malloc" ended the run).  Square, m = 2, h = 1/8, T = 0.5, contact
    closed (measured: all 64 points at some step): the coarse law's errors (the default),
    and the hat law's (which couples a group's nodes too), equal the pointwise law's to
    1e-4 (measured L2 8.369e-4, H1 2.0195e-3 / 2.0196e-3)."""
    fixed = ["material.nu=0.0", "time.T=0.5", "discretization.h=0.125"]
    results = {}
    for method in ("nitsche-pointwise", "nitsche", "nitsche-hat"):
        sim, state = run("square", [*fixed, f"boundary.bottom.method={method}"])
        assert max(row["active_contact_points"] for row in sim.history) > 0
        results[method] = sim.errors(state.u, sim.scene.time.T)
    for norm in ("l2_rel", "h1_rel"):
        pointwise = results["nitsche-pointwise"][norm]
        for method in ("nitsche", "nitsche-hat"):
            assert abs(results[method][norm] - pointwise) <= 1e-4 * pointwise, results
