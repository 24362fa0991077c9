"""Untrusted .geo files (SPEC 9): only the geometry subset reaches gmsh.

Every statement of gmsh's language that runs a program, touches a file, reads the
environment, ends the process or loops without bound is refused with exit 2 /
InputError naming the line and the statement, before gmsh runs: the side effect
it attempts (a SENTINEL file) never happens.  The accepted subset meshes exactly
as gmsh meshes the original file, and the checker's loop counts are gmsh's.
"""

import os
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO, run_parefg
from hypothesis import given, settings
from hypothesis import strategies as st
from mpi4py import MPI

from parefg.errors import InputError
from parefg.geometry import gmsh_mesh, shapes
from parefg.geometry.geo import MAX_GEO_BYTES, load_geo, sanitize_geo
from parefg.geometry.geo.bounds import run_program
from parefg.geometry.geo.statements import StatementParser
from parefg.geometry.geo.tokens import tokenize
from parefg.geometry.gmsh_mesh import build_node_cloud

COMM = MPI.COMM_WORLD
SQUARE = (
    'SetFactory("Built-in");\n'
    "Point(1) = {0, 0, 0}; Point(2) = {1, 0, 0}; Point(3) = {1, 1, 0}; Point(4) = {0, 1, 0};\n"
    "Line(1) = {1, 2}; Line(2) = {2, 3}; Line(3) = {3, 4}; Line(4) = {4, 1};\n"
    "Curve Loop(1) = {1, 2, 3, 4}; Plane Surface(1) = {1};\n"
    'Physical Curve("bottom") = {1}; Physical Curve("rest") = {2, 3, 4};\n'
    'Physical Surface("square") = {1};\n'
)  # the hostile statement goes on line 7
PARTS = ["bottom", "rest"]
#: statement (SENTINEL = an absolute path it tries to create) -> word the message names
SIDE_EFFECTS = {
    "System": ('System "touch SENTINEL";', "System"),
    "SystemCall": ('SystemCall "touch SENTINEL";', "SystemCall"),
    "NonBlockingSystemCall": ('NonBlockingSystemCall "touch SENTINEL";', "NonBlockingSystemCall"),
    "OnelabRun": ('OnelabRun("client", "SCRIPT");', "OnelabRun"),
    "OnelabRun string": ('OnelabRun "SCRIPT";', "OnelabRun"),
    "Printf > file": ('Printf("owned") > "SENTINEL";', "Printf"),
    "Printf >> file": ('Printf("owned") >> "SENTINEL";', "Printf"),
    "Print": ('Print "SENTINEL.msh";', "Print"),
    "Save": ('Save "SENTINEL.msh";', "Save"),
    "CreateDir": ('CreateDir "SENTINEL";', "CreateDir"),
    "Include": ('Include "EVIL";', "Include"),
    "Merge": ('Merge "EVIL";', "Merge"),
    "MergeWithBoundingBox": ('MergeWithBoundingBox "EVIL";', "MergeWithBoundingBox"),
    "string hides EndIf in a false If": (
        "If (0) Physical Curve(\"x EndIf System 'touch SENTINEL'; \") = {1}; EndIf",
        "EndIf",
    ),
}
#: statements with no file to watch (or fatal to an in-process gmsh) -> word the message names
REFUSED = {
    "Exit": ("Exit;", "Exit"),
    "Abort": ("Abort;", "Abort"),
    "Sleep": ("Sleep 30;", "Sleep"),
    "Delete Model": ("Delete Model;", "Delete"),
    "Delete Physicals": ("Delete Physicals;", "Delete"),
    "Delete entities": ("Delete { Surface{1}; }", "Delete"),
    "Mesh": ("Mesh 2;", "Mesh"),
    "RefineMesh": ("RefineMesh;", "RefineMesh"),
    "Coherence Mesh": ("Coherence Mesh;", "Coherence"),
    "SetName": ('SetName "x";', "SetName"),
    "Plugin": ("Plugin(NewView).Run;", "Plugin"),
    "View": ('View "v" { SP(0, 0, 0){1}; };', "View"),
    "Draw": ("Draw;", "Draw"),
    "SendToServer": ('SendToServer View[0] "x";', "SendToServer"),
    "Macro": ('Macro m System "touch x"; Return', "Macro"),
    "Function": ("Function f x = 1; Return", "Function"),
    "Call": ("Call m;", "Call"),
    "GetEnv": ('x = StrLen(GetEnv("HOME"));', "StrLen"),
    "GetValue prompt": ('x = GetValue("size?", 1);', "GetValue"),
    "GetNumber": ('x = GetNumber("Gmsh/size");', "GetNumber"),
    "FileExists": ('x = FileExists("/etc/passwd");', "FileExists"),
    "DefineConstant": ("DefineConstant[ x = 1 ];", "DefineConstant"),
    "ShapeFromFile": ('v() = ShapeFromFile("/etc/hostname");', "ShapeFromFile"),
    "ListFromFile": ('a[] = ListFromFile("/etc/hostname");', "ListFromFile"),
    "Field ExternalProcess": ("Field[1] = ExternalProcess;", "field type"),
    "Field CommandLine": ('Field[1] = MathEval; Field[1].CommandLine = "touch x";', "string"),
    "Field Structured": ("Field[1] = Structured;", "field type"),
    "Field PostView": ("Field[1] = PostView;", "field type"),
    "Mesh option": ("Mesh.MeshSizeFromCurvature = 20;", "Mesh.*"),
    "General option": ("General.NumThreads = 64;", "General.*"),
    "Geometry option": ("Geometry.Tolerance = 1;", "Geometry.*"),
    "Solver option": ('Solver.Executable0 = "/bin/sh";', "Solver.*"),
    "Print option": ("Print.Width = 1;", "Print.*"),
    "NewModel": ("NewModel;", "NewModel"),
    "SetNumber": ('SetNumber("Gmsh/x", 1);', "SetNumber"),
    "Error": ('Error("x");', "Error"),
    "Extrude": ("Extrude {0, 0, 1} { Surface{1}; }", "Extrude"),
    "string variable": ('s = "/etc/passwd";', "string"),
    "StrCat name": ('Physical Point(StrCat("a", "b")) = {1};', "StrCat"),
    "unknown factory": ('SetFactory("Evil");', "factory"),
}


