"""Scene data as numpy callables, compiled from expression text without sympy.

Every datum of a scene (body force, boundary data, initial state, exact solution) is a
:class:`CompiledField`: expression texts in the notation sympy prints (``sin(x)*exp(-t)``,
``Abs(x)``, ``Heaviside(x, 1/2)``, ``Min(x, y)``, ``x**(-2)``) compiled by a whitelist
evaluator into a tree of numpy calls.  The text is parsed with :mod:`ast` and only
numbers, the field's argument names, pi and E, ``+ - * / **`` and the functions of
:data:`FUNCTIONS` are admitted: text never reaches ``eval``, ``exec`` or ``sympify``, so
fields read back from the scene cache (:mod:`parefg.scene.scene_cache`) can do nothing but
arithmetic.  Numbers are numpy doubles (no exact big-integer arithmetic to exhaust; an
overflow is inf, caught by the run-time guards).

Deriving the texts needs sympy (:mod:`parefg.scene.expressions`); compiling and
evaluating them does not, which is what lets a cached scene start without importing it.
Not collective.
"""

import ast
import math
import operator
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import reduce
from typing import Any

import numpy as np

from parefg.boundary import BoundaryKind
from parefg.discretization.dirichlet import DEFAULT_DIRICHLET_METHOD
from parefg.mechanics.friction import DEFAULT_FRICTION_LAW

MAX_TEXT = 2_000_000  # characters of one compiled expression (derived data: < 1e5)

#: a vectorized field: (x, y[, t[, nx, ny]]) point arrays -> (k, n) values
Field = Callable[..., np.ndarray]
Evaluator = Callable[[dict], Any]  # name -> array (or number) -> ndarray or number


def _minimum(*values):
    return reduce(np.minimum, values)


def _maximum(*values):
    return reduce(np.maximum, values)


def _heaviside(argument, at_zero=0.5):
    return np.heaviside(argument, at_zero)


def dirac_delta(argument, *order):
    """Derivatives of heaviside/sign/abs: zero almost everywhere, which is what quadrature sees."""
    return np.zeros_like(np.asarray(argument, dtype=float))


#: sympy's printed name -> (numpy function, allowed numbers of arguments)
FUNCTIONS: dict[str, tuple[Callable, Sequence[int]]] = {
    "sin": (np.sin, (1,)),
    "cos": (np.cos, (1,)),
    "tan": (np.tan, (1,)),
    "asin": (np.arcsin, (1,)),
    "acos": (np.arccos, (1,)),
    "atan": (np.arctan, (1,)),
    "sinh": (np.sinh, (1,)),
    "cosh": (np.cosh, (1,)),
    "tanh": (np.tanh, (1,)),
    "exp": (np.exp, (1,)),
    "log": (np.log, (1,)),
    "sqrt": (np.sqrt, (1,)),
    "Abs": (np.abs, (1,)),
    "sign": (np.sign, (1,)),
    "Heaviside": (_heaviside, (1, 2)),
    "Min": (_minimum, range(1, 1000)),
    "Max": (_maximum, range(1, 1000)),
    "atan2": (np.arctan2, (2,)),
    "DiracDelta": (dirac_delta, (1, 2)),
}
CONSTANTS = {"pi": np.float64(math.pi), "E": np.float64(math.e)}
_BINARY: dict[type, Callable[[Any, Any], Any]] = {
    ast.Add: operator.add,
    ast.Sub: operator.sub,
    ast.Mult: operator.mul,
    ast.Div: operator.truediv,
    ast.Pow: operator.pow,
}
_UNARY: dict[type, Callable[[Any], Any]] = {ast.USub: operator.neg, ast.UAdd: operator.pos}


def _unknown(*args):
    raise AssertionError("never called: no arity admits it")


class UnsupportedText(ValueError):
    """Expression text outside the whitelist (or too large to parse)."""


def compile_text(text: str, args: Sequence[str]) -> Evaluator:
    """``evaluate(values) -> ndarray or float`` of one expression, ``values``: name -> array.

    Raises UnsupportedText for anything but numbers, ``args``, pi, E, ``+ - * / **`` and
    :data:`FUNCTIONS` called with positional arguments.
    """
    if not isinstance(text, str) or len(text) > MAX_TEXT:
        raise UnsupportedText("not an expression text of at most MAX_TEXT characters")
    try:
        tree = ast.parse(text, mode="eval")
        return _build(tree.body, frozenset(args))
    except (SyntaxError, ValueError, RecursionError, MemoryError) as exc:
        raise UnsupportedText(f"{text[:60]!r}: {exc}") from None


def _build(node: ast.AST, names: frozenset) -> Evaluator:
    """The evaluator of one whitelisted node (recursively of its operands)."""
    if isinstance(node, ast.Constant):
        if isinstance(node.value, bool) or not isinstance(node.value, int | float):
            raise UnsupportedText(f"constant {node.value!r}")
        value = np.float64(node.value)  # numpy arithmetic: overflow is inf, not an exception
        return lambda values: value
    if isinstance(node, ast.Name):
        name = node.id
        if name in names:
            return lambda values: values[name]
        if name in CONSTANTS:
            constant = CONSTANTS[name]
            return lambda values: constant
        raise UnsupportedText(f"name {name!r}")
    if isinstance(node, ast.UnaryOp) and type(node.op) in _UNARY:
        unary, operand = _UNARY[type(node.op)], _build(node.operand, names)
        return lambda values: unary(operand(values))
    if isinstance(node, ast.BinOp) and type(node.op) in _BINARY:
        binary = _BINARY[type(node.op)]
        left, right = _build(node.left, names), _build(node.right, names)
        return lambda values: binary(left(values), right(values))
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and not node.keywords:
        function, arities = FUNCTIONS.get(node.func.id, (_unknown, ()))
        if len(node.args) in arities:
            operands = [_build(arg, names) for arg in node.args]
            if len(operands) == 1:  # most calls (sin, exp, Abs): no generator per evaluation
                operand = operands[0]
                return lambda values: function(operand(values))
            return lambda values: function(*(operand(values) for operand in operands))
    raise UnsupportedText(f"{type(node).__name__} node")


