"""The problem-size budget (SPEC 9): refuse what cannot fit before building it; gmsh never asks.

A scene whose estimated run exceeds the machine exits 2 within seconds with the estimate
in one line and nothing created, on 1 and 2 ranks; --max-memory moves the limit; the
estimate follows the meshes gmsh makes and the memory a run takes; gmsh never reads stdin.
CLI tests run the child under a 4 GB address-space limit, so that a regression fails
with MemoryError instead of exhausting the shared machine.
"""

import json
import os
import resource
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import PAREFG, REPO, mpi_env
from mpi4py import MPI
from petsc4py import PETSc

from parefg.discretization import aot
from parefg.discretization.budget import (
    CLOUD_SLACK,
    FLOOR_RANGE,
    GB,
    MEMORY_FRACTION,
    Budget,
    check_problem_size,
    cloud_size,
    estimate_scene,
    make_budget,
    memory_per_rank,
    unstructured_size,
    uses_direct_solver,
)
from parefg.discretization.mls import MLS
from parefg.discretization.quadrature import cell_quadrature
from parefg.errors import InputError
from parefg.geometry.gmsh_mesh import build_node_cloud
from parefg.scene.loader import load_scene

COMM = MPI.COMM_WORLD
ADDRESS_SPACE = 4 * 10**9  # bytes of virtual memory a refusing child may take
CLUSTERED_GEO = REPO / "meshes" / "clustered.geo"
# --set overrides the budget refuses, and what the message must quote
HUGE = {
    "h=1e-6": (["discretization.h=1e-6"], ["discretization.h = 1e-06", "1.0e+12 nodes"]),
    "h=1e-3": (["discretization.h=1e-3"], ["discretization.h = 0.001", "1.0e+06 nodes", "GB"]),
    "support=1e6": (
        ["discretization.h=0.015625", "discretization.support=1e6"],
        ["support = 1e+06", "about 4225 nodes", "about 4225 neighbours", "GB"],
    ),
}


def run_cli(args, ranks=1, limit_memory=True, timeout=120):
    """(CompletedProcess, seconds) of ``parefg ARGS``, its stdin a pipe nobody writes to.

    The write end stays open for the whole run, as in a pipeline whose producer waits:
    a child that reads stdin blocks until the timeout.
    """
    cmd = [PAREFG, *args]
    if ranks > 1:
        cmd = ["mpirun", "--timeout", str(timeout), "-n", str(ranks), *cmd]

    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (ADDRESS_SPACE, ADDRESS_SPACE))

    read_end, write_end = os.pipe()
    start = time.perf_counter()
    try:
        result = subprocess.run(
            cmd,
            stdin=read_end,
            capture_output=True,
            text=True,
            timeout=timeout,
            env=mpi_env(),
            preexec_fn=limit if limit_memory else None,
        )
    finally:
        os.close(read_end)
        os.close(write_end)
    return result, time.perf_counter() - start


def sets(overrides):
    return [arg for item in overrides for arg in ("--set", item)]


def refusal_line(result) -> str:
    """Exit 2 and exactly one `parefg: error:` line, no traceback; returns the line."""
    assert result.returncode == 2, (result.returncode, result.stderr[-2000:])
    assert "Traceback" not in result.stderr + result.stdout
    lines = [line for line in result.stderr.splitlines() if line.startswith("parefg: error:")]
    assert len(lines) == 1, result.stderr
    return lines[0]


# --------------------------------------------------------------------------- the CLI


@pytest.mark.serial_only
@pytest.mark.parametrize(
    "case, ranks", [("h=1e-6", 1), ("h=1e-3", 1), ("support=1e6", 1), ("h=1e-3", 2)]
)
def test_huge_scene_is_refused_quickly_and_creates_nothing(tmp_path, case, ranks):
    overrides, words = HUGE[case]
    out = tmp_path / "out"
    result, seconds = run_cli(["run", "square", *sets(overrides), "--out", str(out)], ranks)
    line = refusal_line(result)
    for word in words:
        assert word in line, (word, line)
    assert "--max-memory" in line or "32-bit indices" in line
    assert not out.exists()
    # the estimate takes microseconds: the time is Python's and PETSc's start-up, so it is
    # measured against a scene refused while loading (same ranks, same load on the machine);
    # meshing 1e6 nodes first would take minutes
    baseline, baseline_seconds = run_cli(["run", "square", "--set", "time.dt=-1"], ranks)
    assert baseline.returncode == 2, baseline.stderr[-2000:]
    assert seconds < 3 * baseline_seconds + 5, (seconds, baseline_seconds)


