"""Time-separable splits g(x, t) = sum_k a_k(t) f_k(x) of scene data (parefg.scene.separable).

A split must be the same expression rewritten: each a_k depends on t alone, each f_k on
the space arguments alone, and the sum reproduces the expression at random points to
round-off.  Data that mix x and t inside a function are not split (None).
"""

import numpy as np
import pytest
import sympy

from parefg.scene.expressions import SYMBOLS, parse_expression
from parefg.scene.loader import load_scene
from parefg.scene.numeric import CompiledField
from parefg.scene.separable import MAX_TERMS, separate

X, Y, T, NX, NY = (SYMBOLS[name] for name in ("x", "y", "t", "nx", "ny"))
SPACE = {X, Y, NX, NY}


def parsed(texts):
    return [parse_expression(text, "test") for text in texts]


def assert_reproduces(exprs, split, samples=20):
    """The split's pieces are functions of t / of space alone, their sum equals exprs."""
    for a in split.time:
        assert a.free_symbols <= {T}
    for row in split.space:
        for f in row:
            assert f.free_symbols <= SPACE
    symbols = [X, Y, T, NX, NY]
    rng = np.random.default_rng(7)
    points = rng.uniform(-1.5, 1.5, size=(len(symbols), samples))
    original = sympy.lambdify(symbols, exprs, "numpy")
    rebuilt = sympy.lambdify(symbols, split.expressions(), "numpy")
    want = np.broadcast_arrays(*original(*points))
    got = np.broadcast_arrays(*rebuilt(*points))
    for w, g in zip(want, got, strict=True):
        scale = np.max(np.abs(w))
        np.testing.assert_allclose(g, w, rtol=0, atol=1e-13 * scale)


@pytest.mark.parametrize(
    ("texts", "count"),
    [(["sin(pi*x)*cos(t)"], 1),
     (["sin(pi*x)*cos(t) + 2*x*cos(t)"], 1),  # one time factor
     (["(cos(t) - 1)*x + (1 - cos(t))*y"], 1),  # factors equal up to a constant
     (["(1 - cos(t))*(1 + x)*exp(y)", "-(1 - cos(t))*y*exp(x)"], 1),
     (["(1 + t**2)*exp(x)*y + t*x - 3"], 3),
     (["(x + t)**2"], 3),  # x**2 + 2 x t + t**2
     (["x/(1 + t) + t/(1 + x**2)"], 2),
     (["abs((1 - cos(t))*x - (1 - cos(t))*y)"], 1),  # |a(t) f(x)| = |a(t)| |f(x)|
     (["exp(-t)*sin(x)", "sin(t)*y"], 2)],
)  # fmt: skip
def test_split_reproduces_the_expression(texts, count):
    exprs = parsed(texts)
    split = separate(exprs)
    assert split is not None
    assert len(split.time) == count
    assert_reproduces(exprs, split)


@pytest.mark.parametrize(
    "texts",
    [["sin(x*t)"],
     ["exp(x + t)"],  # x + t inside a function
     ["1/(x + t)"],
     ["sqrt(x*t + 1)"],
     ["heaviside(x - t)"],
     ["abs(x - t)"],  # two time factors inside abs
     ["x*cos(t)", "sin(x*t)"],  # one component spoils the field
     ["x*cos(t) + sin(x*t)"]],
)  # fmt: skip
def test_data_mixing_x_and_t_are_not_split(texts):
    assert separate(parsed(texts)) is None


def test_time_independent_data_are_one_term():
    """1 * f: integrated once per run instead of at every step."""
    exprs = parsed(["x**2 + y", "0"])
    split = separate(exprs)
    assert split is not None and split.time == [1]
    assert_reproduces(exprs, split)


def test_a_product_of_too_many_sums_is_not_split():
    """The distributed product would exceed MAX_TERMS terms."""
    factors = [f"(x + {i} + sin({i}*t))" for i in range(1, 8)]  # 2**7 > MAX_TERMS terms
    assert 2 ** len(factors) > MAX_TERMS
    assert separate(parsed(["*".join(factors)])) is None


def sample(field, names, rng, n=50):
    values = {name: rng.uniform(-1, 1, n) for name in names}
    if "nx" in values:  # unit normals
        angle = rng.uniform(0, 2 * np.pi, n)
        values["nx"], values["ny"] = np.cos(angle), np.sin(angle)
    return values


@pytest.mark.parametrize("scene_name", ["square", "z"])
def test_builtin_scene_data_are_split_and_reproduced(scene_name):
    """f, the tractions, the Dirichlet value and the friction bound derived from u."""
    scene = load_scene(scene_name, ["discretization.h=0.25"])
    fields = [scene.loads.f]
    for bc in scene.boundaries.values():
        fields += [f for f in (bc.value, bc.traction, bc.friction) if f is not None]
    assert len(fields) >= 4
    rng = np.random.default_rng(3)
    for field in fields:
        split = field.separated
        assert split is not None, field.texts
        values = sample(field, field.args, rng)
        for t in (0.0, 0.37, 1.0):
            want = field(*(t if name == "t" else values[name] for name in field.args))
            space = split.space(*(values[name] for name in split.space.args))
            got = np.tensordot(split.time(t), space, axes=1)
            scale = max(np.max(np.abs(want)), 1e-300)
            np.testing.assert_allclose(got, want, rtol=0, atol=1e-13 * scale)


def test_split_survives_the_json_of_the_scene_cache():
    field = load_scene("square", ["discretization.h=0.25"]).loads.f
    again = CompiledField.from_json(field.to_json())
    assert again.separated is not None
    assert again.separated.time.texts == field.separated.time.texts
    assert again.separated.space.texts == field.separated.space.texts
    x, y = np.linspace(0, 1, 7), np.linspace(1, 0, 7)
    np.testing.assert_array_equal(again.separated.space(x, y), field.separated.space(x, y))


def test_non_separable_scene_datum_has_no_split(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text(
        '[domain]\nshape = "square"\n[discretization]\nh = 0.25\n'
        '[boundary.top]\ntype = "dirichlet"\nvalue = ["sin(x*t)", 0]\n'
        '[loads]\nf = ["x*cos(t)", "exp(x + t)"]\n'
    )
    scene = load_scene(str(path))
    assert scene.loads.f.separated is None
    assert scene.boundaries["top"].value.separated is None


@pytest.mark.parametrize(
    "texts",
    [["x*(t + 1/x)"], ["(t - 0.5)*(x + 1/(t - 0.5))"], ["(exp(t)*x + 1)*exp(-t)*y"],
     ["(x + 1)/(t - 0.5) - x/(t - 0.5) - 1/(t - 0.5) + t*y"], ["t*(x + 1) - t*x - t"]],
)  # fmt: skip
def test_data_whose_split_would_cancel_a_singularity_or_everything_are_not_split(texts):
    """x (1/x) = 1, (t - 1/2)/(t - 1/2) = 1, exp(t) exp(-t) = 1, or K = 0: no split."""
    assert separate(parsed(texts)) is None
