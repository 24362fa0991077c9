"""Checks of scene data that need the domain: gap s >= 0 and friction bound g >= 0 (SPEC 1, 9).

Numbers are checked by the schema; expressions here, at load, at fixed points along each
contact part, so that a negative gap or friction bound is refused with the key before
any meshing, with the same verdict on every rank.
"""

import numpy as np
import sympy

from parefg.errors import InputError
from parefg.geometry.shapes import part_segments
from parefg.scene.expressions import SYMBOLS
from parefg.scene.symbolic import first_negative
from parefg.scene.table import show

SIGN_SAMPLES = 16  # points per contact part at which gap and friction are checked at load
SIGN_TIMES = 5  # times in [0, T] at which the friction bound is checked
# Relative tolerance of those checks: sample points off a slanted edge by round-off may
# see a gap that vanishes on the edge as -1e-17.
SIGN_TOLERANCE = 1e-12


class SignChecks:
    """gap >= 0 and friction >= 0 checked at load where the boundary is known.  Not collective.

    Expressions are sampled at SIGN_SAMPLES points along each contact part (and the friction
    bound at SIGN_TIMES times in [0, T]) and decided in multiple precision, so the verdict
    is the same on every rank and CPU.  Left to the run-time checks at the quadrature
    points: parts of a .geo domain, values between the samples, and points where a value
    is not a finite real number.
    """

    MEANING = {"gap": "the initial gap s to the obstacle", "friction": "the friction bound g"}

    def __init__(self, where: str, params: dict, E: float):
        self.where = where
        self.segments = part_segments(params["domain"])
        self.times = np.linspace(0.0, params["time"]["T"], SIGN_TIMES)
        if self.segments is not None:
            corners = np.concatenate(list(self.segments.values())).reshape(-1, 2)
            diameter = float(np.linalg.norm(np.ptp(corners, axis=0)))
        else:
            diameter = 0.0
        # a gap is a length, a friction bound a stress
        self.tolerance = {"gap": SIGN_TOLERANCE * diameter, "friction": SIGN_TOLERANCE * E}

    def nonnegative(self, part: str, key: str, given, expr: sympy.Expr) -> None:
        """Raise InputError if ``expr`` (the value of boundary.PART.KEY) is negative somewhere."""
        if self.segments is None or isinstance(given, int | float):  # numbers: in the schema
            return
        xy = part_samples(self.segments[part], SIGN_SAMPLES)  # (n, 2)
        names = ("x", "y") if key == "gap" else ("x", "y", "t")
        if key == "friction":  # (n * n_times, 3): every point at every time
            xy = np.column_stack(
                [np.repeat(xy, len(self.times), axis=0), np.tile(self.times, len(xy))]
            )
        symbols = [SYMBOLS[s] for s in names]
        # a constant has no sample point off the edge: its sign is exact
        tolerance = self.tolerance[key] if expr.free_symbols else 0.0
        found = first_negative(expr, symbols, xy, tolerance)
        if found is not None:
            point, value = found
            at = ", ".join(f"{s} = {v:.6g}" for s, v in zip(names, point, strict=True))
            raise InputError(
                f"{self.where}: boundary.{part}.{key} = {show(given)}: must be >= 0 "
                f"({self.MEANING[key]}), is {value:.6g} at {at}"
            )


def part_samples(segments: np.ndarray, count: int) -> np.ndarray:
    """(count, 2) points evenly spread by arc length over (n, 2, 2) segments [start, end]."""
    lengths = np.linalg.norm(segments[:, 1] - segments[:, 0], axis=1)  # (n,)
    cumulative = np.concatenate([[0.0], np.cumsum(lengths)])  # (n + 1,)
    arc = (np.arange(count) + 0.5) / count * cumulative[-1]  # (count,)
    which = np.clip(np.searchsorted(cumulative, arc, side="right") - 1, 0, len(segments) - 1)
    with np.errstate(invalid="ignore", divide="ignore"):  # zero-length parts
        fraction = np.nan_to_num((arc - cumulative[which]) / lengths[which])
    start, end = segments[which, 0], segments[which, 1]
    return start + fraction[:, None] * (end - start)
