"""Time-separable scene data: g(x, t) = sum_k a_k(t) f_k(x), exactly.

Loads, boundary data and friction bounds are evaluated at fixed points at every time
step.  When a datum is a finite sum of products of a function of t and a function of
the space arguments (x, y, and for boundary data the normal nx, ny), the space parts
need to be evaluated (and integrated against the shape functions) once per run and a
step only evaluates the few a_k(t).

:func:`separate` finds such a split on the sympy tree by the rules of algebra alone, so
the split is the same expression rewritten, never an approximation:

- a subtree without t is a space factor, a subtree of t alone a time factor (kept whole:
  ``1 - cos(t)`` stays one factor, not 1 and -cos(t));
- a sum is the concatenation of the splits of its terms, a product the distribution of
  the splits of its factors, an integer power a repeated product (a negative one only
  of a single term);
- |a(t) f(x)| = |a(t)| |f(x)| for a single term (the symbols are real);
- anything else that mixes t with a space argument (sin(x t), exp(x + t), a quotient by
  a sum in x and t) leaves the datum non-separable: :func:`separate` returns None and
  the datum keeps its per-point evaluation;
- a datum without t is the one term 1 * f(x).

Terms with the same time factor, up to a constant (``cos(t) - 1`` and ``1 - cos(t)``),
are merged, so K is the number of distinct time factors.  Not collective.
"""

import copy
import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

import sympy

from parefg.scene.expressions import SYMBOLS, compile_field
from parefg.scene.numeric import CompiledField, SeparatedField
from parefg.scene.sections import LoadsSection

MAX_TERMS = 64  # terms of one split (a distributed product beyond it is not separated)
MAX_POWER = 4  # largest integer exponent of a sum that is distributed

Term = tuple[sympy.Expr, sympy.Expr]  # (a(t), f(space)) with the product a * f


@dataclass
class Separation:
    """k expressions as sum_k time[k] * space[k][i] (i: the component)."""

    time: list[sympy.Expr]  # (K,) functions of t alone (1 for the time-independent part)
    space: list[list[sympy.Expr]]  # (K, c) functions of the space arguments alone

    def expressions(self) -> list[sympy.Expr]:
        """The c expressions the split stands for (for checks)."""
        columns = zip(*self.space, strict=True)
        return [sympy.Add(*(a * f for a, f in zip(self.time, col, strict=True))) for col in columns]


def separate(exprs: Sequence[sympy.Expr], t: sympy.Symbol = SYMBOLS["t"]) -> Separation | None:
    """The split of ``exprs`` (c expressions) into sum_k a_k(t) f_k, or None.

    None when some expression is not separable by the rules of the module docstring.  Data
    that do not depend on t are one term, 1 * f (K = 1): a run integrates them once instead
    of at every step (constant loads, clamped or fixed Dirichlet data, a constant friction
    bound are the common case).  Not collective.
    """
    exprs = [sympy.sympify(expr) for expr in exprs]
    if not any(t in expr.free_symbols for expr in exprs):
        return Separation([sympy.S.One], [list(exprs)])
    time: dict[sympy.Expr, int] = {}  # canonical time factor -> k
    space: list[list[sympy.Expr]] = []
    for component, expr in enumerate(exprs):
        terms = _terms(expr, t)
        if terms is None:
            return None
        grouped = _grouped(terms)
        if grouped is None:
            return None
        for factor, part in grouped:
            if factor not in time:
                time[factor] = len(space)
                space.append([sympy.S.Zero] * len(exprs))
            row = space[time[factor]]
            row[component] = row[component] + part
    keep = [k for k, row in enumerate(space) if any(f != 0 for f in row)]
    if not keep:  # every time factor cancelled (t (x + 1) - t x - t): nothing to split
        return None
    factors = list(time)
    return Separation([factors[k] for k in keep], [space[k] for k in keep])


def _terms(expr: sympy.Expr, t: sympy.Symbol) -> list[Term] | None:
    """expr as a list of (a(t), f(space)) whose products sum to expr, or None."""
    symbols = expr.free_symbols
    if t not in symbols:
        return [(sympy.S.One, expr)]
    if symbols == {t}:
        return [(expr, sympy.S.One)]
    if expr.is_Add:
        return _concatenated([_terms(arg, t) for arg in expr.args])
    if expr.is_Mul:
        return _product([_terms(arg, t) for arg in expr.args])
    if expr.is_Pow and expr.exp.is_Integer:
        base = _terms(expr.base, t)
        n = int(expr.exp)
        if base is None:
            return None
        if len(base) == 1:
            ((a, f),) = base
            return [(a**n, f**n)]
        if 0 < n <= MAX_POWER:
            return _product([base] * n)
        return None
    if isinstance(expr, sympy.Abs):
        inner = _terms(expr.args[0], t)
        grouped = None if inner is None else _grouped(inner)
        if grouped is not None and len(grouped) == 1:
            ((a, f),) = grouped
            return [(sympy.Abs(a), sympy.Abs(f))]
    return None