@pytest.mark.serial_only
def test_max_memory_lowers_and_raises_the_limit(tmp_path):
    """A normal scene (square, h = 1/64, m = 2) refused at 0.01 GB; 1e6 GB lets h = 1e-3 pass."""
    out = tmp_path / "out"
    args = ["run", "square", "--set", "discretization.h=0.015625", "--out", str(out)]
    line = refusal_line(run_cli([*args, "--max-memory", "0.01"])[0])
    assert "limit 0.01 GB: --max-memory" in line and "4225 nodes" in line
    assert not out.exists()
    # the same scene passes the default budget (in-process: the run itself is not needed)
    scene = load_scene("square", ["discretization.h=0.015625"])
    assert scene.discretization.degree == 2
    check_problem_size(COMM, scene)
    # and a huge one passes a huge --max-memory (then fails for lack of memory: not run)
    huge = load_scene("square", ["discretization.h=1e-3"])
    check_problem_size(COMM, huge, max_memory=1e6)


@pytest.mark.parametrize("value", [0.0, -1.0, float("nan"), float("inf")])
def test_max_memory_must_be_positive(value):
    with pytest.raises(InputError, match="--max-memory: must be a number of GB > 0"):
        check_problem_size(COMM, load_scene("square"), max_memory=value)


@pytest.mark.serial_only
def test_sweep_refuses_before_running_any_case(tmp_path):
    out = tmp_path / "sweep"
    result, _ = run_cli(
        ["sweep", "square", "--vary", "discretization.h=0.25,1e-4", "--out", str(out)]
    )
    assert "discretization.h = 0.0001" in refusal_line(result)
    assert not out.exists()


@pytest.mark.serial_only
@pytest.mark.parametrize("solver", ["direct", "iterative"])
def test_estimate_is_at_most_1_5_times_and_not_below_the_measured_peak(tmp_path, solver):
    """square, m = 2, h = 1/32, 2 steps: summary.json peak_rss_mb against memory_per_rank.

    scripts/bench/calibrate_budget.py measures m = 1, 2, direct and iterative, 1 and 2
    ranks, up to 1e6 DOFs; these are the cheapest of them.  Fails for an estimate that
    charges an iterative run the direct factor or the old per-point storage (> 1.5x), or
    that undercounts (< 0.9x).  stdin stays an unwritten pipe: a normal run never reads it.
    """
    overrides = [
        "discretization.h=0.03125",
        "time.T=0.1",
        "time.dt=0.05",
        f"solver.method={solver}",
    ]
    # The first run of a fresh checkout compiles the numba kernels (LLVM: ~80 MB at m = 2),
    # a one-off the estimate does not model: the second run is the one measured.
    for out in (tmp_path / "warm", tmp_path / "out"):
        result, _ = run_cli(
            ["run", "square", *sets(overrides), "--quiet", "--out", str(out)], limit_memory=False
        )
        assert result.returncode == 0, result.stderr
    measured = json.loads((out / "summary.json").read_text())["peak_rss_mb"] * 2**20
    scene = load_scene("square", overrides)
    jit = not aot.available()  # numba's JIT in the run: its share of the process
    estimated = memory_per_rank(estimate_scene(scene), 1, uses_direct_solver(scene), jit=jit)
    assert 0.9 < estimated / measured < 1.5, (estimated / 2**20, measured / 2**20)


