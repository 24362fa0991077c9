"""The scene cache (parefg.scene.scene_cache): a hit gives the bits of a derivation, and a
corrupt, hostile or unwritable cache only costs a derivation."""

import json
import threading

import numpy as np
import pytest

from parefg.scene import loader, scene_cache
from parefg.scene.numeric import CompiledField

RNG = np.random.default_rng(5)
X, Y = RNG.uniform(0.0, 1.0, size=(2, 30))
NX, NY = np.zeros(30), -np.ones(30)
T = 0.7


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """An empty cache directory of this test."""
    monkeypatch.setenv("PAREFG_CACHE_DIR", str(tmp_path))
    monkeypatch.delenv("PAREFG_SCENE_CACHE", raising=False)
    return tmp_path / "scenes"


def no_derivation(*args):
    raise AssertionError("derived although cached")


def values(scene) -> list[np.ndarray]:
    """Every datum of the scene at the sample points."""
    out = [scene.loads.f(X, Y, T), scene.initial.u(X, Y), scene.initial.v(X, Y)]
    out += [scene.exact.u(X, Y, T), scene.exact.v(X, Y, T), scene.exact.grad(X, Y, T)]
    if scene.initial.grad is not None:
        out += [scene.initial.grad(X, Y), scene.initial.div_stress(X, Y)]
    for bc in scene.boundaries.values():
        for field in (bc.value, bc.traction, bc.friction):
            if field is not None:
                out.append(field(X, Y, T, NX, NY) if field.args[-1] == "ny" else field(X, Y, T))
        if bc.gap is not None:
            out.append(bc.gap(X, Y))
    return out


@pytest.mark.parametrize(
    "source, overrides",
    [("square", ()), ("stick", ()), ("square", ["initial.u=['x * y', '0']"])],
    ids=["square", "stick", "given-initial-u"],
)
def test_a_hit_gives_the_derived_bits(cache, monkeypatch, source, overrides):
    derived = loader.load_scene(source, overrides)
    assert len(list(cache.glob("*.json"))) == 1
    monkeypatch.setattr(loader, "_derive", no_derivation)
    cached = loader.load_scene(source, overrides)
    for a, b in zip(values(derived), values(cached), strict=True):
        np.testing.assert_array_equal(a, b)
    assert cached.boundaries.keys() == derived.boundaries.keys()
    for name, bc in derived.boundaries.items():
        assert cached.boundaries[name].friction_is_zero == bc.friction_is_zero
        assert cached.boundaries[name].kind == bc.kind
        assert cached.boundaries[name].method == bc.method
    assert cached.exact.given == derived.exact.given == cached.params["exact"]["u"]


def test_a_changed_scene_misses(cache, monkeypatch):
    loader.load_scene("square")
    monkeypatch.setattr(loader, "_derive", no_derivation)
    with pytest.raises(AssertionError, match="derived although cached"):
        loader.load_scene("square", ["material.nu=0.25"])


@pytest.mark.parametrize(
    "changed", [["material.E=2.0"], ["time.T=0.5"], ["boundary.bottom.gap=0.01"]]
)
def test_what_the_derivation_reads_misses(cache, monkeypatch, changed):
    loader.load_scene("square")
    monkeypatch.setattr(loader, "_derive", no_derivation)
    with pytest.raises(AssertionError, match="derived although cached"):
        loader.load_scene("square", changed)


@pytest.mark.parametrize(
    "changed",
    [["discretization.h=0.125", "discretization.degree=1"], ["time.dt=0.01"], ["output.every=0"]],
)
def test_what_the_derivation_does_not_read_hits(cache, monkeypatch, changed):
    """A sweep over h, m or dt derives once: the key holds only what _derive reads."""
    reference = values(loader.load_scene("square"))
    monkeypatch.setattr(loader, "_derive", no_derivation)
    again = loader.load_scene("square", changed)
    for a, b in zip(reference, values(again), strict=True):
        np.testing.assert_array_equal(a, b)


def entry_file(cache):
    (path,) = cache.glob("*.json")
    return path


@pytest.mark.parametrize(
    "spoil",
    [
        lambda text: text[: len(text) // 2],  # a torn write
        lambda text: "not json",
        lambda text: json.dumps({"key": "other"}),
        # code in place of an expression: refused by the evaluator, never run
        lambda text: text.replace('"(1 - cos(t))', "\"__import__('os').system('touch PWNED')"),
        lambda text: text.replace('"texts"', '"text"'),
    ],
    ids=["torn", "not-json", "other-key", "code", "layout"],
)
def test_a_spoiled_entry_is_derived_again(cache, tmp_path, monkeypatch, spoil):
    monkeypatch.chdir(tmp_path)
    reference = values(loader.load_scene("square"))
    path = entry_file(cache)
    text = path.read_text()
    spoiled = spoil(text)
    assert spoiled != text
    path.write_text(spoiled)
    again = loader.load_scene("square")
    for a, b in zip(reference, values(again), strict=True):
        np.testing.assert_array_equal(a, b)
    assert not (tmp_path / "PWNED").exists()
    assert entry_file(cache).read_text() == text  # rewritten whole


def test_an_unwritable_cache_is_skipped(tmp_path, monkeypatch):
    blocker = tmp_path / "file"
    blocker.write_text("")
    monkeypatch.setenv("PAREFG_CACHE_DIR", str(blocker))  # scenes/ cannot be created in it
    scene = loader.load_scene("square")
    assert scene.loads.f(X, Y, T).shape == (2, X.size)
    assert list(tmp_path.iterdir()) == [blocker]


def test_off_switch(cache, monkeypatch):
    monkeypatch.setenv("PAREFG_SCENE_CACHE", "0")
    assert scene_cache.scene_key({"name": "square"}, True) is None  # no key work when off
    loader.load_scene("square")
    assert not cache.exists()


def test_a_field_not_compiled_from_text_is_not_stored(cache):
    data = {name: None for name in scene_cache.FIELDS}
    data["body_force"] = CompiledField(None, ("x",), (1,), function=lambda x: [x])
    data.update(exact=None, boundaries={})
    scene_cache.store("k" * 64, data)
    assert not cache.exists() or not list(cache.iterdir())


def test_concurrent_writers_and_readers(cache):
    """Readers see a whole entry or none while writers replace it (ranks of one run)."""
    scene = loader.load_scene("square")
    initial = scene.initial
    data = {"body_force": scene.loads.f, "initial_u": initial.u, "initial_v": initial.v}
    data.update(initial_grad=initial.grad, initial_div_stress=initial.div_stress)
    assert set(data) == set(scene_cache.FIELDS)
    data.update(exact=scene.exact, boundaries=scene.boundaries)
    key = "f" * 64
    seen = []

    def write():
        for _ in range(30):
            scene_cache.store(key, data)

    writers = [threading.Thread(target=write) for _ in range(2)]

    def read():
        # until both writers are done (on a loaded machine 60 reads can all come before
        # the first store has finished), then once more: that read must see the entry
        while any(writer.is_alive() for writer in writers) or len(seen) < 60:
            seen.append(scene_cache.load(key))
        for writer in writers:
            writer.join()
        seen.append(scene_cache.load(key))

    threads = [*writers, threading.Thread(target=read)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    hits = [entry for entry in seen if entry is not None]
    assert hits, "no reader saw the entry"
    for entry in hits:
        np.testing.assert_array_equal(entry["body_force"](X, Y, T), scene.loads.f(X, Y, T))
    assert not list(cache.glob(".*.tmp"))  # no temporary left
