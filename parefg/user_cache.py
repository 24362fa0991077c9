"""The per-user cache directory of parefg: where derived data that are costly to rebuild
(the compiled data of a scene, the gmsh mesh of a built-in shape) are kept between runs.

Opt-in, because a run writes nothing outside its output directory unless the user says
so: on when ``$PAREFG_CACHE_DIR`` names the directory, or with ``PAREFG_CACHE=1`` in
``$XDG_CACHE_HOME/parefg``, else ``~/.cache/parefg`` (as numba and pip keep theirs);
``PAREFG_CACHE=0`` turns every cache off whatever else is set.  Entries are named by a
hash of everything they depend on (:func:`source_digest` included), so a changed input or
changed code misses and nothing is invalidated by hand.  Writes are atomic: readers
(other ranks, other runs) see a whole entry or none.  Every failure to read is a miss and
every failure to write is skipped, silently.  Not collective.

Next to it, read only, the entries of the built-in scenes at their defaults that
``make setup`` prebuilt into the installation (:func:`prebuilt_dir`, written by
scripts/setup/prebuild_scenes.py, as the numba kernels are compiled there): the default
run imports neither sympy nor gmsh without the user opting in to a cache, and writes
nothing outside its output directory.  The same keys apply, so an edit of the package
misses until setup prebuilds again.
"""

import hashlib
import os
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parent
_SOURCE_DIGEST: list[str] = []  # the package source's digest, computed once per process


def disabled() -> bool:
    """Whether ``PAREFG_CACHE=0`` turns every cache off (the in-process ones too)."""
    return os.environ.get("PAREFG_CACHE") == "0"


def cache_dir(kind: str) -> Path | None:
    """The directory of one kind of entry ("scenes", "meshes"), or None when caching is off."""
    root = os.environ.get("PAREFG_CACHE_DIR")
    if disabled() or not (root or os.environ.get("PAREFG_CACHE") == "1"):
        return None
    if not root:
        xdg = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
        root = os.path.join(xdg, "parefg")
    return Path(root) / kind


def prebuilt_dir(kind: str) -> Path | None:
    """The read-only directory of one kind of prebuilt entry, or None when there is none.

    ``$PAREFG_PREBUILT_DIR`` (empty: none), by default ``share/parefg/prebuilt`` of the
    Python installation (the virtual environment of `make setup`); ``PAREFG_CACHE=0``
    turns it off with every cache.
    """
    root = os.environ.get("PAREFG_PREBUILT_DIR", str(default_prebuilt_root()))
    if disabled() or not root:
        return None
    path = Path(root) / kind
    return path if path.is_dir() else None


def default_prebuilt_root() -> Path:
    """Where ``make setup`` prebuilds: inside the environment that runs parefg."""
    return Path(sys.prefix) / "share" / "parefg" / "prebuilt"


def read_dirs(kind: str) -> list[Path]:
    """The directories an entry of one kind is looked up in: the user cache first (when
    on), then the prebuilt entries (when present)."""
    return [path for path in (cache_dir(kind), prebuilt_dir(kind)) if path is not None]


def source_digest() -> str:
    """sha256 of every .py file of the package (path and bytes): code changes miss."""
    if not _SOURCE_DIGEST:
        digest = hashlib.sha256()
        for path in sorted(PACKAGE_DIR.rglob("*.py")):
            digest.update(str(path.relative_to(PACKAGE_DIR)).encode())
            digest.update(path.read_bytes())
        _SOURCE_DIGEST.append(digest.hexdigest())
    return _SOURCE_DIGEST[0]


def write_atomic(path: Path, write: Callable) -> None:
    """``write(stream)`` into a temporary file next to ``path``, then rename it to ``path``.

    Skipped (the temporary removed) when the directory cannot be created or written.
    """
    name = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(
            "wb", dir=path.parent, prefix=f".{path.stem[:16]}.", suffix=".tmp", delete=False
        ) as stream:
            name = stream.name
            write(stream)
        os.replace(name, path)
    except OSError:
        if name is not None:
            try:
                os.unlink(name)
            except OSError:
                pass