def test_only_direct_solvers_are_charged_a_factor():
    """A 1e6-DOF m = 1 square (measured peak 10.5 GB with CG + GAMG) fits 16 GB iteratively.

    The direct run's factor (~ 9 GB more) does not fit; an LU preconditioner under the
    iterative method is charged it too.
    """
    base = ["discretization.degree=1", f"discretization.h={1 / 706!r}"]
    verdicts = {}
    for name, extra in {
        "iterative": ["solver.method=iterative"],
        "direct": ["solver.method=direct"],
        "iterative+lu": ["solver.method=iterative", "solver.pc_type=lu"],
    }.items():
        scene = load_scene("square", base + extra)
        budget = Budget(scene, 16e9, host_ranks=1, n_ranks=1, given=True)
        verdicts[name] = budget.refusal(estimate_scene(scene)) is None
    assert verdicts == {"iterative": True, "direct": False, "iterative+lu": False}


@pytest.mark.parametrize(
    "method, command_line, factors",
    [("iterative", "lu", True), ("iterative", "cholesky", True), ("direct", "gamg", False)],
)
def test_the_command_lines_pc_type_decides_whether_the_factor_is_charged(
    method, command_line, factors
):
    """`parefg run --solver iterative -pc_type lu` factors: the budget must count it.

    The command line's -pc_type (PETSc's options database) overrides the scene's method.
    """
    scene = load_scene("square", [f"solver.method={method}"])
    options = PETSc.Options()
    assert not options.hasName("pc_type")
    options["pc_type"] = command_line
    try:
        assert uses_direct_solver(scene) is factors
    finally:
        options.delValue("pc_type")
    assert uses_direct_solver(scene) is (method == "direct")


# --------------------------------------------------------------------------- gmsh and stdin

PROMPTING_MODEL = """
import gmsh
from parefg.geometry.gmsh_mesh import _gmsh_initialize

_gmsh_initialize(gmsh)
# point sizes 1e7 times below the model's size make gmsh ask "Do you really want to
# continue?" (TooManyElements); MeshSizeFromPoints = 0 keeps the mesh itself small
gmsh.option.setNumber("Mesh.MeshSizeFromPoints", 0)
gmsh.option.setNumber("Mesh.MeshSizeMax", 0.25)
points = [gmsh.model.geo.addPoint(x, y, 0, 1e-7) for x, y in ((0, 0), (1, 0), (1, 1), (0, 1))]
lines = [gmsh.model.geo.addLine(a, b) for a, b in zip(points, points[1:] + points[:1])]
gmsh.model.geo.addPlaneSurface([gmsh.model.geo.addCurveLoop(lines)])
gmsh.model.geo.synchronize()
gmsh.model.mesh.generate(2)
print("nodes", len(gmsh.model.mesh.getNodes()[0]))
gmsh.finalize()
"""


def run_python(code: str, timeout=60, **options):
    """The finished ``python -c CODE``; ``options`` as for subprocess.run (stdin, input, ...)."""
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        capture_output=True,
        timeout=timeout,
        **options,
    )


@pytest.mark.serial_only
def test_gmsh_never_asks_on_stdin():
    """The size question would block on a pipe that stays open (a pipeline's stdin)."""
    read_end, write_end = os.pipe()
    try:
        result = run_python(PROMPTING_MODEL, stdin=read_end)
    finally:
        os.close(read_end)
        os.close(write_end)
    assert result.returncode == 0, result.stderr
    assert b"continue?" not in result.stdout and b"nodes" in result.stdout


STDIN_DURING_MESHING = """
import os
from parefg.geometry.gmsh_mesh import _stdin_closed

with _stdin_closed():
    print("inside", os.read(0, 10))
print("after", os.read(0, 10) if os.environ.get("READ_AFTER") else "-")
"""


@pytest.mark.serial_only
def test_meshing_reads_dev_null_and_restores_stdin():
    """Inside the block fd 0 is /dev/null (end of file at once), afterwards the caller's again."""
    result = run_python(STDIN_DURING_MESHING, input=b"typed", env=dict(os.environ, READ_AFTER="1"))
    assert result.stdout.split(b"\n")[:2] == [b"inside b''", b"after b'typed'"], result
    # with fd 0 closed it stays closed, and nothing fails
    closed = run_python(STDIN_DURING_MESHING, preexec_fn=lambda: os.close(0))
    assert closed.returncode == 0 and b"inside b''" in closed.stdout, closed


