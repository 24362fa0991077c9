"""gmsh's arithmetic on .geo values: its math functions and operators, unknown-aware.

A value is a float or None (unknown before gmsh runs); every operation on an unknown
value is unknown, and a result that is not finite (C's NaN or inf) becomes unknown too.
Used by the abstract run of :mod:`parefg.geometry.geo.bounds` and, for the names and
argument counts of FUNCTIONS, by the parser (:mod:`parefg.geometry.geo.expressions`).
"""

from __future__ import annotations

import math
from collections.abc import Callable


def hypot(a: float, b: float) -> float:
    return math.sqrt(a * a + b * b)  # gmsh's Hypot, not math.hypot (which rounds differently)


#: name -> (number of arguments, the C function gmsh calls); Rand has no known value
FUNCTIONS: dict[str, tuple[int, Callable[..., float] | None]] = {
    "Exp": (1, math.exp), "Log": (1, math.log), "Log10": (1, math.log10),
    "Sqrt": (1, math.sqrt), "Sin": (1, math.sin), "Asin": (1, math.asin),
    "ArcSin": (1, math.asin), "Cos": (1, math.cos), "Acos": (1, math.acos),
    "ArcCos": (1, math.acos), "Tan": (1, math.tan), "Atan": (1, math.atan),
    "ArcTan": (1, math.atan), "Atan2": (2, math.atan2), "ArcTan2": (2, math.atan2),
    "Sinh": (1, math.sinh), "Cosh": (1, math.cosh), "Tanh": (1, math.tanh),
    "Fabs": (1, abs), "Abs": (1, abs), "Floor": (1, math.floor), "Ceil": (1, math.ceil),
    "Round": (1, lambda x: math.floor(x + 0.5)), "Fmod": (2, math.fmod),
    "Modulo": (2, math.fmod), "Hypot": (2, hypot), "Max": (2, max), "Min": (2, min),
    "Rand": (1, None),
}  # fmt: skip


def unary(op: str, operand: float | None) -> float | None:
    if operand is None:
        return None
    if op == "-":
        return -operand
    if op == "+":
        return operand
    return 0.0 if operand else 1.0


def binary(op: str, a: float | None, b: float | None) -> float | None:
    if a is None or b is None:
        return None
    try:
        if op == "+":
            return a + b
        if op == "-":
            return a - b
        if op == "*":
            return a * b
        if op == "/":
            return a / b if b else None  # gmsh: "Division by zero", value undefined
        if op == "^":
            return math.pow(a, b)
    except (ValueError, OverflowError):
        return None
    comparisons = {
        "<": a < b, ">": a > b, "<=": a <= b, ">=": a >= b, "==": a == b, "!=": a != b,
        "&&": bool(a) and bool(b), "||": bool(a) or bool(b),
    }  # fmt: skip
    return float(comparisons[op])


def finite(value: float | None) -> float | None:
    return value if value is not None and math.isfinite(value) else None


def combine(op: str, old: float | None, new: float | None) -> float | None:
    """``x op= new`` on a scalar (Gmsh.y Affectation); ``/= 0`` leaves x unknown."""
    if op == "=":
        return new
    if op == "/=" and new == 0:
        return None
    return finite(binary({"+=": "+", "-=": "-", "*=": "*", "/=": "/"}[op], old, new))
