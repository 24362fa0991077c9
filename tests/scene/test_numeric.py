"""The whitelist evaluator of expression text (parefg.scene.numeric): the values sympy's
lambdify gives, to the bit, and nothing but arithmetic for any text."""

import numpy as np
import pytest
import sympy

from parefg.scene.expressions import SYMBOLS, VARIABLES, numeric_form, parse_expression
from parefg.scene.numeric import CompiledField, UnsupportedText, compile_text

RNG = np.random.default_rng(11)
X, Y = RNG.uniform(-0.95, 0.95, size=(2, 40))  # (n,) points on both sides of the kinks at 0
T = 0.61

# Scene text whose derivatives cover what sympy prints: Abs -> sign -> DiracDelta,
# Min/Max -> Heaviside, atan2 -> rational functions, sqrt -> negative powers.
TEXTS = [
    "(1 - cos(t)) * (1 + x) * exp(y)",
    "abs(x) * sign(y) + heaviside(x - 0.25, 1)",
    "min(x, y**2, 0.5) * max(x, 0.2) / (3 + x)",
    "atan2(y, 2 + x) + arcsin(x / 2) * sqrt(2 + y) + log(2 + x) ** 3",
    "tanh(x) * cosh(y) - sinh(t) * tan(x / 2) + e**(-x**2) + pi * 10**25 * 1e-25",
    "x**(1/3) + (2 + x)**(-2) + 1/(2 + y) + 0.1 * t",
]


def lambdified(expr: sympy.Expr):
    """The reference: sympy's own numpy code for the expression."""
    from parefg.scene.expressions import _NUMPY_EXTRAS

    symbols = [SYMBOLS[name] for name in VARIABLES]
    return sympy.lambdify(symbols, numeric_form(expr), modules=[_NUMPY_EXTRAS, "numpy"])


def derivatives(text: str) -> list[sympy.Expr]:
    """The expression, its first x and y derivatives and a second t derivative."""
    expr = parse_expression(text, "k")
    x, y, t = (SYMBOLS[name] for name in VARIABLES)
    return [expr, expr.diff(x), expr.diff(y), expr.diff(x, y), expr.diff(t, 2)]


@pytest.mark.parametrize("text", TEXTS)
def test_printed_text_evaluates_as_lambdify(text):
    """The printed form of scene expressions and their derivatives gives lambdify's values
    (to round-off; equal where both take the same operations in the same order)."""
    for expr in derivatives(text):
        printed = str(numeric_form(expr))
        field = CompiledField([printed], VARIABLES)  # raises UnsupportedText if refused
        with np.errstate(invalid="ignore"):  # x**(1/3) at x < 0: NaN in both
            got = field(X, Y, T)[0]
            expected = np.broadcast_to(lambdified(expr)(X, Y, T), X.shape)
        np.testing.assert_allclose(got, expected, rtol=4e-15, atol=1e-300, equal_nan=True)


def test_components_shape_the_values():
    field = CompiledField(["x", "y", "t", "1"], VARIABLES, components=(2, 2))
    values = field(X, Y, T)  # (2, 2, n)
    assert values.shape == (2, 2, X.size)
    np.testing.assert_array_equal(values[0, 1], Y)
    np.testing.assert_array_equal(values[1, 1], np.ones(X.size))
    scalar = CompiledField(["x * y"], ("x", "y"), components=())
    assert scalar(X, Y).shape == X.shape
    values[1, 1, 0] = 7.0  # fresh arrays: the constant row is not shared
    assert field(X, Y, T)[1, 1, 0] == 1.0


@pytest.mark.parametrize(
    "text",
    [
        "__import__('os').system('true')",
        "x.__class__",
        "open('f')",
        "(lambda: 1)()",
        "[x for x in ()]",
        "x if y else t",
        "x < y",
        "sin(x, key=1)",
        "sin(x, y)",
        "nx",  # not an argument of this field
        "'text'",
        "True + x",
        "x @ y",
        "x // y",
        "numpy.sin(x)",
        "exp" + "(" * 5000 + "x" + ")" * 5000,
        "x +",
    ],
)
def test_refuses_everything_but_arithmetic(text):
    with pytest.raises(UnsupportedText):
        compile_text(text, VARIABLES)


def test_numbers_are_doubles():
    """A huge exact power costs nothing: numbers are floats, overflow gives inf."""
    evaluate = compile_text("9**9**9 + x", VARIABLES)
    with np.errstate(over="ignore"):
        assert evaluate({"x": np.zeros(2)}).tolist() == [np.inf, np.inf]
