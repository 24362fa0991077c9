"""The trace-inverse estimate behind Nitsche's beta (parefg.discretization.trace_inverse).

C_e bounds ||sigma(v) n||^2_e by C_e a_{omega_e}(v, v) on the MLS space; Nitsche's K + D
is coercive for beta = safety x 2 C_e (cells with one Nitsche edge).  Checked here: the
estimate scales as E / h (a trace-inverse constant, not a fitted number), and it decides
coercivity from the right side: K + D is positive definite on the clamped square at
safety just above 1 and indefinite when beta is far below the bound.  Serial: dense
eigenvalues of the assembled matrices (the estimate itself is per segment, rank-local).
"""

import numpy as np
import pytest
from held_nodes import whole_array
from mpi4py import MPI

from parefg.discretization.dirichlet import DIRICHLET_METHODS, local_operators
from parefg.discretization.operators import build_discretization
from parefg.discretization.trace_inverse import trace_inverse_constants
from parefg.geometry.cloud import boundary_cells
from parefg.geometry.partition import partition_cloud
from parefg.scene.loader import load_scene

COMM = MPI.COMM_WORLD
serial = pytest.mark.skipif(COMM.size > 1, reason="dense serial matrices")


def _top_constants(h: float, degree: int, material=()) -> np.ndarray:
    scene = load_scene(
        "square", [f"discretization.h={h}", f"discretization.degree={degree}", *material]
    )
    disc = build_discretization(MPI.COMM_SELF, scene)
    cloud = disc.cloud
    segments = np.flatnonzero(cloud.segment_part == cloud.part_names.index("top"))
    mls = _mls(scene, cloud)
    return trace_inverse_constants(
        mls, cloud, segments, scene.discretization.quadrature, scene.material.lam, scene.material.mu
    )


def _mls(scene, cloud):
    from parefg.discretization.mls import MLS

    settings = scene.discretization
    return MLS(cloud.coords, settings.support * cloud.spacing, settings.degree, settings.weight,
               support_factor=settings.support)  # fmt: skip


@serial
@pytest.mark.parametrize("degree", [1, 2])
def test_constant_scales_as_young_modulus_over_h(degree):
    """On the uniform square grid C_e h is the same at h = 1/8 and 1/16, and C_e is
    proportional to E (A ~ E^2, B ~ E).  Measured C_e h / E: 4.6 .. 6.6 (m = 1),
    20 .. 38 (m = 2): the corner cells need the largest."""
    coarse, fine = _top_constants(1 / 8, degree), _top_constants(1 / 16, degree)
    np.testing.assert_allclose(
        [coarse.min() / 8, coarse.max() / 8], [fine.min() / 16, fine.max() / 16], rtol=1e-6
    )
    stiff = _top_constants(1 / 8, degree, ["material.E=10.0"])
    np.testing.assert_allclose(stiff, 10 * coarse, rtol=1e-6)
    assert 1.0 < coarse.min() / 8 < coarse.max() / 8 < 100.0


@pytest.mark.parametrize("cells", ["quad", "tri"])
def test_every_segment_bounds_exactly_one_cell(cells):
    """The cell kept for each segment (every rank, whatever it owns) has the segment as
    a counter-clockwise edge, and is the one cell of the whole mesh that does."""
    from parefg.geometry.gmsh_mesh import build_node_cloud

    scene = load_scene("z", ["discretization.h=0.25", f"discretization.cells='{cells}'"])
    cloud = build_discretization(COMM, scene).cloud
    whole = build_node_cloud(COMM, scene.domain, 0.25, cells, min_cells=scene.discretization.degree)
    whole = partition_cloud(whole, COMM.size)[0]
    kept = cloud.segment_cells
    assert kept is not None and np.all(kept.cell >= 0)
    kept_corners = whole_array(cloud.global_ids(), kept.corners)  # held positions -> global
    np.testing.assert_array_equal(kept_corners, boundary_cells(whole).corners)
    segments = whole_array(cloud.global_ids(), cloud.segments)
    np.testing.assert_array_equal(segments, whole.segments)
    for (a, b), corners in zip(segments, kept_corners, strict=True):
        corners = corners[corners >= 0]
        edges = set(zip(corners, np.roll(corners, -1), strict=True))
        assert (a, b) in edges
    every = [len(whole.quads), len(whole.triangles)]
    owned = [len(cloud.quads), len(cloud.triangles)]
    assert np.sum(COMM.allreduce(np.array(owned))) == sum(every)


def _smallest_eigenvalue(scale: float, method: str) -> float:
    """Smallest eigenvalue of K + D(scale x bound) on the square clamped on top (Nitsche)."""
    scene = load_scene("square", ["discretization.h=0.125", "discretization.degree=2",
                                  "boundary.top.safety=1.01",
                                  f'boundary.top.method="{method}"'])  # fmt: skip
    disc = build_discretization(MPI.COMM_SELF, scene)
    mls = _mls(scene, disc.cloud)
    total = disc.owned["stiffness"].toarray()
    for name in ("top",):
        points, part = disc.boundary[name], disc.dirichlet_parts[name]
        shape = mls.evaluate(points.points, gradients=True)
        beta = part.beta * scale / 1.01  # the bound 2 C_e n_c times scale
        matrix, _, _ = local_operators(
            DIRICHLET_METHODS[method],
            shape,
            points.weights,
            points.normals,
            beta,
            disc.n_nodes,
            scene.material.lam,
            scene.material.mu,
            part.projection,
        )
        total += matrix.toarray()
    return float(np.linalg.eigvalsh(total)[0])


@serial
@pytest.mark.parametrize("method", ["nitsche", "nitsche-pointwise"])
def test_the_bound_decides_coercivity(method):
    """K + D is positive definite at beta = 1.01 x the bound; far below it, indefinite.

    (A bound far above the critical beta would pass the first check only; a bound below
    it fails the first.)  K alone is singular (rigid motions): D must hold them.  The
    coarse trace's D (the default "nitsche") acts on projections, whose traction is no
    larger than the pointwise one, so the same per-segment bound (its group's largest)
    holds it.
    """
    assert _smallest_eigenvalue(1.01, method) > 0
    assert _smallest_eigenvalue(0.05, method) < 0
