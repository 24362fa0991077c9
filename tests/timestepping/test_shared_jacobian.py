"""A_const kept in the contact Jacobian's storage: the same run, one DOF matrix less.

From SHARED_JACOBIAN_BYTES per rank on, the contact Jacobian J = A_const + C takes A_const's
matrix as its storage and A_const keeps aside only its Gamma_C rows
(parefg.timestepping.shared_jacobian).  These tests force it on small clouds (threshold
0) and compare with the plain copy: scenes whose active set changes (the impact: open,
closed, sliding, open again), Coulomb's outer iterations, and A_const's products after a
Jacobian with contact terms was built.
"""

import numpy as np
import pytest
from mpi4py import MPI
from petsc4py import PETSc

from parefg.run import prepare
from parefg.scene.library import COULOMB_SLIDE
from parefg.timestepping import simulation
from parefg.timestepping.shared_jacobian import SharedConstant

COMM = MPI.COMM_WORLD
CASES = {
    "square": ("square", ["discretization.h=0.25", "time.dt=0.05", "time.T=0.2"]),
    # falls, closes, slides and rebounds: the Jacobian is rebuilt as the active set moves
    "impact": ("impact", ["discretization.h=0.2", "time.dt=0.02", "time.T=0.6"]),
    "coulomb": ("coulomb", ["discretization.h=0.25", "time.T=0.2"]),
}


@pytest.fixture(scope="module")
def coulomb_scene(tmp_path_factory):
    """The Coulomb block's scene file (rank 0's directory, shared by every rank)."""
    directory = COMM.bcast(str(tmp_path_factory.mktemp("shared")) if COMM.rank == 0 else None)
    path = f"{directory}/slide.toml"
    if COMM.rank == 0:
        with open(path, "w") as file:
            file.write(COULOMB_SLIDE)
    COMM.barrier()
    return path


def run(source, overrides, threshold, monkeypatch):
    """(simulation, final u, step history) of a short run with SHARED_JACOBIAN_BYTES set."""
    monkeypatch.setattr(simulation, "SHARED_JACOBIAN_BYTES", threshold)
    sim = prepare(COMM, source, overrides)
    state = sim.start()
    for n in range(1, sim.scene.time.n_steps + 1):
        state = sim.step(state, n)
    return sim, state.u.getArray(readonly=True).copy(), sim.history


@pytest.mark.parametrize("case", sorted(CASES))
def test_sharing_the_storage_changes_no_result(case, coulomb_scene, monkeypatch):
    source, overrides = CASES[case]
    source = coulomb_scene if source == "coulomb" else source
    plain, u_plain, rows_plain = run(source, overrides, 10**15, monkeypatch)
    shared, u_shared, rows_shared = run(source, overrides, 0, monkeypatch)
    assert not isinstance(plain.a_const, SharedConstant)
    assert isinstance(shared.a_const, SharedConstant)
    assert shared.solver.jacobian is shared.a_const.jacobian  # one matrix, not two
    assert shared.solver.jacobian_builds > 1  # the rows were written back at least once
    assert shared.solver.jacobian_builds == plain.solver.jacobian_builds
    # J = A_const + C and A_const x are the same sums as with a copy of A_const: the same
    # bits on this machine; asserted to round-off, as the products' kernels may differ
    scale = COMM.allreduce(float(np.abs(u_plain).max()), op=MPI.MAX)
    assert COMM.allreduce(float(np.abs(u_shared - u_plain).max()), op=MPI.MAX) <= 1e-12 * scale
    assert len(rows_shared) == len(rows_plain)
    for shared_row, plain_row in zip(rows_shared, rows_plain, strict=True):
        for key, value in plain_row.items():
            if isinstance(value, int):  # Newton and linear iterations, active points
                assert shared_row[key] == value, key
            else:  # energies and work: the stored energy's scale, round-off apart
                size = max(abs(v) for v in plain_row.values()) or 1.0
                assert abs(shared_row[key] - value) <= 1e-10 * size, key


def test_a_const_products_after_a_contact_jacobian(monkeypatch):
    """A_const x from the shared storage equals the product with A_const itself once J
    holds contact terms (which differ from A_const in the Gamma_C rows)."""
    source, overrides = CASES["impact"]
    monkeypatch.setattr(simulation, "SHARED_JACOBIAN_BYTES", 0)
    sim = prepare(COMM, source, overrides)
    original = sim.a_const.jacobian.duplicate(copy=True)  # A_const's values, before any step
    state = sim.start()
    x, _ = sim.a_const.createVecs()  # as a benchmark asks A_const for vectors
    start, stop = x.getOwnershipRange()
    x.setArray(np.sin(np.arange(start, stop) * 0.37))
    expected, product = original.createVecLeft(), original.createVecLeft()
    original.mult(x, expected)
    differs = False
    for n in range(1, sim.scene.time.n_steps + 1):
        state = sim.step(state, n)
        jacobian_product = original.createVecLeft()
        sim.solver.jacobian.mult(x, jacobian_product)
        jacobian_product.axpy(-1.0, expected)
        differs = differs or jacobian_product.norm() > 1e-8 * expected.norm()
        sim.a_const.mult(x, product)
        product.axpy(-1.0, expected)
        assert product.norm() <= 1e-14 * expected.norm()  # the same sums (bits, here)
    assert COMM.allreduce(differs, op=MPI.LOR)  # J held contact terms at some step
    assert sim.a_const.norm(PETSc.NormType.NORM_INFINITY) == pytest.approx(
        original.norm(PETSc.NormType.NORM_INFINITY), rel=1e-14
    )


def test_contact_rows_outside_the_gamma_c_rows_are_refused(monkeypatch):
    """A contact term in a row that was not kept aside would make A_const x wrong there:
    refused on every rank (one rank's bad row is enough)."""
    import scipy.sparse as sp

    monkeypatch.setattr(simulation, "SHARED_JACOBIAN_BYTES", 0)
    sim = prepare(COMM, *CASES["square"])
    shared = sim.a_const
    n_local = shared.jacobian.getLocalSize()[0]
    outside = np.setdiff1d(np.arange(n_local), shared.rows)
    assert COMM.allreduce(len(outside) > 0, op=MPI.LAND)  # the square's top rows are not
    rows = sp.lil_matrix((n_local, shared.jacobian.getSize()[1]))
    if COMM.rank == 0:
        start = shared.jacobian.getOwnershipRange()[0]
        rows[int(outside[0]), start + int(outside[0])] = 1.0
    with pytest.raises(RuntimeError, match="outside the Gamma_C pattern"):
        shared.set_jacobian(rows.tocsr())
