"""Bounded symbolic work on scene expressions, and decisions that round-off cannot flip.

A scene of a few hundred characters can ask sympy for work without end: the second
derivatives of a product of 71 sines have millions of terms, and ``simplify`` of a
friction bound can run for hours.  Everything here is bounded by counts of expression
nodes, never by wall-clock time, so every MPI rank reaches the same verdict:

- :class:`DerivativeBudget` estimates the size of a derivative before sympy computes it
  and refuses (one-line :class:`InputError` naming the key) once the derived data would
  exceed :data:`MAX_DERIVED_NODES` nodes in all;
- :func:`is_identically_zero` and :func:`first_negative` decide "g = 0 everywhere" and
  "g < 0 somewhere" by evaluating the expression in multiple-precision arithmetic
  (mpmath: pure integer arithmetic, the same bits on every CPU) at two precisions.  A
  value that agrees at 30 and 60 digits is a true value, however small (1e-20 x is
  not zero); a value that shrinks with the precision is round-off of a true zero
  (sin(x)**2 + cos(x)**2 - 1).  Intermediate values are confined to the range of a
  double, so the evaluation itself stays cheap.
"""

from collections.abc import Mapping, Sequence

import mpmath
import numpy as np
import sympy

from parefg.errors import InputError

#: Nodes of all derived expression trees of one scene (body force, tractions, friction,
#: gradients, ...).  The built-in scenes derive < 2000; 40000 nodes differentiate and
#: compile in about 2 s.
MAX_DERIVED_NODES = 10_000
LOW_DPS, HIGH_DPS = 30, 60  # decimal digits of the two evaluations
AGREEMENT = 1e-6  # relative difference below which the two evaluations agree
ZERO_SAMPLES = 6  # points of the identically-zero test
ZERO_SEED = 12345
_DOUBLE_MAX = mpmath.mpf(np.finfo(float).max)


class DerivativeBudget:
    """Symbolic differentiation with a cap on the nodes it may produce.  Not collective.

    Parameters
    ----------
    where, key
        Prefix and key of the error message (``"scene s"``, ``"exact.u"``).
    limit
        Total nodes of all derivatives taken through this budget.
    """

    def __init__(self, where: str, key: str, limit: int = MAX_DERIVED_NODES):
        self.where, self.key, self.limit = where, key, limit
        self.used = 0

    def diff(self, expr: sympy.Expr, symbol: sympy.Symbol, order: int = 1) -> sympy.Expr:
        """d^order expr / d symbol^order, refused before sympy starts one beyond the budget."""
        for _ in range(order):
            self._charge(derivative_size(expr, symbol))
            expr = sympy.diff(expr, symbol)
            self.used += tree_size(expr)
        return expr

    def charge(self, *exprs: sympy.Expr) -> None:
        """Count expressions built from derivatives (sums, products) against the budget."""
        self._charge(sum(tree_size(expr) for expr in exprs))
        self.used += sum(tree_size(expr) for expr in exprs)

    def _charge(self, nodes: int) -> None:
        if self.used + nodes > self.limit:
            raise InputError(
                f"{self.where}: {self.key}: too large to differentiate symbolically (the derived "
                f"data would have more than {self.limit} expression nodes); give a smaller "
                "exact solution, or the loads and boundary data explicitly"
            )


def tree_size(expr: sympy.Basic) -> int:
    """Nodes of the expression tree: what printing, lambdify and differentiation walk.

    Computed on the DAG (equal subtrees once), so it is cheap even when the tree is huge.
    """
    sizes: dict[sympy.Basic, int] = {}

    def size(node: sympy.Basic) -> int:
        if node not in sizes:
            sizes[node] = 1 + sum(size(arg) for arg in node.args)
        return sizes[node]

    return size(expr)


