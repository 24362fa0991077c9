"""In-process set-up and sweeps: ``parefg.run.prepare`` and ``parefg.sweep.run_cases``.

Scene "square" (the unit square) at h = 1/4: 5 x 5 = 25 nodes, 2 DOFs each.  Both
functions are collective; every test runs serially and under ``mpirun -n 2``.
"""

import json
from pathlib import Path

import numpy as np
import pytest
from mpi4py import MPI
from petsc4py import PETSc

from parefg.errors import InputError
from parefg.profiling import factorization_stats
from parefg.run import prepare, run_scene
from parefg.scene.loader import load_scene
from parefg.sweep import run_cases
from parefg.timestepping.loop import time_loop

TINY = ["discretization.h=0.25", "discretization.degree=1", "time.dt=0.25", "time.T=0.5"]


def test_prepare_applies_the_overrides(comm):
    sim = prepare(comm, "square", TINY)
    assert (sim.scene.discretization.h, sim.scene.time.dt, sim.scene.time.n_steps) == (
        0.25,
        0.25,
        2,
    )
    assert (sim.disc.n_nodes, sim.disc.n_dofs) == (25, 50)
    state = sim.start()
    state = time_loop(sim, state, 1)
    assert len(sim.history) == 3  # t = 0 and both steps
    assert sim.history[-1]["time"] == pytest.approx(0.5)


def test_prepare_keeps_only_the_last_row_when_asked(comm):
    sim = prepare(comm, "square", TINY, keep_history=False)
    state = sim.start()
    state = time_loop(sim, state, 1)
    assert len(sim.history) == 1 and sim.history[0]["time"] == pytest.approx(0.5)


def test_prepare_refuses_bad_input_on_every_rank(comm):
    with pytest.raises(InputError, match="discretization.h"):
        prepare(comm, "square", ["discretization.h=-1"])


def test_prepare_configures_the_solvers_with_the_scene_solver_table(comm):
    """As in `parefg run`: the step's KSP reads [solver], which is gone afterwards."""
    sim = prepare(comm, "square", [*TINY, "solver.ksp_type=cg", "solver.pc_type=jacobi"])
    assert sim.solver.snes.getKSP().getType() == "cg"
    assert not PETSc.Options().hasName("ksp_type")
    with pytest.raises(InputError, match="bogus"):
        prepare(comm, "square", [*TINY, "solver.ksp_type=bogus"])


def test_run_cases_runs_the_grid_in_order_and_prints_nothing(comm, tmp_path, capsys):
    out = comm.bcast(str(tmp_path / "sweep") if comm.rank == 0 else None, root=0)
    vary = ["discretization.h=0.25,0.125"]
    rows, out_dir = run_cases(comm, "square", vary, TINY[1:], out, progress=False)
    assert capsys.readouterr().out == ""
    assert [row["h"] for row in rows] == [0.25, 0.125]
    assert [row["discretization.h"] for row in rows] == ["0.25", "0.125"]
    assert [row["n_dofs"] for row in rows] == [50, 162]  # 5 x 5 and 9 x 9 nodes
    assert all(np.isfinite(row["l2_rel"]) and row["l2_rel"] > 0 for row in rows)
    assert out_dir == Path(out)
    if comm.rank == 0:
        for i, row in enumerate(rows):
            summary = json.loads((out_dir / f"case{i:03d}" / "summary.json").read_text())
            assert summary["errors"]["l2_rel"] == row["l2_rel"]


def test_summary_counts_the_factorizations_of_its_own_run_only(comm, tmp_path):
    """PETSc's log accumulates over the process: a second in-process run (a sweep's next
    case) must report its own factorization time, not the sum since the process began."""
    out = comm.bcast(str(tmp_path) if comm.rank == 0 else None, root=0)
    scene = load_scene("square", TINY)
    run_scene(comm, scene, out=f"{out}/first", quiet=True)  # factorizes: the log is not empty
    before = factorization_stats()[0]
    assert comm.allreduce(before, op=MPI.MIN) > 0
    summary = run_scene(comm, scene, out=f"{out}/second", quiet=True)
    own = comm.allreduce(factorization_stats()[0] - before, op=MPI.MAX)
    assert summary["timings"]["factorization"] == pytest.approx(own, rel=1e-12, abs=1e-12)
