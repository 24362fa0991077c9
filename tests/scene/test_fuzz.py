"""Property-based fuzzing of the scene input (SPEC 6, 9) with hypothesis.

Two contracts are fuzzed:

- ``parse_expression(text, key)`` returns a sympy expression or raises
  ``InputError`` with a one-line message starting with ``key``; never another
  exception, never a hang, never executes anything (a sentinel file that any
  successful code execution would create must never appear).  Valid
  expressions drawn from a grammar evaluate to the same numbers as an
  independent numpy evaluation built alongside the text.
- ``load_scene(path, overrides)`` on TOML documents built from the schema
  (valid, and mutated: random keys, types, values, missing sections, random
  overrides) returns a ``Scene`` or raises ``InputError`` with one line naming
  a key; valid documents always load.

Each property prints how many inputs it tried and how many were accepted
(``pytest -s`` shows it).  The properties are not collective; they run in the
serial pass only, to keep the MPI pass short.
"""

import json
import math
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from parefg.errors import InputError
from parefg.scene.expressions import compile_field, parse_expression
from parefg.scene.loader import Scene, load_scene
from parefg.scene.schema import SECTIONS

pytestmark = pytest.mark.serial_only

SECONDS_PER_CALL = 5.0  # a single parse or load beyond this counts as a hang
FUZZ = settings(
    max_examples=300,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
    database=None,
)


class Tally:
    """How many inputs a property tried and how many were accepted."""

    def __init__(self, name: str):
        self.name, self.tried, self.accepted = name, 0, 0

    def report(self) -> None:
        print(f"\n[fuzz] {self.name}: {self.tried} inputs tried, {self.accepted} accepted")


def timed(call, *args):
    """``call(*args)`` -> (result or InputError, seconds); other exceptions propagate."""
    start = time.monotonic()
    try:
        result = call(*args)
    except InputError as error:
        result = error
    seconds = time.monotonic() - start
    assert seconds < SECONDS_PER_CALL, f"{call.__name__}{args!r} took {seconds:.1f} s"
    return result


def assert_one_line(error: InputError, prefix: str) -> None:
    message = str(error)
    assert "\n" not in message and "\r" not in message, repr(message)
    assert message.startswith(prefix), repr(message)


# ---------------------------------------------------------------------------
# (a) the expression parser on hostile text

PYTHON_TOKENS = [
    *"x y t pi e sin cos exp log sqrt abs min max heaviside atan2 sign".split(),
    *"__import__ os system open eval exec compile globals getattr lambda import".split(),
    *"__class__ __base__ __subclasses__ __globals__ __builtins__ __dict__ self".split(),
    *"( ) [ ] { } , . : ; ' \" ** * / // % @ + - ~ < > == != and or not if else for in".split(),
    *"0 1 2 0.5 1e308 1e-400 1e999 9999999999999999999999999999999999 0x1f 1j 1_000 .5".split(),
    " ",
    "\n",
    "\t",
    "\x00",
    "π",
    "ｓｉｎ",  # full-width: Python identifiers normalize (NFKC) to sin
    "√",
    "²",
    "𝑥",
    "\\",
    "#",
    "...",
    ":=",
    "f'{x}'",
    "b'x'",
]
token_soup = st.lists(st.sampled_from(PYTHON_TOKENS), max_size=30).map("".join)
expression_like_text = st.one_of(st.text(max_size=80), token_soup)


def sentinel_payloads(sentinel: Path) -> list[str]:
    """Texts that create ``sentinel`` if any part of them is ever executed by Python."""
    path = str(sentinel)
    return [
        f"__import__('os').system('touch {path}')",
        f"__import__('pathlib').Path({path!r}).touch()",
        f"open({path!r}, 'w')",
        f"(lambda: open({path!r}, 'w'))()",
        f"[open({path!r}, 'w') for _ in (1,)]",
        f"x + exec(\"open({path!r}, 'w')\")",
        f"sin(x) + eval(\"open({path!r}, 'w')\")",
        f"().__class__.__base__.__subclasses__() or open({path!r}, 'w')",
        f"sin.__globals__['__builtins__'].open({path!r}, 'w')",
        f"1 if open({path!r}, 'w') else 0",
    ]


