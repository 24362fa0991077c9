"""Registries: each interchangeable part is named once, and the scene schema reads the names.

Each test adds an entry to one registry (monkeypatched, so nothing leaks) and checks that a
scene may then name it without any other change, or checks that two users of one concept
share one definition.  Not collective.
"""

import dataclasses

import numpy as np
import pytest
from mpi4py import MPI

from parefg.boundary import BoundaryKind
from parefg.discretization import weights
from parefg.discretization.mls import MLS
from parefg.errors import InputError
from parefg.geometry import shapes
from parefg.geometry.gmsh_mesh import mesh_domain
from parefg.geometry.polygon import polygon_problem
from parefg.io.observers import output_fields
from parefg.mechanics import normal_force
from parefg.mechanics.penalty import PENALTY_KINDS
from parefg.run import prepare
from parefg.scene import schema
from parefg.scene.boundaries import BOUNDARY_KEYS
from parefg.scene.loader import load_scene
from parefg.timestepping import schemes

CLOCKWISE = [[0.0, 0.0], [0.0, 1.0], [1.0, 0.0]]  # a triangle listed clockwise


def _message(excinfo) -> str:
    return str(excinfo.value)


def test_a_registered_weight_is_a_scene_choice(monkeypatch):
    # W(r) = 1 - r, written here: the schema must not keep its own list of weight names.
    flat = weights.Weight(
        "linear", lambda r: np.where(r < 1, 1.0 - r, 0.0), lambda r: np.where(r < 1, -1.0, 0.0)
    )
    monkeypatch.setitem(weights.WEIGHTS, "linear", flat)
    assert load_scene("square", ["discretization.weight=linear"]).discretization.weight == "linear"


def test_a_registered_shape_is_a_scene_choice(monkeypatch):
    unit = dataclasses.replace(shapes.SHAPES["square"], name="unit")
    monkeypatch.setitem(shapes.SHAPES, "unit", unit)
    scene = load_scene("square", ["domain.shape=unit"])
    assert scene.part_names == ["bottom", "right", "top", "left"]


def test_a_registered_scheme_is_a_scene_choice(monkeypatch):
    monkeypatch.setitem(schemes.SCHEMES, "quasistatic", schemes.StaticScheme)
    scene = load_scene("square", ["time.scheme=quasistatic"])
    assert scene.time.scheme == "quasistatic" and not scene.time.dynamic
    # The body force derived from [exact] follows the scheme's registry entry: a static
    # scheme has no inertia, so f = -div sigma, the same as under "static".
    static = load_scene("square", ["time.scheme=static"])
    x, y = np.array([0.3, 0.7]), np.array([0.6, 0.2])
    np.testing.assert_array_equal(scene.loads.f(x, y, 0.5), static.loads.f(x, y, 0.5))


def test_boundary_kinds_are_one_enum():
    scene = load_scene("square")
    assert {type(bc.kind) for bc in scene.boundaries.values()} == {BoundaryKind}
    assert set(BOUNDARY_KEYS) == set(BoundaryKind)
    with pytest.raises(InputError) as excinfo:
        load_scene("square", ["boundary.top.type=robin"])
    assert "'dirichlet', 'neumann', 'contact'" in _message(excinfo)


def test_every_weight_the_kernel_compiles_is_used_by_mls(monkeypatch):
    # 25 nodes take the numpy kernels by default (discretization/backends.py): where numba
    # is chosen, every registered weight must run on it.
    monkeypatch.setenv("PAREFG_KERNELS", "numba")
    nodes = np.stack(np.meshgrid(np.linspace(0, 1, 5), np.linspace(0, 1, 5)), -1).reshape(-1, 2)
    for name, weight in weights.WEIGHTS.items():
        assert weight.code is not None
        assert MLS(nodes, 0.6, 1, name).backend == "numba"


def test_scene_and_mesher_refuse_a_polygon_with_one_check(tmp_path):
    """A clockwise triangle: the schema and gmsh_mesh.mesh_domain give the same reason."""
    reason = polygon_problem(CLOCKWISE)
    assert reason is not None and "counter-clockwise" in reason
    domain = {"shape": "polygon", "vertices": CLOCKWISE, "edge_names": ["a"] * 3}
    with pytest.raises(InputError) as meshed:
        mesh_domain(domain, 0.5)
    scene = tmp_path / "clockwise.toml"
    scene.write_text(
        f'[domain]\nshape = "polygon"\nvertices = {CLOCKWISE}\nedge_names = ["a", "a", "a"]\n'
    )
    with pytest.raises(InputError) as loaded:
        load_scene(str(scene))
    assert _message(meshed).endswith(reason) and _message(loaded).endswith(reason)


def test_a_registered_contact_force_is_a_scene_choice(monkeypatch):
    class Blunt(normal_force.EndpointForce):
        name = "blunt"

    monkeypatch.setitem(normal_force.CONTACT_FORCES, "blunt", Blunt)
    assert load_scene("impact", ["time.contact_force=blunt"]).time.contact_force == "blunt"
    # the default is the registry's first entry
    assert load_scene("impact").time.contact_force == next(iter(normal_force.CONTACT_FORCES))


def test_penalty_keys_are_the_registered_kinds():
    scene = load_scene("square", ["penalty.alpha=5.0", "penalty.alpha_contact=7.0"])
    assert set(scene.params["penalty"]) == {"alpha"} | {f"alpha_{k}" for k in PENALTY_KINDS}
    assert (
        scene.penalty.alpha_dirichlet,
        scene.penalty.alpha_contact,
        scene.penalty.alpha_friction,
    ) == (5.0, 7.0, 5.0)


def test_output_datasets_are_named_by_the_output_registry(monkeypatch):
    """The writer takes each field's dataset names from OUTPUT_FIELDS, not from a twin."""
    monkeypatch.setitem(schema.OUTPUT_FIELDS, "u", ("u_h",))
    sets = ["discretization.h=0.25", "discretization.degree=1", "time.T=0.1"]
    sim = prepare(MPI.COMM_WORLD, "square", [*sets, "output.fields=['u', 'contact']"])
    node_fields, contact_fields = output_fields(sim, sim.start())
    assert set(node_fields) == {"u_h"}
    assert tuple(contact_fields) == schema.OUTPUT_FIELDS["contact"]
