"""Newton that checks its answer (SPEC 4): a step converges only when its residual meets the
SNES tolerances; the exact-piece shortcut only with an exact linear solve.

Scene: the square's manufactured sliding solution (SPEC 6), h = 1/8, m = 1, T = 0.2.
"""

import dataclasses

import numpy as np
import pytest
from mpi4py import MPI
from petsc4py import PETSc

from parefg.discretization.operators import build_discretization
from parefg.errors import InputError, SolverError
from parefg.run import prepare
from parefg.scene.loader import load_scene
from parefg.timestepping.loop import time_loop
from parefg.timestepping.simulation import Simulation

COMM = MPI.COMM_WORLD
SHORT = ["discretization.h=0.125", "discretization.degree=1", "time.T=0.2"]
NO_CONTACT = [*SHORT, 'boundary.bottom.type="neumann"']
# measured (square, h = 1/16, m = 2): the errors of a run solved to the residual tolerance
# rtol |b| differ from the direct solver's by about 3e4 rtol (3e-6 at rtol 1e-10)
ERROR_AMPLIFICATION = 1e6


@pytest.fixture
def petsc_options():
    """Set PETSc options for the solvers built inside the test; removed afterwards."""
    options, names = PETSc.Options(), []

    def put(values):
        for key, value in values.items():
            options.setValue(key, value)
            names.append(key)

    yield put
    for key in names:
        options.delValue(key)


def _simulation(overrides):
    return prepare(COMM, "square", overrides)


def _true_residual(solver, b, u) -> float:
    """|A_const u - b + contact forces(u)|, computed here from the law.  Collective."""
    residual = b.duplicate()
    solver.a_const.mult(u, residual)
    residual.axpy(-1.0, b)
    if getattr(solver, "law", None) is not None:
        solver.law.add_residual(residual, *solver.law.kinematics(u))
    return residual.norm()


def _record_residuals(sim, rtol: float):
    """Wrap the step solver: per accepted step, (|F(u_n)|, rtol max(|b|, |A u_0|))."""
    solve, log = sim.solver.solve, []

    def checked(b, u, t):
        work = b.duplicate()
        sim.solver.a_const.mult(u, work)
        scale = max(b.norm(), work.norm())
        result = solve(b, u, t)
        log.append((_true_residual(sim.solver, b, u), rtol * scale))
        return result

    sim.solver.solve = checked
    return log


def _run(sim):
    state = sim.start()
    state = time_loop(sim, state, 1)
    return sim.errors(state.u, sim.scene.time.T)


@pytest.fixture(scope="module")
def direct_errors():
    return {name: _run(_simulation(o)) for name, o in [("contact", SHORT), ("free", NO_CONTACT)]}


ITERATIVE = {
    "jacobi-rtol-1e-1": {"ksp_type": "cg", "pc_type": "jacobi", "ksp_rtol": "1e-1"},
    "gamg": {"ksp_type": "cg", "pc_type": "gamg"},
}


@pytest.mark.parametrize("case", ["contact", "free"])
@pytest.mark.parametrize("solver", sorted(ITERATIVE))
def test_iterative_solve_matches_the_direct_solver_or_fails(
    petsc_options, direct_errors, case, solver
):
    """CG + Jacobi (ksp_rtol 1e-1) and CG + GAMG: every accepted step meets the tolerance and
    the errors equal the direct solver's to ERROR_AMPLIFICATION * rtol -- or the run fails
    (SolverError, exit 1).  Jacobi must converge: the test cannot pass by failing only."""
    petsc_options(ITERATIVE[solver])
    sim = _simulation(SHORT if case == "contact" else NO_CONTACT)
    rtol = 1e-10  # the default SNES rtol (relative to max(|b|, |A u_0|))
    if case == "contact":
        assert sim.solver.snes.getTolerances()[0] == rtol
    log = _record_residuals(sim, rtol)
    try:
        errors = _run(sim)
    except SolverError:
        assert solver != "jacobi-rtol-1e-1"
        return
    residuals = np.array(log)  # (n_steps, 2): |F|, tolerance
    assert len(residuals) == sim.scene.time.n_steps
    assert np.all(residuals[:, 0] <= residuals[:, 1]), residuals
    for key in ("l2_rel", "h1_rel"):
        reference = direct_errors[case][key]
        assert errors[key] == pytest.approx(reference, rel=ERROR_AMPLIFICATION * rtol)


def test_direct_solver_steps_meet_the_tolerance():
    """The exact-piece shortcut of the direct solver ends at a residual below tolerance."""
    sim = _simulation(SHORT)
    log = _record_residuals(sim, 1e-10)
    _run(sim)
    residuals = np.array(log)
    assert len(residuals) == sim.scene.time.n_steps
    assert np.all(residuals[:, 0] <= residuals[:, 1]), residuals


