"""The scalable linear-solver path: rigid-body near-null space and CG + GAMG."""

import numpy as np
import pytest
from mpi4py import MPI
from petsc4py import PETSc

from parefg.run import prepare
from parefg.timestepping.loop import time_loop


def _simulation(overrides):
    comm = MPI.COMM_WORLD
    return prepare(comm, "square", overrides)


def test_rigid_body_modes_are_in_the_kernel_of_the_stiffness():
    """MLS reproduces linear fields, so K annihilates the 3 rigid modes given to GAMG."""
    sim = _simulation(["discretization.h=0.125"])
    modes = sim.a_const.getNearNullSpace().getVecs()
    assert len(modes) == 3
    stiffness = sim.disc.stiffness
    scale = stiffness.norm(PETSc.NormType.INFINITY)
    for mode in modes:
        image = stiffness.createVecLeft()
        stiffness.mult(mode, image)
        assert image.norm(PETSc.NormType.INFINITY) <= 1e-10 * scale * mode.norm(
            PETSc.NormType.INFINITY
        )
    # and they are not in the kernel of the mass matrix (the modes are not zero)
    mass_image = sim.disc.mass.createVecLeft()
    sim.disc.mass.mult(modes[0], mass_image)
    assert mass_image.norm() > 1e-3


@pytest.fixture
def gamg_options():
    options = PETSc.Options()
    values = {"ksp_type": "cg", "pc_type": "gamg", "ksp_rtol": "1e-10"}
    for key, value in values.items():
        options.setValue(key, value)
    yield
    for key in values:
        options.delValue(key)


def _errors(sim):
    state = sim.start()
    state = time_loop(sim, state, 1)
    return sim.errors(state.u, sim.scene.time.T)


def test_cg_gamg_reproduces_the_direct_solver(gamg_options):
    # the penalty clamp: CG + GAMG with these options stops with DIVERGED_INDEFINITE_PC on
    # the Nitsche clamp (K + D is SPD: smallest eigenvalue 1.5e-3; the GAMG setup is not)
    overrides = ["discretization.h=0.0625", "discretization.degree=1", "time.T=0.3",
                 "boundary.top.method=penalty"]  # fmt: skip
    iterative = _simulation(overrides)
    errors_iterative = _errors(iterative)
    assert iterative.solver.snes.getKSP().getPC().getType() == "gamg"
    PETSc.Options().delValue("pc_type")
    PETSc.Options().delValue("ksp_type")
    errors_direct = _errors(_simulation(overrides))
    for key in ("l2_rel", "h1_rel"):
        assert errors_iterative[key] == pytest.approx(errors_direct[key], rel=1e-6)
    assert np.isfinite(errors_iterative["h1_rel"])


def test_a_mumps_factorization_short_of_workspace_is_redone_with_more():
    """The mass matrix at m = 2, support 2.4, h = 1/64: on 2 ranks MUMPS's Cholesky (AMF
    ordering) ran out of the workspace its analysis estimated (INFOG(1) = -9 with the
    default ICNTL(14) = 20) and the run failed with "mass-matrix solve failed: KSP reason
    -11"; set_up_factored redoes it with ICNTL(14) doubled.  On 1 rank the first
    factorization succeeds.  Both: the initial projection succeeds and M u_0 = the
    projection's right-hand side."""
    sim = _simulation(
        ["discretization.h=0.015625", "discretization.degree=2", "discretization.support=2.4"]
        + ["time.T=0.05", 'initial.u=["0.01 * x * y", "0.0"]']
    )
    state = sim.start()  # the u_0, v_0 and a_0 projections: mass solves
    assert state.u.norm() > 0
    ksp = sim._mass_ksp
    assert ksp.getConvergedReason() > 0
    assert ksp.getPC().getFactorMatrix().getMumpsInfog(1) == 0


def test_a_contact_step_factorization_short_of_workspace_is_redone():
    """The contact steps factor their Jacobian inside SNES: with MUMPS's workspace
    relaxation ICNTL(14) = 0, a step's Cholesky on 2 ranks ran short (INFOG(1) = -9) and the
    run failed ("Newton failed at t = 0.05: ... DIVERGED_PCSETUP_FAILED").  The Jacobian
    callback sets the KSP up itself (set_up_factored), which redoes it with more.  On 1 rank
    the first factorization succeeds."""
    options = PETSc.Options()
    try:
        options.setValue("mat_mumps_icntl_14", 0)
        sim = _simulation(["discretization.h=0.03125", "time.T=0.1"])
        state = time_loop(sim, sim.start(), 1, [])
        assert sim.history[-1]["active_contact_points"] > 0
        assert np.isfinite(state.u.norm())
    finally:
        options.delValue("mat_mumps_icntl_14")
