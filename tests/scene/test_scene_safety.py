"""Scene names and polygons that used to escape runs/ or abort gmsh (SPEC 9).

A scene's name is the directory of its default output, runs/<name>: a name given
in the scene must be plain, and one taken from the file name is made plain.  A
polygon domain must be simple: gmsh aborts the process (SIGABRT, on every rank
count) on a self-intersecting curve loop, so the scene is refused at load with
the two edges that meet.
"""

import numpy as np
import pytest
from conftest import run_parefg
from mpi4py import MPI

from parefg.errors import InputError
from parefg.geometry.gmsh_mesh import build_node_cloud
from parefg.geometry.polygon import MAX_POLYGON_VERTICES, polygon_defect
from parefg.geometry.shapes import Z_VERTICES
from parefg.scene.loader import load_scene

COMM = MPI.COMM_WORLD
STATIC = '[time]\nscheme = "static"\nT = 1.0\ndt = 1.0\n\n[discretization]\nh = 0.25\n'
BOW_TIE = [[0, 0], [1, 1], [1, 0], [0, 1]]  # shoelace area 0
FIGURE_EIGHT = [[0, 0], [0, 1], [3, 0], [3, 3]]  # unequal loops: shoelace area +3


def polygon_scene(vertices) -> str:
    names = ", ".join(f'"e{i}"' for i in range(len(vertices)))
    return (
        f'[domain]\nshape = "polygon"\nvertices = {vertices}\nedge_names = [{names}]\n\n'
        f'{STATIC}\n[boundary.e0]\ntype = "dirichlet"\n'
    )


def write_scene(tmp_path, text: str, file_name: str = "scene.toml"):
    """The scene file in this process's own tmp_path (loading a scene is not collective)."""
    path = tmp_path / file_name
    path.write_text(text)
    return path


# ----------------------------------------------------------------------- names


@pytest.mark.parametrize(
    "name",
    ["/tmp/escape", "../../x", "..", ".", "a/b", ".hidden", "-rf", "a b", "x" * 101, "é", ""],
)
def test_scene_name_must_be_plain(tmp_path, name):
    path = write_scene(tmp_path, f"name = {name!r}\n{STATIC}".replace("'", '"'))
    with pytest.raises(InputError, match="name = .*must be a plain name"):
        load_scene(str(path))


@pytest.mark.parametrize("name", ["square", "run_2.b-3", "A" * 100, "_x"])
def test_plain_scene_names_are_kept(tmp_path, name):
    path = write_scene(tmp_path, f'name = "{name}"\n{STATIC}')
    assert load_scene(str(path)).name == name


@pytest.mark.parametrize(
    "file_name, name",
    [("my scene (v2).toml", "my_scene__v2_"), ("...toml", "scene"), ("-x.toml", "x")],
)
def test_name_from_the_file_name_is_made_plain(tmp_path, file_name, name):
    path = write_scene(tmp_path, STATIC, file_name)
    assert load_scene(str(path)).name == name


@pytest.mark.serial_only
@pytest.mark.parametrize("name", ["../../escaped", "/tmp/parefg-escaped-name"])
def test_cli_refuses_a_name_pointing_outside_runs(tmp_path, name):
    """exit 2, one line; nothing is created, inside the working directory or outside."""
    work = tmp_path / "a" / "b"
    work.mkdir(parents=True)
    (work / "scene.toml").write_text(f'name = "{name}"\n{STATIC}')
    result = run_parefg(["run", "scene.toml"], cwd=work, timeout=120)
    assert result.returncode == 2, (result.returncode, result.stderr)
    errors = [line for line in result.stderr.splitlines() if line.startswith("parefg: error:")]
    assert len(errors) == 1 and "plain name" in errors[0], result.stderr
    assert [p.name for p in work.iterdir()] == ["scene.toml"]
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["a", "b", "scene.toml"]
    assert not (work / name).resolve().exists()


# ----------------------------------------------------------------------- polygons


@pytest.mark.parametrize(
    "vertices, words",
    [
        (BOW_TIE, "edges 0 and 2 cross"),
        (FIGURE_EIGHT, "edges 1 and 3 cross"),
        ([[0, 0], [2, 0], [1, 0], [1, 1]], "edges 0 and 1 overlap"),
        ([[0, 0], [1, 0], [1, 1], [0.5, 0], [0, 1]], "edges 0 and 2 cross or touch"),
        ([[0, 0], [1, 0], [1, 0], [0, 1]], "edge 1 has zero length"),
        ([[0, 0], [2, 0], [2, 2], [1, 1], [0, 2], [1, 1]], "vertices 3 and 5 coincide"),
        (
            [[0, 0], [1, 0], [1 + 1e-13, 1], [1, 2], [1 + 1e-13, 1], [0, 2]],
            "vertices 2 and 4 coincide",
        ),
    ],
)
def test_polygon_that_is_not_simple_is_refused_at_load(tmp_path, vertices, words):
    path = write_scene(tmp_path, polygon_scene(vertices))
    with pytest.raises(InputError, match="domain.vertices = .*must be a simple polygon: " + words):
        load_scene(str(path))


def test_self_intersecting_polygon_never_reaches_gmsh():
    domain = {"shape": "polygon", "vertices": FIGURE_EIGHT, "edge_names": ["a"] * 4}
    with pytest.raises(InputError, match="edges 1 and 3 cross"):
        build_node_cloud(COMM, domain, 0.25)


def test_simple_polygons_pass():
    assert polygon_defect(Z_VERTICES) is None
    angles = np.linspace(0, 2 * np.pi, 2001)[:-1]
    assert polygon_defect(np.c_[np.cos(angles), np.sin(angles)]) is None
    # A thin comb: every edge spans the whole width (many candidate pairs), none meet.
    k = np.arange(2000)
    comb = np.vstack([np.c_[k % 2, k / 2000], [[1.5, 1.0], [1.5, -0.5], [-0.5, -0.5]]])
    assert polygon_defect(comb) is None
    # Almost touching, 1e-6 of the extent apart: still simple.
    assert polygon_defect([[0, 0], [2, 0], [2, 2], [1, 1e-6], [0, 2]]) is None
    assert "at most" in polygon_defect(np.zeros((MAX_POLYGON_VERTICES + 1, 2)))


@pytest.mark.serial_only
@pytest.mark.parametrize("ranks", [1, 2])
def test_cli_refuses_a_figure_eight_polygon_on_every_rank_count(tmp_path, ranks):
    """Was SIGABRT (exit 134) inside gmsh; now exit 2, one line, no output directory."""
    (tmp_path / "fig8.toml").write_text(polygon_scene(FIGURE_EIGHT))
    result = run_parefg(["run", "fig8.toml"], ranks=ranks, cwd=tmp_path, timeout=120)
    assert result.returncode == 2, (result.returncode, result.stderr[-500:])
    errors = [line for line in result.stderr.splitlines() if line.startswith("parefg: error:")]
    assert len(errors) == 1 and "edges 1 and 3 cross" in errors[0], result.stderr
    assert [p.name for p in tmp_path.iterdir()] == ["fig8.toml"]