@pytest.fixture(scope="module")
def sentinel(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz_sentinel") / "EXECUTED"


def check_parse(text: str, tally: Tally):
    """Parse ``text``: an expression or a one-line InputError prefixed with the key."""
    tally.tried += 1
    result = timed(parse_expression, text, "fuzz.key")
    if isinstance(result, InputError):
        assert_one_line(result, "fuzz.key: ")
    else:
        tally.accepted += 1
        # the parser's contract: a real, finite expression in x, y, t only
        assert {s.name for s in result.free_symbols} <= {"x", "y", "t"}
        assert result.is_real is not False, (text, result)
    return result


def test_parser_on_random_text(sentinel):
    tally = Tally("parse_expression on random text and token soup")

    @FUZZ
    @given(expression_like_text)
    def prop(text):
        check_parse(text, tally)

    prop()
    tally.report()
    assert tally.tried >= 300 and not sentinel.exists()


def test_parser_never_executes_payloads(sentinel):
    tally = Tally("parse_expression on code-execution payloads in token noise")
    payloads = sentinel_payloads(sentinel)

    @FUZZ
    @given(st.sampled_from(payloads), token_soup, token_soup)
    def prop(payload, before, after):
        # alone, no payload is a whitelisted expression
        assert isinstance(check_parse(payload, tally), InputError)
        # in noise ("x #" + payload is the valid "x") it may parse, but never runs
        check_parse(before + payload + after, tally)
        assert not sentinel.exists(), payload

    prop()
    tally.report()
    assert tally.tried >= 600 and not sentinel.exists()


WHITELIST_TOKENS = [
    *"x y t pi e 0 1 2 -1 0.5 64 65 1e300 ( ) ( ) , + - * / ** ** /0 ".split(),
    *"sin( cos( tan( arcsin( arccos( log( sqrt( exp( abs( sign( heaviside(".split(),
    *"min( max( atan2( arctan2( sinh( tanh(".split(),
]
# whitelisted tokens in random order: far more of these parse, and reach sympy's corners
whitelist_soup = st.lists(st.sampled_from(WHITELIST_TOKENS), min_size=1, max_size=24).map(" ".join)


def test_parser_on_whitelisted_token_soup():
    tally = Tally("parse_expression on whitelisted tokens in random order")

    @FUZZ
    @given(whitelist_soup)
    def prop(text):
        check_parse(text, tally)

    prop()
    tally.report()
    assert tally.tried >= 300 and tally.accepted > 0


@pytest.mark.parametrize(
    "text",
    ["max(sqrt(-1), 1)", "min(1/0, x)", "max(x, log(0))", "(-8)**(1/3)", "2 ** 1e300", "1e300**64"],
)
def test_parser_refuses_non_real_or_non_comparable(text):
    """Found by the fuzzing: sympy's Min/Max raised ValueError on complex or infinite
    arguments, and a negative base to a fractional power gave a complex constant."""
    with pytest.raises(InputError, match=r"^k: "):
        parse_expression(text, "k")


# ---------------------------------------------------------------------------
# (a') valid expressions from a grammar, evaluated independently with numpy

# Each node is (text, numpy function of (x, y, t)).  Functions with a restricted domain
# get arguments that keep them inside it, so every value is finite and real.
LEAVES = {
    "x": lambda x, y, t: x,
    "y": lambda x, y, t: y,
    "t": lambda x, y, t: t,
    "pi": lambda x, y, t: np.pi + 0 * x,
    "e": lambda x, y, t: np.e + 0 * x,
}
UNARY = {
    "sin({})": np.sin,
    "cos({})": np.cos,
    "tanh({})": np.tanh,
    "arctan({})": np.arctan,
    "atan({})": np.arctan,
    "exp(sin({}))": lambda a: np.exp(np.sin(a)),
    "sqrt(1 + ({})**2)": lambda a: np.sqrt(1 + a**2),
    "log(2 + cos({}))": lambda a: np.log(2 + np.cos(a)),
    # arcsin's argument kept within [-1/2, 1/2]: near +-1 its condition number is unbounded,
    # so arcsin(tanh(19)) turned a 1-ulp difference of tanh into 1e-8 (machine-dependent)
    "arcsin(tanh({}) / 2)": lambda a: np.arcsin(np.tanh(a) / 2),
    "acos(sin({}) / 2)": lambda a: np.arccos(np.sin(a) / 2),
    "cosh(sin({}))": lambda a: np.cosh(np.sin(a)),
    "sinh(cos({}))": lambda a: np.sinh(np.cos(a)),
    "tan(sin({}))": lambda a: np.tan(np.sin(a)),
    "abs({})": np.abs,
    "-({})": np.negative,
    "+({})": lambda a: a,
    "({})**2": np.square,
    "({})**3": lambda a: a**3,
    "(2 + sin({}))**-1": lambda a: 1 / (2 + np.sin(a)),
    "(1 + ({})**2)**0.5": lambda a: (1 + a**2) ** 0.5,
}
BINARY = {
    "({}) + ({})": np.add,
    "({}) - ({})": np.subtract,
    "({}) * ({})": np.multiply,
    "({}) / (3 + cos({}))": lambda a, b: a / (3 + np.cos(b)),
    "min({}, {})": np.minimum,
    "max({}, {})": np.maximum,
    "atan2({}, 1 + ({})**2)": lambda a, b: np.arctan2(a, 1 + b**2),
    "arctan2(1 + ({})**2, {})": lambda a, b: np.arctan2(1 + a**2, b),
}


@st.composite
def numbers(draw):
    """A literal: a small integer or a float written in Python syntax."""
    # no subnormals: 1 / 2.2e-311 overflows a double, which the parser rightly refuses, so
    # such a literal does not make a *valid* expression (seen once in CI-like runs)
    value = draw(st.one_of(st.integers(0, 50), st.floats(0, 10, allow_subnormal=False)))
    return repr(value), (lambda x, y, t: value + 0 * x)


@st.composite
def steps(draw):
    """sign / heaviside of a variable minus a constant: their jump sits off the samples."""
    variable = draw(st.sampled_from("xyt"))
    shift = draw(st.sampled_from([0.25, 0.5, 0.75]))
    index = "xyt".index(variable)
    kinds = {
        "sign({} - {})": np.sign,
        "heaviside({} - {})": lambda a: np.heaviside(a, 0.5),
        "heaviside({} - {}, 1)": lambda a: np.heaviside(a, 1.0),
    }
    pattern = draw(st.sampled_from(sorted(kinds)))
    return pattern.format(variable, shift), (
        lambda *xyt: kinds[pattern](xyt[index] - shift) + 0 * xyt[0]
    )


def unary(children):
    def node(pattern, child):
        text, f = child
        return pattern.format(text), (lambda x, y, t: UNARY[pattern](f(x, y, t)))

    return st.builds(node, st.sampled_from(sorted(UNARY)), children)


def binary(children):
    def node(pattern, left, right):
        (ltext, lf), (rtext, rf) = left, right
        return pattern.format(ltext, rtext), (
            lambda x, y, t: BINARY[pattern](lf(x, y, t), rf(x, y, t))
        )

    return st.builds(node, st.sampled_from(sorted(BINARY)), children, children)


leaves = st.one_of(
    st.sampled_from(sorted(LEAVES)).map(lambda name: (name, LEAVES[name])), numbers(), steps()
)
valid_expressions = st.recursive(
    leaves, lambda children: st.one_of(unary(children), binary(children)), max_leaves=12
)

# off the jumps of sign / heaviside at 0.25, 0.5, 0.75
SAMPLE_POINTS = np.random.default_rng(7).uniform(0.0, 1.0, size=(3, 40))  # (x, y, t) rows
SAMPLE_POINTS = SAMPLE_POINTS[
    :, np.all(np.abs(SAMPLE_POINTS[:, :, None] - [0.25, 0.5, 0.75]) > 1e-3, axis=(0, 2))
]


def test_valid_expressions_match_numpy():
    tally = Tally("valid grammar expressions vs independent numpy evaluation")

    @FUZZ
    @given(valid_expressions)
    def prop(node):
        text, reference = node
        tally.tried += 1
        expr = timed(parse_expression, text, "grammar")
        assert not isinstance(expr, InputError), f"{text!r}: {expr}"
        x, y, t = SAMPLE_POINTS
        with np.errstate(over="raise", invalid="raise", divide="raise", under="ignore"):
            expected = reference(x, y, t)  # (n,)
        got = compile_field([expr])(x, y, t)[0]
        scale = max(1.0, float(np.max(np.abs(expected))))
        np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-11 * scale, err_msg=text)
        tally.accepted += 1

    prop()
    tally.report()
    assert tally.accepted == tally.tried >= 300


