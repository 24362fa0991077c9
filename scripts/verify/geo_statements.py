"""Run one dangerous .geo statement per case through ``parefg run`` and report its side effects.

Each case writes a unit-square .geo (physical curves "bottom" and "rest") with one hostile
statement, a scene using it, and runs ``PAREFG run scene.toml --out out`` in a fresh
temporary directory.  Reported: exit code, elapsed seconds, whether the sentinel file
SENTINEL (which the statement tries to create) exists afterwards, and the last stderr line.

    python scripts/verify/geo_statements.py [PAREFG] [--ranks 2] [-k NAME]
"""

import argparse
import os
import subprocess
import tempfile
import time
from pathlib import Path

SQUARE = (
    'SetFactory("Built-in");\n'
    "Point(1) = {0, 0, 0}; Point(2) = {1, 0, 0}; Point(3) = {1, 1, 0}; Point(4) = {0, 1, 0};\n"
    "Line(1) = {1, 2}; Line(2) = {2, 3}; Line(3) = {3, 4}; Line(4) = {4, 1};\n"
    "Curve Loop(1) = {1, 2, 3, 4}; Plane Surface(1) = {1};\n"
    'Physical Curve("bottom") = {1}; Physical Curve("rest") = {2, 3, 4};\n'
    'Physical Surface("square") = {1};\n'
)
SCENE = """[domain]
shape = "geo"
file = "{geo}"
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
EVIL = 'System "touch SENTINEL";\n'
SCRIPT = '#!/bin/sh\ntouch "$(dirname "$0")/SENTINEL"\n'
#: name -> (statement added to the .geo, extra files {name: text}, .geo file name)
CASES = {
    "System": ('System "touch SENTINEL";', {}, "d.geo"),
    "SystemCall": ('SystemCall "touch SENTINEL";', {}, "d.geo"),
    "NonBlockingSystemCall": ('NonBlockingSystemCall "touch SENTINEL";', {}, "d.geo"),
    "OnelabRun": ('OnelabRun("x", "{cwd}/evil.sh");', {"evil.sh": SCRIPT}, "d.geo"),
    "Printf > file": ('Printf("owned") > "SENTINEL";', {}, "d.geo"),
    "Printf >> file": ('Printf("owned") >> "SENTINEL";', {}, "d.geo"),
    "Printf": ('Printf("x = %g", 1);', {}, "d.geo"),
    "Print": ('Print "SENTINEL.msh";', {}, "d.geo"),
    "Save": ('Save "SENTINEL.msh";', {}, "d.geo"),
    "CreateDir": ('CreateDir "SENTINEL";', {}, "d.geo"),
    "Include": ('Include "evil.txt";', {"evil.txt": EVIL}, "d.geo"),
    "Merge": ('Merge "evil.geo";', {"evil.geo": EVIL}, "d.geo"),
    "MergeWithBoundingBox": ('MergeWithBoundingBox "evil.geo";', {"evil.geo": EVIL}, "d.geo"),
    "ShapeFromFile": (
        'SetFactory("OpenCASCADE"); v() = ShapeFromFile("/etc/hostname");',
        {},
        "d.geo",
    ),
    "sidecar .geo.opt": ("", {"d.geo.opt": EVIL}, "d.geo"),
    "file named *.gz": ("", {}, "d;touch SENTINEL;.gz"),
    "Delete Model": ("Delete Model;", {}, "d.geo"),
    "Delete Physicals": ("Delete Physicals;", {}, "d.geo"),
    "Delete {entities}": ("Delete { Surface{1}; }", {}, "d.geo"),
    "Exit": ("Exit;", {}, "d.geo"),
    "Abort": ("Abort;", {}, "d.geo"),
    "Sleep": ("Sleep 5;", {}, "d.geo"),
    "Mesh 2": ("Mesh 2;", {}, "d.geo"),
    "RefineMesh": ("Mesh 2; RefineMesh;", {}, "d.geo"),
    "SetName": ('SetName "x";', {}, "d.geo"),
    "Plugin": ("Plugin(NewView).Run;", {}, "d.geo"),
    "GetEnv": ('x = StrLen(GetEnv("HOME"));', {}, "d.geo"),
    "Field ExternalProcess": (
        'Field[1] = ExternalProcess; Field[1].CommandLine = "touch SENTINEL"; '
        "Background Field = 1;",
        {},
        "d.geo",
    ),
    "Mesh.* option": ("Mesh.MeshSizeFromCurvature = 20;", {}, "d.geo"),
    "General.* option": ("General.Terminal = 1;", {}, "d.geo"),
    "Macro/Call": ('Macro m System "touch SENTINEL"; Return Call m;', {}, "d.geo"),
    "unbounded For": ("For i In {1:1e15}\nx = i;\nEndFor", {}, "d.geo"),
    "For resetting its variable": ("For i In {1:3}\ni = 1;\nEndFor", {}, "d.geo"),
    "huge list index": ("a[2e9] = 1;", {}, "d.geo"),
    "modulo by zero": ("x = 1 % 0;", {}, "d.geo"),
    "System in a skipped If (string hides EndIf)": (
        "If (0) Physical Curve(\"x EndIf System 'touch SENTINEL'; \") = {1}; EndIf",
        {},
        "d.geo",
    ),
    "comment and string mention System": (
        '// System "touch SENTINEL";\nPhysical Point("System") = {1};',
        {},
        "d.geo",
    ),
}


def run_case(parefg, name, ranks, timeout):
    statement, extra, geo_name = CASES[name]
    with tempfile.TemporaryDirectory() as tmp:
        cwd = Path(tmp)
        (cwd / geo_name).write_text(SQUARE + statement.replace("{cwd}", tmp) + "\n")
        for file_name, text in extra.items():
            (cwd / file_name).write_text(text)
            (cwd / file_name).chmod(0o755)
        geo_in_scene = geo_name.replace("\\", "\\\\")
        (cwd / "scene.toml").write_text(SCENE.format(geo=geo_in_scene))
        cmd = [parefg, "run", "scene.toml", "--out", "out"]
        if ranks > 1:
            cmd = ["mpirun", "--timeout", str(int(timeout)), "-n", str(ranks), *cmd]
        env = dict(
            os.environ,
            OMPI_ALLOW_RUN_AS_ROOT="1",
            OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1",
            OMPI_MCA_rmaps_base_oversubscribe="1",
        )
        start = time.perf_counter()
        try:
            done = subprocess.run(
                cmd,
                cwd=cwd,
                capture_output=True,
                text=True,
                timeout=timeout,
                env=env,
                stdin=subprocess.DEVNULL,
            )
            code, err = done.returncode, done.stderr.strip().splitlines()
        except subprocess.TimeoutExpired:
            code, err = "timeout", []
        elapsed = time.perf_counter() - start
        time.sleep(0.3)  # NonBlockingSystemCall runs in the background
        sentinel = any(p.name.startswith("SENTINEL") for p in cwd.iterdir())
        summary = (cwd / "out" / "summary.json").exists()
        last = err[-1][:110] if err else ""
    return code, elapsed, sentinel, summary, last


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument(
        "parefg", nargs="?", default=str(Path(__file__).parents[2] / ".venv/bin/parefg")
    )
    parser.add_argument("--ranks", type=int, default=1)
    parser.add_argument("--timeout", type=float, default=30)
    parser.add_argument("-k", default="")
    args = parser.parse_args()
    print("| statement | exit | s | SENTINEL created | summary.json | last stderr line |")
    print("|---|---|---|---|---|---|")
    for name in CASES:
        if args.k.lower() not in name.lower():
            continue
        code, elapsed, sentinel, summary, last = run_case(
            args.parefg, name, args.ranks, args.timeout
        )
        print(
            f"| {name} | {code} | {elapsed:.1f} | {'YES' if sentinel else 'no'} | "
            f"{'yes' if summary else 'no'} | {last.replace('|', '/')} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
