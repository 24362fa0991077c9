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
from mpi4py import MPI
from scipy.spatial import cKDTree

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
    # each segment's cell as gmsh's whole mesh has it (the run makes the Z part by part,
    # patch_parts: its nodes numbered otherwise, placed to round-off)
    distance, gmsh_of = cKDTree(whole.coords).query(cloud.coords)
    assert distance.max() < 1e-9

    def by_segment(segments, corners) -> dict:
        def cell(c):  # a quad from its least corner (its Gauss points do not depend on
            # that), a triangle as listed (its collapsed rule's do)
            c = c[c >= 0]
            return tuple(np.roll(c, -int(np.argmin(c))) if len(c) == 4 else c)

        return {tuple(s): cell(c) for s, c in zip(segments, corners, strict=True)}

    mine = np.where(kept.corners >= 0, gmsh_of[kept.corners], -1)
    assert by_segment(gmsh_of[cloud.segments], mine) == (
        by_segment(whole.segments, boundary_cells(whole).corners)
    )
    for (a, b), corners in zip(cloud.segments, kept.corners, strict=True):
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


# -- a reference: B and A summed point by point, one segment at a time ---------------


def _reference_constants(mls, cloud, segment_ids, order, lam, mu) -> np.ndarray:
    """C_e segment by segment: B on the cell's nodes from its Gauss points, A from the
    edge's, then the largest eigenvalue on the range of B (numpy, one segment at a time)."""
    from parefg.discretization.quadrature import cell_quadrature, segment_quadrature
    from parefg.discretization.trace_inverse import (
        ESTIMATE_QUADRATURE,
        RANGE_THRESHOLD,
        segment_cells,
    )

    def dense(shape, row, nodes):
        out = np.zeros((len(nodes), 2))
        listed = shape.mask[row]
        out[np.searchsorted(nodes, shape.neighbours[row][listed])] = shape.dphi[row][listed]
        return out

    def strain(dphi):  # (n, 2) -> (3, 2 n): eps_xx, eps_yy, 2 eps_xy
        rows = np.zeros((3, len(dphi), 2))
        rows[0, :, 0], rows[1, :, 1] = dphi[:, 0], dphi[:, 1]
        rows[2, :, 0], rows[2, :, 1] = dphi[:, 1], dphi[:, 0]
        return rows.reshape(3, -1)

    elasticity = np.array([[lam + 2 * mu, lam, 0.0], [lam, lam + 2 * mu, 0.0], [0.0, 0.0, mu]])
    constants = []
    cell_order = max(order + 3, ESTIMATE_QUADRATURE)
    for segment in segment_ids:
        quads, triangles, _ = segment_cells(cloud).of(np.array([segment]))
        cell = cell_quadrature(cloud.coords, quads, triangles, cell_order)
        edge = segment_quadrature(cloud.coords, cloud.segments, order, segment_ids=[segment])
        cell_shape = mls.evaluate(cell.points, gradients=True)
        edge_shape = mls.evaluate(edge.points, gradients=True)
        nodes = np.unique(
            np.concatenate(
                [cell_shape.neighbours[cell_shape.mask], edge_shape.neighbours[edge_shape.mask]]
            )
        )
        b = sum(
            w
            * strain(dense(cell_shape, q, nodes)).T
            @ elasticity
            @ strain(dense(cell_shape, q, nodes))
            for q, w in enumerate(cell.weights)
        )
        a_rows = []
        for q, (w, (nx, ny)) in enumerate(zip(edge.weights, edge.normals, strict=True)):
            stress = elasticity @ strain(dense(edge_shape, q, nodes))  # xx, yy, xy
            a_rows += [np.sqrt(w) * (stress[0] * nx + stress[2] * ny)]
            a_rows += [np.sqrt(w) * (stress[2] * nx + stress[1] * ny)]
        a = np.array(a_rows).T @ np.array(a_rows)
        values, vectors = np.linalg.eigh(b)
        keep = values > RANGE_THRESHOLD * values[-1]
        inverse_root = vectors[:, keep] / np.sqrt(values[keep])
        constants.append(np.linalg.eigvalsh(inverse_root.T @ a @ inverse_root)[-1])
    return np.array(constants)


@pytest.mark.parametrize(
    "scene, settings",
    [
        ("square", ["discretization.degree=1", "discretization.h=0.125"]),
        ("square", ["discretization.degree=2", "discretization.h=0.125"]),
        ("square", ["discretization.degree=3", "discretization.h=0.125"]),
        (
            "square",
            ["discretization.degree=2", "discretization.cells=tri", "discretization.h=0.125"],
        ),
        ("z", ["discretization.degree=2", "discretization.h=0.125"]),
    ],
)
def test_constants_equal_a_pointwise_reference(scene, settings):
    """The estimate against the reference above (B and A summed point by point from
    MLS evaluated per segment), on every boundary segment this rank holds, to 1e-6
    relative.  The estimate is only as exact as the eigenvalues of B near the range
    threshold allow: mirror-image segments, equal in exact arithmetic, differ by up to
    1e-8, and the two summation orders by up to 7e-8 (measured)."""
    scene = load_scene(scene, settings)
    disc = build_discretization(COMM, scene)
    cloud = disc.cloud
    mls = _mls(scene, cloud)
    segments = np.arange(len(cloud.segments))
    order, lam, mu = scene.discretization.quadrature, scene.material.lam, scene.material.mu
    estimated = trace_inverse_constants(mls, cloud, segments, order, lam, mu)
    reference = _reference_constants(mls, cloud, segments, order, lam, mu)
    assert len(np.unique(np.round(reference, 6))) > 1  # not one constant for all
    np.testing.assert_allclose(estimated, reference, rtol=1e-6)
