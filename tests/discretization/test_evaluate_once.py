"""MLS is evaluated once per point set: what the build has already evaluated is reused.

The reused data must give the numbers of a fresh evaluation bit for bit: the domain's
shape gradients kept from the fill pass (error norms), the nodes' gradients evaluated
with their values (von Mises), the Dirichlet part's edge shape in the trace-inverse
estimate, and pass 1's neighbour lists in pass 2 of a one-block domain.
"""

import numpy as np
import pytest
from mpi4py import MPI

from parefg.discretization import domain_assembly
from parefg.discretization.mls import MLS
from parefg.discretization.operators import build_discretization
from parefg.discretization.point_gradients import PointGradients
from parefg.discretization.quadrature import segment_quadrature
from parefg.discretization.trace_inverse import nitsche_beta
from parefg.scene.loader import load_scene

SMALL = ["discretization.h=0.125", "discretization.degree=2"]


def _scene(*overrides):
    return load_scene("square", [*SMALL, *overrides])


def _wavy(disc):
    """A DOF vector without symmetry: u_k = sin(1 + 0.37 k) at global DOF k."""
    u = disc.create_vec()
    start, stop = u.getOwnershipRange()
    u.setArray(np.sin(1.0 + 0.37 * np.arange(start, stop)))
    return u


def test_domain_keeps_its_gradients_when_small_and_they_equal_fresh_ones(monkeypatch):
    comm = MPI.COMM_WORLD
    kept = build_discretization(comm, _scene())
    assert kept.domain.gradients.kept is not None  # from the fill pass, before any use
    monkeypatch.setattr(domain_assembly, "KEEP_GRADIENT_BYTES", 0)
    fresh = build_discretization(comm, _scene())
    assert fresh.domain.gradients.kept is None
    np.testing.assert_array_equal(
        kept.domain.evaluate_gradient(_wavy(kept)), fresh.domain.evaluate_gradient(_wavy(fresh))
    )


def test_kept_domain_gradients_are_bounded(monkeypatch):
    """A cloud whose padded gradients exceed KEEP_GRADIENT_BYTES keeps none."""
    comm = MPI.COMM_WORLD
    disc = build_discretization(comm, _scene())
    size = sum(nodes.nbytes + dphi.nbytes for nodes, dphi in disc.domain.gradients.kept)
    assert size <= domain_assembly.KEEP_GRADIENT_BYTES
    monkeypatch.setattr(domain_assembly, "KEEP_GRADIENT_BYTES", size - 1)
    assert build_discretization(comm, _scene()).domain.gradients.kept is None
    monkeypatch.setattr(domain_assembly, "KEEP_GRADIENT_BYTES", size)
    assert build_discretization(comm, _scene()).domain.gradients.kept is not None


def test_domain_of_several_blocks_keeps_gradients_that_equal_fresh_ones(monkeypatch):
    monkeypatch.setattr(domain_assembly, "BLOCK_POINTS", 37)
    disc = build_discretization(MPI.COMM_WORLD, _scene())
    assert len(disc.domain.gradients.kept) > 1
    fresh = PointGradients(disc.domain.gradients.mls, disc.domain.points, keep=False)
    u = _wavy(disc)
    np.testing.assert_array_equal(disc.domain.evaluate_gradient(u), fresh.evaluate(disc.comm, u))


@pytest.mark.parametrize("fields, kept", [("['u', 'von_mises']", True), ("['u']", False)])
def test_nodes_evaluate_gradients_with_their_values_only_for_von_mises(fields, kept):
    disc = build_discretization(MPI.COMM_WORLD, _scene(f"output.fields={fields}"))
    assert (disc.nodes.gradients.kept is not None) == kept
    fresh = PointGradients(disc.nodes.gradients.mls, disc.nodes.points, keep=False)
    u = _wavy(disc)
    np.testing.assert_array_equal(disc.nodes.evaluate_gradient(u), fresh.evaluate(disc.comm, u))


def test_one_block_domain_searches_its_neighbours_once(monkeypatch):
    calls = []
    search = MLS.find_neighbours

    def counted(self, points):
        calls.append(len(points))
        return search(self, points)

    monkeypatch.setattr(MLS, "find_neighbours", counted)
    scene = _scene()
    disc = build_discretization(MPI.COMM_WORLD, scene)
    n_domain = len(disc.domain.points)
    assert n_domain > 0 and calls.count(n_domain) == 1


def _beta_inputs():
    scene = _scene("boundary.top.method='nitsche'")
    disc = build_discretization(MPI.COMM_SELF, scene)
    cloud, settings = disc.cloud, scene.discretization
    mls = MLS(cloud.coords, settings.support * cloud.spacing, settings.degree, settings.weight)
    top = np.flatnonzero(cloud.segment_part == cloud.part_names.index("top"))
    rule = segment_quadrature(cloud.coords, cloud.segments, settings.quadrature, segment_ids=top)
    material = (settings.quadrature, scene.material.lam, scene.material.mu)
    return mls, cloud, top, rule, material


def test_nitsche_beta_from_the_callers_edge_shape_equals_its_own():
    mls, cloud, top, rule, material = _beta_inputs()
    own = nitsche_beta(mls, cloud, top, top, *material)
    shape = mls.evaluate(rule.points, gradients=True)
    reused = nitsche_beta(mls, cloud, top, top, *material, edge_values=(rule.points, shape))
    assert np.all(own > 0)
    np.testing.assert_array_equal(reused, own)


def test_nitsche_beta_ignores_an_edge_shape_of_other_points():
    mls, cloud, top, rule, material = _beta_inputs()
    own = nitsche_beta(mls, cloud, top, top, *material)
    shifted = rule.points + [0.0, -0.01]  # inside the square, not the Gauss points of top
    other = (shifted, mls.evaluate(shifted, gradients=True))
    np.testing.assert_array_equal(
        nitsche_beta(mls, cloud, top, top, *material, edge_values=other), own
    )