# --------------------------------------------------------------------------- the estimate


def geo_domain(path: Path, parts: list[str]) -> list[str]:
    """--set overrides making a scene's domain the .geo file ``path`` with ``parts``."""
    return [
        'domain.shape="geo"',
        f'domain.file="{path}"',
        f"domain.parts={parts!r}".replace("'", '"'),
    ]


# The Z's outline as a user polygon, meshed unstructured (Frontal-Delaunay, Blossom for quads).
Z_AS_POLYGON = [
    'domain.shape="polygon"',
    "domain.vertices=[[0, 0], [1, 0], [1, 0.25], [0.4, 0.25], [1, 0.75], [1, 1], [0, 1], "
    "[0, 0.75], [0.6, 0.75], [0, 0.25]]",
    'domain.edge_names=["bottom", "sides", "sides", "sides", "sides", "top", "sides", "sides", '
    '"sides", "sides"]',
]


def actual_size(scene):
    """(nodes, cells, domain points, padded neighbours) of the run gmsh and MLS make."""
    cloud = build_node_cloud(COMM, scene.domain, scene.discretization.h, scene.discretization.cells)
    quadrature = cell_quadrature(
        cloud.coords, cloud.quads, cloud.triangles, scene.discretization.quadrature
    )
    mls = MLS(
        cloud.coords,
        scene.discretization.support * cloud.spacing,
        scene.discretization.degree,
        scene.discretization.weight,
    )
    neighbours, _ = mls.find_neighbours(quadrature.points)
    n_cells = len(cloud.quads) + len(cloud.triangles)
    return cloud, (cloud.n_nodes, n_cells, len(quadrature.points), neighbours.shape[1])


@pytest.mark.parametrize(
    "source, overrides, tolerance",
    [
        ("square", ["discretization.h=0.03125"], 0.0),  # a transfinite grid: exact counts
        ("square", ["discretization.h=0.03125", "discretization.cells='tri'"], 0.0),
        ("square", ['domain.shape="rectangle"', "domain.size=[2.0, 0.5]"], 0.0),
        ("z", ["discretization.h=0.02"], 0.0),  # transfinite patches: exact counts too
        ("z", ["discretization.h=0.02", "discretization.cells='tri'"], 0.0),
        ("z", [*Z_AS_POLYGON, "discretization.h=0.02"], 0.1),  # unstructured: within 10 %
        ("z", [*Z_AS_POLYGON, "discretization.h=0.02", "discretization.cells='tri'"], 0.1),
    ],
)
def test_estimate_follows_the_mesh(source, overrides, tolerance):
    scene = load_scene(source, overrides)
    size = estimate_scene(scene)
    cloud, (n_nodes, n_cells, n_points, n_max) = actual_size(scene)
    for estimated, actual in [
        (size.n_nodes, n_nodes),
        (size.n_cells, n_cells),
        (size.n_domain_points, n_points),
    ]:
        assert abs(estimated - actual) <= tolerance * actual, (estimated, actual)
    # the padded neighbour lists: an over- rather than an under-estimate
    assert n_max <= size.neighbours <= 1.3 * n_max, (size.neighbours, n_max)
    # the estimate from the cloud agrees with the one from the scene
    from_cloud = cloud_size(scene, cloud)
    assert abs(memory_per_rank(from_cloud, 1) / memory_per_rank(size, 1) - 1) < 0.1