def write_on_root(tmp_path_factory, files: dict[str, str]) -> Path:
    """A directory (the same on every rank) holding ``files``, written by rank 0."""
    folder = None
    if COMM.rank == 0:
        folder = tmp_path_factory.mktemp("geo")
        for name, text in files.items():
            (folder / name).write_text(text.replace("FOLDER", str(folder)))
    return Path(COMM.bcast(str(folder) if folder else None))


def hostile_files(statement: str) -> dict[str, str]:
    """domain.geo with the statement on line 7, plus what it would read or run."""
    statement = statement.replace("SENTINEL", "FOLDER/SENTINEL").replace("SCRIPT", "FOLDER/evil")
    statement = statement.replace("EVIL", "FOLDER/evil.geo")
    return {
        "domain.geo": SQUARE + statement + "\n",
        "evil.geo": 'System "touch FOLDER/SENTINEL";\n',
        "evil": '#!/bin/sh\ntouch "FOLDER/SENTINEL"\n',
    }


def sentinels(folder: Path) -> list[str]:
    """Names of files the hostile statement created (checked on rank 0, agreed by all)."""
    found = sorted(p.name for p in folder.iterdir() if p.name.startswith("SENTINEL"))
    return COMM.bcast(found if COMM.rank == 0 else None)


@pytest.mark.parametrize("case", SIDE_EFFECTS)
def test_statement_with_side_effect_is_refused_before_gmsh_runs(tmp_path_factory, case):
    statement, word = SIDE_EFFECTS[case]
    folder = write_on_root(tmp_path_factory, hostile_files(statement))
    if COMM.rank == 0:
        (folder / "evil").chmod(0o755)
    domain = {"shape": "geo", "file": str(folder / "domain.geo"), "parts": PARTS}
    with pytest.raises(InputError, match="line 7: .*" + word):
        build_node_cloud(COMM, domain, 0.25)
    assert sentinels(folder) == []


@pytest.mark.parametrize("case", REFUSED)
def test_statement_outside_the_subset_is_refused(case):
    statement, word = REFUSED[case]
    with pytest.raises(InputError, match="line 7: .*" + word.replace("*", r"\*")):
        sanitize_geo(SQUARE + statement + "\n")


def test_option_file_beside_the_geo_is_not_read(tmp_path_factory):
    """gmsh merges NAME.opt when it exists beside NAME; parefg's gmsh reads a private copy."""
    files = {"domain.geo": SQUARE, "domain.geo.opt": 'System "touch FOLDER/SENTINEL";\n'}
    folder = write_on_root(tmp_path_factory, files)
    domain = {"shape": "geo", "file": str(folder / "domain.geo"), "parts": PARTS}
    cloud = build_node_cloud(COMM, domain, 0.25)
    assert cloud.n_nodes > 0
    assert sentinels(folder) == []


