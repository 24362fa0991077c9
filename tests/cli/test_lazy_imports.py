"""Light commands stay light: ``import parefg.cli``, ``parefg --help`` and ``parefg scenes``
import none of the heavy layers a run needs (sympy, matplotlib, h5py, numba, gmsh), a
run whose scene data and mesh are cached imports neither sympy nor gmsh, a run on a
rectangle or the Z never imports gmsh (each rank makes its part), and a run of the
default scene (small: numpy kernels, parefg.discretization.backends) never imports numba.

Each case runs in a fresh interpreter (``sys.modules`` of this one is full of them) and
prints, as its last line, the heavy modules it ended up with.
"""

import json
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import QUICK, REPO, mpi_env

HEAVY = ("sympy", "matplotlib", "h5py", "numba", "gmsh")
# scene -> what its first run imports of gmsh and sympy: the built-in domains are made part
# by part, without gmsh (grid_parts, patch_parts); a jittered Z is meshed by gmsh
FIRST_RUN_IMPORTS = {"square": "sympy", "z": "sympy"}
JITTERED_Z = ["z", "--set", "discretization.jitter=0.1"]
PROBE = """
import sys
from parefg import cli
argv = {argv!r}
code = 0
if argv is not None:
    try:
        code = cli.main(argv)
    except SystemExit as exit:
        code = exit.code
print(" ".join(sorted(name for name in {heavy!r} if name in sys.modules)))
sys.exit(code or 0)
"""


@pytest.mark.serial_only
@pytest.mark.parametrize("argv", [None, ["--help"], ["scenes"]], ids=["import", "help", "scenes"])
def test_light_commands_import_no_heavy_module(argv):
    probe = PROBE.format(argv=argv, heavy=HEAVY)
    result = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, env=mpi_env(), timeout=120
    )
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    if argv == ["scenes"]:  # the command itself worked: it listed the default scene
        assert any(line.startswith("square ") for line in lines), result.stdout
    assert lines[-1] == "", f"imported {lines[-1]}"


def probe_run(argv, heavy, env, cwd=None) -> tuple[str, dict]:
    """Run ``parefg argv`` (a run with --out) in a fresh interpreter: the ``heavy`` modules
    it imported (space-separated) and its summary.json without timings and memory."""
    probe = PROBE.format(argv=argv, heavy=heavy)
    result = subprocess.run(
        [sys.executable, "-c", probe],
        capture_output=True, text=True, env=env, timeout=300, cwd=cwd,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    out = Path(argv[argv.index("--out") + 1])
    summary = json.loads((out / "summary.json").read_text())
    return result.stdout.splitlines()[-1], {
        key: value for key, value in summary.items() if key not in ("timings", "peak_rss_mb")
    }


@pytest.mark.serial_only
@pytest.mark.parametrize("scene, first", [*FIRST_RUN_IMPORTS.items(), ("jittered-z", "gmsh sympy")])
def test_a_run_of_a_cached_scene_imports_neither_sympy_nor_gmsh(tmp_path, scene, first):
    """The first run derives the scene's data (sympy) and meshes (gmsh; only the jittered
    Z), the next one reads both from the user cache: same results, and neither sympy nor
    gmsh imported.  Neither run imports numba (the kernels compiled ahead of time, or
    numpy's below backends.NUMBA_MIN_NODES)."""
    env = {**mpi_env(), "PAREFG_CACHE_DIR": str(tmp_path / "cache")}
    env.pop("PAREFG_SCENE_CACHE", None)
    env.pop("PAREFG_KERNELS", None)
    imported, results = [], []
    source = JITTERED_Z if scene == "jittered-z" else [scene]
    for run in ("derived", "cached"):
        argv = ["run", *source, "--quiet", "--out", str(tmp_path / run), *QUICK]
        heavy, summary = probe_run(argv, ("gmsh", "numba", "sympy"), env)
        imported.append(heavy)
        results.append(summary)
    assert imported == [first, ""]
    assert results[0] == results[1]


@pytest.mark.serial_only
@pytest.mark.parametrize("scene", FIRST_RUN_IMPORTS)
def test_a_run_of_a_prebuilt_scene_imports_neither_sympy_nor_gmsh_and_writes_nowhere(
    tmp_path, scene
):
    """`make setup` prebuilds the built-in scenes (scripts/setup/prebuild_scenes.py): a run
    of one at its defaults (dt is not part of what is prebuilt) then reads the prebuilt data
    and mesh, with no user cache: neither sympy nor gmsh imported, the results of a run
    that derives and meshes (PAREFG_CACHE=0), and nothing written but the output."""
    prebuilt, home = tmp_path / "prebuilt", tmp_path / "home"
    home.mkdir()
    env = {**mpi_env(), "HOME": str(home), "PAREFG_PREBUILT_DIR": str(prebuilt)}
    for name in ("PAREFG_CACHE", "PAREFG_CACHE_DIR", "PAREFG_SCENE_CACHE", "XDG_CACHE_HOME"):
        env.pop(name, None)
    script = REPO / "scripts" / "setup" / "prebuild_scenes.py"
    built = subprocess.run(
        [sys.executable, str(script), "--to", str(prebuilt)],
        capture_output=True, text=True, env=env, timeout=300,
    )  # fmt: skip
    assert built.returncode == 0, built.stderr
    # no built-in scene is meshed by gmsh in a run: no mesh prebuilt
    assert {path.parent.name for path in prebuilt.rglob("*.*")} == {"scenes"}
    before = sorted((str(path), path.stat().st_mtime_ns) for path in prebuilt.rglob("*"))
    imported, results = [], []
    for run, extra in (("prebuilt", {}), ("derived", {"PAREFG_CACHE": "0"})):
        out = tmp_path / f"run-{run}"
        argv = ["run", scene, "--quiet", "--out", str(out), "--set", "time.dt=0.25"]
        heavy, summary = probe_run(argv, ("gmsh", "sympy"), {**env, **extra}, cwd=tmp_path)
        imported.append(heavy)
        results.append(summary)
    assert imported == ["", FIRST_RUN_IMPORTS[scene]]
    assert results[0] == results[1]
    assert sorted((str(path), path.stat().st_mtime_ns) for path in prebuilt.rglob("*")) == before
    assert list(home.iterdir()) == []
    assert sorted(path.name for path in tmp_path.iterdir()) == [
        "home", "prebuilt", "run-derived", "run-prebuilt"
    ]  # fmt: skip
