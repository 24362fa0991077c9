"""A safe expression language for scene values (SPEC 6, 9).

Scene values such as ``"sin(pi*x)*exp(-t)"`` are parsed with :mod:`ast` and
translated node by node into sympy through a whitelist: numbers, the
variables x, y, t, the constants pi and e, the operators ``+ - * / **`` and a
fixed set of numpy-named functions.  User text never reaches ``eval``,
``exec`` or ``sympify``.  Inputs that could exhaust time or memory (very long
text, deep nesting, huge integers, huge powers) are rejected before sympy
sees them.

The symbols are real, so that sympy differentiates ``abs`` and friends as
real functions.  :func:`compile_field` turns a list of such expressions into a
vectorized numpy function (:class:`~parefg.scene.numeric.CompiledField`).
"""

import ast
import math
import sys
import warnings
from collections.abc import Callable, Sequence
from functools import reduce

import numpy as np
import sympy

from parefg.errors import InputError
from parefg.scene.numeric import CompiledField, UnsupportedText, dirac_delta

MAX_LENGTH = 1000  # characters of one expression
MAX_DEPTH = 50  # nesting levels (a chain a + b + c counts as one level)
MAX_INTEGER_DIGITS = 30  # digits of one integer literal
MAX_EXPONENT = 64  # |n| for a numeric exponent in a ** n
MAX_NUMBER_DIGITS = 1000  # digits of an exact number built by a ** n
CONSTANT_DIGITS = 20  # digits of a constant subexpression evaluated at load (sin(10**25))

#: Every symbol an expression may contain; ``nx``, ``ny`` (the outward unit
#: normal) appear only in data derived from an exact solution, never in user text.
SYMBOLS = {name: sympy.Symbol(name, real=True) for name in ("x", "y", "t", "nx", "ny")}
VARIABLES = ("x", "y", "t")
CONSTANTS = {"pi": sympy.pi, "e": sympy.E}

#: name -> (sympy function, allowed numbers of arguments)
FUNCTIONS = {
    "sin": (sympy.sin, (1,)),
    "cos": (sympy.cos, (1,)),
    "tan": (sympy.tan, (1,)),
    "arcsin": (sympy.asin, (1,)),
    "arccos": (sympy.acos, (1,)),
    "arctan": (sympy.atan, (1,)),
    "asin": (sympy.asin, (1,)),
    "acos": (sympy.acos, (1,)),
    "atan": (sympy.atan, (1,)),
    "sinh": (sympy.sinh, (1,)),
    "cosh": (sympy.cosh, (1,)),
    "tanh": (sympy.tanh, (1,)),
    "exp": (sympy.exp, (1,)),
    "log": (sympy.log, (1,)),
    "sqrt": (sympy.sqrt, (1,)),
    "abs": (sympy.Abs, (1,)),
    "sign": (sympy.sign, (1,)),
    "heaviside": (sympy.Heaviside, (1, 2)),
    "min": (sympy.Min, range(2, 17)),
    "max": (sympy.Max, range(2, 17)),
    "atan2": (sympy.atan2, (2,)),
    "arctan2": (sympy.atan2, (2,)),
}

ALLOWED = "use numbers, x, y, t, pi, e, + - * / ** and " + ", ".join(FUNCTIONS)

_BINARY_OPERATORS = {
    ast.Add: lambda a, b: a + b,
    ast.Sub: lambda a, b: a - b,
    ast.Mult: lambda a, b: a * b,
    ast.Div: lambda a, b: a / b,
    ast.Pow: lambda a, b: a**b,
}
_UNARY_OPERATORS = {ast.UAdd: lambda a: a, ast.USub: lambda a: -a}
# Operators of one precedence level; a left-associated chain of them is one nesting level.
_PRECEDENCE = {ast.Add: 0, ast.Sub: 0, ast.Mult: 1, ast.Div: 1}


def _shorten(text: str, limit: int = 60) -> str:
    """``repr`` of ``text`` cut to ``limit`` characters: one line, whatever the input."""
    return repr(text if len(text) <= limit else text[: limit - 3] + "...")