class CompiledField:
    """A field of k expression texts in ``args``, vectorized over points.

    ``field(*values)`` -> ndarray of shape ``(*components, *shape)``, where ``shape`` is the
    broadcast shape of the argument arrays and ``components`` is ``(k,)`` by default, ``()``
    for a scalar field (k = 1) or e.g. ``(2, 2)`` for a gradient (k = 4, row-major).  A
    fresh, writable float array; constant expressions are broadcast to full shape.
    ``texts`` is None for a field compiled another way (``function``): it cannot be cached.
    ``separated`` is the field's time-separable form when it has one
    (:mod:`parefg.scene.separable`), else None.
    """

    def __init__(
        self,
        texts: Sequence[str] | None,
        args: Sequence[str],
        components: Sequence[int] | None = None,
        function: Callable | None = None,
        separated: "SeparatedField | None" = None,
    ):
        self.separated = separated
        self.texts = None if texts is None else list(texts)
        self.args = tuple(args)
        self.components = (len(texts or ()),) if components is None else tuple(components)
        if function is None:
            evaluators = [compile_text(text, self.args) for text in self.texts or ()]
            count = len(evaluators)

            def function(*values):
                named = dict(zip(self.args, values, strict=True))
                return [evaluate(named) for evaluate in evaluators]

        else:
            count = math.prod(self.components)
        self._rows = function
        self._count = count

    def __call__(self, *values) -> np.ndarray:
        shape = np.broadcast(*values).shape
        out = np.empty((self._count, *shape))  # (k, *shape)
        for row, component in enumerate(self._rows(*values)):
            out[row] = component
        return out.reshape(*self.components, *shape)

    def to_json(self) -> dict:
        """The texts, arguments, components and split (``texts`` must not be None)."""
        data: dict[str, Any] = {
            "texts": self.texts,
            "args": list(self.args),
            "components": list(self.components),
        }
        if self.separated is not None:
            data["separated"] = self.separated.to_json()
        return data

    @classmethod
    def from_json(cls, data: dict) -> "CompiledField":
        """The field of :meth:`to_json`; raises UnsupportedText (or KeyError, TypeError)."""
        separated = data.get("separated")
        return cls(
            data["texts"],
            data["args"],
            data["components"],
            separated=None if separated is None else SeparatedField.from_json(separated),
        )


@dataclass
class SeparatedField:
    """A field g(space, t) = sum_k a_k(t) f_k(space) (see :mod:`parefg.scene.separable`).

    ``time(t) -> (K,)`` the a_k; ``space(*space_args) -> (K, *components, n)`` the f_k, the
    space arguments being the field's arguments without "t", in their order.
    """

    time: CompiledField
    space: CompiledField

    def to_json(self) -> dict:
        """Both parts' :meth:`CompiledField.to_json` (their texts must not be None)."""
        return {"time": self.time.to_json(), "space": self.space.to_json()}

    @classmethod
    def from_json(cls, data: dict) -> "SeparatedField":
        return cls(CompiledField.from_json(data["time"]), CompiledField.from_json(data["space"]))


@dataclass
class BoundaryCondition:
    """The data of one boundary part; fields not used by ``kind`` are None.

    ``value(x, y, t) -> (2, n)`` (dirichlet ubar), ``traction(x, y, t, nx, ny)
    -> (2, n)`` (neumann p), ``gap(x, y) -> (n,)`` and ``friction(x, y, t, nx,
    ny) -> (n,)`` (contact s and Tresca bound g); ``friction_is_zero`` is True
    when g is identically zero, so the solver can skip tangential terms;
    ``friction_law`` names the contact part's law in parefg.mechanics.friction.FRICTION_LAWS.
    A Coulomb part (friction_law in PRESSURE_LAWS) has the coefficient mu_f
    ``friction_coefficient``, a zero ``friction`` field (its bound mu_f p is set by the
    step), and ``friction_is_zero`` iff mu_f = 0.  A Dirichlet part names its ``method``
    (parefg.discretization.dirichlet.DIRICHLET_METHODS) and Nitsche's ``safety``.
    """

    name: str
    kind: BoundaryKind
    value: CompiledField | None = None
    traction: CompiledField | None = None
    gap: CompiledField | None = None
    friction: CompiledField | None = None
    friction_is_zero: bool = True
    friction_law: str = DEFAULT_FRICTION_LAW
    friction_coefficient: float = 0.0
    # a Dirichlet part's method (DIRICHLET_METHODS) or a contact part's (CONTACT_METHODS)
    method: str = DEFAULT_DIRICHLET_METHOD
    safety: float = 0.0  # Nitsche's beta over the coercivity bound


@dataclass
class ExactSolution:
    """A manufactured solution: ``u(x, y, t) -> (d, n)``, ``v`` = du/dt ``-> (d, n)``,
    ``grad(x, y, t) -> (d, d, n)`` with ``[i, j] = d u_i / d x_j`` (d = 2: plane strain);
    ``given``: the scene's ``[exact] u`` values, as written."""

    given: list
    u: CompiledField
    v: CompiledField
    grad: CompiledField
