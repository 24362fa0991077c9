"""A per-user cache of the gmsh meshes of built-in shapes: a run need not import gmsh.

Importing gmsh and meshing the default square cost ~0.4 s of a run's start-up.  gmsh is
deterministic, so its cloud (:class:`~parefg.geometry.cloud.NodeCloud`, as
:func:`~parefg.geometry.gmsh_mesh.mesh_domain` extracts it, before any jitter) is kept
under a key that hashes everything it depends on: the ``[domain]`` table, h, the cell
type, the gmsh module (path, size, modification time) and the package source.  A hit
returns gmsh's arrays bit for bit; the nodes are still gmsh's.  Only domains whose
outline the scene alone defines are cached; a .geo domain (whose file and budget gmsh
reads) is meshed every time.

Entries are .npz files read without pickle (arrays only); anything unreadable is a
miss.  Directory: ``meshes/`` of :func:`parefg.user_cache.cache_dir` (written and read),
then of :func:`parefg.user_cache.prebuilt_dir` (read only).  Not collective (rank 0 meshes).

Within a process, the last ``MEMORY_ENTRIES`` small clouds (``MEMORY_NODES`` nodes at
most) are also kept in memory, keyed by the same inputs (the code is the process's):
repeated runs of one scene in a process (sweeps, benchmarks, in-process drivers) mesh
once.  Both return copies, which the caller may modify.  ``PAREFG_CACHE=0`` turns both
off.
"""

import dataclasses
import hashlib
import importlib.util
import json
import os
import zipfile
from collections import OrderedDict
from typing import Any

import numpy as np

from parefg import user_cache
from parefg.geometry.cloud import NodeCloud
from parefg.geometry.shapes import SHAPES

FORMAT = 1  # layout of an entry; part of the key
# the arrays of a meshed cloud (a distributed one adds segment_cells and node_ids, not cached)
ARRAYS = [
    f.name
    for f in dataclasses.fields(NodeCloud)
    if f.name not in ("part_names", "segment_cells", "node_ids")
]


def _gmsh_identity() -> str:
    """Where the gmsh module is and which file it is, without importing it."""
    spec = importlib.util.find_spec("gmsh")
    if spec is None or spec.origin is None:
        return "none"
    stat = os.stat(spec.origin)
    return f"{spec.origin}:{stat.st_size}:{stat.st_mtime_ns}"


def _outlined(domain: dict) -> bool:
    """Whether the scene alone defines the domain's outline (a built-in shape)."""
    name = domain.get("shape")
    shape = SHAPES.get(name) if isinstance(name, str) else None
    return shape is not None and shape.outline is not None


def _mesh_inputs(domain: dict, h: float, cells: str, min_cells: int) -> dict:
    """What the mesh depends on; ``min_cells`` only for a domain meshed as patches."""
    inputs = {"domain": domain, "h": float(h), "cells": cells}
    if SHAPES[domain["shape"]].patches is not None:
        inputs["min_cells"] = int(min_cells)
    return inputs


def mesh_key(domain: dict, h: float, cells: str, min_cells: int = 1) -> str | None:
    """The cache key of one mesh, or None when it is not cached (a .geo domain, or no
    cache to read: the key reads the package source, which a run need not pay for)."""
    if not _outlined(domain) or not user_cache.read_dirs("meshes"):
        return None
    identity = {
        "format": FORMAT,
        **_mesh_inputs(domain, h, cells, min_cells),
        "gmsh": _gmsh_identity(),
        "source": user_cache.source_digest(),
    }
    text = json.dumps(identity, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


# Meshing costs more than reading only on small clouds, where start-up matters; bounding
# the entries (~50 B per node) keeps a sweep of fine clouds from filling the disk.
MAX_CACHED_NODES = 200_000


# The in-process layer: a few small clouds (~50 B per node each), most recent last.
MEMORY_ENTRIES = 8
MEMORY_NODES = 50_000
_MEMORY: OrderedDict[str, NodeCloud] = OrderedDict()


def memory_key(domain: dict, h: float, cells: str, min_cells: int = 1) -> str | None:
    """The in-process key of one mesh, or None when it is not kept (a .geo domain, or
    PAREFG_CACHE=0)."""
    if user_cache.disabled() or not _outlined(domain):
        return None
    return json.dumps(_mesh_inputs(domain, h, cells, min_cells), sort_keys=True, default=str)


def _copy(cloud: NodeCloud) -> NodeCloud:
    arrays = {name: getattr(cloud, name).copy() for name in ARRAYS}
    return NodeCloud(part_names=list(cloud.part_names), **arrays)


def recall(key: str | None) -> NodeCloud | None:
    """A copy of the cloud kept in memory under ``key``, or None."""
    cloud = None if key is None else _MEMORY.get(key)
    if key is None or cloud is None:
        return None
    _MEMORY.move_to_end(key)
    return _copy(cloud)


def remember(key: str | None, cloud: NodeCloud) -> None:
    """Keep a copy of ``cloud`` in memory under ``key`` (dropping the oldest beyond the
    bound); nothing when key is None or the cloud is large."""
    if key is None or cloud.n_nodes > MEMORY_NODES:
        return
    _MEMORY[key] = _copy(cloud)
    _MEMORY.move_to_end(key)
    while len(_MEMORY) > MEMORY_ENTRIES:
        _MEMORY.popitem(last=False)


def forget() -> None:
    """Empty the in-process layer."""
    _MEMORY.clear()


def load(key: str | None) -> NodeCloud | None:
    """The cloud stored under ``key`` in the user cache or the prebuilt entries, or None on a
    miss (or when key is None)."""
    if key is None:
        return None
    for directory in user_cache.read_dirs("meshes"):
        cloud = _read(directory / f"{key}.npz", key)
        if cloud is not None:
            return cloud
    return None


def _read(path, key: str) -> NodeCloud | None:
    """The cloud of one entry file, or None when it is missing, corrupt or another key's."""
    try:
        with np.load(path, allow_pickle=False) as stored:
            if str(stored["key"]) != key:
                return None
            arrays: dict[str, Any] = {name: np.array(stored[name]) for name in ARRAYS}
            part_names = [str(name) for name in stored["part_names"]]
    except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError):
        return None
    return NodeCloud(part_names=part_names, **arrays)


def store(key: str | None, cloud: NodeCloud) -> None:
    """Keep ``cloud`` under ``key`` (atomically); nothing when key is None or caching is off."""
    directory = user_cache.cache_dir("meshes")
    if key is None or directory is None or cloud.n_nodes > MAX_CACHED_NODES:
        return
    arrays = {name: getattr(cloud, name) for name in ARRAYS}
    names = np.array(cloud.part_names, dtype=str)

    def write(stream):
        np.savez(stream, key=np.array(key), part_names=names, **arrays)

    user_cache.write_atomic(directory / f"{key}.npz", write)
