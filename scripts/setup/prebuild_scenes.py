"""Prebuild the built-in scenes' derived data and meshes into the installation.

A run of a built-in scene at its defaults then reads both (read only, as
:mod:`parefg.user_cache` describes) instead of importing sympy to derive the scene (~0.3 s)
and gmsh to mesh it (~0.2 s): `parefg run square` starts as fast as with a warm user
cache, without writing anywhere but its output directory.  A rectangle's grid and the Z's
patches are not meshed by gmsh in a run (each rank makes its part,
parefg.geometry.grid_parts and patch_parts), so only the other domains' meshes are
prebuilt (none of today's built-in scenes has one).  `make setup` runs this once per
change of the package source (the entries' keys hash it, so stale ones would only miss).
The directory is rebuilt whole, in a temporary sibling renamed into place.

    .venv/bin/python scripts/setup/prebuild_scenes.py [--to DIR]
"""

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import petsc4py

import parefg  # noqa: F401  (PETSC_DIR)

petsc4py.init(sys.argv[:1])
from mpi4py import MPI  # noqa: E402

from parefg import user_cache  # noqa: E402
from parefg.discretization.operators import scene_cloud_on_root  # noqa: E402
from parefg.geometry.grid_parts import scene_grid  # noqa: E402
from parefg.geometry.patch_parts import patched  # noqa: E402
from parefg.scene.loader import builtin_scenes, load_scene  # noqa: E402


def prebuild(target: Path) -> list[str]:
    """Write every built-in scene's entries into ``target`` (replaced whole); their names."""
    target.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=".prebuilt.", dir=target.parent))
    os.environ["PAREFG_CACHE_DIR"] = str(staging)  # the entries are written where a user
    os.environ.pop("PAREFG_CACHE", None)  # cache would be, with the same keys
    os.environ.pop("PAREFG_SCENE_CACHE", None)
    os.environ["PAREFG_PREBUILT_DIR"] = ""  # derive and mesh: read no older entry
    names = sorted(builtin_scenes())
    for name in names:
        scene = load_scene(name)  # derives and stores the scene's data
        if scene_grid(scene) is None and not patched(scene):  # a run meshes it with gmsh
            scene_cloud_on_root(MPI.COMM_SELF, scene)  # the run's mesh inputs
    shutil.rmtree(target, ignore_errors=True)
    os.replace(staging, target)
    return names


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--to", type=Path, default=user_cache.default_prebuilt_root())
    args = parser.parse_args()
    tic = time.perf_counter()
    names = prebuild(args.to)
    seconds = time.perf_counter() - tic
    print(f"setup: built-in scenes {', '.join(names)} prebuilt in {args.to} ({seconds:.1f} s)")


if __name__ == "__main__":
    main()