@pytest.mark.parametrize("h", [0.3, 0.125, 0.1, 0.03125])
@pytest.mark.parametrize("cells", ["quad", "tri"])
@pytest.mark.parametrize("degree", [1, 3])
def test_z_counts_are_exact(h, cells, degree):
    """The Z's patch counts, also at a coarse h where its sides get m cells (min_cells)."""
    sets = [f"discretization.h={h}", f"discretization.cells='{cells}'"]
    scene = load_scene("z", [*sets, f"discretization.degree={degree}"])
    size = estimate_scene(scene)
    cloud = build_node_cloud(COMM, scene.domain, h, cells, min_cells=degree)
    assert size.n_nodes == cloud.n_nodes
    assert size.n_cells == len(cloud.quads) + len(cloud.triangles)
    assert size.n_boundary_points == len(cloud.segments) * scene.discretization.quadrature


@pytest.mark.parametrize("h, cells", [(0.0625, "quad"), (0.03125, "tri")])
def test_geo_that_fits_its_bounding_box_passes_both_checks(h, cells):
    """A .geo meshed at size h (no refinement) and exactly at its box's budget is not refused.

    The box bounds the area; the node count of gmsh's mesh varies by up to ~20 % about the
    estimate (plate_with_hole at h = 1/16: 706 nodes, 645 estimated), which CLOUD_SLACK absorbs.
    """
    plate = REPO / "meshes" / "plate_with_hole.geo"
    overrides = [f"discretization.h={h}", f"discretization.cells={cells!r}".replace("'", '"')]
    scene = load_scene("z", [*geo_domain(plate, ["bottom", "top", "sides"]), *overrides])
    assert estimate_scene(scene) is None  # known only once gmsh has read the file
    box = unstructured_size(scene, 2.0 * 1.0, 2 * (2.0 + 1.0))
    budget = Budget(scene, memory_per_rank(box, 1), host_ranks=1, n_ranks=1, given=True)
    cloud = build_node_cloud(
        COMM, scene.domain, scene.discretization.h, scene.discretization.cells, budget=budget
    )
    budget.check_cloud(COMM, cloud)
    assert abs(cloud.n_nodes / box.n_nodes - 1) < 0.2


def test_refusal_is_collective_and_names_the_estimate():
    """Every rank raises the same message (this file also runs under mpirun -n 2)."""
    scene = load_scene("square", ["discretization.h=1e-3"])
    with pytest.raises(InputError) as refused:
        check_problem_size(COMM, scene)
    messages = COMM.allgather(str(refused.value))
    assert len(set(messages)) == 1
    assert "scene square: discretization.h = 0.001 with support = 3.2 needs about" in messages[0]


def test_estimate_takes_microseconds():
    scene = load_scene("z", ["discretization.h=1e-5"])
    start = time.perf_counter()
    for _ in range(1000):
        estimate_scene(scene)
    assert time.perf_counter() - start < 1.0  # about 10 us each


@pytest.mark.parametrize("h", ["1e-300", "1e-160"])
def test_absurd_sizes_give_a_message_not_an_overflow(h):
    scene = load_scene("square", [f"discretization.h={h}"])
    with pytest.raises(InputError, match="more than 1e300 nodes .* 32-bit indices"):
        check_problem_size(COMM, scene)
    huge_polygon = load_scene(
        "square",
        [
            'domain.shape="polygon"',
            "domain.vertices=[[0, 0], [1e150, 0], [1e150, 1e150], [0, 1e150]]",
            'domain.edge_names=["bottom", "right", "top", "left"]',
        ],
    )
    with pytest.raises(InputError, match="nodes"):
        check_problem_size(COMM, huge_polygon)