@pytest.mark.parametrize(
    "text, message",
    [
        ("For i In {1:1e15}\n  x = i;\nEndFor\n", "more than 10000 iterations"),
        ("For (1:200)\n  For (1:200)\n  EndFor\nEndFor\n", "more than 10000 iterations"),
        ("For i In {1:3}\n  i = 1;\nEndFor\n", "loop variable 'i'"),
        ("For i In {1:3}\n  For i In {0:0}\n  EndFor\nEndFor\n", "reuses the loop variable"),
        ("For i In {1:10:0}\nEndFor\n", "step is 0"),
        ("For i In {1e20:1e20 + 1e6}\nEndFor\n", "more than 10000 iterations"),
        ("h = Mesh.MeshSizeMax;\nFor i In {0:1:h}\nEndFor\n", "known before gmsh runs"),
        ("p = newp;\nFor i In {1:p}\nEndFor\n", "known before gmsh runs"),
        ("x = 5; x /= 0;\nFor i In {1:x}\nEndFor\n", "known before gmsh runs"),
        ("n = 1;\nIf (Rand(1) > 0.5)\n n = 1e9;\nEndIf\nFor (1:n)\nEndFor\n", "known before"),
        ("a[2e9] = 1;\n", "index must be known"),
        ("a[-1] = 1;\n", "index must be known"),
        ("x = 1 % 0;\n", "a % b"),
        ("x = 7; y = 3 % (x - 8);\n", "a % b"),
        ("a[] = {1:1e9};\n", "more than 100000 items"),
        ("a[] = {1:50000}; b[] = {a[], a[], a[]};\n", "more than 100000 items"),
        ("a[] = {1};\nFor i In {1:40}\n  a[] += a[];\nEndFor\n", "beyond 100000 items"),
        ("a[] = {1:50000}; a += 1; b[] = {a[], a[]};\n", "more than 100000 items"),
        ("For i In {1:3}\nx = 1;\n", "no EndFor closes"),
        ("If (1)\nx = 1;\nEndFor\n", "EndFor without"),
        ("x = " + "(" * 1000 + "1" + ")" * 1000 + ";\n", "nested more than"),
        ("x = " + "- " * 1000 + "1;\n", "nested more than"),
        ("If2 = 1;\n", "reads as If/For"),
        ('Physical Curve("a/*b") = {1};\n', "comment marker"),
        ("x = 1; $y = 2;\n", "character '[$]'"),
        ('Physical Curve("abc) = {1};\n', "never closed"),
        ("/* System \"touch x\";\n", "never closed"),
    ],
)  # fmt: skip
def test_unbounded_or_unsafe_program_is_refused(text, message):
    with pytest.raises(InputError, match=message):
        sanitize_geo(text)


def test_comments_and_strings_mentioning_commands_are_accepted():
    text = (
        '// System "touch x"; Exit;\n/* Include "y"; */\nSetFactory("Built-in");\n'
        'Point(1) = {0, 0, 0};\nPhysical Point("System Exit Printf") = {1};\n'
    )
    checked = sanitize_geo(text)
    assert "System" not in checked.splitlines()[0]  # the comment is gone
    assert 'Physical Point ( "System Exit Printf" ) = { 1 } ;' in checked


def test_checked_text_keeps_every_token_on_its_line():
    text = 'x = 1; // one\n/* two\nlines */ y = x+2;\n\nPhysical Curve("a", 3) = {1:3};\n'
    assert sanitize_geo(text).splitlines() == [
        "x = 1 ;", "", "y = x + 2 ;", "", 'Physical Curve ( "a" , 3 ) = { 1 : 3 } ;',
    ]  # fmt: skip


def gmsh_point_count(text: str, folder: Path) -> int:
    """Points gmsh creates from a .geo text (this process, not collective)."""
    import gmsh

    path = folder / f"count-{COMM.rank}.geo"
    path.write_text(text)
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.open(str(path))
        return len(gmsh.model.getEntities(0))
    finally:
        gmsh.finalize()


