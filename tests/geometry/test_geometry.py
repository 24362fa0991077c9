"""Node clouds built by gmsh: areas, boundary parts, orientation, spacing, errors.

Expected values come from the domain definitions (areas and edge lengths by
hand or by the shoelace formula on the vertex list), never from parefg.
"""

import hashlib
import os

import numpy as np
import pytest
from conftest import REPO
from mpi4py import MPI

from parefg.errors import InputError
from parefg.geometry import gmsh_mesh
from parefg.geometry.cloud import orient_counter_clockwise
from parefg.geometry.gmsh_mesh import build_node_cloud

COMM = MPI.COMM_WORLD
PLATE_GEO = str(REPO / "meshes" / "plate_with_hole.geo")
PLATE_PARTS = ["bottom", "top", "sides", "hole"]
HOLE_CENTRE, HOLE_RADIUS = np.array([1.0, 0.5]), 0.25  # as written in plate_with_hole.geo
Z_POLYGON = np.array(
    [[0, 0], [1, 0], [1, 0.25], [0.4, 0.25], [1, 0.75], [1, 1], [0, 1], [0, 0.75], [0.6, 0.75],
     [0, 0.25]], dtype=float,
)  # fmt: skip
SQUARE = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=float)


def shoelace(polygons):
    """Signed areas of (..., n_corners, 2) polygons, written independently of parefg."""
    x, y = polygons[..., 0], polygons[..., 1]
    return 0.5 * np.sum(x * np.roll(y, -1, axis=-1) - np.roll(x, -1, axis=-1) * y, axis=-1)


def cell_areas(cloud):
    """(n_cells,) signed areas of all quads and triangles."""
    return np.concatenate(
        [shoelace(cloud.coords[cloud.quads]), shoelace(cloud.coords[cloud.triangles])]
    )


def part_lengths(cloud):
    """{part name: total length of its segments}."""
    ends = cloud.coords[cloud.segments]  # (n_segments, 2, 2)
    lengths = np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1)
    totals = np.bincount(cloud.segment_part, weights=lengths, minlength=len(cloud.part_names))
    return dict(zip(cloud.part_names, totals, strict=True))


def in_polygon(points, vertices, tol=1e-9):
    """(n_points,) True where a point is inside the polygon or within tol of its boundary."""
    on_edge, strictly_inside = polygon_relation(points, vertices, tol)
    return on_edge | strictly_inside


