"""A run on a domain made part by part against the same scene meshed by gmsh on rank 0
(tests of parefg.geometry.grid_parts and patch_parts)."""

import pytest

from parefg.discretization import operators
from parefg.run import run_scene


def assert_answers_as_on_root(comm, scene, run_dir, monkeypatch, builder: str, bound: float):
    """Run ``scene`` as made part by part, then with ``operators.<builder>`` switched off
    (gmsh on rank 0, coordinate bisection): the same nodes and Newton iterations, errors
    below ``bound`` and equal to 1e-8."""
    by_parts = run_scene(comm, scene, out=str(run_dir / "parts"), quiet=True)
    monkeypatch.setattr(operators, builder, lambda comm, scene: None)
    on_root = run_scene(comm, scene, out=str(run_dir / "root"), quiet=True)
    assert by_parts["n_nodes"] == on_root["n_nodes"]
    assert by_parts["newton_iterations"] == on_root["newton_iterations"]
    for norm in ("l2_rel", "h1_rel"):
        assert 0 < on_root["errors"][norm] < bound
        assert by_parts["errors"][norm] == pytest.approx(on_root["errors"][norm], rel=1e-8, abs=0)