def parse_expression(value: int | float | str, key: str) -> sympy.Expr:
    """Translate a scene value into a sympy expression in x, y, t.

    Not collective.

    Parameters
    ----------
    value
        A number, or a string such as ``"(1 - cos(t)) * (1 + x) * exp(y)"``.
    key
        Where the value came from (e.g. ``"scene square: loads.f[0]"``); every
        error message starts with it.

    Returns
    -------
    sympy.Expr
        A real, finite expression whose free symbols are among
        ``SYMBOLS["x"], SYMBOLS["y"], SYMBOLS["t"]``.

    Raises
    ------
    InputError
        One line naming ``key`` and what is allowed, for anything outside the
        whitelist or beyond the resource limits.
    """
    if isinstance(value, bool) or not isinstance(value, int | float | str):
        raise InputError(f"{key}: {_shorten(str(value))} is not an expression ({ALLOWED})")
    text = value.strip() if isinstance(value, str) else repr(value)
    if len(text) > MAX_LENGTH:
        raise InputError(f"{key}: expression of {len(text)} characters (at most {MAX_LENGTH})")
    try:
        with warnings.catch_warnings():  # "1x" warns (invalid decimal literal) before failing
            warnings.simplefilter("ignore")
            tree = ast.parse(text, mode="eval")
    except (SyntaxError, ValueError, RecursionError, MemoryError) as exc:
        reason = getattr(exc, "msg", None) or str(exc).splitlines()[0]
        raise InputError(f"{key}: {_shorten(text)} is not a valid expression ({reason})") from None
    expr = _Translator(text, key).build(tree.body, depth=1)
    if not _is_finite_real(expr):
        raise InputError(f"{key}: {_shorten(text)} is not a finite real expression")
    return expr


def _is_finite_real(expr: sympy.Expr) -> bool:
    """False for what numpy could not evaluate to a finite real number.

    Division by zero, sqrt(-1), log(0), ... leave sympy's non-real or infinite atoms;
    (-8)**(1/3) = 2 (-1)**(1/3) is complex without containing I; 1e300**64 is a finite
    sympy Float but overflows a double, and so does the constant exp(1000).
    """
    if expr.has(sympy.I, sympy.zoo, sympy.nan, sympy.oo, -sympy.oo):
        return False
    if any(abs(number) > sys.float_info.max for number in expr.atoms(sympy.Number)):
        return False
    if not all(_is_double(part.evalf(CONSTANT_DIGITS)) for part in _constant_parts(expr)):
        return False
    return expr.is_extended_real is not False


def _constant_parts(expr: sympy.Expr):
    """The largest subexpressions of expr without free symbols that are not atoms.

    sympy combines constants across the tree: x*exp(700)*exp(700) becomes x*exp(1400).
    """
    if expr.is_Atom:
        return
    if not expr.free_symbols:
        yield expr
        return
    for arg in expr.args:
        yield from _constant_parts(arg)


def _is_double(value: sympy.Expr) -> bool:
    """Whether an evaluated constant is a real number within the range of a double."""
    return bool(value.is_Number and value.is_finite and abs(value) <= sys.float_info.max)