def polygon_relation(points, vertices, tol):
    """(on the boundary within tol, inside by the even-odd rule), each (n_points,)."""
    a, b = vertices, np.roll(vertices, -1, axis=0)  # (n_edges, 2) edge ends
    p = points[:, None, :]  # (n_points, 1, 2)
    t = np.clip(np.sum((p - a) * (b - a), axis=-1) / np.sum((b - a) ** 2, axis=-1), 0, 1)
    on_edge = np.linalg.norm(p - (a + t[..., None] * (b - a)), axis=-1).min(axis=1) <= tol
    # Even-odd rule with a horizontal ray to +x.
    straddles = (a[:, 1] > p[..., 1]) != (b[:, 1] > p[..., 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        x_cross = a[:, 0] + (p[..., 1] - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
    crossings = np.sum(straddles & (x_cross > p[..., 0]), axis=1)
    return on_edge, (crossings % 2 == 1) & ~on_edge


def plate_membership(hole_vertices):
    """Inside-or-on test of the plate (0,2) x (0,1) minus the given polygonal hole."""

    def inside(points, tol=1e-9):
        in_box = np.all((points >= -tol) & (points <= np.array([2, 1]) + tol), axis=1)
        return in_box & ~polygon_relation(points, hole_vertices, tol)[1]

    return inside


def outward_probes(cloud, eps=1e-6):
    """Points just outside and just inside each segment midpoint along its stated normal."""
    a, b = cloud.coords[cloud.segments[:, 0]], cloud.coords[cloud.segments[:, 1]]
    tangent = b - a
    normal = (
        np.stack([tangent[:, 1], -tangent[:, 0]], axis=1) / np.linalg.norm(tangent, axis=1)[:, None]
    )
    middle = 0.5 * (a + b)
    return middle + eps * normal, middle - eps * normal


@pytest.fixture(scope="module")
def square():
    return build_node_cloud(COMM, {"shape": "square"}, 1 / 8)


@pytest.fixture(scope="module")
def zcloud():
    return build_node_cloud(COMM, {"shape": "z"}, 0.05)


@pytest.fixture(scope="module")
def plate():
    return build_node_cloud(COMM, {"shape": "geo", "file": PLATE_GEO, "parts": PLATE_PARTS}, 0.1)


def check_common(cloud, inside):
    """Invariants of every cloud: CCW cells, no unused node, closed boundary, outward normals."""
    assert cloud.quads.dtype == cloud.triangles.dtype == cloud.segments.dtype == np.int64
    assert np.all(cell_areas(cloud) > 0)
    # Green: the boundary, oriented with the domain on the left, encloses the cells' area.
    a, b = cloud.coords[cloud.segments[:, 0]], cloud.coords[cloud.segments[:, 1]]
    enclosed = 0.5 * np.sum(a[:, 0] * b[:, 1] - b[:, 0] * a[:, 1])
    assert abs(enclosed - cell_areas(cloud).sum()) < 1e-12
    used = np.unique(np.concatenate([cloud.quads.ravel(), cloud.triangles.ravel()]))
    np.testing.assert_array_equal(used, np.arange(len(cloud.coords)))
    np.testing.assert_array_equal(cloud.original_index, np.arange(len(cloud.coords)))
    # A closed boundary: each boundary node starts one segment and ends one.
    np.testing.assert_array_equal(np.sort(cloud.segments[:, 0]), np.sort(cloud.segments[:, 1]))
    assert np.all(inside(cloud.coords))
    outside_probe, inside_probe = outward_probes(cloud)
    assert not np.any(inside(outside_probe, tol=0.0))
    assert np.all(inside(inside_probe, tol=0.0))


def test_square_is_a_regular_grid(square):
    """(0,1)^2 at h = 1/8: 9 x 9 nodes, 64 quads, spacing exactly h."""
    assert square.coords.shape == (81, 2) and square.quads.shape == (64, 4)
    assert square.triangles.shape == (0, 3)
    assert abs(cell_areas(square).sum() - 1.0) < 1e-13
    assert sorted(square.part_names) == ["bottom", "left", "right", "top"]
    for name, length in part_lengths(square).items():
        assert abs(length - 1.0) < 1e-13, name
    np.testing.assert_allclose(square.spacing, 1 / 8, rtol=0, atol=1e-12)
    check_common(square, lambda p, tol=1e-9: in_polygon(p, SQUARE, tol))


def test_square_parts_lie_on_their_edges(square):
    ends = square.coords[square.segments]  # (n_segments, 2, 2)
    expected = {"bottom": (1, 0.0), "right": (0, 1.0), "top": (1, 1.0), "left": (0, 0.0)}
    for part, name in enumerate(square.part_names):
        axis, value = expected[name]
        np.testing.assert_allclose(ends[square.segment_part == part][..., axis], value, atol=1e-14)


def test_rectangle_with_origin():
    """size [2, 0.5] at origin [1, 1], h = 0.1: 20 x 5 cells."""
    domain = {"shape": "rectangle", "size": [2.0, 0.5], "origin": [1.0, 1.0]}
    cloud = build_node_cloud(COMM, domain, 0.1)
    assert cloud.quads.shape == (100, 4)
    assert abs(cell_areas(cloud).sum() - 1.0) < 1e-12
    lengths = part_lengths(cloud)
    expected = {"bottom": 2.0, "top": 2.0, "left": 0.5, "right": 0.5}
    for name, length in expected.items():
        assert abs(lengths[name] - length) < 1e-12, name
    box = np.array([[1, 1], [3, 1], [3, 1.5], [1, 1.5]], dtype=float)
    check_common(cloud, lambda p, tol=1e-9: in_polygon(p, box, tol))


def test_z_domain(zcloud):
    area = shoelace(Z_POLYGON)
    assert area > 0
    assert abs(cell_areas(zcloud).sum() - area) < 1e-12
    perimeter = np.sum(np.linalg.norm(np.roll(Z_POLYGON, -1, axis=0) - Z_POLYGON, axis=1))
    lengths = part_lengths(zcloud)
    assert sorted(lengths) == ["bottom", "sides", "top"]
    assert abs(lengths["bottom"] - 1) < 1e-12 and abs(lengths["top"] - 1) < 1e-12
    assert abs(lengths["sides"] - (perimeter - 2)) < 1e-12
    assert np.all((zcloud.spacing >= 0.3 * 0.05) & (zcloud.spacing <= 2 * 0.05))
    check_common(zcloud, lambda p, tol=1e-9: in_polygon(p, Z_POLYGON, tol))


def z_patch_counts(h, min_cells=1):
    """(n_nodes, n_cells) of the Z's five transfinite patches, from their side lengths.

    Bottom-left 0.4 x 0.25, bottom-right 0.6 x 0.25, the parallelogram 0.4 x |(0.6, 0.5)|,
    top-left 0.6 x 0.25, top-right 0.4 x 0.25; ceil(L / h) cells along a side, at least min_cells.
    Four sides are shared (bottom-left with bottom-right and with the parallelogram, the
    parallelogram with top-right, top-left with top-right), and their nodes counted once.
    """
    lengths = (0.25, 0.4, 0.6, np.hypot(0.6, 0.5))
    n = {length: max(min_cells, int(np.ceil(length / h - 1e-9))) for length in lengths}
    sides = [(0.4, 0.25), (0.6, 0.25), (0.4, np.hypot(0.6, 0.5)), (0.6, 0.25), (0.4, 0.25)]
    cells = sum(n[a] * n[b] for a, b in sides)
    nodes = sum((n[a] + 1) * (n[b] + 1) for a, b in sides)
    shared = 2 * (n[0.25] + 1) + 2 * (n[0.4] + 1)
    return nodes - shared, cells


@pytest.mark.parametrize("h, min_cells", [(0.05, 1), (0.125, 1), (0.125, 3), (0.3, 1), (0.3, 2)])
def test_z_is_five_conforming_transfinite_patches(h, min_cells):
    """All quads (no recombination leftovers), as many as the patches hold, conforming
    (check_common: a hanging node would leave an interior boundary segment); min_cells
    (the MLS degree) raises the count of a coarse patch side, such as the 0.25-thick
    strips' 2 cells at h = 1/8."""
    cloud = build_node_cloud(COMM, {"shape": "z"}, h, min_cells=min_cells)
    n_nodes, n_cells = z_patch_counts(h, min_cells)
    assert cloud.coords.shape == (n_nodes, 2)
    assert cloud.quads.shape == (n_cells, 4) and cloud.triangles.shape == (0, 3)
    # The parallelogram's cells keep its angles: 90 degrees or its 39.8 / 140.2.
    corner = cloud.coords[np.roll(cloud.quads, 1, axis=1)] - cloud.coords[cloud.quads]
    other = cloud.coords[np.roll(cloud.quads, -1, axis=1)] - cloud.coords[cloud.quads]
    cosine = np.sum(corner * other, axis=2) / np.linalg.norm(corner, axis=2)
    cosine /= np.linalg.norm(other, axis=2)
    slant = 0.6 / np.hypot(0.6, 0.5)  # cos of the parallelogram's acute angle
    assert np.all(np.isclose(abs(cosine), 0, atol=1e-9) | np.isclose(abs(cosine), slant))
    check_common(cloud, lambda p, tol=1e-9: in_polygon(p, Z_POLYGON, tol))


@pytest.mark.parametrize("shape, polygon", [("square", SQUARE), ("z", Z_POLYGON)])
def test_triangle_cells(shape, polygon):
    cloud = build_node_cloud(COMM, {"shape": shape}, 0.1, cells="tri")
    assert cloud.quads.shape == (0, 4) and len(cloud.triangles) > 0
    if shape == "z":  # each transfinite quad split along its shorter diagonal
        assert len(cloud.triangles) == 2 * z_patch_counts(0.1)[1]
        sides = np.roll(cloud.coords[cloud.triangles], -1, axis=1) - cloud.coords[cloud.triangles]
        lengths = np.linalg.norm(sides, axis=2)  # (n_triangles, 3)
        squared = np.sort(lengths, axis=1) ** 2
        # No obtuse angle: the longest side^2 <= the sum of the other two's (a 90 degree tie).
        assert np.all(squared[:, 2] <= (squared[:, 0] + squared[:, 1]) * (1 + 1e-9))
    assert abs(cell_areas(cloud).sum() - shoelace(polygon)) < 1e-12
    check_common(cloud, lambda p, tol=1e-9: in_polygon(p, polygon, tol))


def test_polygon_equal_names_merge():
    """An L-shape whose three names cover six edges."""
    vertices = [[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]]
    names = ["base", "wall", "notch", "notch", "wall", "base"]
    cloud = build_node_cloud(
        COMM, {"shape": "polygon", "vertices": vertices, "edge_names": names}, 0.1
    )
    assert abs(cell_areas(cloud).sum() - 3.0) < 1e-12
    lengths = part_lengths(cloud)
    assert sorted(lengths) == ["base", "notch", "wall"]
    expected = {"base": 2 + 2, "wall": 1 + 1, "notch": 1 + 1}  # edges 0+5, 1+4, 2+3
    for name, length in expected.items():
        assert abs(lengths[name] - length) < 1e-12, name
    check_common(cloud, lambda p, tol=1e-9: in_polygon(p, np.array(vertices, float), tol))


def test_geo_plate_with_hole(plate):
    ends = plate.coords[plate.segments]  # (n_segments, 2, 2)
    hole_segments = ends[plate.segment_part == plate.part_names.index("hole")]
    a, b = hole_segments[:, 0], hole_segments[:, 1]
    # The hole's segments run clockwise around it (domain on their left): negative area.
    hole_polygon_area = -0.5 * np.sum(a[:, 0] * b[:, 1] - b[:, 0] * a[:, 1])
    assert 0.97 * np.pi * HOLE_RADIUS**2 < hole_polygon_area < np.pi * HOLE_RADIUS**2
    assert abs(cell_areas(plate).sum() - (2.0 - hole_polygon_area)) < 1e-12
    lengths = part_lengths(plate)
    assert abs(lengths["bottom"] - 2) < 1e-12 and abs(lengths["top"] - 2) < 1e-12
    assert abs(lengths["sides"] - 2) < 1e-12
    assert 0.99 * 2 * np.pi * HOLE_RADIUS < lengths["hole"] < 2 * np.pi * HOLE_RADIUS
    np.testing.assert_allclose(
        np.linalg.norm(a - HOLE_CENTRE, axis=1), HOLE_RADIUS, rtol=0, atol=1e-12
    )
    hole_vertices = a[np.argsort(np.arctan2(a[:, 1] - HOLE_CENTRE[1], a[:, 0] - HOLE_CENTRE[0]))]
    check_common(plate, plate_membership(hole_vertices))


def test_geo_unlisted_curves_are_free():
    domain = {"shape": "geo", "file": PLATE_GEO, "parts": ["bottom", "hole"]}
    cloud = build_node_cloud(COMM, domain, 0.1)
    assert cloud.part_names == ["bottom", "hole", "_free"]
    assert abs(part_lengths(cloud)["_free"] - 4.0) < 1e-12  # top and both sides


def cloud_digest(cloud):
    digest = hashlib.sha256()
    for array in (cloud.coords, cloud.spacing, cloud.quads, cloud.triangles, cloud.segments,
                  cloud.segment_part, cloud.original_index):  # fmt: skip
        digest.update(np.ascontiguousarray(array).tobytes())
    digest.update(repr(cloud.part_names).encode())
    return digest.hexdigest()


def test_every_rank_gets_the_same_cloud(zcloud, plate):
    for cloud in (zcloud, plate):
        digests = COMM.allgather(cloud_digest(cloud))
        assert len(set(digests)) == 1
        assert len(digests) == COMM.size


@pytest.mark.parametrize(
    "domain, message",
    [
        ({"shape": "geo", "file": "/nonexistent/plate.geo", "parts": ["a"]}, "cannot read"),
        ({"shape": "geo", "file": PLATE_GEO, "parts": ["bottom", "rim"]}, "rim"),
        ({"shape": "polygon", "vertices": [[0, 0], [0, 1], [1, 0]], "edge_names": ["a"] * 3},
         "counter-clockwise"),
        ({"shape": "polygon", "vertices": [[0, 0], [1, 0], [0, 1]], "edge_names": ["a"]},
         "edge_names"),
        ({"shape": "torus"}, "torus"),
    ],
)  # fmt: skip
def test_bad_domains_raise_input_error_on_every_rank(domain, message):
    with pytest.raises(InputError, match=message):
        build_node_cloud(COMM, domain, 0.1)


def test_malformed_geo_raises_input_error(tmp_path_factory):
    path = write_geo_on_root(
        tmp_path_factory, "Point(1) = {0, 0, 0};\nLine(1) = {1, undefined_point};\n"
    )
    with pytest.raises(InputError, match="gmsh"):
        build_node_cloud(COMM, {"shape": "geo", "file": path, "parts": []}, 0.1)


def test_bad_h_and_cells():
    with pytest.raises(InputError, match="h"):
        build_node_cloud(COMM, {"shape": "square"}, -0.1)
    with pytest.raises(InputError, match="cells"):
        build_node_cloud(COMM, {"shape": "square"}, 0.1, cells="hex")


def write_geo_on_root(tmp_path_factory, text):
    """Path of a .geo file written by rank 0 (only rank 0 reads it), same on every rank."""
    path = None
    if COMM.rank == 0:
        path = tmp_path_factory.mktemp("geo") / "domain.geo"
        path.write_text(text)
    return COMM.bcast(str(path) if path else None)


def test_clockwise_geo_surface_gives_counter_clockwise_cells(tmp_path_factory):
    """A unit square whose curve loop runs clockwise: gmsh meshes it clockwise."""
    path = write_geo_on_root(
        tmp_path_factory,
        "Point(1) = {0, 0, 0}; Point(2) = {1, 0, 0}; Point(3) = {1, 1, 0}; Point(4) = {0, 1, 0};\n"
        "Line(1) = {1, 2}; Line(2) = {2, 3}; Line(3) = {3, 4}; Line(4) = {4, 1};\n"
        "Curve Loop(1) = {-4, -3, -2, -1}; Plane Surface(1) = {1};\n"
        'Physical Curve("bottom") = {1}; Physical Curve("rest") = {2, 3, 4};\n',
    )
    for cells in ("quad", "tri"):
        cloud = build_node_cloud(
            COMM, {"shape": "geo", "file": path, "parts": ["bottom", "rest"]}, 0.2, cells
        )
        assert abs(part_lengths(cloud)["rest"] - 3.0) < 1e-12
        check_common(cloud, lambda p, tol=1e-9: in_polygon(p, SQUARE, tol))


def test_degenerate_cell_is_an_input_error():
    coords = np.array([[0, 0], [1, 0], [2, 0], [0, 1]], dtype=float)
    with pytest.raises(InputError, match="degenerate"):
        orient_counter_clockwise(coords, np.array([[0, 1, 2]]))
    flipped = orient_counter_clockwise(coords, np.array([[0, 3, 1], [0, 1, 3]]))
    np.testing.assert_array_equal(flipped, [[1, 3, 0], [0, 1, 3]])


def test_meshing_writes_nothing_into_home(tmp_path_factory, monkeypatch):
    """gmsh's FLTK layer writes ~/.fltk/fltk.org/fltk.prefs at start-up: meshing runs with a
    private HOME, so the user's home (here a fresh directory) stays empty and HOME is
    restored afterwards; the user cache is opt-in, so by default nothing lands in
    ~/.cache either."""
    home = tmp_path_factory.mktemp("home")
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.delenv("XDG_CACHE_HOME", raising=False)
    monkeypatch.delenv("PAREFG_CACHE", raising=False)
    monkeypatch.delenv("PAREFG_CACHE_DIR", raising=False)
    build_node_cloud(MPI.COMM_WORLD, {"shape": "square"}, 0.5)
    assert list(home.iterdir()) == []
    assert os.environ["HOME"] == str(home)


def smallest_angles(cloud):
    """(n_cells,) the smallest interior angle of each cell, degrees (independent of parefg)."""
    angles = []
    for cells in (cloud.quads, cloud.triangles):
        corners = cloud.coords[cells]  # (n_cells, n_corners, 2)
        before = np.roll(corners, 1, axis=1) - corners
        after = np.roll(corners, -1, axis=1) - corners
        cosine = np.sum(before * after, axis=2)
        cosine /= np.linalg.norm(before, axis=2) * np.linalg.norm(after, axis=2)
        angles.append(np.degrees(np.arccos(np.clip(cosine, -1, 1))).min(axis=1))
    return np.concatenate(angles)


@pytest.mark.parametrize("cells", ["tri", "quad"])
def test_a_large_unstructured_cloud_is_a_split_coarser_mesh(cells, monkeypatch):
    """Above gmsh_mesh.DIRECT_NODES estimated nodes (lowered here to 300) the plate is meshed
    at 2^k h and split k times: the same spacing and node count as meshing at h (within
    20 %), the same cell type, the hole's nodes on the circle, angles nearly as good, and
    every invariant of a cloud.  Measured: triangles 1000 nodes against 956, smallest angle
    35.6 against 39.3 degrees; quads 988 against 928, 46.1 against 48.0."""
    domain = {"shape": "geo", "file": PLATE_GEO, "parts": PLATE_PARTS}
    counts = []
    generate = gmsh_mesh.generate
    monkeypatch.setattr(gmsh_mesh, "generate", lambda *a: counts.append(generate(*a)) or 0)
    direct = gmsh_mesh.mesh_domain(domain, 0.05, cells)
    monkeypatch.setattr(gmsh_mesh, "DIRECT_NODES", 300)  # estimate 1.16 x 2 / 0.05^2 = 928
    split = gmsh_mesh.mesh_domain(domain, 0.05, cells)
    assert counts == [0, 1]
    assert 0.8 < split.n_nodes / direct.n_nodes < 1.2, (split.n_nodes, direct.n_nodes)
    assert np.median(split.spacing) == pytest.approx(np.median(direct.spacing), rel=0.2)
    assert (len(split.quads) > 0) == (cells == "quad") and (len(split.triangles) > 0) == (
        cells == "tri"
    )
    assert smallest_angles(split).min() >= 0.8 * smallest_angles(direct).min()
    hole = split.coords[split.segments[split.segment_part == split.part_names.index("hole")]]
    np.testing.assert_allclose(
        np.linalg.norm(hole - HOLE_CENTRE, axis=2), HOLE_RADIUS, rtol=0, atol=1e-12
    )
    assert part_lengths(split)["bottom"] == pytest.approx(2.0, abs=1e-12)
    a = hole[:, 0]
    hole_vertices = a[np.argsort(np.arctan2(a[:, 1] - HOLE_CENTRE[1], a[:, 0] - HOLE_CENTRE[0]))]
    check_common(split, plate_membership(hole_vertices))


SMALL_HOLE_GEO = """SetFactory("Built-in");
Point(1) = {0, 0, 0}; Point(2) = {1, 0, 0}; Point(3) = {1, 1, 0}; Point(4) = {0, 1, 0};
Line(1) = {1, 2}; Line(2) = {2, 3}; Line(3) = {3, 4}; Line(4) = {4, 1};
Point(5) = {0.5, 0.5, 0}; Point(6) = {0.51, 0.5, 0}; Point(7) = {0.5, 0.51, 0};
Point(8) = {0.49, 0.5, 0}; Point(9) = {0.5, 0.49, 0};
Circle(5) = {6, 5, 7}; Circle(6) = {7, 5, 8}; Circle(7) = {8, 5, 9}; Circle(8) = {9, 5, 6};
Curve Loop(1) = {1, 2, 3, 4}; Curve Loop(2) = {5, 6, 7, 8};
Plane Surface(1) = {1, 2};
Physical Curve("bottom") = {1}; Physical Curve("rest") = {2, 3, 4};
Physical Curve("hole") = {5, 6, 7, 8};
"""
TRANSFINITE_GEO = """SetFactory("Built-in");
Point(1) = {0, 0, 0}; Point(2) = {1, 0, 0}; Point(3) = {1, 1, 0}; Point(4) = {0, 1, 0};
Line(1) = {1, 2}; Line(2) = {2, 3}; Line(3) = {3, 4}; Line(4) = {4, 1};
Curve Loop(1) = {1, 2, 3, 4}; Plane Surface(1) = {1};
Transfinite Curve {1, 2, 3, 4} = 21;
Physical Curve("bottom") = {1}; Physical Curve("rest") = {2, 3, 4};
"""


@pytest.mark.parametrize(
    "text, parts, h",
    [
        (SMALL_HOLE_GEO, ["bottom", "rest", "hole"], 0.02),
        (TRANSFINITE_GEO, ["bottom", "rest"], 0.01),
    ],
    ids=["small hole", "transfinite curves"],
)
def test_curves_that_do_not_scale_are_not_split(text, parts, h, tmp_path, monkeypatch):
    """A curve whose segment count does not follow the sizes (a hole of radius h / 2 at
    gmsh's minimum points per circle; a .geo's Transfinite Curve) would be split into 2^k
    times its count: the split is refused (k = 0) and the cloud is the one meshed at h.
    Measured before the check, hole of radius 0.01 at h = 0.02: 8104 nodes against 4494,
    smallest angle 21 against 38 degrees."""
    path = tmp_path / "domain.geo"
    path.write_text(text)
    domain = {"shape": "geo", "file": str(path), "parts": parts}
    direct = gmsh_mesh.mesh_domain(domain, h, "tri")
    counts = []
    generate = gmsh_mesh.generate
    monkeypatch.setattr(gmsh_mesh, "generate", lambda *a: counts.append(generate(*a)) or 0)
    monkeypatch.setattr(gmsh_mesh, "DIRECT_NODES", 300)  # the estimate asks for k >= 1
    checked = gmsh_mesh.mesh_domain(domain, h, "tri")
    assert counts == [0]
    np.testing.assert_array_equal(checked.coords, direct.coords)
    np.testing.assert_array_equal(checked.triangles, direct.triangles)