def derivative_size(expr: sympy.Expr, symbol: sympy.Symbol) -> int:
    """An upper estimate of the nodes of d expr / d symbol before sympy's simplifications.

    Product rule: d(f_1 ... f_n) has one term per factor that depends on the symbol, each a
    copy of the other factors; a function or power copies its arguments into its
    derivative (d asin(a) = a' / sqrt(1 - a**2), d Max(a, b) = a' Heaviside(a - b) + ...).
    """
    sizes: dict[sympy.Basic, int] = {}
    depends: dict[sympy.Basic, bool] = {}
    estimates: dict[sympy.Basic, int] = {}

    def size(node):
        if node not in sizes:
            sizes[node] = 1 + sum(size(arg) for arg in node.args)
        return sizes[node]

    def dependent(node):
        if node not in depends:
            depends[node] = node == symbol or any(dependent(arg) for arg in node.args)
        return depends[node]

    def estimate(node):
        if node not in estimates:
            varying = [arg for arg in node.args if dependent(arg)]
            if node.is_Add:
                estimates[node] = 1 + sum(estimate(arg) for arg in varying)
            elif node.is_Mul:  # one copy of the other factors per varying factor
                estimates[node] = 1 + sum(estimate(a) + size(node) - size(a) for a in varying)
            else:  # powers and functions copy their arguments into the derivative
                estimates[node] = 1 + sum(estimate(a) + 2 * size(node) + 8 for a in varying)
        return estimates[node]

    return estimate(expr)


class _Undecided(Exception):
    """The value at a point is not a finite real number within the range of a double."""


_FUNCTIONS = {
    sympy.sin: mpmath.sin,
    sympy.cos: mpmath.cos,
    sympy.tan: mpmath.tan,
    sympy.asin: mpmath.asin,
    sympy.acos: mpmath.acos,
    sympy.atan: mpmath.atan,
    sympy.sinh: mpmath.sinh,
    sympy.cosh: mpmath.cosh,
    sympy.tanh: mpmath.tanh,
    sympy.exp: mpmath.exp,
    sympy.log: mpmath.log,
    sympy.Abs: abs,
    sympy.sign: mpmath.sign,
    sympy.atan2: mpmath.atan2,
    sympy.Min: min,
    sympy.Max: max,
    sympy.Heaviside: lambda a, h0: h0 if a == 0 else mpmath.mpf(a > 0),  # sympy stores h0
    # zero almost everywhere, as in compile_field: what quadrature sees
    sympy.DiracDelta: lambda *args: mpmath.mpf(0),
}


def _evaluate(expr: sympy.Expr, point: Mapping[sympy.Symbol, float], dps: int) -> mpmath.mpf:
    """expr at ``point`` with ``dps`` decimal digits; raises _Undecided.

    Every node's value must be real, finite and within the range of a double (where
    numpy would overflow, the data are not usable anyway), which keeps mpmath's work
    per node small.
    """
    values: dict[sympy.Basic, mpmath.mpf] = {}

    def value(node):
        if node not in values:
            values[node] = _checked(_node_value(node, value, point))
        return values[node]

    with mpmath.workdps(dps):
        try:
            return value(expr)
        except (ZeroDivisionError, ValueError, TypeError, OverflowError):
            raise _Undecided from None


def _node_value(node, value, point):
    """One node from the values of its arguments."""
    if node.is_Symbol:
        if node not in point:
            raise _Undecided
        return mpmath.mpf(point[node])
    if node.is_Integer:
        return mpmath.mpf(int(node))
    if node.is_Rational:
        return mpmath.mpf(int(node.p)) / int(node.q)
    if node.is_Float or node.is_NumberSymbol:
        return mpmath.mpf(node.evalf(mpmath.mp.dps)._mpf_)
    if node.is_Add:
        return mpmath.fsum(value(arg) for arg in node.args)
    if node.is_Mul:
        return mpmath.fprod(value(arg) for arg in node.args)
    if node.is_Pow:
        base, exponent = node.args
        if exponent.is_Integer:
            return value(base) ** int(exponent)
        return mpmath.power(value(base), value(exponent))
    function = _FUNCTIONS.get(node.func)
    if function is None:
        raise _Undecided
    return function(*(value(arg) for arg in node.args))


