"""The mesh cache (parefg.geometry.mesh_cache): a hit is gmsh's cloud bit for bit, a
spoiled entry is meshed again, and a .geo domain is never cached."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO
from mpi4py import MPI

from parefg import user_cache
from parefg.geometry import gmsh_mesh, mesh_cache
from parefg.geometry.gmsh_mesh import build_node_cloud

COMM = MPI.COMM_WORLD
DOMAINS = [
    ({"shape": "square"}, 0.25, "quad"),
    ({"shape": "z"}, 0.2, "tri"),
    (
        {"shape": "polygon", "vertices": [[0, 0], [2, 0], [1, 1.5]], "edge_names": ["a", "b", "c"]},
        0.3,
        "quad",
    ),
]


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """An empty cache directory of this test, rank 0's on every rank (rank 0 meshes)."""
    root = COMM.bcast(str(tmp_path))
    monkeypatch.setenv("PAREFG_CACHE_DIR", root)
    monkeypatch.delenv("PAREFG_CACHE", raising=False)
    mesh_cache.forget()  # no cloud of an earlier test in this process's memory
    return Path(root) / "meshes"


def assert_same_cloud(a, b):
    for field in dataclasses.fields(a):
        x, y = getattr(a, field.name), getattr(b, field.name)
        if isinstance(x, np.ndarray):
            assert x.dtype == y.dtype and x.shape == y.shape, field.name
            np.testing.assert_array_equal(x, y, err_msg=field.name)
        else:
            assert x == y, field.name


def no_meshing(*args):
    raise AssertionError("meshed although cached")


@pytest.mark.parametrize("domain, h, cells", DOMAINS, ids=["square", "z", "polygon"])
def test_a_hit_is_gmsh_cloud(cache, monkeypatch, domain, h, cells):
    meshed = build_node_cloud(COMM, domain, h, cells, jitter=0.2, seed=3)
    monkeypatch.setattr(gmsh_mesh, "mesh_domain", no_meshing)
    cached = build_node_cloud(COMM, domain, h, cells, jitter=0.2, seed=3)
    assert_same_cloud(meshed, cached)
    assert len(list(cache.glob("*.npz"))) == 1


def test_another_spacing_misses(cache, monkeypatch):
    build_node_cloud(COMM, {"shape": "square"}, 0.25)
    monkeypatch.setattr(gmsh_mesh, "mesh_domain", no_meshing)
    with pytest.raises((AssertionError, RuntimeError), match="meshed although cached"):
        build_node_cloud(COMM, {"shape": "square"}, 0.2)