def test_node_cloud_beyond_its_estimate_is_refused_before_mls(tmp_path_factory):
    """clustered.geo refines its mesh 4x near a point: more nodes than its bounding box says.

    A budget between the two estimates lets the .geo through gmsh and refuses the cloud.
    """
    parts = ["bottom", "right", "top", "left"]
    # 5 x 5 Gauss points (the default of m = 2 before issue 12; unstructured cells now take
    # 10 x 10, which raises the estimates above the modest budget this test means)
    sets = [
        *geo_domain(CLUSTERED_GEO, parts),
        "discretization.h=0.0125",  # the base does not dominate both estimates
        "discretization.quadrature=5",
    ]
    scene = load_scene("square", sets)
    cloud = build_node_cloud(COMM, scene.domain, scene.discretization.h, scene.discretization.cells)
    from_box = memory_per_rank(unstructured_size(scene, 1.0, 4.0), 1)
    from_cloud = memory_per_rank(cloud_size(scene, cloud), 1)
    assert from_cloud > 1.1 * CLOUD_SLACK * from_box  # the premise of the test
    limit = np.sqrt(from_box * from_cloud / CLOUD_SLACK)
    budget = Budget(scene, limit, host_ranks=1, n_ranks=1, given=True)
    budget.check_extent(1.0, 4.0)  # the bounding box fits
    with pytest.raises(InputError, match=f"meshed with about {cloud.n_nodes} nodes"):
        budget.check_cloud(COMM, cloud)
    assert limit / GB < 2  # a modest budget: nothing large was built
    # Meshed under that budget, gmsh clamps the cluster's h/4 to the budget's size floor:
    # fewer nodes, and the cloud fits (Budget.size_floor).
    floor = budget.size_floor(1.0, 4.0)
    assert scene.discretization.h / 4 < floor < scene.discretization.h
    coarser = build_node_cloud(
        COMM, scene.domain, scene.discretization.h, scene.discretization.cells, budget=budget
    )
    assert coarser.n_nodes < cloud.n_nodes
    budget.check_cloud(COMM, coarser)


def test_matrix_beyond_32_bit_indices_is_refused_whatever_the_memory():
    """1.6e8 DOFs fit PETSc's int32 indices, their 4e10 stiffness entries do not."""
    scene = load_scene("z", ["discretization.h=1e-4"])
    with pytest.raises(InputError, match="matrix entries per rank.*more ranks"):
        check_problem_size(COMM, scene, max_memory=1e9)


# --------------------------------------------------------------------------- .geo sizes

UNIT_SQUARE_GEO = """SetFactory("Built-in");
Point(1) = {0, 0, 0%s};
Point(2) = {1, 0, 0%s};
Point(3) = {1, 1, 0};
Point(4) = {0, 1, 0};
Line(1) = {1, 2};
Line(2) = {2, 3};
Line(3) = {3, 4};
Line(4) = {4, 1};
Curve Loop(1) = {1, 2, 3, 4};
Plane Surface(1) = {1};
Physical Curve("bottom") = {1};
Physical Curve("right") = {2};
Physical Curve("top") = {3};
Physical Curve("left") = {4};
"""
# .geo sizes far below h: on main, gmsh meshes at 1e-9 and aborts (std::bad_alloc) or
# exhausts the machine inside gmsh.model.mesh.generate
TINY_SIZES = {
    "MeshSize": ("", "MeshSize{1, 2} = 1e-9;"),
    "Characteristic Length": ("", "Characteristic Length{:} = 1e-9;"),
    "point size": (", 1e-9", ""),
    "Threshold": (
        "",
        "Field[1] = Distance; Field[1].PointsList = {1}; Field[2] = Threshold;"
        " Field[2].InField = 1; Field[2].SizeMin = 1e-9; Field[2].SizeMax = 0.1;"
        " Field[2].DistMin = 0.1; Field[2].DistMax = 0.5; Background Field = 2;",
    ),
    "MathEval": ("", 'Field[1] = MathEval; Field[1].F = "1e-9"; Background Field = 1;'),
    "Box": (
        "",
        "Field[1] = Box; Field[1].VIn = 1e-9; Field[1].VOut = 0.1; Field[1].XMax = 1;"
        " Field[1].YMax = 1; Field[1].ZMin = -1; Field[1].ZMax = 1; Background Field = 1;",
    ),
}
SQUARE_PARTS = ["bottom", "right", "top", "left"]

MESH_UNDER_BUDGET = """
import sys
from parefg.discretization.budget import Budget, GB
from parefg.geometry.gmsh_mesh import mesh_domain
from parefg.scene.loader import load_scene

scene = load_scene("square", sys.argv[1:])
budget = Budget(scene, 0.5 * GB, host_ranks=1, n_ranks=1, given=True)
print(mesh_domain(scene.domain, scene.discretization.h, scene.discretization.cells, budget).n_nodes)
"""


