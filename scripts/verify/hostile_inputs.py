"""Hostile-input matrix for the parefg command line (issue 9, "Safe with any input").

Each case is one ``parefg`` command (1 rank, some under ``mpirun -n 2``) fed a scene, a
.geo file, a checkpoint, a PETSc option or an --out that a new user or a hostile one might
give, with its expected exit code (0 ok, 1 solver failure, 2 bad input, 130 Ctrl-C) and,
where the wording is predictable, a loose pattern for the message.  Every case runs in a
fresh temporary tree::

    ROOT/                 snapshot: every path, size and mtime, before and after the run
      SENTINEL...         payloads try to create this (System "touch ...", Printf > ...)
      home/               $HOME
        work/             the working directory: scene.toml, payload.geo, checkpoints
          out/            the usual --out
      tmp/                $TMPDIR (MPI session files, gmsh scratch); not in the snapshot

with stdin a pipe that is never written (a prompt hangs instead of reading EOF), under
``prlimit --as`` (4 GiB per process) and a timeout that kills the whole session (mpirun
and its ranks included).  The checks of a case:

- ``exit``: the exit code is the expected one (TIMEOUT when it had to be killed);
- ``oneline``: for exit 1 / 2, stderr is exactly one line starting with ``parefg: error:``;
  for exit 0 / 130, stderr is empty (some cases allow a ``parefg: warning:`` line); never a
  Traceback, a numpy RuntimeWarning or native abort text, on stdout or stderr;
- ``message``: the error line matches the case's pattern (case-insensitive);
- ``executed``: no file named SENTINEL* exists afterwards, no process of the run survives;
- ``outside``: nothing was created or changed outside the run's output directory;
- ``home``: no dot-file was created in $HOME (gmsh.initialize writes ~/.fltk/ today);
- ``leftover``: bad input (exit 2) leaves nothing at all behind (no --out, no runs/...);
- ``kept``: a solver failure (exit 1) leaves result.h5 and summary.json readable;
- ``interrupted``: Ctrl-C (SIGINT to the process group after the first progress line,
  ``progress`` if none came within half the timeout) -> summary "interrupted";
- case-specific checks (frames in the time series, fields written, RSS, ...).

Usage::

    .venv/bin/python scripts/verify/hostile_inputs.py [--parefg PATH] [-k SUBSTRING ...]
        [--jobs N] [--list] [--out DIR] [--keep] [--timeout-scale F]

``-k`` selects cases whose id or item contains SUBSTRING (repeatable), ``--list`` lists
them.  It prints a markdown table and writes DIR/hostile_inputs.csv (default
results/hostile/); the exit status is 1 if any case misbehaves.  Most cases take the 2-4 s
of parefg's start-up; with --jobs 2 the matrix takes about 11 minutes on today's code (14
cases hang until their timeout) and should take about 5 once nothing hangs.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
MEMORY_LIMIT = 4 * 1024**3  # bytes of address space per process
FAST = 15.0  # seconds: a case that must be refused before any real work
RUN = 40.0  # seconds: a case that meshes, assembles and steps a small scene
# quick run of the built-in square: 81 nodes, 4 steps (about 2 s)
QUICK = ["--set", "time.dt=0.25", "--set", "discretization.h=0.125"]
NATIVE_CRASH = re.compile(
    r"Traceback|RuntimeWarning|terminate called|std::bad_alloc|Segmentation fault|"
    r"Aborted|core dumped|MPI_ABORT|free\(\)|double free|Fatal Python error",
)
ERROR_LINE = "parefg: error:"
WARNING_LINE = "parefg: warning:"

# ----------------------------------------------------------------------------- scenes


def toml(sections: dict) -> str:
    """A TOML document from {section: {key: value}} (nested tables as dotted sections)."""
    lines: list[str] = []

    def value(v) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, list | tuple):
            return "[" + ", ".join(value(item) for item in v) + "]"
        return repr(v)

    def table(prefix: str, body: dict) -> None:
        scalars = {k: v for k, v in body.items() if not isinstance(v, dict)}
        if prefix:
            lines.append(f"[{prefix}]")
        lines.extend(f"{k} = {value(v)}" for k, v in scalars.items())
        for k, v in body.items():
            if isinstance(v, dict):
                table(f"{prefix}.{k}" if prefix else k, v)

    table("", sections)
    return "\n".join(lines) + "\n"


def static_scene(domain: dict, **extra) -> str:
    """A small static scene: bottom clamped, top pulled down; parts bottom/top required."""
    sections = {
        "domain": domain,
        "discretization": {"h": 0.25, "degree": 1},
        "time": {"scheme": "static", "T": 1.0, "dt": 1.0},
        "boundary": {
            "bottom": {"type": "dirichlet"},
            "top": {"type": "neumann", "traction": [0.0, -0.01]},
        },
    }
    for key, body in extra.items():
        sections.setdefault(key, {}).update(body)
    return toml(sections)


def dynamic_scene(n_steps: int, h: float = 0.25, contact: bool = False, **extra) -> str:
    """A clamped square (contact at the bottom if asked) pushed by a body force."""
    bottom = {"type": "contact", "gap": 0.0} if contact else {"type": "dirichlet"}
    sections = {
        "domain": {"shape": "square"},
        "discretization": {"h": h, "degree": 1},
        "time": {"T": 1.0, "dt": 1.0 / n_steps},
        "boundary": {"top": {"type": "dirichlet"}, "bottom": bottom},
        "loads": {"f": [0.0, "-0.1 * sin(t)"]},
    }
    for key, body in extra.items():
        sections.setdefault(key, {}).update(body)
    return toml(sections)


GEO_SQUARE = """SetFactory("Built-in");
Point(1) = {0, 0, 0};
Point(2) = {1, 0, 0};
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
Physical Surface("body") = {1};
"""
GEO_PARTS = ["bottom", "right", "top", "left"]
GEO_SCENE = static_scene({"shape": "geo", "file": "payload.geo", "parts": GEO_PARTS})


def geo_files(payload: str, where: str = "before") -> dict[str, str]:
    """payload.geo: the unit square with ``payload`` before or after its geometry."""
    text = payload + "\n" + GEO_SQUARE if where == "before" else GEO_SQUARE + payload + "\n"
    return {"payload.geo": text}


# ----------------------------------------------------------------------------- cases


@dataclass
class Case:
    """One hostile input: what to run, what must come out.

    ``args`` follow ``parefg``; the tokens @ROOT@, @HOME@, @WORK@, @OUT@, @SENTINEL@ and
    @REPO@ in args, scene and files are replaced by the case's paths.  ``expect`` is one
    exit code or a tuple of acceptable ones.  ``setup(ctx)`` prepares files that text cannot
    express (a FIFO, HDF5 checkpoints); ``check(ctx, result)`` returns a failure reason or
    None.
    """

    id: str
    item: str
    what: str
    args: list[str]
    expect: int | tuple[int, ...]
    message: str | None = None
    scene: str | None = None
    files: dict[str, str] = field(default_factory=dict)
    setup: Callable | None = None
    check: Callable | None = None
    timeout: float = FAST
    ranks: int = 1
    allow_warning: bool = False
    allow_usage: bool = False
    sigint: bool = False
    out_dirs: tuple[str, ...] = ("@OUT@",)  # where a successful or failed run may write
    # bad data found during the run (exit 2): the output so far is kept, like a failure's
    kept: bool = False

    @property
    def codes(self) -> tuple[int, ...]:
        return self.expect if isinstance(self.expect, tuple) else (self.expect,)


def run_args(*extra: str, scene: str = "@WORK@/scene.toml", out: bool = True) -> list[str]:
    """``run SCENE [extra] [--out @OUT@] --quiet``."""
    return ["run", scene, *extra, *(["--out", "@OUT@"] if out else []), "--quiet"]


def bad_set(cid: str, item: str, what: str, override: str, message: str, **kw) -> Case:
    """``parefg run square --set override`` must be refused with exit 2."""
    return Case(cid, item, what, run_args("--set", override, scene="square"), 2, message, **kw)


def geo_case(cid: str, what: str, payload: str, where: str = "before", **kw) -> Case:
    """A .geo payload in an otherwise valid geo scene: refused, nothing executed."""
    kw.setdefault("message", None)
    return Case(
        cid, "2 geo", what, run_args(), 2, scene=GEO_SCENE, files=geo_files(payload, where), **kw
    )


# ---- case-specific checks (ctx: paths of the case; result: the finished run)


def h5_open(path: Path):
    import h5py

    return h5py.File(path, "r")


def frames(ctx: dict) -> int:
    with h5_open(ctx["out"] / "result.h5") as handle:
        return len(handle["steps/time"])


def expect_frames(low: int, high: int) -> Callable:
    def check(ctx, result):
        n = frames(ctx)
        return None if low <= n <= high else f"{n} output frames, expected {low}..{high}"

    return check


def expect_fields(wanted: set[str]) -> Callable:
    def check(ctx, result):
        with h5_open(ctx["out"] / "result.h5") as handle:
            have = set(handle["fields"]) if "fields" in handle else set()
            have |= set(handle["contact_fields"]) if "contact_fields" in handle else set()
        return None if have == wanted else f"fields {sorted(have)}, expected {sorted(wanted)}"

    return check


def expect_stdout(pattern: str) -> Callable:
    def check(ctx, result):
        return None if re.search(pattern, result.stdout) else f"stdout lacks {pattern!r}"

    return check


def expect_untouched(name: str, text: str) -> Callable:
    def check(ctx, result):
        path = ctx["work"] / name
        if not path.is_file() or path.read_text() != text:
            return f"{name} was changed or removed"
        return None

    return check


def expect_summary(**wanted) -> Callable:
    def check(ctx, result):
        summary = json.loads((ctx["out"] / "summary.json").read_text())
        wrong = {k: summary.get(k) for k, v in wanted.items() if summary.get(k) != v}
        return f"summary {wrong}, expected {wanted}" if wrong else None

    return check


def expect_output_time(limit: float) -> Callable:
    """Output cost linear in the number of outputs: the run's output phase below ``limit``."""

    def check(ctx, result):
        seconds = json.loads((ctx["out"] / "summary.json").read_text())["timings"]["output"]
        return None if seconds < limit else f"output took {seconds:.1f} s (limit {limit:g} s)"

    return check