@pytest.mark.parametrize(
    "bounds",
    [
        "1:10", "10:1", "0:1:0.1", "1:2^3", "1:-2^2 + 10", "1:7 % 3 + 2", "0:Round(2.5) * 2",
        "1:Floor(10 / 3)", "1:Hypot(3, 4)", "1:Sqrt(16) + Max(1, 2)", "3:1:-0.5",
        "1:(1 < 2) + (2 >= 2) + !0", "0:Pi:Pi / 7", "1:n", "1:n - 1 + 1e-12",
    ],
)  # fmt: skip
def test_loop_count_is_the_one_gmsh_runs(tmp_path, bounds):
    """The checker counts a loop's iterations as gmsh does: one Point per iteration."""
    text = f"n = 6;\nk = 0;\nFor i In {{{bounds}}}\n  k += 1;\n  Point(k) = {{k, 0, 0}};\nEndFor\n"
    counted = run_program(StatementParser(tokenize(text)).program())
    assert counted == gmsh_point_count(sanitize_geo(text), tmp_path)


def test_for_and_if_build_the_square(tmp_path_factory):
    """A For loop places the corners and an If picks the part names: the subset works."""
    text = (
        "n = 4; corners[] = {0, 0, 1, 0, 1, 1, 0, 1};\n"
        "For i In {0:n - 1}\n  Point(i + 1) = {corners[2 * i], corners[2 * i + 1], 0};\nEndFor\n"
        "For (1:n)\nEndFor\n"
        "For i In {1:n}\n  Line(i) = {i, i % n + 1};\nEndFor\n"
        "Curve Loop(1) = {1:n}; Plane Surface(1) = {1};\n"
        'If (n == 4)\n  Physical Curve("bottom") = {1}; Physical Curve("rest") = {2:n};\n'
        'Else\n  Physical Curve("none") = {1};\nEndIf\n'
    )
    folder = write_on_root(tmp_path_factory, {"domain.geo": text})
    domain = {"shape": "geo", "file": str(folder / "domain.geo"), "parts": PARTS}
    cloud = build_node_cloud(COMM, domain, 0.25)
    ends = cloud.coords[cloud.segments]
    lengths = np.bincount(cloud.segment_part, np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1))
    np.testing.assert_allclose(lengths, [1.0, 3.0], rtol=1e-12)


@pytest.mark.parametrize(
    "name, parts",
    [
        ("plate_with_hole.geo", ["bottom", "top", "sides", "hole"]),
        ("clustered.geo", ["bottom", "right", "top", "left"]),
        ("half_disk.geo", ["contact", "free", "top"]),
    ],
)
def test_example_meshes_mesh_as_gmsh_meshes_the_original(monkeypatch, name, parts):
    """The checked text gives the very mesh the original file gives (not collective)."""
    path = str(REPO / "meshes" / name)
    domain = {"shape": "geo", "file": path, "parts": parts}
    checked = gmsh_mesh.mesh_domain(domain, 0.1)
    monkeypatch.setattr(shapes, "load_geo", lambda p, **_: Path(p).read_text())
    original = gmsh_mesh.mesh_domain(domain, 0.1)
    assert checked.n_nodes == original.n_nodes > 50
    np.testing.assert_array_equal(checked.coords, original.coords)
    np.testing.assert_array_equal(checked.segments, original.segments)