def write_geo(path: Path, point_size: str, extra: str) -> Path:
    path.write_text(UNIT_SQUARE_GEO % (point_size, point_size) + extra + "\n")
    return path


@pytest.mark.serial_only
@pytest.mark.parametrize("variant", sorted(TINY_SIZES))
def test_tiny_geo_sizes_mesh_within_the_budget(tmp_path, variant):
    """gmsh clamps every size to the budget's floor: the mesh stays at what the budget holds.

    The child meshes under a 4 GB address-space limit with a 0.5 GB budget; on the old code
    it died inside gmsh (std::bad_alloc, exit 134) or ran for minutes.
    """
    geo = write_geo(tmp_path / "tiny.geo", *TINY_SIZES[variant])
    overrides = [*geo_domain(geo, SQUARE_PARTS), "discretization.h=0.1"]

    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (ADDRESS_SPACE, ADDRESS_SPACE))

    start = time.perf_counter()
    result = subprocess.run(
        [sys.executable, "-c", MESH_UNDER_BUDGET, *overrides],
        capture_output=True,
        text=True,
        timeout=120,
        preexec_fn=limit,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    n_nodes = int(result.stdout)
    scene = load_scene("square", overrides)
    floor = Budget(scene, 0.5 * GB, host_ranks=1, n_ranks=1, given=True).size_floor(1.0, 4.0)
    at_floor = unstructured_size(scene, 1.0, 4.0, floor).n_nodes
    # no finer than the floor everywhere (the box at the floor holds the budget)
    assert 0.1**-2 < n_nodes <= CLOUD_SLACK * at_floor, (n_nodes, at_floor)
    assert time.perf_counter() - start < 60


@pytest.mark.serial_only
def test_tiny_geo_size_run_stays_in_budget_from_the_cli(tmp_path):
    """The whole run: meshed at the floor, the cloud fits, the run finishes (exit 0).

    Before, gmsh meshed at 1e-9 and died of std::bad_alloc beyond 4 GB.  Peak RSS is
    bounded loosely: a process that compiles the numba kernels (a cold cache, as on a
    fresh machine) peaks near 750 MB whatever the mesh, which the budget does not model.
    """
    geo = write_geo(tmp_path / "tiny.geo", *TINY_SIZES["MeshSize"])
    sets = [f"--set={item}" for item in [*geo_domain(geo, SQUARE_PARTS), "discretization.h=0.1"]]
    out = tmp_path / "out"
    args = ["run", "square", *sets, "--set=time.T=0.05", "--max-memory=0.6", "--quiet"]
    result, seconds = run_cli([*args, "--out", str(out)])
    assert result.returncode == 0, result.stderr[-2000:]
    summary = json.loads((out / "summary.json").read_text())
    scene = load_scene("square", [*geo_domain(geo, SQUARE_PARTS), "discretization.h=0.1"])
    floor = Budget(scene, 0.6 * GB, host_ranks=1, n_ranks=1, given=True).size_floor(1.0, 4.0)
    at_floor = unstructured_size(scene, 1.0, 4.0, floor).n_nodes
    assert 100 < summary["n_nodes"] <= CLOUD_SLACK * at_floor, (summary["n_nodes"], at_floor)
    assert summary["peak_rss_mb"] < 1500, summary["peak_rss_mb"]


@pytest.mark.parametrize(
    "source, name, parts, extent",
    [
        ("square", "clustered.geo", SQUARE_PARTS, (1.0, 4.0)),
        ("z", "plate_with_hole.geo", ["bottom", "top", "sides"], (2.0, 6.0)),
    ],
)
def test_size_floor_leaves_legitimate_refinement_alone(source, name, parts, extent):
    """With a budget that holds the box at the file's finest size, the floor changes nothing.

    clustered.geo refines to h/4 near a point: meshed under an 8 GB budget (floor < h/4)
    and without any, gmsh makes the very same mesh.
    """
    scene = load_scene(source, [*geo_domain(REPO / "meshes" / name, parts), "discretization.h=0.1"])
    budget = Budget(scene, 8 * GB, host_ranks=1, n_ranks=1, given=True)
    assert budget.size_floor(*extent) < scene.discretization.h / 4
    if COMM.rank == 0:  # meshing is rank 0's
        from parefg.geometry.gmsh_mesh import mesh_domain

        bounded = mesh_domain(
            scene.domain, scene.discretization.h, scene.discretization.cells, budget
        )
        free = mesh_domain(scene.domain, scene.discretization.h, scene.discretization.cells)
        assert bounded.n_nodes == free.n_nodes > 100
        np.testing.assert_array_equal(bounded.coords, free.coords)
        np.testing.assert_array_equal(bounded.quads, free.quads)
        np.testing.assert_array_equal(bounded.segments, free.segments)


@pytest.mark.serial_only
@pytest.mark.parametrize(
    "extra, line, why",
    [
        ("Transfinite Curve{1} = 1e12;", 16, "Transfinite Curves would put more than"),
        ("Transfinite Curve{1} = 1e5;", 16, "Transfinite Curves would put more than"),
        (
            "Transfinite Curve{1, 3} = 3e4; Transfinite Curve{2, 4} = 3e4; Transfinite Surface{1};",
            16,
            "Transfinite Curves would put more than 20000 nodes",
        ),
        (
            "n = 6000; Transfinite Curve{1, 2, 3, 4} = n; Transfinite Surface{1};",
            16,
            "Transfinite Curves would put more than 20000 nodes",
        ),
        (
            "Transfinite Curve{1, 3} = 2000; Transfinite Curve{2, 4} = 10; Transfinite Surface{1};",
            16,
            "Transfinite Surfaces of up to 2000 nodes a side may have more than 1000000",
        ),
    ],
)
def test_transfinite_counts_beyond_the_cap_are_refused(tmp_path, extra, line, why):
    """Transfinite counts ignore mesh sizes: the checker caps them (gmsh aborted at 1e5)."""
    geo = write_geo(tmp_path / "transfinite.geo", "", extra)
    sets = [f"--set={item}" for item in [*geo_domain(geo, SQUARE_PARTS), "discretization.h=0.1"]]
    result, seconds = run_cli(["run", "square", *sets, "--out", str(tmp_path / "out")])
    assert result.returncode == 2, result.stderr[-2000:]
    assert f"line {line}: {why}" in result.stderr
    assert len(result.stderr.splitlines()) == 1 and seconds < 30
    assert not (tmp_path / "out").exists()


def test_size_floor_does_not_move_with_the_free_memory(monkeypatch):
    """The floor budgets the machine's capacity, not its free memory: same mesh under any load.

    Before, the floor came from MemAvailable, so a .geo file with a refinement field was
    meshed with 3280 nodes in one run and 3774 in the next on the same machine.
    """
    import parefg.discretization.budget as budget_module

    scene = load_scene("square", ["discretization.h=0.1"])
    monkeypatch.setattr(budget_module, "machine_capacity", lambda: 4 * GB)
    floors, limits = [], []
    for free in (0.1 * GB, 1 * GB):
        monkeypatch.setattr(budget_module, "machine_memory", lambda free=free: free)
        budget = make_budget(COMM, scene)
        limits.append(budget.rank_bytes)
        floors.append(budget.size_floor(1.0, 4.0))
    assert limits[1] > 5 * limits[0]  # the run's own limit follows the free memory
    assert floors[0] == floors[1]
    assert scene.discretization.h * FLOOR_RANGE < floors[0] < scene.discretization.h  # binding
    # and the floor is the one of a budget holding that capacity
    n_host = COMM.Split_type(MPI.COMM_TYPE_SHARED)
    share = MEMORY_FRACTION * 4 * GB / n_host.size
    n_host.Free()
    fixed = Budget(scene, share, host_ranks=1, n_ranks=COMM.size, given=True)
    assert floors[0] == fixed.size_floor(1.0, 4.0)