def _concatenated(splits: list[list[Term] | None]) -> list[Term] | None:
    if any(split is None for split in splits):
        return None
    terms = [term for split in splits for term in split]  # type: ignore[union-attr]
    return terms if len(terms) <= MAX_TERMS else None


def _product(splits: list[list[Term] | None]) -> list[Term] | None:
    """The distributed product of the splits of the factors."""
    terms: list[Term] = [(sympy.S.One, sympy.S.One)]
    for split in splits:
        if split is None or len(terms) * len(split) > MAX_TERMS:
            return None
        if any(_cancels(a, b) or _cancels(f, g) for a, f in terms for b, g in split):
            return None
        terms = [(a * b, f * g) for a, f in terms for b, g in split]
    return terms


def _cancels(p: sympy.Expr, q: sympy.Expr) -> bool:
    """Whether sympy's product p q cancelled part of a denominator.

    x (1/x) = 1 and (t - 1/2) / (t - 1/2) = 1 lose the NaN the datum as written has at
    x = 0 or t = 1/2 (exp(t) exp(-t) = 1 the overflow); such a datum is not split.
    """
    return sympy.fraction(p * q)[1] != sympy.fraction(p)[1] * sympy.fraction(q)[1]


def _grouped(terms: list[Term]) -> list[Term] | None:
    """Terms merged by time factor up to a constant: sum of (a_k, f_k), a_k distinct.

    None when a time factor with a denominator cancels out (x/(t - 1/2) - x/(t - 1/2)):
    the datum as written is NaN where that denominator vanishes.
    """
    groups: dict[sympy.Expr, sympy.Expr] = {}
    for a, f in terms:
        coefficient, factor = a.as_coeff_Mul()
        if factor.could_extract_minus_sign():
            coefficient, factor = -coefficient, -factor
        groups[factor] = groups.get(factor, sympy.S.Zero) + coefficient * f
    if any(f == 0 and sympy.fraction(a)[1] != 1 for a, f in groups.items()):
        return None
    return [(a, f) for a, f in groups.items() if f != 0]


def separated_field(
    exprs: Sequence[sympy.Expr], args: Sequence[str], components: Sequence[int] | None = None
) -> SeparatedField | None:
    """The compiled split of a field of ``exprs`` in ``args`` (one of them "t"), or None.

    ``time(t) -> (K,)``; ``space(*space_args) -> (K, *components, n)``, the space
    arguments being ``args`` without "t".  ``components`` as in compile_field.
    """
    split = separate(exprs)
    if split is None:
        return None
    space_args = [name for name in args if name != "t"]
    shape = (len(exprs),) if components is None else tuple(components)
    time = compile_field(split.time, ("t",))
    space = compile_field(
        [f for row in split.space for f in row], space_args, (len(split.time), *shape)
    )
    return SeparatedField(time, space)


def with_separation(field: CompiledField, exprs: Sequence[sympy.Expr]) -> CompiledField:
    """``field`` (compiled from ``exprs``) with its split attached when it has one.

    A split whose parts are beyond the whitelist evaluator (compiled by lambdify) is
    attached only to a field that is itself not cacheable.
    """
    split = separated_field(exprs, field.args, field.components)
    cacheable = split is None or None not in (split.time.texts, split.space.texts)
    if cacheable or field.texts is None:
        field.separated = split
    return field


def without_splits(scene):
    """A copy of ``scene`` whose data have no split: they take the per-point path.

    For comparisons of the two paths (tests, benchmarks); the fields are shallow copies.
    """

    def plain(field: CompiledField | None) -> CompiledField | None:
        if field is None or field.separated is None:
            return field
        field = copy.copy(field)
        field.separated = None
        return field

    boundaries = {
        name: dataclasses.replace(
            bc, value=plain(bc.value), traction=plain(bc.traction), friction=plain(bc.friction)
        )
        for name, bc in scene.boundaries.items()
    }
    loads = LoadsSection(f=plain(scene.loads.f))
    return dataclasses.replace(scene, loads=loads, boundaries=boundaries)