def expect_flat_rss(ctx, result) -> str | None:
    """Peak RSS of this run against a 50-step run of the same scene: flat within 60 MB."""
    ref_out = ctx["root"] / "tmp" / "reference"
    scene = ctx["work"] / "reference.toml"
    scene.write_text(dynamic_scene(50))
    command = [*ctx["prefix"], "run", str(scene), "--out", str(ref_out), "--quiet"]
    subprocess.run(command, cwd=ctx["work"], env=ctx["env"], capture_output=True, timeout=RUN)
    scene.unlink()
    reference = json.loads((ref_out / "summary.json").read_text())["peak_rss_mb"]
    peak = json.loads((ctx["out"] / "summary.json").read_text())["peak_rss_mb"]
    growth = peak - reference
    return None if growth < 60 else f"peak RSS {peak:.0f} MB vs {reference:.0f} MB at 50 steps"


def expect_dir(relative: str) -> Callable:
    def check(ctx, result):
        return None if (ctx["work"] / relative).is_dir() else f"no {relative}/"

    return check


# ---- checkpoints: one genuine checkpoint per script run, variants derived from it

_CHECKPOINT_LOCK = threading.Lock()
_CHECKPOINT: dict[str, Path] = {}


def genuine_checkpoint(ctx) -> Path:
    """checkpoint.h5 after step 2 of the QUICK square run (the run then fails at step 3)."""
    with _CHECKPOINT_LOCK:
        if "path" not in _CHECKPOINT:
            base = Path(tempfile.mkdtemp(prefix="hostile-checkpoint-"))
            out = base / "run"
            command = [*ctx["prefix"], "run", "square", *QUICK, "--out", str(out), "--quiet"]
            command += ["--checkpoint-every", "2", "--fail-at-step", "3"]
            subprocess.run(command, cwd=base, env=ctx["env"], capture_output=True, timeout=RUN)
            if not (out / "checkpoint.h5").is_file():
                raise RuntimeError("could not write the reference checkpoint")
            _CHECKPOINT.update(path=out / "checkpoint.h5", result=out / "result.h5", base=base)
        return _CHECKPOINT["path"]


def checkpoint_variant(edit: Callable | None = None, source: str = "path") -> Callable:
    """setup(): copy the genuine checkpoint (or result.h5) to WORK/ckpt.h5, then ``edit``."""

    def setup(ctx):
        genuine_checkpoint(ctx)
        target = ctx["work"] / "ckpt.h5"
        shutil.copy(_CHECKPOINT[source], target)
        if edit is not None:
            import h5py

            with h5py.File(target, "r+") as handle:
                edit(handle)

    return setup


def _drop(name):
    return lambda handle: handle.__delitem__(name)


def _attr(name, value):
    return lambda handle: handle.attrs.__setitem__(name, value)