def test_file_limits(tmp_path):
    big = tmp_path / "big.geo"
    big.write_text("x = 1;\n" * (MAX_GEO_BYTES // 7 + 1))
    with pytest.raises(InputError, match="larger than"):
        load_geo(str(big))
    binary = tmp_path / "binary.geo"
    binary.write_bytes(b"x = 1;\n\xff\xfe\n")
    with pytest.raises(InputError, match="UTF-8"):
        load_geo(str(binary))
    fifo = tmp_path / "fifo.geo"
    os.mkfifo(fifo)
    with pytest.raises(InputError, match="regular file"):
        load_geo(str(fifo))  # returns at once: opened without blocking


def test_long_flat_expression_is_checked_quickly():
    sanitize_geo("x = " + " + ".join(["1"] * 100_000) + ";\n")


# ----------------------------------------------------------------------- CLI

SCENE = """[domain]
shape = "geo"
file = "domain.geo"
parts = ["bottom", "rest"]

[discretization]
h = 0.25

[time]
scheme = "static"
T = 1.0
dt = 1.0

[boundary.bottom]
type = "dirichlet"
"""


@pytest.mark.serial_only
@pytest.mark.parametrize(
    "statement, ranks",
    [('System "touch SENTINEL";', 1), ('System "touch SENTINEL";', 2), ("Exit;", 1)],
)
def test_cli_refuses_hostile_geo_with_one_line(tmp_path, statement, ranks):
    """exit 2, one line naming file, line and statement; no SENTINEL, no output directory."""
    (tmp_path / "domain.geo").write_text(SQUARE + statement + "\n")
    (tmp_path / "scene.toml").write_text(SCENE)
    result = run_parefg(["run", "scene.toml"], ranks=ranks, cwd=tmp_path, timeout=120)
    assert result.returncode == 2, (result.returncode, result.stderr)
    assert "Traceback" not in result.stderr
    lines = [line for line in result.stderr.splitlines() if line.startswith("parefg: error:")]
    assert len(lines) == 1, result.stderr
    assert "domain.file" in lines[0] and "line 7" in lines[0] and statement[:4] in lines[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["domain.geo", "scene.toml"]


SOUP = (
    "x", "a", "i", "[", "]", "{", "}", "(", ")", ";", "=", "+=", "++", "1", "1e5", "0.5", ":",
    ",", "-", "%", "^", "#", ".", "For", "EndFor", "If", "EndIf", "Else", "ElseIf", "In",
    "Point", "Line", "Loop", "Physical", "Curve", '"n"', "Field", "F", "Mesh", "MeshSizeMax",
    "System", "newp", "BooleanUnion", "Surface", "Delete", "Sin", "/*", "*/", "//", "\n",
)  # fmt: skip


@settings(max_examples=400, deadline=None)
@given(st.lists(st.sampled_from(SOUP), max_size=40))
def test_token_soup_is_accepted_or_refused_and_checking_is_idempotent(words):
    """Any text: InputError or a checked text that checks to itself (no other exception)."""
    try:
        checked = sanitize_geo(" ".join(words))
    except InputError:
        return
    assert sanitize_geo(checked) == checked


# --------------------------------------------------------------------------- transfinite counts

UNIT_SQUARE = (
    "Point(1) = {0, 0, 0}; Point(2) = {1, 0, 0}; Point(3) = {1, 1, 0}; Point(4) = {0, 1, 0};\n"
    "Line(1) = {1, 2}; Line(2) = {2, 3}; Line(3) = {3, 4}; Line(4) = {4, 1};\n"
    "Curve Loop(1) = {1, 2, 3, 4}; Plane Surface(1) = {1};\n"
)


@pytest.mark.parametrize(
    "text",
    [
        "Transfinite Curve{1, 2, 3, 4} = 100 Using Progression 1.1; Transfinite Surface{1};",
        "Transfinite Curve{1, 3} = 1000; Transfinite Curve{2, 4} = 1000; Transfinite Surface{1};",
        "n = Ceil(1 / Mesh.MeshSizeMax) + 1; Transfinite Curve{1, 2, 3, 4} = n;",
    ],
)
def test_transfinite_counts_within_the_caps_pass(text):
    for h in (None, 0.1):
        assert "Transfinite" in sanitize_geo(UNIT_SQUARE + text, mesh_size_max=h)


@pytest.mark.parametrize(
    "text, h, why",
    [
        ("Transfinite Curve{1} = 1e12;", None, "more than 20000 nodes on curves"),
        ("Transfinite Curve{1} = -1e9;", 0.1, "more than 20000 nodes on curves"),
        ("For i In {1:4}\nTransfinite Curve{i} = 6000;\nEndFor", None, "more than 20000 nodes"),
        ("n = 1 / Mesh.MeshSizeMax; Transfinite Curve{1} = n;", 1e-9, "more than 20000 nodes"),
        ("Transfinite Curve{1} = newp;", 0.1, "count must be known before gmsh runs"),
        ("Transfinite Curve{:} = 10;", None, "Transfinite Curve{:} cannot be bounded"),
        ("Transfinite Surface{:};", None, "Transfinite Surface{:} cannot be bounded"),
        (
            "Transfinite Surface{1}; Transfinite Curve{1, 2, 3, 4} = 1001;",
            None,
            "Surfaces of up to 1001 nodes a side may have more than 1000000 nodes",
        ),
    ],
)
def test_transfinite_counts_beyond_the_caps_are_refused_with_the_line(text, h, why):
    """Transfinite nodes ignore every mesh size: a count of 1e12 would exhaust gmsh."""
    with pytest.raises(InputError, match=r"line [4-6]: .*" + why.replace("{:}", r"\{:\}")):
        sanitize_geo(UNIT_SQUARE + text, mesh_size_max=h)


def test_transfinite_count_from_h_is_checked_once_h_is_known():
    """Without h (the scene being read) an h-dependent count passes; with h it is bounded."""
    text = UNIT_SQUARE + "Transfinite Curve{1} = 1 / Mesh.MeshSizeMax;"
    sanitize_geo(text)
    sanitize_geo(text, mesh_size_max=0.01)
    with pytest.raises(InputError, match="line 4: Transfinite Curves would put more than"):
        sanitize_geo(text, mesh_size_max=1e-6)