def test_an_ascent_direction_fails_the_step():
    """A linear solve returning -J^-1 F (flipped here in front of the line search) is not
    a descent direction: the step fails with that message, whatever the KSP types say."""
    sim = _simulation(SHORT)
    line_search = sim.solver._exact_line_search

    def flipped(x, y):
        y.scale(-1.0)
        return line_search(x, y)

    sim.solver.snes.setLineSearchPreCheck(flipped)
    with pytest.raises(SolverError, match="not a descent direction"):
        _run(sim)


@pytest.mark.parametrize("kind", ["bt", "cp", "nleqerr"])
def test_other_line_search_types_give_the_basic_result(petsc_options, direct_errors, kind):
    """The pre-check computes A x - b itself, so bt/cp/nleqerr reach the same answer; on
    impact too, through closing and opening (final displacement compared)."""
    petsc_options({"snes_linesearch_type": kind})
    errors = _run(_simulation(SHORT))
    for key in ("l2_rel", "h1_rel"):
        assert errors[key] == pytest.approx(direct_errors["contact"][key], rel=1e-6)
    u = _impact_displacement()
    PETSc.Options().delValue("snes_linesearch_type")
    reference = _impact_displacement()
    u.axpy(-1.0, reference)
    assert u.norm() <= 1e-6 * reference.norm()


def _impact_displacement():
    sim = prepare(COMM, "impact", ["time.T=0.4"])
    state = sim.start()
    state = time_loop(sim, state, 1)
    return state.u.copy()


@pytest.mark.parametrize("kind", ["l2", "shell", "ncglinear"])
def test_unsupported_line_search_types_are_refused(petsc_options, kind):
    petsc_options({"snes_linesearch_type": kind})
    with pytest.raises(InputError, match=f"-snes_linesearch_type {kind}: not supported"):
        _simulation(SHORT)


def test_exactness_is_read_from_the_types_in_use(petsc_options):
    """Direct by default; -pc_type lu stays exact; Jacobi or a Krylov method is not."""
    assert _simulation(SHORT).solver.exact
    petsc_options({"pc_type": "lu"})
    assert _simulation(SHORT).solver.exact
    petsc_options({"pc_type": "jacobi"})
    assert not _simulation(SHORT).solver.exact
    petsc_options({"pc_type": "lu", "ksp_type": "gmres"})
    assert not _simulation(SHORT).solver.exact


def test_linear_path_refuses_an_answer_above_the_tolerance(petsc_options):
    """No Gamma_C: one application of Jacobi (preonly) is no solve; refinement does not reduce
    the residual, so the step fails instead of returning that answer."""
    petsc_options({"ksp_type": "preonly", "pc_type": "jacobi"})
    with pytest.raises(SolverError, match="above the step tolerance"):
        _run(_simulation(NO_CONTACT))


def test_an_exact_step_that_does_not_solve_the_jacobian_fails():
    """VCI's stiffness is nonsymmetric and factored by LU; factored by Cholesky (one triangle:
    another system) the exact-step shortcut would accept steps that
    do not solve the Jacobian.  The first accepted exact step of each factorization is
    checked, so the run fails with that message instead."""
    overrides = ["discretization.degree=3", 'discretization.integration="vci"',
                 "discretization.h=0.125", "time.dt=0.1", "time.T=0.3"]  # fmt: skip
    scene = load_scene("z", overrides)
    disc = build_discretization(COMM, scene)
    assert not disc.symmetric
    _run(Simulation(COMM, scene, disc))  # LU: the steps meet the tolerance
    cholesky = Simulation(COMM, scene, dataclasses.replace(disc, symmetric=True))
    with pytest.raises(SolverError, match="accepted as an exact solve"):
        _run(cholesky)


def test_a_symmetric_solver_on_the_nonsymmetric_stiffness_is_refused(petsc_options):
    """Options that reach the step solver past the scene loader (set in-process here; an
    options file alike) and assume symmetry are refused when K is VCI's nonsymmetric one,
    by the contact and the linear step solver; prepare() reads them and picks Gauss."""
    overrides = ["discretization.degree=3", "discretization.h=0.125", "time.T=0.1"]
    for steps in ([], ["boundary.bottom.type=neumann"]):  # contact, then linear steps
        scene = load_scene("square", [*overrides, *steps])  # no options yet: VCI
        disc = build_discretization(COMM, scene)
        assert not disc.symmetric
        refused = (
            {"pc_type": "cholesky"},
            {"ksp_type": "cg", "pc_type": "jacobi"},
            {"ksp_type": "gmres", "pc_type": "bjacobi", "sub_pc_type": "icc"},  # the blocks'
        )
        for options in refused:
            petsc_options(options)
            with pytest.raises(InputError, match="needs a symmetric matrix"):
                Simulation(COMM, scene, disc)
            chosen = prepare(COMM, "square", [*overrides, *steps]).scene.params
            assert chosen["discretization"]["integration"] == "gauss"
            for key in options:
                PETSc.Options().delValue(key)
        # block Jacobi with its default ILU blocks does not assume symmetry
        petsc_options({"ksp_type": "gmres", "pc_type": "bjacobi"})
        Simulation(COMM, scene, disc)
        for key in ("ksp_type", "pc_type"):
            PETSc.Options().delValue(key)