def _checked(number) -> mpmath.mpf:
    if not isinstance(number, mpmath.mpf) or not mpmath.isfinite(number):
        raise _Undecided
    if abs(number) > _DOUBLE_MAX:
        raise _Undecided
    return number


def _true_value(expr, point, low=None) -> mpmath.mpf:
    """expr at ``point`` if the 30- and 60-digit values agree, 0 if the value is round-off.

    Raises _Undecided.  ``low``: the 30-digit value, when already known.
    """
    low = _evaluate(expr, point, LOW_DPS) if low is None else low
    high = _evaluate(expr, point, HIGH_DPS)
    if high == 0 or abs(low - high) > AGREEMENT * abs(high):
        return mpmath.mpf(0)
    return high


# Functions whose value is piecewise constant or chosen among their arguments: a test
# at a few points cannot see where they switch, so each becomes a free variable.
_PIECEWISE = (sympy.Heaviside, sympy.sign, sympy.Min, sympy.Max, sympy.atan2)


def is_identically_zero(expr: sympy.Expr, symbols: Sequence[sympy.Symbol]) -> bool:
    """Whether ``expr`` vanishes for all values of ``symbols`` (the same answer on every rank).

    Not collective.  True only when proven to high probability: every Heaviside, sign,
    min and max is replaced by a free variable w_i and abs(a) by w_i a, which leaves an
    analytic function of the symbols and the w_i; such a function is zero everywhere iff
    it is zero at random points, decided there in multiple precision (a true zero
    shrinks with the precision; any true value, however small, does not).  An expression
    not finite and real at a sample point (sqrt(x - 2) at x < 2), or zero only where a
    Heaviside switches off (heaviside(x - 0.999)), is "not zero": the safe answer, which
    only costs the solver the work of a zero term.  DiracDelta counts as zero, as in
    :func:`~parefg.scene.expressions.compile_field`.
    """
    if expr == 0:
        return True
    analytic, free = _free_piecewise(expr)
    names = sorted(symbols, key=str) + free
    rng = np.random.default_rng(ZERO_SEED)
    for _ in range(ZERO_SAMPLES):
        point = dict(zip(names, rng.uniform(0.05, 0.95, size=len(names)), strict=True))
        try:
            if _true_value(analytic, point) != 0:
                return False
        except _Undecided:
            return False
    return True


def _free_piecewise(expr: sympy.Expr) -> tuple[sympy.Expr, list[sympy.Symbol]]:
    """expr with each piecewise node replaced by a new symbol w_i (abs(a) by w_i a)."""
    nodes = sorted(expr.atoms(*_PIECEWISE, sympy.Abs), key=sympy.default_sort_key)
    free = [sympy.Symbol(f"_w{i}", real=True) for i in range(len(nodes))]
    replacement = {
        node: w * node.args[0] if isinstance(node, sympy.Abs) else w
        for node, w in zip(nodes, free, strict=True)
    }
    # xreplace works top-down: a node inside a replaced one disappears with it
    return expr.xreplace(replacement), free


def first_negative(
    expr: sympy.Expr, symbols: Sequence[sympy.Symbol], points: np.ndarray, tolerance: float
) -> tuple[np.ndarray, float] | None:
    """The first of ``points`` where expr < -tolerance in exact arithmetic, and its value.

    Not collective; deterministic (the same answer on every rank and CPU).

    Parameters
    ----------
    symbols
        The k symbols, in the order of the columns of ``points``.
    points
        (n, k) float sample points.
    tolerance
        >= 0, in the units of expr (a length for a gap, a stress for a friction bound).

    Returns
    -------
    (point, value) or None
        None if expr >= -tolerance at every point where it is a finite real number;
        points where it is not are left to the run-time checks.
    """
    if not expr.free_symbols:
        points = points[:1]
    for row in points:
        point = dict(zip(symbols, row, strict=True))
        try:
            low = _evaluate(expr, point, LOW_DPS)
            if low < -tolerance:
                value = _true_value(expr, point, low)
                if value < -tolerance:
                    return row, float(value)
        except _Undecided:
            continue
    return None