# ---------------------------------------------------------------------------
# (b) the scene loader on TOML documents built from the schema


class TomlDate:
    """A TOML datetime literal (tomllib turns it into datetime, a type no key accepts)."""

    text = "1979-05-27T07:32:00Z"


def key_text(key: str) -> str:
    return json.dumps(key, ensure_ascii=False)


def toml_value(value) -> str:
    """One TOML value: inline arrays and inline tables for nesting."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return (
            "nan"
            if math.isnan(value)
            else {math.inf: "inf", -math.inf: "-inf"}.get(value, repr(value))
        )
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)  # JSON escapes are TOML escapes
    if isinstance(value, TomlDate):
        return value.text
    if isinstance(value, list):
        return "[" + ", ".join(map(toml_value, value)) + "]"
    items = (f"{key_text(k)} = {toml_value(v)}" for k, v in value.items())
    return "{" + ", ".join(items) + "}"


def toml_document(doc: dict) -> str:
    """Top-level scalars first, then one [section] per table."""
    scalars = [
        f"{key_text(k)} = {toml_value(v)}" for k, v in doc.items() if not isinstance(v, dict)
    ]
    tables = [
        f"[{key_text(k)}]\n"
        + "".join(f"{key_text(sk)} = {toml_value(sv)}\n" for sk, sv in v.items())
        for k, v in doc.items()
        if isinstance(v, dict)
    ]
    return "\n".join(scalars) + "\n" + "\n".join(tables)


PARTS = {"square": ["bottom", "right", "top", "left"], "z": ["bottom", "top", "sides"]}
simple_expression = st.one_of(
    st.floats(-2, 2, allow_nan=False),
    st.integers(-3, 3),
    st.sampled_from(["x", "sin(pi*x)*t", "(1 - cos(t)) * (1 + x) * exp(y)", "0.01*y*x"]),
)
vector = st.lists(simple_expression, min_size=2, max_size=2)
# gap s >= 0 and friction bound g >= 0 on every domain below (checked at load)
gap = st.one_of(st.floats(0, 0.1), st.sampled_from(["0.01 * (x * (1 - x))**2", "0.1*abs(y)"]))
friction_bound = st.one_of(
    st.floats(0, 2),
    st.integers(0, 3),
    st.sampled_from(["x**2", "abs(sin(pi*x))*t", "(1 - cos(t)) * (1 + x**2) * exp(y)", "0.01*y*y"]),
)


@st.composite
def domains(draw):
    """(domain table, its boundary part names)."""
    shape = draw(st.sampled_from(["square", "rectangle", "z", "polygon"]))
    if shape == "rectangle":
        size = draw(st.lists(st.floats(0.1, 5), min_size=2, max_size=2))
        return {"shape": shape, "size": size, "origin": [0.0, -1.0]}, PARTS["square"]
    if shape == "polygon":
        n = draw(st.integers(3, 6))
        angles = np.linspace(0, 2 * np.pi, n, endpoint=False)  # counter-clockwise
        vertices = [[float(np.cos(a)), float(np.sin(a))] for a in angles]
        names = [draw(st.sampled_from(["base", "wall", "lid"])) for _ in range(n)]
        return {"shape": shape, "vertices": vertices, "edge_names": names}, sorted(set(names))
    return {"shape": shape}, PARTS[shape]


@st.composite
def boundary_tables(draw, part_names, has_exact):
    tables = {}
    for name in draw(st.lists(st.sampled_from(part_names), unique=True)):
        kind = draw(st.sampled_from(["dirichlet", "neumann", "contact"]))
        table = {"type": kind}
        data = {"dirichlet": ["value"], "neumann": ["traction"], "contact": ["gap", "friction"]}
        for key in data[kind]:
            if draw(st.booleans()) or (key == "friction" and not has_exact):
                continue
            table[key] = draw({"gap": gap, "friction": friction_bound}.get(key, vector))
        if kind == "contact" and "friction" not in table and not has_exact:
            table["friction"] = draw(st.sampled_from([0, 0.5, "abs(x) + t"]))
        tables[name] = table
    return tables


@st.composite
def valid_scenes(draw):
    """A TOML scene that satisfies the schema (SPEC 6)."""
    domain, part_names = draw(domains())
    degree = draw(st.integers(1, 3))
    T = draw(st.sampled_from([0.5, 1.0, 2.0, 3.0]))
    doc = {
        "name": "fuzz",
        "domain": domain,
        "discretization": {
            "h": draw(st.floats(0.01, 0.5)),
            "degree": degree,
            "weight": draw(st.sampled_from(["cubic", "quartic", "gaussian"])),
            "support": draw(st.floats(1.5, 4.0)),
            "quadrature": draw(st.integers(1, 10)),
            "cells": draw(st.sampled_from(["quad", "tri"])),
        },
        "material": draw(
            st.one_of(
                st.fixed_dictionaries({"E": st.floats(0.1, 1e3), "nu": st.floats(-0.9, 0.49)}),
                st.fixed_dictionaries({"lam": st.floats(0, 10), "mu": st.floats(0.1, 10)}),
            )
        ),
        "time": {
            "scheme": draw(st.sampled_from(["newmark", "static"])),
            "T": T,
            "dt": T / draw(st.integers(1, 40)),
            "beta": draw(st.sampled_from([0.25, 0.5])),
            "gamma": 0.5,
        },
        "output": {"every": draw(st.integers(0, 5)), "fields": ["u", "contact"]},
        "solver": {"ksp_type": "preonly", "pc_type": "lu", "snes_monitor": False},
    }
    doc["material"]["rho"] = draw(st.floats(0.1, 10))
    has_exact = draw(st.integers(0, 4)) == 0
    if has_exact:
        doc["exact"] = {"u": draw(vector)}
    else:
        doc["initial"] = {"u": draw(vector), "v": [0, 0]}
        doc["loads"] = {"f": draw(vector)}
    doc["boundary"] = draw(boundary_tables(part_names, has_exact))
    if draw(st.booleans()):
        doc["penalty"] = {"alpha": draw(st.floats(1.0, 1e6))}
    return doc


def write_scene(directory: Path, doc: dict) -> Path:
    path = directory / "fuzz.toml"
    path.write_text(toml_document(doc))
    return path


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz_scenes")


def test_valid_scenes_load(scene_dir):
    tally = Tally("load_scene on valid schema-built documents")

    @FUZZ
    @given(valid_scenes())
    def prop(doc):
        tally.tried += 1
        scene = timed(load_scene, str(write_scene(scene_dir, doc)))
        assert isinstance(scene, Scene), f"{toml_document(doc)}\n-> {scene}"
        assert scene.time.n_steps == round(doc["time"]["T"] / doc["time"]["dt"])
        assert scene.discretization.h == doc["discretization"]["h"]
        assert set(scene.boundaries) == set(doc["boundary"])
        tally.accepted += 1

    prop()
    tally.report()
    assert tally.accepted == tally.tried >= 200


# TOML text needs no surrogates, and DEL is a character JSON leaves unescaped
plain_text = st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="\x7f"))
toml_scalars = st.one_of(
    st.integers(-(10**400), 10**400),
    st.integers(-3, 3),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, -1.0, 1e-320, 1e308, 0.5, 1.0]),
    st.booleans(),
    plain_text.filter(lambda s: len(s) < 40),
    st.sampled_from(["x", "sin(x)", "__import__('os')", "newmark", "static", "cubic", "quad"]),
    st.just(TomlDate()),
)
toml_values = st.recursive(
    toml_scalars,
    lambda inner: st.one_of(
        st.lists(inner, max_size=4), st.dictionaries(plain_text.filter(bool), inner, max_size=3)
    ),
    max_leaves=6,
)
SCHEMA_KEYS = [
    *"shape size origin vertices edge_names file parts h degree weight support".split(),
    *"quadrature cells E nu lam mu rho scheme T dt beta gamma alpha alpha_dirichlet".split(),
    *"alpha_contact alpha_friction type value traction gap friction u v f every fields".split(),
]
key_names = st.one_of(st.sampled_from(SCHEMA_KEYS + list(SECTIONS)), plain_text.filter(bool))


@st.composite
def mutated_scenes(draw):
    """A valid scene with 1..3 random edits; returns (doc, the keys touched)."""
    doc = draw(valid_scenes())
    touched = set()
    for _ in range(draw(st.integers(1, 3))):
        # a random table of the document (top level, a section or a boundary part)
        tables = [("", doc)] + [(k, v) for k, v in doc.items() if isinstance(v, dict)]
        boundary = doc.get("boundary")
        if isinstance(boundary, dict):
            tables += [(f"boundary.{k}", v) for k, v in boundary.items() if isinstance(v, dict)]
        path, table = draw(st.sampled_from(tables))
        edit = draw(st.sampled_from(["delete", "add", "replace"]))
        if edit == "add" or not table:
            key = draw(key_names)
            table[key] = draw(toml_values)
        else:
            key = draw(st.sampled_from(sorted(table)))
            if edit == "delete":
                del table[key]
            else:
                table[key] = draw(toml_values)
        touched |= {key, path.split(".")[0]} - {""}
    return doc, touched


override_texts = st.one_of(
    st.builds(
        "{}.{}={}".format,
        st.sampled_from(list(SECTIONS) + ["boundary.bottom", "boundary.top", "name"]),
        key_names,
        st.one_of(plain_text.filter(lambda s: len(s) < 30), toml_values.map(toml_value)),
    ),
    plain_text.filter(lambda s: len(s) < 40),
)


def names_a_key(message: str, words) -> bool:
    """Whether an error message names a schema key, a section, a touched key or --set."""
    return any(word in message for word in ("--set", *SECTIONS, *SCHEMA_KEYS, *words))


def test_mutated_scenes_and_overrides(scene_dir):
    tally = Tally("load_scene on mutated documents with random overrides")

    @FUZZ
    @given(mutated_scenes(), st.lists(override_texts, max_size=3))
    def prop(mutated, overrides):
        doc, touched = mutated
        tally.tried += 1
        result = timed(load_scene, str(write_scene(scene_dir, doc)), overrides)
        if isinstance(result, Scene):
            tally.accepted += 1
            numbers = [
                result.discretization.h,
                result.material.E,
                result.material.nu,
                result.material.lam,
                result.material.mu,
                result.material.rho,
                result.time.T,
            ]
            numbers += [
                result.time.dt,
                result.penalty.alpha_dirichlet,
                result.penalty.alpha_contact,
            ]
            assert np.all(np.isfinite(numbers)), numbers
            return
        assert_one_line(result, "scene fuzz: ")
        message = str(result).removeprefix("scene fuzz: ")
        assert "TOML syntax error" not in message, toml_document(doc)
        assert names_a_key(message, touched), (message, touched, overrides)

    prop()
    tally.report()
    assert tally.tried >= 300 and 0 < tally.accepted < tally.tried


@pytest.mark.parametrize(
    ("overrides", "key"),
    [
        # TOML integers are unbounded: TypeError before
        (["discretization.h=1" + "0" * 400], "discretization.h"),
        # T / dt = inf: OverflowError in round() before
        (["time.T=1e300", "time.dt=1e-10"], "time.dt"),
        # the default alpha = 1e4 E / h = inf was accepted
        (["discretization.h=1e-320"], "penalty.alpha"),
        # lam = inf was accepted
        (["material.E=1e308", "material.nu=0.4999"], "material"),
        # a key with a newline made a two-line message
        (["solver.a\nb=1"], "solver."),
        # ValueError from sympy's Max
        (['boundary.bottom.friction="max(sqrt(-1), x)"'], "boundary.bottom.friction"),
    ],
)
def test_scene_loader_regressions(overrides, key):
    """Inputs the fuzzing found: each is now a one-line InputError naming its key."""
    with pytest.raises(InputError) as caught:
        load_scene("square", overrides)
    message = str(caught.value)
    assert "\n" not in message and message.startswith("scene square: ")
    assert key in message, message