def _reshape(name):
    def edit(handle):
        data = handle[name][...]
        del handle[name]
        handle.create_dataset(name, data=data.ravel()[: data.size // 2 * 2].reshape(-1, 1))

    return edit


def _foreign_h5(ctx):
    import h5py
    import numpy as np

    with h5py.File(ctx["work"] / "ckpt.h5", "w") as handle:
        handle.create_dataset("temperature", data=np.arange(10.0))
        handle.attrs["creator"] = "not parefg"


def _fifo(ctx):
    os.mkfifo(ctx["work"] / "ckpt.h5")


def _victim(ctx):
    (ctx["work"] / "victim.txt").write_text("precious\n")


def _taken_out(ctx):
    ctx["out"].mkdir()
    (ctx["out"] / "notes.txt").write_text("mine\n")


def _out_is_file(ctx):
    ctx["out"].write_text("a file\n")


def _regular_file(ctx):
    (ctx["work"] / "afile").write_text("x\n")


def _dangling(ctx):
    (ctx["work"] / "dangling").symlink_to(ctx["root"] / "nowhere" / "x")


def _previous_run(ctx):
    (ctx["work"] / "runs" / "square").mkdir(parents=True)
    (ctx["work"] / "runs" / "square" / "summary.json").write_text("{}\n")


def retry_without_restart(ctx, result) -> str | None:
    """After a refused --restart, the same --out must still be usable."""
    command = [*ctx["prefix"], "run", "square", *QUICK, "--out", str(ctx["out"]), "--quiet"]
    retry = subprocess.run(
        command, cwd=ctx["work"], env=ctx["env"], capture_output=True, text=True, timeout=RUN
    )
    return None if retry.returncode == 0 else f"retry exit {retry.returncode}: {retry.stderr[-80:]}"


def _empty_out(ctx):
    ctx["out"].mkdir()


RESTART = ["--restart", "@WORK@/ckpt.h5"]


# ---- the case list


def sentinel_payloads() -> list[tuple[str, str, str]]:
    """(id, what, .geo statement) trying to run a program or write a file."""
    s = "@SENTINEL@"
    return [
        ("geo-system", "System touch", f'System "touch {s}";'),
        ("geo-systemcall", "SystemCall touch", f'SystemCall "touch {s}";'),
        ("geo-nonblocking", "NonBlockingSystemCall", f'NonBlockingSystemCall "touch {s}";'),
        ("geo-onelabrun", "OnelabRun touch", f'OnelabRun("x", "touch {s}");'),
        ("geo-printf-gt", "Printf > file", f'Printf("pwned") > "{s}";'),
        ("geo-printf-gtgt", "Printf >> file", f'Printf("pwned") >> "{s}";'),
        ("geo-printf-sprintf", "Printf > Sprintf path", f'Printf("x") > Sprintf("{s}%g", 1);'),
        ("geo-print", "Print mesh to file", f'Print "{s}.msh";'),
        ("geo-save", "Save .msh", f'Save "{s}.msh";'),
        ("geo-createdir", "CreateDir", f'CreateDir "{s}_dir";'),
        ("geo-renamefile", "RenameFile", f'RenameFile "@WORK@/victim.txt", "{s}";'),
        ("geo-system-strcat", "System StrCat(...)", f'System StrCat("tou", "ch {s}");'),
        ("geo-system-sprintf", "System Sprintf(...)", f'System Sprintf("touch %s", "{s}");'),
        ("geo-macro-call", "Macro + Call", f'Macro M\nSystem "touch {s}";\nReturn\nCall M;'),
        ("geo-function", "Function + Call", f'Function F\nSystem "touch {s}";\nReturn\nCall F;'),
        ("geo-getenv", "GetEnv + Printf >", f'home = GetEnv("HOME");\nPrintf(home) > "{s}";'),
        ("geo-after-comment", "/* */ then System", f'/* harmless */ System "touch {s}";'),
        ("geo-same-line", "Point; System", f'Point(99) = {{0.5, 0.5, 0}}; System "touch {s}";'),
        ("geo-string-semicolon", "'a;b' string then System", f'Printf("a;b"); System "touch {s}";'),
        ("geo-multiline", "System split over lines", f'System\n  "touch {s}"\n  ;'),
        ("geo-after-line-comment", "// then newline System", f'// comment\\\nSystem "touch {s}";'),
        ("geo-tab-case", "tabs, CRLF", f'System\t"touch {s}";\r\n'),
        ("geo-at-end", "System after geometry", f'System "touch {s}";'),
        ("geo-include-abs", "Include absolute", 'Include "@WORK@/evil.geo";'),
        ("geo-include-rel", "Include relative", 'Include "evil.geo";'),
        ("geo-merge", "Merge .geo", 'Merge "@WORK@/evil.geo";'),
        ("geo-if-true", "System inside If(1)", f'If (1)\nSystem "touch {s}";\nEndIf'),
        ("geo-for-body", "System in For body", f'For i In {{1:1}}\nSystem "touch {s}";\nEndFor'),
    ]


def geo_cases() -> list[Case]:
    cases = []
    evil = {"evil.geo": 'System "touch @SENTINEL@";\n'}
    for cid, what, payload in sentinel_payloads():
        where = "after" if cid == "geo-at-end" else "before"
        files = {**geo_files(payload, where), **(evil if "evil" in payload else {})}
        setup = _victim if "victim" in payload else None
        check = expect_untouched("victim.txt", "precious\n") if setup else None
        cases.append(
            Case(cid, "2 geo", what, run_args(), 2, None, GEO_SCENE, files, setup, check=check)
        )
    # the scene is rejected for another reason; the .geo payload must not have run first
    cases.append(
        Case(
            "geo-system-bad-scene",
            "2 geo",
            "System + parts not in file",
            run_args(),
            2,
            None,
            static_scene({"shape": "geo", "file": "payload.geo", "parts": ["bottom", "top", "x"]}),
            geo_files('System "touch @SENTINEL@";'),
        )
    )
    setup_victim, untouched = _victim, expect_untouched("victim.txt", "precious\n")
    cases += [
        geo_case(
            "geo-printf-overwrite",
            "Printf > existing file",
            'Printf("overwritten") > "@WORK@/victim.txt";',
            setup=setup_victim,
            check=untouched,
        ),
        geo_case(
            "geo-deletefile",
            "DeleteFile",
            'DeleteFile "@WORK@/victim.txt";',
            setup=setup_victim,
            check=untouched,
        ),
        geo_case("geo-exit", "Exit;", "Exit;"),
        geo_case("geo-abort", "Abort;", "Abort;"),
        geo_case("geo-sleep", "Sleep 60", "Sleep 60;"),
        geo_case("geo-solver-exe", "Solver.Executable0 =", 'Solver.Executable0 = "/bin/sh";'),
        geo_case("geo-general-option", "General.* option", "General.NumThreads = 64;"),
        geo_case("geo-setstring", "SetString option", 'SetString("General.FileName", "x");'),
        geo_case("geo-plugin", "Plugin(...).Run", "Plugin(Triangulate).Run;"),
        geo_case(
            "geo-meshsize-tiny", "Mesh.MeshSizeMax = 1e-6", "Mesh.MeshSizeMax = 1e-6;", "after"
        ),
        geo_case(
            "geo-mesh-inside",
            "Mesh 2; inside the file",
            "Mesh.MeshSizeFactor = 1e-5;\nMesh 2;",
            "after",
        ),
        geo_case(
            "geo-transfinite-huge",
            "Transfinite Curve = 1e12",
            "Transfinite Curve{1} = 1e12;",
            "after",
            message="Transfinite",
        ),
        geo_case(
            "geo-transfinite-surface",
            "Transfinite 3e4 x 3e4 surface",
            "Transfinite Curve{1, 3} = 30000;\nTransfinite Curve{2, 4} = 30000;\n"
            "Transfinite Surface{1};",
            "after",
            message="Transfinite",
        ),
        geo_case("geo-huge-for", "For 1:1e9 empty loop", "For i In {1:1e9}\nEndFor"),
        geo_case(
            "geo-huge-points",
            "For 1:1e8 Point()",
            "For i In {1:1e8}\nPoint(100 + i) = {0.5, 0.5, 0};\nEndFor",
        ),
        geo_case("geo-lowercase", "lower-case 'system'", 'system "touch @SENTINEL@";'),
        geo_case("geo-uppercase", "upper-case 'SYSTEM'", 'SYSTEM "touch @SENTINEL@";'),
        geo_case("geo-syntax-error", "gibberish", "this is not a geo file ((("),
        Case(
            "geo-etc-passwd",
            "2 geo",
            "file = /etc/passwd",
            run_args(),
            2,
            None,
            static_scene({"shape": "geo", "file": "/etc/passwd", "parts": GEO_PARTS}),
        ),
        Case(
            "geo-missing-file",
            "2 geo",
            "file does not exist",
            run_args(),
            2,
            "domain.file",
            static_scene({"shape": "geo", "file": "nope.geo", "parts": GEO_PARTS}),
        ),
        Case(
            "geo-missing-part",
            "2 geo",
            "parts not in file",
            run_args(),
            2,
            "domain.parts",
            static_scene({"shape": "geo", "file": "payload.geo", "parts": ["bottom", "top", "x"]}),
            geo_files(""),
        ),
        geo_case(
            "geo-mesh-2-ranks",
            "System touch, 2 ranks",
            'System "touch @SENTINEL@";',
            ranks=2,
        ),
    ]
    # valid files that must keep working, including harmless look-alikes of the payloads
    ok = dict(timeout=RUN, out_dirs=("@OUT@",))
    plate = {"shape": "geo", "file": "@REPO@/meshes/plate_with_hole.geo"}
    clustered = {"shape": "geo", "file": "@REPO@/meshes/clustered.geo"}
    cases += [
        Case(
            "geo-ok-plate",
            "2 geo (valid)",
            "meshes/plate_with_hole.geo",
            run_args(),
            0,
            scene=static_scene({**plate, "parts": ["bottom", "top", "sides", "hole"]}),
            **ok,
        ),
        Case(
            "geo-ok-clustered",
            "2 geo (valid)",
            "meshes/clustered.geo",
            run_args(),
            0,
            scene=static_scene({**clustered, "parts": GEO_PARTS}, discretization={"h": 0.3}),
            **ok,
        ),
        Case(
            "geo-ok-lookalike",
            "2 geo (valid)",
            "'System' in comment/name",
            run_args(),
            0,
            scene=static_scene(
                {"shape": "geo", "file": "payload.geo", "parts": ["bottom", "System", "top"]}
            ),
            files={
                "payload.geo": '// System "touch @SENTINEL@"; /* Exit; */\n'
                + GEO_SQUARE.replace('"right"', '"System"')
                + '/* Printf("x") > "@SENTINEL@"; */\n'
            },
            **ok,
        ),
        # sizes below h are floored at the budget's size: meshes, within the machine
        Case(
            "geo-ok-tiny-sizes",
            "2 geo (valid)",
            "MeshSize{1, 2} = 1e-9 floored",
            run_args("--max-memory", "1"),
            0,
            scene=GEO_SCENE,
            files=geo_files("MeshSize{1, 2} = 1e-9;", "after"),
            **ok,
        ),
        Case(
            "geo-ok-loop",
            "2 geo (valid)",
            "bounded For loop, variables",
            run_args(),
            0,
            scene=static_scene({"shape": "geo", "file": "loop.geo", "parts": GEO_PARTS}),
            files={"loop.geo": GEO_LOOP},
            **ok,
        ),
        Case(
            "geo-ok-2-ranks",
            "2 geo (valid)",
            "plate_with_hole, 2 ranks",
            run_args(),
            0,
            scene=static_scene({**plate, "parts": ["bottom", "top", "sides", "hole"]}),
            ranks=2,
            **ok,
        ),
    ]
    return cases


# a valid .geo that needs loops and variables: a square whose bottom is 4 segments
GEO_LOOP = """SetFactory("Built-in");
n = 4;  lx = 1.0;
For i In {0:n}
  Point(1 + i) = {i * lx / n, 0, 0};
EndFor
Point(10) = {lx, 1, 0};
Point(11) = {0, 1, 0};
For i In {1:n}
  Line(i) = {i, i + 1};
EndFor
Line(10) = {n + 1, 10};
Line(11) = {10, 11};
Line(12) = {11, 1};
Curve Loop(1) = {1:n, 10, 11, 12};
Plane Surface(1) = {1};
Physical Curve("bottom") = {1:n};
Physical Curve("right") = {10};
Physical Curve("top") = {11};
Physical Curve("left") = {12};
"""


def name_cases() -> list[Case]:
    names = [
        ("name-abs", "name = /abs/path", "@ROOT@/escaped"),
        ("name-dotdot", "name = ../../x", "../../x"),
        ("name-slash", "name = a/b", "a/b"),
        ("name-parent", 'name = ".."', ".."),
        ("name-dot", 'name = "."', "."),
        ("name-empty", 'name = ""', ""),
        ("name-long", "name of 300 chars", "n" * 300),
        ("name-newline", "name with newline", "a\nb"),
        ("name-nul", "name with NUL", "a\x00b"),
        ("name-backslash", "name = ..\\\\x", "..\\..\\x"),
    ]
    cases = [
        Case(
            cid,
            "2 name",
            what,
            run_args(out=False),
            2,
            "name",
            "name = " + json.dumps(value) + "\n" + static_scene({"shape": "square"}),
            out_dirs=(),
        )
        for cid, what, value in names
    ]
    cases += [
        Case(
            "name-override",
            "2 name",
            "--set name=../../evil",
            ["run", "square", *QUICK, "--set", 'name="../../evil"', "--quiet"],
            2,
            "name",
            out_dirs=(),
        ),
        Case(
            "name-ok",
            "2 name (valid)",
            "name = plain-name_1",
            run_args(out=False),
            0,
            scene='name = "plain-name_1"\n' + static_scene({"shape": "square"}),
            check=expect_dir("runs/plain-name_1"),
            timeout=RUN,
            out_dirs=("@WORK@/runs",),
        ),
    ]
    return cases


def size_cases() -> list[Case]:
    too_big = "(?i)nodes|memory|size|estimate|too"
    cases = [
        bad_set("size-h-1e-6", "3 size", "h = 1e-6", "discretization.h=1e-6", too_big),
        bad_set("size-h-1e-3", "3 size", "h = 1e-3", "discretization.h=1e-3", too_big),
        # fits the memory budget at the default h; the MLS refuses it, advising a smaller one
        bad_set(
            "size-support-1e6", "3 size", "support = 1e6", "discretization.support=1e6", "decrease"
        ),
        bad_set(
            "size-quadrature", "3 size", "quadrature = 2000", "discretization.quadrature=2000", None
        ),
        bad_set("size-h-1e-300", "3 size", "h = 1e-300", "discretization.h=1e-300", too_big),
        Case(
            "size-rectangle",
            "3 size",
            "rectangle 1e5 x 1e5",
            run_args(),
            2,
            too_big,
            static_scene({"shape": "rectangle", "size": [1e5, 1e5]}),
        ),
        Case(
            "size-polygon",
            "3 size",
            "polygon 1e4 wide, h = 0.25",
            run_args(),
            2,
            too_big,
            static_scene(
                {
                    "shape": "polygon",
                    "vertices": [[0, 0], [1e4, 0], [1e4, 1e4], [0, 1e4]],
                    "edge_names": ["bottom", "right", "top", "left"],
                }
            ),
        ),
    ]
    for cid, override in [
        ("size-h-1e-6-2r", "discretization.h=1e-6"),
        ("size-support-1e6-2r", "discretization.support=1e6"),
    ]:
        cases.append(
            bad_set(
                cid,
                "3 size",
                override.split(".")[1] + ", 2 ranks",
                override,
                "decrease" if "support" in override else too_big,
                ranks=2,
            )
        )
    return cases


def symbolic_cases() -> list[Case]:
    sines = " * ".join(f"sin(x + {i})" for i in range(1, 72))
    # measured: sympy.simplify of sqrt(x - 2) times 30 sines runs > 25 s
    sines30 = " * ".join(f"sin(x + {i})" for i in range(1, 31))
    return [
        Case(
            "sym-friction-nan",
            "3 symbolic",
            "friction NaN at samples, 30 sines",
            run_args(
                "--set", f'boundary.bottom.friction="sqrt(x - 2) * {sines30}"', scene="square"
            ),
            2,
            "friction",
        ),
        bad_set(
            "sym-friction-sqrt",
            "5 garbage",
            "friction = sqrt(x - 2)",
            'boundary.bottom.friction="sqrt(x - 2)"',
            "friction",
        ),
        Case(
            "sym-71-sines",
            "3 symbolic",
            "[exact] u = product of 71 sines",
            run_args("--set", f'exact.u=["{sines}", "0"]', scene="square"),
            2,
            "exact",
        ),
        bad_set(
            "sym-pow-tower",
            "3 symbolic",
            "f = x**(10**10**10)",
            'loads.f=["x**(10**10**10)", 0]',
            "loads.f",
        ),
        bad_set(
            "sym-factorial-like", "3 symbolic", "f = 9**9**9", 'loads.f=["9**9**9", 0]', "loads.f"
        ),
    ]


def output_cases() -> list[Case]:
    """Section 3 (leak, output cost, progress) and 6 (time series) and [output]."""
    return [
        Case(
            "out-every-int64",
            "4 one-line",
            "output.every = 2**63",
            run_args("--set", "output.every=9223372036854775808", scene="square"),
            2,
            "output.every",
        ),
        Case(
            "out-every-huge",
            "4 one-line",
            "output.every = 10**30",
            run_args("--set", "output.every=1000000000000000000000000000000", scene="square"),
            2,
            "output.every",
        ),
        bad_set(
            "out-every-neg", "9 schema", "output.every = -1", "output.every=-1", "output.every"
        ),
        bad_set(
            "out-fields-bogus",
            "5 [output]",
            "fields = [bogus]",
            'output.fields=["bogus"]',
            "fields",
        ),
        Case(
            "out-fields-empty",
            "5 [output]",
            "fields = [] writes none",
            run_args("--set", "output.fields=[]", *QUICK, scene="square"),
            0,
            check=expect_fields(set()),
            timeout=RUN,
        ),
        Case(
            "out-fields-u",
            "5 [output]",
            'fields = ["u"]',
            run_args("--set", 'output.fields=["u"]', *QUICK, scene="square"),
            0,
            check=expect_fields({"displacement"}),
            timeout=RUN,
        ),
        Case(
            "out-default-frames",
            "6 time series",
            "200 steps -> ~50 frames",
            run_args(),
            0,
            scene=dynamic_scene(200, contact=True),
            check=expect_frames(40, 60),
            timeout=RUN,
        ),
        Case(
            "out-default-frames-long",
            "6 time series",
            "2000 steps -> ~50 frames",
            run_args(),
            0,
            scene=dynamic_scene(2000),
            check=expect_frames(40, 60),
            timeout=RUN,
        ),
        Case(
            "out-every-5",
            "6 time series",
            "every = 5, 20 steps -> t = 0 + 4",
            run_args(),
            0,
            scene=dynamic_scene(20, output={"every": 5}),
            check=expect_frames(5, 5),
            timeout=RUN,
        ),
        Case(
            "out-every-1-linear",
            "3 output cost",
            "every = 1, 1000 outputs",
            run_args(),
            0,
            scene=dynamic_scene(1000, output={"every": 1}),
            check=expect_output_time(8.0),
            timeout=RUN,
        ),
        Case(
            "leak-rss-flat",
            "3 leak",
            "5000 steps, RSS vs 50",
            run_args(),
            0,
            scene=dynamic_scene(5000),
            check=expect_flat_rss,
            timeout=RUN,
        ),
        Case(
            "progress-tiny-dt",
            "3 progress",
            "1e8 steps: progress, Ctrl-C",
            ["run", "@WORK@/scene.toml", "--out", "@OUT@"],
            130,
            scene=dynamic_scene(10**8),
            sigint=True,
            timeout=25.0,
        ),
        Case(
            "ctrl-c",
            "4 Ctrl-C",
            "SIGINT after 1st progress",
            ["run", "@WORK@/scene.toml", "--out", "@OUT@"],
            130,
            scene=dynamic_scene(20000, contact=True),
            sigint=True,
            timeout=RUN,
        ),
        Case(
            "ctrl-c-2r",
            "4 Ctrl-C",
            "SIGINT, 2 ranks",
            ["run", "@WORK@/scene.toml", "--out", "@OUT@"],
            # Open MPI turns Ctrl-C into SIGTERM to the ranks (exit 143 each), then exits 1
            (1, 130),
            scene=dynamic_scene(20000, contact=True),
            sigint=True,
            ranks=2,
            timeout=RUN,
        ),
    ]


def value_cases() -> list[Case]:
    """Sections 4 and 5: values that used to crash, hang or integrate garbage."""
    deep_array = "x = " + "[" * 5000 + "]" * 5000 + "\n"
    deep_table = "x = " + "{a = " * 3000 + "1" + "}" * 3000 + "\n"
    return [
        Case(
            "toml-deep-array",
            "4 one-line",
            "TOML [[[...]]] x5000",
            run_args(),
            2,
            "TOML",
            deep_array + static_scene({"shape": "square"}),
        ),
        Case(
            "toml-deep-table",
            "4 one-line",
            "TOML {a={a=...}} x3000",
            run_args(),
            2,
            "TOML",
            deep_table + static_scene({"shape": "square"}),
        ),
        bad_set(
            "expr-deep-parens",
            "4 one-line",
            "f = (((...x...))) x2000",
            'loads.f=["' + "(" * 2000 + "x" + ")" * 2000 + '", 0]',
            "loads.f",
        ),
        # constants are evaluated exactly (sympy, 20 digits): sin(10**25) is a number
        Case(
            "expr-sin-1e25",
            "4 one-line",
            'f = "sin(10**25)" runs',
            run_args("--set", 'loads.f=["sin(10**25)", 0]', scene="square"),
            0,
            timeout=RUN,
        ),
        bad_set(
            "expr-exp-1000",
            "4 one-line",
            'f = "exp(1000)"',
            'loads.f=["exp(1000)", 0]',
            "loads.f",
        ),
        bad_set(
            "friction-negative",
            "4 one-line",
            "friction = -1",
            "boundary.bottom.friction=-1",
            "friction",
        ),
        bad_set(
            "friction-neg-expr",
            "4 one-line",
            "friction = x - 2",
            'boundary.bottom.friction="x - 2"',
            "friction",
        ),
        bad_set("gap-negative", "5 garbage", "gap = -0.1", "boundary.bottom.gap=-0.1", "gap"),
        bad_set(
            "friction-law-bogus",
            "9 schema",
            "friction_law = sticky (no such law)",
            "boundary.bottom.friction_law=sticky",
            "friction_law",
        ),
        bad_set(
            "coulomb-no-coefficient",
            "9 schema",
            "friction_law = coulomb without friction_coefficient",
            "boundary.bottom.friction_law=coulomb",
            "friction_coefficient is required",
        ),
        Case(
            "coulomb-negative-coefficient",
            "9 schema",
            "friction_law = coulomb, friction_coefficient = -0.1",
            run_args(
                "--set",
                "boundary.bottom.friction_law=coulomb",
                "--set",
                "boundary.bottom.friction_coefficient=-0.1",
                scene="square",
            ),
            2,
            "friction_coefficient",
        ),
        bad_set(
            "coefficient-without-coulomb",
            "9 schema",
            "friction_coefficient on a tresca part",
            "boundary.bottom.friction_coefficient=0.3",
            "only used with friction_law",
        ),
        bad_set("newmark-beta", "5 garbage", "time.beta = 0.1 < gamma/2", "time.beta=0.1", "beta"),
        bad_set(
            "contact-force-bogus",
            "9 schema",
            "contact_force = midpoint (unknown)",
            "time.contact_force=midpoint",
            "contact_force",
        ),
        Case(
            "static-no-dirichlet",
            "5 garbage",
            "static, no Dirichlet part",
            run_args(),
            (1, 2),
            "(?i)singular|rigid|dirichlet|constrain",
            toml(
                {
                    "domain": {"shape": "square"},
                    "discretization": {"h": 0.25, "degree": 1},
                    "time": {"scheme": "static", "T": 1.0, "dt": 1.0},
                    "boundary": {"top": {"type": "neumann", "traction": [0.0, 0.1]}},
                }
            ),
            timeout=RUN,
            out_dirs=("@OUT@",),
        ),
        bad_set(
            "nonfinite-sqrt",
            "5 garbage",
            "f = sqrt(x - 2)",
            'loads.f=["sqrt(x - 2)", 0]',
            "loads.f",
        ),
        bad_set(
            "nonfinite-exp",
            "5 garbage",
            "f = exp(1000*t)",
            'loads.f=["exp(1000*t)", 0]',
            "loads.f",
            timeout=RUN,
            kept=True,  # found at t = 0.35: the steps before are kept
        ),
        bad_set(
            "nonfinite-traction",
            "5 garbage",
            "traction = 1/x at x = 0",
            'boundary.left.traction=["1/x", 0]',
            "traction",
        ),
        Case(
            "nonfinite-initial",
            "5 garbage",
            "initial u = log(y - 2)",
            run_args(),
            2,
            "initial",
            dynamic_scene(4, initial={"u": ["log(y - 2)", 0]}),
        ),
        bad_set(
            "nonfinite-dirichlet",
            "5 garbage",
            "top value = 1/(y - 1)",
            'boundary.top.value=["1/(y - 1)", 0]',
            "value",
        ),
        bad_set(
            "nonfinite-nan-literal",
            "9 schema",
            "h = nan",
            "discretization.h=nan",
            "discretization.h",
        ),
        bad_set("nonfinite-inf-E", "9 schema", "E = inf", "material.E=inf", "material.E"),
        bad_set("huge-E", "5 garbage", "E = 1e308 (alpha overflows)", "material.E=1e308", None),
    ]


def petsc_cases() -> list[Case]:
    ok = dict(timeout=RUN)
    return [
        Case(
            "petsc-misspelled",
            "5 PETSc options",
            "-ksp_tpye gmres (warn)",
            run_args(*QUICK, "-ksp_tpye", "gmres", scene="square"),
            0,
            allow_warning=True,
            check=lambda ctx, r: None if "ksp_tpye" in r.stderr else "no warning naming ksp_tpye",
            **ok,
        ),
        Case(
            "petsc-linesearch-l2",
            "4 one-line",
            "-snes_linesearch_type l2",
            run_args(*QUICK, "-snes_linesearch_type", "l2", scene="square"),
            2,
            "linesearch",
        ),
        # an inexact linear solve: the step is refined to the tolerance, or the run fails
        Case(
            "petsc-cg-jacobi-loose",
            "5 PETSc options",
            "-ksp_type cg -pc_type jacobi -ksp_rtol 1e-1",
            run_args(
                *QUICK, "-ksp_type", "cg", "-pc_type", "jacobi", "-ksp_rtol", "1e-1", scene="square"
            ),
            0,
            **ok,
        ),
        Case(
            "petsc-ksp-bogus",
            "4 one-line",
            "-ksp_type bogus",
            run_args(*QUICK, "-ksp_type", "bogus", scene="square"),
            2,
            "ksp_type",
        ),
        Case(
            "petsc-ksp-bogus-linear",
            "4 one-line",
            "-ksp_type bogus, no contact",
            run_args("-ksp_type", "bogus"),
            2,
            "ksp_type",
            dynamic_scene(4),
        ),
        Case(
            "petsc-factor-nope",
            "4 one-line",
            "-pc_factor_mat_solver_type nope",
            run_args(*QUICK, "-pc_factor_mat_solver_type", "nope", scene="square"),
            2,
            "nope|solver_type",
        ),
        Case(
            "petsc-pc-bogus",
            "4 one-line",
            "-pc_type bogus",
            run_args(*QUICK, "-pc_type", "bogus", scene="square"),
            2,
            "pc_type",
        ),
        Case(
            "petsc-ksp-bogus-2r",
            "4 one-line",
            "-ksp_type bogus, 2 ranks",
            run_args(*QUICK, "-ksp_type", "bogus", scene="square"),
            2,
            "ksp_type",
            ranks=2,
        ),
        Case(
            "solver-table-bogus",
            "5 [solver]",
            "[solver] ksp_type = bogus",
            run_args(*QUICK, "--set", 'solver.ksp_type="bogus"', scene="square"),
            2,
            "ksp_type",
        ),
        Case(
            "solver-table-applied",
            "5 [solver]",
            "[solver] snes_monitor = true",
            run_args(*QUICK, "--set", "solver.snes_monitor=true", scene="square"),
            0,
            check=expect_stdout("SNES Function norm"),
            **ok,
        ),
        Case(
            "solver-table-name",
            "9 schema",
            "[solver] 'ksp_type;rm' = x",
            run_args(*QUICK, "--set", 'solver.ksp_type;rm="x"', scene="square"),
            2,
            "solver",
        ),
        Case(
            "petsc-ok",
            "9 baseline",
            "-snes_monitor works",
            run_args(*QUICK, "-snes_monitor", scene="square"),
            0,
            check=expect_stdout("SNES Function norm"),
            **ok,
        ),
    ]


def out_cases() -> list[Case]:
    def bad_out(cid, what, out, message="--out|output", setup=None, **kw):
        return Case(
            cid,
            "4 --out",
            what,
            ["run", "square", *QUICK, "--out", out, "--quiet"],
            2,
            message,
            setup=setup,
            out_dirs=(),
            **kw,
        )

    return [
        bad_out("out-proc", "--out under /proc", "/proc/parefg-hostile/run"),
        bad_out("out-sys", "--out under /sys", "/sys/parefg-hostile"),
        bad_out("out-under-file", "--out under a file", "@WORK@/afile/run", setup=_regular_file),
        bad_out("out-dangling", "--out dangling symlink", "@WORK@/dangling", setup=_dangling),
        bad_out("out-long-name", "--out 5000-char name", "@WORK@/" + "d" * 5000),
        bad_out("out-long-path", "--out 300 nested dirs", "@WORK@/" + "/".join(["d" * 20] * 300)),
        bad_out("out-dev-null", "--out /dev/null", "/dev/null"),
        bad_out("out-is-file", "--out is a file", "@OUT@", setup=_out_is_file, message="exists"),
        bad_out(
            "out-taken",
            "--out non-empty: untouched",
            "@OUT@",
            setup=_taken_out,
            message="exists|not empty",
            check=expect_untouched("out/notes.txt", "mine\n"),
        ),
        bad_out(
            "out-2-ranks",
            "--out under file, 2 ranks",
            "@WORK@/afile/run",
            setup=_regular_file,
            ranks=2,
        ),
        Case(
            "out-empty-dir",
            "9 baseline",
            "--out existing empty dir",
            ["run", "square", *QUICK, "--out", "@OUT@", "--quiet"],
            0,
            setup=_empty_out,
            timeout=RUN,
        ),
        Case(
            "out-no-square-2",
            "5 nothing left",
            "runs/square taken, bad mesh",
            ["run", "square", *QUICK, "--set", "discretization.support=1.05", "--quiet"],
            2,
            "support",
            setup=_previous_run,
            out_dirs=(),
            timeout=RUN,
        ),
        Case(
            "out-bad-input-no-runs",
            "5 nothing left",
            "bad input, default out",
            ["run", "square", "--set", "material.nu=0.7", "--quiet"],
            2,
            "material.nu",
            out_dirs=(),
        ),
        Case(
            "out-bad-mesh-no-runs",
            "5 nothing left",
            "support 1.05, default out",
            ["run", "square", *QUICK, "--set", "discretization.support=1.05", "--quiet"],
            2,
            "support",
            out_dirs=(),
            timeout=RUN,
        ),
        Case(
            "out-bad-solver-no-runs",
            "5 nothing left",
            "-ksp_type bogus, default out",
            ["run", "square", *QUICK, "-ksp_type", "bogus", "--quiet"],
            2,
            "ksp_type",
            out_dirs=(),
            timeout=RUN,
        ),
    ]


def checkpoint_cases() -> list[Case]:
    def bad(cid, what, setup, message="restart", extra=(), **kw):
        kw.setdefault("timeout", RUN)
        return Case(
            cid,
            "5 checkpoint" if kw.pop("tag", "") == "fingerprint" else "4 checkpoint",
            what,
            ["run", "square", *QUICK, *extra, *RESTART, "--out", "@OUT@", "--quiet"],
            2,
            message,
            setup=setup,
            out_dirs=(),
            **kw,
        )

    return [
        bad("ckpt-foreign-h5", "foreign .h5", _foreign_h5),
        bad("ckpt-result-h5", "a result.h5", checkpoint_variant(source="result")),
        bad("ckpt-missing-u", "dataset u missing", checkpoint_variant(_drop("u"))),
        bad("ckpt-missing-slip", "dataset slip missing", checkpoint_variant(_drop("slip"))),
        bad("ckpt-shape-u", "u of shape (2n, 1)", checkpoint_variant(_reshape("u"))),
        bad("ckpt-shape-slip", "slip of wrong shape", checkpoint_variant(_reshape("slip"))),
        bad(
            "ckpt-bad-json",
            "history_json not JSON",
            checkpoint_variant(_attr("history_json", "{oops")),
        ),
        bad("ckpt-json-list", "history_json = []", checkpoint_variant(_attr("history_json", "[]"))),
        bad(
            "ckpt-no-step",
            "step attr missing",
            checkpoint_variant(lambda h: h.attrs.__delitem__("step")),
        ),
        bad(
            "ckpt-step-1e6",
            "step = 1e6",
            checkpoint_variant(_attr("step", 1000000)),
            tag="fingerprint",
        ),
        bad("ckpt-step-neg", "step = -5", checkpoint_variant(_attr("step", -5)), tag="fingerprint"),
        bad("ckpt-step-str", "step = 'two'", checkpoint_variant(_attr("step", "two"))),
        bad(
            "ckpt-other-dt",
            "written with other dt",
            checkpoint_variant(),
            extra=("--set", "time.dt=0.125"),
            tag="fingerprint",
        ),
        bad(
            "ckpt-other-degree",
            "written with other degree",
            checkpoint_variant(),
            extra=("--set", "discretization.degree=1"),
            tag="fingerprint",
        ),
        bad(
            "ckpt-other-E",
            "written with other E",
            checkpoint_variant(),
            extra=("--set", "material.E=2"),
            tag="fingerprint",
        ),
        bad(
            "ckpt-other-h",
            "other node count",
            checkpoint_variant(),
            extra=("--set", "discretization.h=0.25"),
            message="discretization.h",
        ),
        bad("ckpt-text", "text file", lambda ctx: (ctx["work"] / "ckpt.h5").write_text("hello\n")),
        bad("ckpt-empty", "empty file", lambda ctx: (ctx["work"] / "ckpt.h5").write_bytes(b"")),
        bad("ckpt-missing", "no such file", None),
        bad("ckpt-directory", "a directory", lambda ctx: (ctx["work"] / "ckpt.h5").mkdir()),
        bad("ckpt-fifo", "a FIFO (hangs today)", _fifo, timeout=FAST),
        Case(
            "ckpt-dev-zero",
            "4 checkpoint",
            "--restart /dev/zero",
            ["run", "square", *QUICK, "--restart", "/dev/zero", "--out", "@OUT@", "--quiet"],
            2,
            "restart",
            out_dirs=(),
            timeout=RUN,
        ),
        bad("ckpt-2-ranks", "foreign .h5, 2 ranks", _foreign_h5, ranks=2),
        Case(
            "ckpt-retry-same-out",
            "5 nothing left",
            "bad --restart, then same --out",
            ["run", "square", *QUICK, *RESTART, "--out", "@OUT@", "--quiet"],
            2,
            "restart",
            setup=_foreign_h5,
            check=retry_without_restart,
            timeout=RUN,
            out_dirs=(),
        ),
        Case(
            "ckpt-ok",
            "9 baseline",
            "valid checkpoint resumes",
            ["run", "square", *QUICK, *RESTART, "--out", "@OUT@", "--quiet"],
            0,
            setup=checkpoint_variant(),
            check=expect_summary(status="ok"),
            timeout=RUN,
        ),
    ]


def polygon_cases() -> list[Case]:
    def polygon(vertices, names=None):
        names = names or ["bottom", "right", "top", "left"][: len(vertices)]
        names = names + ["sides"] * (len(vertices) - len(names))
        return static_scene({"shape": "polygon", "vertices": vertices, "edge_names": names})

    bowtie = [[0, 0], [1, 1], [1, 0], [0, 1]]  # zero signed area: refused today
    # counter-clockwise (area 2) yet edge 3 crosses edge 1: gmsh aborts (exit 134) today
    crossing = [[0, 0], [4, 0], [4, 2], [1, -1], [0, 2]]
    intersect = "polygon|vertices|intersect|cross"
    return [
        Case(
            "poly-bowtie",
            "4 polygon",
            "bow-tie (zero area)",
            run_args(),
            2,
            intersect,
            polygon(bowtie),
        ),
        Case(
            "poly-self-intersect",
            "4 polygon",
            "self-intersecting, CCW",
            run_args(),
            2,
            intersect,
            polygon(crossing),
        ),
        Case(
            "poly-self-intersect-2r",
            "4 polygon",
            "self-intersecting, 2 ranks",
            run_args(),
            2,
            intersect,
            polygon(crossing),
            ranks=2,
        ),
        Case(
            "poly-duplicate",
            "4 polygon",
            "repeated vertex",
            run_args(),
            2,
            "vert|degenerate",
            polygon([[0, 0], [1, 0], [1, 0], [1, 1], [0, 1]]),
        ),
        Case(
            "poly-collinear",
            "4 polygon",
            "zero-area polygon",
            run_args(),
            2,
            "vertices|area",
            polygon([[0, 0], [1, 0], [2, 0], [3, 0]]),
        ),
        Case(
            "poly-two-vertices",
            "9 schema",
            "2 vertices",
            run_args(),
            2,
            "vertices",
            polygon([[0, 0], [1, 0]], ["bottom", "top"]),
        ),
        Case(
            "poly-nan-vertex",
            "9 schema",
            "vertex = nan",
            run_args(),
            2,
            "vertices",
            polygon([[0, 0], [1, 0], [float("nan"), 1], [0, 1]]),
        ),
    ]


def baseline_cases() -> list[Case]:
    """What parefg handles today (see tests/cli/test_cli.py, tests/scene/test_fuzz.py)."""
    payload = "__import__('os').system('touch @SENTINEL@')"
    cases = [
        Case(
            "ok-square",
            "9 baseline",
            "built-in square, quick",
            run_args(*QUICK, scene="square"),
            0,
            check=expect_summary(status="ok"),
            timeout=RUN,
        ),
        Case(
            "ok-square-2r",
            "9 baseline",
            "built-in square, 2 ranks",
            run_args(*QUICK, scene="square"),
            0,
            check=expect_summary(status="ok", mpi_ranks=2),
            ranks=2,
            timeout=RUN,
        ),
        Case(
            "ok-impact",
            "9 baseline",
            "built-in impact, T = 0.05",
            run_args("--set", "time.T=0.05", scene="impact"),
            0,
            timeout=RUN,
        ),
        bad_set(
            "unknown-key", "9 schema", "discretization.hh", "discretization.hh=0.1", "unknown key"
        ),
        bad_set(
            "wrong-type",
            "9 schema",
            'h = "coarse"',
            'discretization.h="coarse"',
            "discretization.h",
        ),
        bad_set("h-zero", "9 schema", "h = 0", "discretization.h=0", "discretization.h"),
        bad_set("h-negative", "9 schema", "h = -0.1", "discretization.h=-0.1", "discretization.h"),
        bad_set("dt-zero", "9 schema", "dt = 0", "time.dt=0", "time.dt"),
        bad_set("dt-not-dividing", "9 schema", "T / dt not integer", "time.dt=0.3", "time.dt"),
        bad_set("nu-half", "9 schema", "nu = 0.5", "material.nu=0.5", "material.nu"),
        bad_set(
            "nu-2-ranks", "9 schema", "nu = 0.7, 2 ranks", "material.nu=0.7", "material.nu", ranks=2
        ),
        bad_set("rho-zero", "9 schema", "rho = 0", "material.rho=0", "material.rho"),
        bad_set(
            "unknown-part",
            "9 schema",
            "boundary.nowhere",
            'boundary.nowhere.type="dirichlet"',
            "nowhere",
        ),
        bad_set(
            "degree-4", "9 schema", "degree = 4", "discretization.degree=4", "discretization.degree"
        ),
        bad_set(
            "weight-bogus",
            "9 schema",
            'weight = "linear"',
            'discretization.weight="linear"',
            "weight",
        ),
        bad_set("unknown-section", "9 schema", "[bogus] section", "bogus.x=1", "bogus"),
        bad_set("set-malformed", "9 schema", "--set without =", "discretization.h", "--set"),
        bad_set(
            "eval-class",
            "9 expressions",
            "().__class__",
            'exact.u=["().__class__", "0"]',
            "not allowed",
        ),
        bad_set(
            "eval-import",
            "9 expressions",
            "__import__ payload",
            f'loads.f=["{payload}", "0"]',
            "loads.f",
        ),
        bad_set(
            "eval-open",
            "9 expressions",
            "open(SENTINEL)",
            "loads.f=[\"open('@SENTINEL@', 'w')\", 0]",
            "loads.f",
        ),
        bad_set(
            "eval-lambda",
            "9 expressions",
            "lambda payload",
            "loads.f=[\"(lambda: open('@SENTINEL@', 'w'))()\", 0]",
            "loads.f",
        ),
        bad_set("eval-unknown-symbol", "9 expressions", "f = z", 'loads.f=["z", 0]', "loads.f"),
        bad_set(
            "support-small",
            "9 MLS",
            "support = 1.05",
            "discretization.support=1.05",
            "support",
            timeout=RUN,
        ),
        Case(
            "toml-syntax",
            "9 schema",
            "TOML syntax error",
            run_args(),
            2,
            "TOML",
            '[domain\nshape = "square"\n',
        ),
        Case(
            "toml-binary",
            "9 schema",
            "binary garbage scene",
            run_args(),
            2,
            "TOML",
            "\x00\x01\x02\xff garbage\n",
        ),
        Case(
            "scene-missing",
            "9 schema",
            "no such scene",
            run_args(scene="@WORK@/nope.toml"),
            2,
            "nope",
        ),
        Case(
            "scene-unknown-name",
            "9 schema",
            "unknown built-in",
            run_args(scene="squarez"),
            2,
            "squarez",
        ),
        Case(
            "scene-directory",
            "9 schema",
            "scene is a directory",
            run_args(scene="@WORK@/dir.toml"),
            2,
            "dir",
            setup=lambda ctx: (ctx["work"] / "dir.toml").mkdir(),
        ),
        Case(
            "scene-fifo",
            "9 schema",
            "scene is a FIFO",
            run_args(scene="@WORK@/fifo.toml"),
            2,
            "fifo",
            setup=lambda ctx: os.mkfifo(ctx["work"] / "fifo.toml"),
        ),
        Case(
            "fail-at-step",
            "9 solver failure",
            "--fail-at-step 3 -> kept",
            run_args(*QUICK, "--fail-at-step", "3", scene="square"),
            1,
            "step 3",
            timeout=RUN,
        ),
        Case(
            "fail-at-step-2r",
            "9 solver failure",
            "--fail-at-step 3, 2 ranks",
            run_args(*QUICK, "--fail-at-step", "3", scene="square"),
            1,
            "step 3",
            ranks=2,
            timeout=RUN,
        ),
        Case(
            "cli-unknown-option",
            "9 CLI",
            "--frobnicate",
            ["run", "square", "--frobnicate"],
            2,
            "unrecognized",
            allow_usage=True,
            out_dirs=(),
        ),
        Case(
            "cli-checkpoint-neg",
            "9 CLI",
            "--checkpoint-every -1",
            run_args(*QUICK, "--checkpoint-every", "-1", scene="square"),
            2,
            "checkpoint",
        ),
        Case(
            "sweep-bad-vary",
            "9 CLI",
            "sweep --vary h=-1",
            ["sweep", "square", "--vary", "discretization.h=-1", "--out", "@OUT@"],
            2,
            "discretization.h",
        ),
        Case("info", "9 CLI", "parefg info", ["info"], 0, out_dirs=()),
    ]
    return cases


def all_cases() -> list[Case]:
    cases = [
        *baseline_cases(),
        *geo_cases(),
        *name_cases(),
        *size_cases(),
        *symbolic_cases(),
        *value_cases(),
        *petsc_cases(),
        *out_cases(),
        *checkpoint_cases(),
        *polygon_cases(),
        *output_cases(),
    ]
    ids = [case.id for case in cases]
    duplicated = {i for i in ids if ids.count(i) > 1}
    assert not duplicated, duplicated
    return cases


# ----------------------------------------------------------------------------- running


@dataclass
class Result:
    """What one case did and which checks it failed."""

    case: Case
    code: int | str = "?"
    stdout: str = ""
    stderr: str = ""
    seconds: float = 0.0
    failed: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)  # the harness's own observations
    root: str = "/nonexistent"  # the case's temporary tree, shown as ROOT in messages

    @property
    def message(self) -> str:
        lines = [line for line in self.stderr.splitlines() if line.strip()]
        errors = [line for line in lines if line.startswith(ERROR_LINE)]
        if not errors and any(line.startswith("Traceback") for line in lines):
            return lines[-1].strip().replace(self.root, "ROOT")  # the exception's own line
        first = (errors or lines or [""])[0]
        return first.removeprefix(ERROR_LINE).strip().replace(self.root, "ROOT")


def substitute(text: str, ctx: dict) -> str:
    for token, key in (
        ("@SENTINEL@", "sentinel"),
        ("@OUT@", "out"),
        ("@WORK@", "work"),
        ("@HOME@", "home"),
        ("@ROOT@", "root"),
        ("@REPO@", "repo"),
    ):
        text = text.replace(token, str(ctx[key]))
    return text


def snapshot(root: Path, skip: Path) -> dict[str, tuple]:
    """path -> (kind, size, mtime_ns) of everything under ``root`` but ``skip``.

    Directories count by their existence only (their mtime moves whenever an entry is
    added, e.g. when the run creates its --out inside the working directory).
    """
    entries = {}
    for dirpath, dirnames, filenames in os.walk(root):
        here = Path(dirpath)
        if here == skip:
            dirnames[:] = []
            continue
        for name in dirnames:
            entries[str(here / name)] = ("dir",)
        for name in filenames:
            info = (here / name).lstat()
            entries[str(here / name)] = (info.st_mode >> 12, info.st_size, info.st_mtime_ns)
    return entries


def session_processes(sid: int) -> dict[int, str]:
    """Live (not zombie) processes of session ``sid`` -> their command name."""
    found = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            head, tail = (entry / "stat").read_text().rsplit(")", 1)
        except OSError:
            continue
        fields = tail.split()  # state ppid pgrp session ...
        if int(fields[3]) == sid and fields[0] != "Z":
            found[int(entry.name)] = head.split("(", 1)[1]
    return found


def session_pids(sid: int) -> list[int]:
    return list(session_processes(sid))


_ACTIVE: set[int] = set()  # sessions of the cases now running (killed if the script is)


def kill_session(sid: int) -> None:
    for pid in session_pids(sid):
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass


def make_context(case: Case, parefg: str) -> dict:
    root = Path(tempfile.mkdtemp(prefix=f"hostile-{case.id[:40]}-"))
    home, work, tmp = root / "home", root / "home" / "work", root / "tmp"
    for path in (work, tmp):
        path.mkdir(parents=True)
    env = {
        "PATH": os.environ.get("PATH", "/usr/bin:/bin"),
        "HOME": str(home),
        "TMPDIR": str(tmp),
        "LANG": "C.UTF-8",
        "OMPI_ALLOW_RUN_AS_ROOT": "1",
        "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM": "1",
        "OMPI_MCA_rmaps_base_oversubscribe": "1",
    }
    # numba's cache of the package's kernels lives next to the package, not in $HOME
    for key in ("NUMBA_CACHE_DIR", "NPY_DISABLE_CPU_FEATURES", "OMPI_MCA_btl"):
        if key in os.environ:
            env[key] = os.environ[key]
    prefix = ["prlimit", f"--as={MEMORY_LIMIT}", "--", parefg]
    return dict(
        root=root,
        home=home,
        work=work,
        tmp=tmp,
        out=work / "out",
        sentinel=root / "SENTINEL",
        repo=REPO,
        env=env,
        prefix=prefix,
    )


def command_of(case: Case, ctx: dict) -> list[str]:
    args = [substitute(arg, ctx) for arg in case.args]
    command = [*ctx["prefix"], *args]
    if case.ranks > 1:
        command = ["prlimit", f"--as={MEMORY_LIMIT}", "--", "mpirun", "-q", "-n", str(case.ranks)]
        command += [ctx["prefix"][-1], *args]
    return command


def prepare(case: Case, ctx: dict) -> None:
    if case.scene is not None:
        (ctx["work"] / "scene.toml").write_text(substitute(case.scene, ctx))
    for name, text in case.files.items():
        (ctx["work"] / name).write_text(substitute(text, ctx))
    if case.setup is not None:
        case.setup(ctx)


def drain(stream, lines: list[str], seen: threading.Event | None) -> None:
    for line in iter(stream.readline, ""):
        lines.append(line)
        if seen is not None and re.search(r"\bstep\s+\d+", line):
            seen.set()
    stream.close()


def execute(case: Case, ctx: dict, scale: float, result: Result) -> None:
    """Run the case's command; fill ``result`` (exit code or 'TIMEOUT', output, notes)."""
    command = command_of(case, ctx)
    # mpirun adds seconds of start-up on a busy machine
    timeout = (case.timeout if case.ranks == 1 else max(case.timeout, 25.0)) * scale
    start = time.monotonic()
    proc = subprocess.Popen(
        command,
        cwd=ctx["work"],
        env=ctx["env"],
        stdin=subprocess.PIPE,  # never written: a prompt waits instead of reading EOF
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        errors="replace",
        start_new_session=True,
    )
    _ACTIVE.add(proc.pid)
    out_lines: list[str] = []
    err_lines: list[str] = []
    progress = threading.Event()
    readers = [
        threading.Thread(target=drain, args=(proc.stdout, out_lines, progress), daemon=True),
        threading.Thread(target=drain, args=(proc.stderr, err_lines, None), daemon=True),
    ]
    for reader in readers:
        reader.start()
    code: int | str
    try:
        if case.sigint:
            if not progress.wait(timeout / 2):
                result.notes.append("no progress line before SIGINT")
                result.failed.append("progress")
            os.killpg(proc.pid, signal.SIGINT)  # what a terminal's Ctrl-C does
        code = proc.wait(timeout=max(0.1, timeout - (time.monotonic() - start)))
    except subprocess.TimeoutExpired:
        code = "TIMEOUT"
    seconds = time.monotonic() - start
    if code == "TIMEOUT":
        kill_session(proc.pid)
        proc.wait()
    else:
        # ranks may take a moment to go after mpirun; a detached child would stay
        deadline = time.monotonic() + 3.0
        while session_processes(proc.pid) and time.monotonic() < deadline:
            time.sleep(0.1)
        survivors = session_processes(proc.pid)
        if survivors:
            names = ", ".join(sorted(set(survivors.values())))
            result.notes.append(f"processes of the run survived it: {names}")
            result.failed.append("executed")
            kill_session(proc.pid)
    _ACTIVE.discard(proc.pid)
    for reader in readers:
        reader.join(timeout=5)
    proc.stdin.close()
    result.code, result.seconds = code, seconds
    result.stdout, result.stderr = "".join(out_lines), "".join(err_lines)


def bad_input_expected(case: Case) -> bool:
    return case.codes == (2,)


def check_stderr(case: Case, result: Result) -> None:
    """One ``parefg: error:`` line for exit 1 / 2; nothing (or warnings) for 0 / 130."""
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    if case.allow_usage:
        lines = [line for line in lines if not line.startswith(("usage:", " "))]
    if case.allow_warning:
        lines = [line for line in lines if not line.startswith(WARNING_LINE)]
    if result.code == 130:  # an "interrupted at step n" line is fine
        lines = [line for line in lines if not line.startswith("parefg:")]
    if result.code in (0, 130):
        if lines:
            result.failed.append("oneline")
    elif len(lines) != 1 or not lines[0].startswith(ERROR_LINE):
        result.failed.append("oneline")
    if NATIVE_CRASH.search(result.stderr) or NATIVE_CRASH.search(result.stdout):
        result.failed.append("crash-text")
    if case.message and not re.search(case.message, result.message, re.I):
        result.failed.append("message")


def check_files(case: Case, ctx: dict, result: Result, before: dict) -> None:
    """Nothing executed; nothing changed outside the output directory (for bad input: at all)."""
    if list(ctx["root"].glob("SENTINEL*")) and "executed" not in result.failed:
        result.failed.append("executed")
    after = snapshot(ctx["root"], ctx["tmp"])
    changed = [p for p in after if before.get(p) != after[p]]
    changed += [p for p in before if p not in after]
    bad_input = (result.code == 2 or bad_input_expected(case)) and not case.kept
    allowed = [] if bad_input else [substitute(d, ctx) for d in case.out_dirs]
    outside = [p for p in changed if not any(p == a or p.startswith(a + "/") for a in allowed)]
    # dot-files a library drops into $HOME (FLTK's preferences, written by gmsh.initialize)
    in_home = [p for p in outside if is_home_dotfile(Path(rel(p, ctx)).parts)]
    if in_home:
        result.failed.append("home")
        result.notes.append("wrote into $HOME: " + ", ".join(rel(p, ctx) for p in in_home[:3]))
    outside = [p for p in outside if p not in in_home]
    if outside:
        result.failed.append("leftover" if bad_input else "outside")
        result.notes.append("changed: " + ", ".join(rel(p, ctx) for p in sorted(outside)[:4]))


def is_home_dotfile(parts: tuple[str, ...]) -> bool:
    return len(parts) >= 2 and parts[0] == "home" and parts[1].startswith(".")


def rel(path: str, ctx: dict) -> str:
    return os.path.relpath(path, ctx["root"])


def judge(case: Case, ctx: dict, result: Result, before: dict) -> None:
    if result.code not in case.codes:
        result.failed.append("exit")
    check_stderr(case, result)
    check_files(case, ctx, result, before)
    out = ctx["out"] if "@OUT@" in case.args else None
    failed = result.code == 1 and 1 in case.codes and not case.sigint
    if failed or (case.kept and result.code == 2):
        reason = readable_output(out, "failed")
        if reason:
            result.failed.append("kept")
            result.notes.append(reason)
    if case.sigint and result.code in case.codes and result.code != 0:
        reason = readable_output(out, "interrupted")
        if reason:
            result.failed.append("interrupted")
            result.notes.append(reason)
    if case.check is not None and result.code in case.codes and "harness" not in result.failed:
        try:
            reason = case.check(ctx, result)
        except Exception as error:  # a missing file or dataset is a failed check
            reason = f"{type(error).__name__}: {error}"
        if reason:
            result.failed.append("check")
            result.notes.append(reason)


def readable_output(out: Path | None, status: str) -> str | None:
    """None if result.h5 (with /history) and summary.json (with ``status``) are readable."""
    if out is None:
        return "no --out to inspect"
    try:
        summary = json.loads((out / "summary.json").read_text())
        with h5_open(out / "result.h5") as handle:
            rows = len(handle["history/time"])
    except Exception as error:
        return f"{type(error).__name__}: {error}"
    if summary.get("status") != status or rows < 1:
        return f"status {summary.get('status')!r}, {rows} history rows"
    return None


def run_case(case: Case, parefg: str, scale: float, keep: bool) -> Result:
    ctx = make_context(case, parefg)
    result = Result(case, root=str(ctx["root"]))
    try:
        prepare(case, ctx)
        before = snapshot(ctx["root"], ctx["tmp"])
        execute(case, ctx, scale, result)
        judge(case, ctx, result, before)
    except Exception as error:  # the harness itself failed on this case
        result.failed.append("harness")
        result.notes.append(f"harness error: {type(error).__name__}: {error}")
    finally:
        if keep:
            result.notes.append(f"kept {ctx['root']}")
        else:
            shutil.rmtree(ctx["root"], ignore_errors=True)
    return result


# ----------------------------------------------------------------------------- report


def cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def table(results: list[Result]) -> str:
    rows = [
        "| id | item | input | exit (expected) | message | checks | time [s] |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in results:
        expected = "/".join(map(str, r.case.codes))
        checks = "ok" if not r.failed else "FAIL: " + ", ".join(r.failed)
        rows.append(
            f"| {r.case.id} | {r.case.item} | {cell(r.case.what)} | {r.code} ({expected}) | "
            f"{cell(r.message[:70])} | {checks} | {r.seconds:.1f} |"
        )
    return "\n".join(rows)


def write_csv(path: Path, results: list[Result]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as stream:
        writer = csv.writer(stream)
        writer.writerow(
            [
                "id",
                "item",
                "input",
                "args",
                "ranks",
                "expected",
                "exit",
                "passed",
                "failed_checks",
                "message",
                "seconds",
                "diagnostics",
            ]
        )
        for r in results:
            diagnostics = " / ".join(r.notes)
            writer.writerow(
                [
                    r.case.id,
                    r.case.item,
                    r.case.what,
                    " ".join(r.case.args),
                    r.case.ranks,
                    "/".join(map(str, r.case.codes)),
                    r.code,
                    not r.failed,
                    " ".join(r.failed),
                    r.message[:200],
                    f"{r.seconds:.2f}",
                    diagnostics,
                ]
            )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--parefg", default=str(REPO / ".venv" / "bin" / "parefg"))
    parser.add_argument(
        "-k",
        action="append",
        default=[],
        metavar="SUBSTRING",
        help="run only cases whose id or item contains SUBSTRING (repeatable)",
    )
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--list", action="store_true", help="list the cases and exit")
    parser.add_argument("--out", default=str(REPO / "results" / "hostile"))
    parser.add_argument("--keep", action="store_true", help="keep each case's temporary tree")
    parser.add_argument(
        "--timeout-scale",
        type=float,
        default=1.0,
        help="multiply every timeout (slow or busy machines)",
    )
    args = parser.parse_args(argv)
    cases = all_cases()
    if args.k:
        cases = [c for c in cases if any(k in c.id or k in c.item for k in args.k)]
    if args.list:
        for case in cases:
            expected = "/".join(map(str, case.codes))
            print(f"{case.id:<28} {case.item:<18} exit {expected:<5} {case.what}")
        print(f"{len(cases)} cases")
        return 0
    if not Path(args.parefg).is_file():
        parser.error(f"--parefg {args.parefg}: no such file")
    # Ctrl-C and kill end the script through the finally below (also when started in the
    # background of a shell, which would ignore SIGINT)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    start = time.monotonic()
    try:
        results = run_all(cases, args)
    except KeyboardInterrupt:
        print("hostile_inputs: interrupted; the running cases were killed", file=sys.stderr)
        return 130
    finally:  # also on Ctrl-C of this script: no case's processes outlive it
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # a second Ctrl-C must not stop this
        for sid in list(_ACTIVE):
            kill_session(sid)
        if "base" in _CHECKPOINT:
            shutil.rmtree(_CHECKPOINT["base"], ignore_errors=True)
    print(table(results))
    bad = [r for r in results if r.failed]
    print(
        f"\n{len(results) - len(bad)}/{len(results)} cases behaved; "
        f"{time.monotonic() - start:.0f} s"
    )
    csv_path = Path(args.out) / "hostile_inputs.csv"
    write_csv(csv_path, results)
    print(f"CSV: {csv_path}")
    return 1 if bad else 0


def run_all(cases: list[Case], args) -> list[Result]:
    """Run ``cases`` on ``args.jobs`` threads; progress on stderr; results in case order."""
    pool = ThreadPoolExecutor(max_workers=max(1, args.jobs))
    try:
        futures = [
            pool.submit(run_case, c, args.parefg, args.timeout_scale, args.keep) for c in cases
        ]
        results = []
        for future in futures:
            result = future.result()
            results.append(result)
            status = "ok" if not result.failed else "FAIL " + ",".join(result.failed)
            print(
                f"[{len(results)}/{len(cases)}] {result.case.id}: {result.code} {status}",
                file=sys.stderr,
                flush=True,
            )
    finally:  # on Ctrl-C: start nothing new (the caller kills what runs)
        pool.shutdown(wait=False, cancel_futures=True)
    return results


if __name__ == "__main__":
    sys.exit(main())
