"""A per-user cache of the compiled data of scenes, so that a run need not import sympy.

Deriving a scene's data (parsing its expressions, differentiating its exact solution,
checking signs) needs sympy: ~0.5 s of imports for milliseconds of work.  The result is
a set of expression texts (:class:`~parefg.scene.numeric.CompiledField`) and a few flags,
stored as JSON under a key that hashes everything it depends on: the sections of the
effective scene the derivation reads (:data:`DERIVED_FROM`, which hold every expression
and default; not the discretization, solver or output, so a sweep over h or dt hits),
the source of the package, and the versions of parefg and sympy.  A changed scene or
code misses; nothing is ever invalidated by hand.

Safety: the cache is read as data only.  Its texts go through the whitelist evaluator of
:mod:`parefg.scene.numeric` (numbers, x, y, t, nx, ny, + - * / ** and numpy functions),
never through ``eval`` or sympy; a file that is unreadable, corrupt or of another layout
is a miss, and the scene is derived again.  Writes go to a temporary file in the cache
directory, then :func:`os.replace`: readers (other ranks, other runs) see a whole file or
none.  An unwritable directory is silently skipped.

Directory: ``scenes/`` of :func:`parefg.user_cache.cache_dir` (opt-in: ``$PAREFG_CACHE_DIR``,
or ``PAREFG_CACHE=1`` for ``~/.cache/parefg``), then, read only, of
:func:`parefg.user_cache.prebuilt_dir` (the built-in scenes, prebuilt by `make setup`);
``PAREFG_SCENE_CACHE=0`` turns this cache off, ``PAREFG_CACHE=0`` every cache.
Not collective.
"""

import dataclasses
import hashlib
import importlib.util
import json
import os
from pathlib import Path

import parefg
from parefg import user_cache
from parefg.boundary import BoundaryKind
from parefg.scene.numeric import BoundaryCondition, CompiledField, ExactSolution

FORMAT = 1  # layout of an entry; part of the key

#: Scene fields holding a CompiledField (or None) in an entry
FIELDS = ("body_force", "initial_u", "initial_v", "initial_grad", "initial_div_stress")
#: The scene sections the derivation (:func:`parefg.scene.loader._derive`) reads: the
#: expressions and what checks them (the domain's parts, the material, the time span of
#: the sign checks and whether the scheme is dynamic).
DERIVED_FROM = ("exact", "boundary", "loads", "initial", "material", "domain")
DERIVED_FROM_TIME = ("T", "scheme")


def _switched_off() -> bool:
    return os.environ.get("PAREFG_SCENE_CACHE", "1") == "0"


def cache_dir() -> Path | None:
    """The directory scene entries are written to, or None when the cache is off."""
    return None if _switched_off() else user_cache.cache_dir("scenes")


def read_dirs() -> list[Path]:
    """The directories scene entries are read from: the user cache, then the prebuilt."""
    return [] if _switched_off() else user_cache.read_dirs("scenes")


def scene_key(params: dict, dynamic: bool) -> str | None:
    """The cache key of a scene's compiled data; None when there is no cache to read (the key
    reads the package source: a run without a cache need not pay for it)."""
    if not read_dirs():
        return None
    identity = {
        "format": FORMAT,
        "parefg": parefg.__version__,
        "sympy": sympy_version(),
        "source": user_cache.source_digest(),
        "dynamic": dynamic,
        "params": {section: params.get(section) for section in DERIVED_FROM},
        "time": {item: params["time"].get(item) for item in DERIVED_FROM_TIME},
    }
    text = json.dumps(identity, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def sympy_version() -> str:
    """The installed sympy's version, read from its sympy/release.py (``__version__ = ...``)
    without importing sympy or importlib.metadata (whose version lookup, imports included,
    costs ~25 ms a run); "none" without sympy."""
    spec = importlib.util.find_spec("sympy")
    if spec is None or spec.origin is None:
        return "none"
    try:
        return Path(spec.origin).with_name("release.py").read_text().strip()
    except OSError:  # a sympy without release.py: its package path still tells it apart
        return spec.origin


def load(key: str | None) -> dict | None:
    """The compiled scene data stored under ``key`` (see :func:`entry`), or None on a miss
    (or when key is None).

    Every failure to read or rebuild the entry is a miss.
    """
    if key is None:
        return None
    for directory in read_dirs():
        data = _read(directory / f"{key}.json", key)
        if data is not None:
            return data
    return None


def _read(path: Path, key: str) -> dict | None:
    """The compiled data of one entry file, or None when it cannot be used."""
    try:
        stored = json.loads(path.read_text())
        if stored.get("key") != key:
            return None
        return _rebuild(stored)
    except (OSError, ValueError, KeyError, TypeError, AttributeError, RecursionError):
        return None  # missing, corrupt, of another layout, or refused by the evaluator


def store(key: str | None, data: dict) -> None:
    """Write ``data`` (keys FIELDS, "exact", "boundaries") under ``key``, atomically.

    Does nothing when the cache is off, a field was not compiled from text, or the
    directory is not writable.
    """
    directory = cache_dir()
    if key is None or directory is None:
        return
    try:
        text = json.dumps({"key": key, **_serialized(data)})
    except _NotCacheable:
        return
    user_cache.write_atomic(directory / f"{key}.json", lambda stream: stream.write(text.encode()))


class _NotCacheable(Exception):
    """A field was compiled by lambdify (its texts are beyond the whitelist)."""


def _field_json(field: CompiledField | None) -> dict | None:
    if field is None:
        return None
    if field.texts is None:
        raise _NotCacheable
    return field.to_json()


def _field(data: dict | None) -> CompiledField | None:
    return None if data is None else CompiledField.from_json(data)


def _serialized(data: dict) -> dict:
    """JSON-ready form of the compiled data; raises _NotCacheable."""
    exact = data["exact"]
    boundaries = {}
    for name, bc in data["boundaries"].items():
        row = {}
        for item in dataclasses.fields(bc):
            value = getattr(bc, item.name)
            if isinstance(value, CompiledField) or item.name in _BOUNDARY_FIELDS:
                value = _field_json(value)
            row[item.name] = value.value if isinstance(value, BoundaryKind) else value
        boundaries[name] = row
    return {
        "fields": {name: _field_json(data[name]) for name in FIELDS},
        "exact": None
        if exact is None
        else {
            "given": exact.given,
            **{name: _field_json(getattr(exact, name)) for name in ("u", "v", "grad")},
        },
        "boundaries": boundaries,
    }


_BOUNDARY_FIELDS = ("value", "traction", "gap", "friction")


def _rebuild(stored: dict) -> dict:
    """The compiled data of a stored entry (inverse of :func:`_serialized`)."""
    data: dict = {name: _field(stored["fields"][name]) for name in FIELDS}
    exact = stored["exact"]
    if exact is None:
        data["exact"] = None
    else:
        u, v, grad = (CompiledField.from_json(exact[name]) for name in ("u", "v", "grad"))
        data["exact"] = ExactSolution(given=list(exact["given"]), u=u, v=v, grad=grad)
    boundaries = {}
    for name, row in stored["boundaries"].items():
        values: dict = {k: _field(row[k]) if k in _BOUNDARY_FIELDS else row[k] for k in row}
        values["kind"] = BoundaryKind(values["kind"])
        boundaries[name] = BoundaryCondition(**values)
    data["boundaries"] = boundaries
    return data