class _Translator:
    """Build a sympy expression from a whitelisted :mod:`ast` tree."""

    def __init__(self, text: str, key: str):
        self.text = text
        self.key = key

    def reject(self, node: ast.AST, why: str = "") -> InputError:
        """The one-line error for ``node``: its source text and what is allowed."""
        segment = ast.get_source_segment(self.text, node) or self.text
        return InputError(f"{self.key}: {_shorten(segment)} is not allowed ({why or ALLOWED})")

    def build(self, node: ast.AST, depth: int) -> sympy.Expr:
        """Translate ``node`` nested ``depth`` levels deep."""
        if depth > MAX_DEPTH:
            raise self.reject(node, f"nested more than {MAX_DEPTH} levels deep")
        handler = self._HANDLERS.get(type(node))
        if handler is None:
            raise self.reject(node)
        expr = handler(self, node, depth)
        # Constants are evaluated level by level: each evaluation starts from values in
        # the range of a double, so it stays cheap (sin(exp(exp(exp(10)))) stops at the
        # second exp instead of asking for 10**9565 digits of pi).
        if not expr.free_symbols and not _is_finite_real(expr):
            raise self.reject(node, "not a finite real number within the range of a double")
        return expr

    def constant(self, node: ast.Constant, depth: int) -> sympy.Expr:
        value = node.value
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self.reject(node)
        if isinstance(value, int):
            if len(str(abs(value))) > MAX_INTEGER_DIGITS:
                raise self.reject(node, f"integers have at most {MAX_INTEGER_DIGITS} digits")
            return sympy.Integer(value)
        if not math.isfinite(value):
            raise self.reject(node, "numbers must be finite")
        return sympy.Float(value)

    def name(self, node: ast.Name, depth: int) -> sympy.Expr:
        if node.id in VARIABLES:
            return SYMBOLS[node.id]
        if node.id in CONSTANTS:
            return CONSTANTS[node.id]
        raise self.reject(node)

    def unary(self, node: ast.UnaryOp, depth: int) -> sympy.Expr:
        operator = _UNARY_OPERATORS.get(type(node.op))
        if operator is None:
            raise self.reject(node)
        return operator(self.build(node.operand, depth + 1))

    def binary(self, node: ast.BinOp, depth: int) -> sympy.Expr:
        operator = _BINARY_OPERATORS.get(type(node.op))
        if operator is None:
            raise self.reject(node)
        # a + b + c parses as ((a + b) + c): the left chain is one level, not many.
        level = _PRECEDENCE.get(type(node.op))
        chained = isinstance(node.left, ast.BinOp) and _PRECEDENCE.get(type(node.left.op)) == level
        left = self.build(node.left, depth if level is not None and chained else depth + 1)
        right = self.build(node.right, depth + 1)
        if isinstance(node.op, ast.Pow):
            self._check_power(node, left, right)
        return operator(left, right)

    def _check_power(self, node: ast.BinOp, base: sympy.Expr, exponent: sympy.Expr) -> None:
        """Refuse powers sympy would evaluate exactly at great cost (9**9**9)."""
        if not exponent.is_Number:
            return
        if abs(exponent) > MAX_EXPONENT:
            raise self.reject(node, f"numeric exponents are at most {MAX_EXPONENT} in size")
        if base.is_Rational and base != 0:
            numerator, denominator = base.as_numer_denom()
            digits = math.log10(abs(int(numerator))) + math.log10(abs(int(denominator)))
            if digits * abs(float(exponent)) > MAX_NUMBER_DIGITS:
                raise self.reject(node, f"exact numbers have at most {MAX_NUMBER_DIGITS} digits")

    def call(self, node: ast.Call, depth: int) -> sympy.Expr:
        if not isinstance(node.func, ast.Name) or node.func.id not in FUNCTIONS:
            raise self.reject(node)
        function, arities = FUNCTIONS[node.func.id]
        if node.keywords:
            raise self.reject(node, "keyword arguments are not allowed")
        if len(node.args) not in arities:
            many = len(arities) > 2
            counts = f"{arities[0]} to {arities[-1]}" if many else " or ".join(map(str, arities))
            plural = "" if counts == "1" else "s"
            raise self.reject(node, f"{node.func.id} takes {counts} argument{plural}")
        args = [self.build(arg, depth + 1) for arg in node.args]
        # Checked first: sympy's Min/Max raise ValueError on complex or infinite arguments.
        for arg, arg_node in zip(args, node.args, strict=True):
            if not _is_finite_real(arg):
                raise self.reject(arg_node, "not a finite real expression")
        result = function(*args)
        if function is sympy.atan2 and result.has(sympy.I) and not result.free_symbols:
            # sympy rewrites atan2 of some constants as -I*log(...), which reads as complex
            return function(*args, evaluate=False)
        return result

    _HANDLERS: dict[type, Callable[..., sympy.Expr]] = {
        ast.Constant: constant,
        ast.Name: name,
        ast.UnaryOp: unary,
        ast.BinOp: binary,
        ast.Call: call,
    }