@pytest.mark.parametrize(
    "spoil",
    [lambda data: data[: len(data) // 2], lambda data: b"not an npz", lambda data: b""],
    ids=["torn", "garbage", "empty"],
)
def test_a_spoiled_entry_is_meshed_again(cache, spoil):
    reference = gmsh_mesh.mesh_domain({"shape": "square"}, 0.25)
    key = mesh_cache.mesh_key({"shape": "square"}, 0.25, "quad")
    path = cache / f"{key}.npz"
    if COMM.rank == 0:  # one writer of the shared directory
        mesh_cache.store(key, reference)
        path.write_bytes(spoil(path.read_bytes()))
    COMM.barrier()
    assert mesh_cache.load(key) is None
    COMM.barrier()  # every rank has read the spoiled entry before rank 0 replaces it
    assert_same_cloud(reference, build_node_cloud(COMM, {"shape": "square"}, 0.25))


def test_a_geo_domain_is_not_cached(cache):
    domain = {"shape": "geo", "file": str(REPO / "meshes" / "plate_with_hole.geo")}
    assert mesh_cache.mesh_key(domain, 0.2, "quad") is None
    mesh_cache.store(None, gmsh_mesh.mesh_domain({"shape": "square"}, 0.5))
    build_node_cloud(COMM, domain, 0.2)
    assert not cache.exists()


def test_a_cloud_over_the_size_bound_is_not_kept(cache, monkeypatch):
    """Only small clouds are kept: a sweep of fine clouds must not fill the disk."""
    monkeypatch.setattr(mesh_cache, "MAX_CACHED_NODES", 24)  # square at h = 1/4: 25 nodes
    build_node_cloud(COMM, {"shape": "square"}, 0.25)
    assert not cache.exists() or list(cache.glob("*.npz")) == []
    monkeypatch.setattr(mesh_cache, "MAX_CACHED_NODES", 25)
    mesh_cache.forget()  # meshed again, not recalled from memory
    build_node_cloud(COMM, {"shape": "square"}, 0.25)
    assert COMM.bcast(len(list(cache.glob("*.npz")))) == 1


def test_the_user_cache_is_opt_in(tmp_path, monkeypatch):
    """By default a run writes nothing outside its output directory: no cache directory
    unless PAREFG_CACHE_DIR or PAREFG_CACHE=1 asks for one; PAREFG_CACHE=0 wins."""
    for name in ("PAREFG_CACHE", "PAREFG_CACHE_DIR"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert user_cache.cache_dir("meshes") is None
    assert mesh_cache.mesh_key({"shape": "square"}, 0.25, "quad") is None  # no key work
    monkeypatch.setenv("PAREFG_CACHE", "1")
    assert user_cache.cache_dir("meshes") == tmp_path / "xdg" / "parefg" / "meshes"
    monkeypatch.setenv("PAREFG_CACHE_DIR", str(tmp_path / "mine"))
    assert user_cache.cache_dir("meshes") == tmp_path / "mine" / "meshes"
    monkeypatch.setenv("PAREFG_CACHE", "0")
    assert user_cache.cache_dir("meshes") is None


# ---------------------------------------------------------------------- the in-process layer


@pytest.fixture
def memory(monkeypatch):
    """The in-process layer alone (no cache directory), empty."""
    monkeypatch.delenv("PAREFG_CACHE_DIR", raising=False)
    monkeypatch.delenv("PAREFG_CACHE", raising=False)
    mesh_cache.forget()
    yield
    mesh_cache.forget()


def test_memory_returns_the_same_cloud_as_a_copy(memory, monkeypatch):
    meshed = build_node_cloud(COMM, {"shape": "square"}, 0.25)
    reference = gmsh_mesh.mesh_domain({"shape": "square"}, 0.25)
    meshed.coords[:] = -1.0  # the caller's copy: the kept cloud stays
    monkeypatch.setattr(gmsh_mesh, "mesh_domain", no_meshing)
    again = build_node_cloud(COMM, {"shape": "square"}, 0.25)
    assert_same_cloud(again, reference)
    assert again.coords is not build_node_cloud(COMM, {"shape": "square"}, 0.25).coords


@pytest.mark.parametrize(
    "other",
    [
        ({"shape": "square"}, 0.2, "quad"),
        ({"shape": "square"}, 0.25, "tri"),
        ({"shape": "rectangle", "size": [2.0, 1.0]}, 0.25, "quad"),
    ],
    ids=["h", "cells", "domain"],
)
def test_memory_misses_for_other_inputs(memory, other):
    build_node_cloud(COMM, {"shape": "square"}, 0.25)
    domain, h, cells = other
    assert_same_cloud(build_node_cloud(COMM, domain, h, cells), gmsh_mesh.mesh_domain(*other))


def test_memory_is_off_with_the_cache(memory, monkeypatch):
    monkeypatch.setenv("PAREFG_CACHE", "0")
    build_node_cloud(COMM, {"shape": "square"}, 0.25)
    assert mesh_cache.memory_key({"shape": "square"}, 0.25, "quad") is None
    monkeypatch.setattr(gmsh_mesh, "mesh_domain", no_meshing)
    with pytest.raises((AssertionError, RuntimeError), match="meshed although cached"):
        build_node_cloud(COMM, {"shape": "square"}, 0.25)


def test_memory_keeps_the_most_recent_few(memory, monkeypatch):
    monkeypatch.setattr(mesh_cache, "MEMORY_ENTRIES", 2)
    for h in (0.5, 0.4, 0.25):
        build_node_cloud(COMM, {"shape": "square"}, h)
    monkeypatch.setattr(gmsh_mesh, "mesh_domain", no_meshing)
    build_node_cloud(COMM, {"shape": "square"}, 0.25)  # kept
    build_node_cloud(COMM, {"shape": "square"}, 0.4)  # kept
    with pytest.raises((AssertionError, RuntimeError), match="meshed although cached"):
        build_node_cloud(COMM, {"shape": "square"}, 0.5)  # dropped