def _minimum(values, axis=0):
    """sympy prints Min(a, b, ...) as ``amin((a, b, ...), axis=0)``; allow mixed shapes."""
    return reduce(np.minimum, values)


def _maximum(values, axis=0):
    return reduce(np.maximum, values)


# lambdify's names beyond numpy's, for the rare text the whitelist evaluator refuses
_NUMPY_EXTRAS = {"amin": _minimum, "amax": _maximum, "DiracDelta": dirac_delta}


def numeric_form(expr: sympy.Expr) -> sympy.Expr:
    """``expr`` with its constants as the doubles numpy should compute with.

    Not collective.  A constant subexpression (sin(10**25), sqrt(2)) becomes its value
    rounded to a double, computed by sympy to CONSTANT_DIGITS digits: numpy would take
    sin of the Python int 10**25 as an object array and fail.  Integers and fractions
    beyond 2**53 become doubles too (10**25 * x), and every Float is printed with the 17
    digits that identify a double (sympy prints 15).
    """
    memo: dict[sympy.Basic, sympy.Expr] = {}

    def fold(node: sympy.Basic) -> sympy.Basic:
        if node not in memo:
            if node.is_Float or (node.is_Rational and max(abs(node.p), node.q) > 2**53):
                memo[node] = _double(node)
            elif node.is_Atom:
                memo[node] = node
            elif not node.free_symbols:
                memo[node] = _double(node.evalf(CONSTANT_DIGITS), node)
            else:
                args = [fold(arg) for arg in node.args]
                same = all(new is old for new, old in zip(args, node.args, strict=True))
                memo[node] = node if same else node.func(*args)
        return memo[node]

    return fold(expr)


def _double(value: sympy.Expr, otherwise: sympy.Expr | None = None) -> sympy.Expr:
    """A sympy Float equal to the double nearest ``value``, printed with 17 digits.

    ``otherwise`` (default ``value``) when value is not a real number (parse_expression
    admits none; derived data only combine what it admitted).
    """
    try:
        return sympy.Float(float(value), 17)
    except TypeError:
        return value if otherwise is None else otherwise


def compile_field(
    exprs: Sequence[sympy.Expr],
    args: Sequence[str] = VARIABLES,
    components: Sequence[int] | None = None,
) -> CompiledField:
    """Vectorize expressions into one numpy function.

    Not collective.

    Parameters
    ----------
    exprs
        k sympy expressions whose free symbols are among ``SYMBOLS[a]`` for ``a`` in ``args``.
    args
        Names of the positional arguments of the returned function.
    components
        Shape of the value at one point: ``(k,)`` (default), ``()`` for k = 1 or e.g.
        ``(2, 2)`` for k = 4 (row-major).

    Returns
    -------
    CompiledField
        ``field(*values) -> ndarray`` of shape ``(*components, *shape)``, where ``shape``
        is the broadcast shape of ``values`` (``(n,)`` for points x, y of shape
        ``(n,)`` and a scalar t).  Constant expressions are broadcast to full
        shape, and the result is a fresh, writable float array.  Its ``texts`` (sympy's
        printing of :func:`numeric_form`) are what the scene cache stores; the same
        texts compiled again give the same bits.
    """
    numeric = [numeric_form(sympy.sympify(expr, strict=True)) for expr in exprs]
    components = (len(exprs),) if components is None else tuple(components)
    try:
        return CompiledField([str(expr) for expr in numeric], args, components)
    except UnsupportedText:  # beyond the whitelist evaluator: lambdify (and no caching)
        symbols = [SYMBOLS[name] for name in args]
        rows = sympy.lambdify(symbols, numeric, modules=[_NUMPY_EXTRAS, "numpy"])
        return CompiledField(None, args, components, function=rows)
