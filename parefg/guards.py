"""Run-time guards: scene data evaluated at the points, and rigid motions of static scenes.

Scene values are expressions checked at load time, but only their values at the
quadrature points and times of a run show whether they are finite there
(``sqrt(x - 2)`` on the unit square, ``exp(1000 t)`` for t > 0.71).  A
:class:`DataGuard` evaluates every datum without numpy warnings and remembers the
first bad value locally; :meth:`DataGuard.check` then decides on all ranks at
once, before the values reach a solve.

A static scene (no mass term) has a singular Jacobian when its constraints do not
hold the rigid motions r of the body (translations, rotation): r^T J r = 0.
:class:`RigidModes` measures that on the 3-dimensional space of rigid motions,
exactly as the Jacobian of the current active set sees it.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import scipy.linalg
from petsc4py import PETSc

from parefg.boundary import BoundaryKind
from parefg.errors import DataError, InputError, SolverError

# Data beyond this size are refused with the non-finite ones: their squares (energies,
# norms) overflow a double (about 1.3e154 squared), so they can only end in inf or NaN.
DATA_BOUND = 1e150
# A friction bound below -FRICTION_FLOOR * E is refused; above it, a negative value is the
# round-off of a zero bound (sin(x)**2 + cos(x)**2 - 1) and is read as 0.
FRICTION_FLOOR = 1e-12
# Rigid motions whose stiffness r^T J r / r^T r is below this fraction of ||A_const||_inf
# are free.  A free motion is zero to round-off, about sqrt(n_dofs) eps (<= 1e-12 up to
# 1e6 DOFs; measured <= 3e-17 on the unit square, h = 1/4 .. 1/32, m = 1 .. 3); a closed
# contact edge holds its motions at 6.7 .. 40 (default alpha_C = 1e4 E/h), and a weaker
# real constraint only scales that by alpha_C h / E and 1/sqrt(n_nodes).
RIGID_TOLERANCE = 1e-9
_NO_FAULT = (math.inf, 0, 0.0, 0.0, 0.0)


class DataGuard:
    """Evaluate scene data at this rank's points; fail on all ranks at the first bad value.

    Parameters
    ----------
    comm
        The run's communicator (only :meth:`check` is collective).
    scene
        The scene, whose ``params`` give the text of each datum in messages.
    """

    def __init__(self, comm, scene):
        self.comm, self.scene = comm, scene
        # (key, t, vector datum, nonnegative) of each evaluation since the last check
        self._evaluations: list[tuple[tuple[str, ...], float, bool, bool]] = []
        self._fault = _NO_FAULT  # (evaluation, component, x, y, value) of the first bad value
        self.splits = SplitCoefficients()  # the a_k(t) of the split data evaluated through it

    def evaluate(self, key, field, points, t, *args, nonnegative=False) -> np.ndarray:
        """``field(*args)`` at ``points`` (n, 2), its first bad value recorded.  Not collective.

        ``key`` is the scene path of the datum, e.g. ``("loads", "f")``; a value is bad
        when it is not finite or beyond DATA_BOUND in size or, with ``nonnegative``, below
        the round-off floor of zero (see FRICTION_FLOOR).  Returns the values, shape (k, n)
        for a vector datum or (n,), with round-off negatives set to 0.
        """
        with np.errstate(all="ignore"):
            values = np.asarray(field(*args), dtype=float)
            return self.record(key, values, points, t, nonnegative=nonnegative)

    def record(self, key, values, points, t, nonnegative=False) -> np.ndarray:
        """Check ``values`` of a datum computed elsewhere, as :meth:`evaluate` checks its own.

        Not collective.  ``values`` (k, n) or (n,) at ``points`` (n, 2), a fresh array
        (round-off negatives of a ``nonnegative`` datum are set to 0 in place).  Call it
        under ``np.errstate(all="ignore")`` unless the values are finite and at most a few
        DATA_BOUND in size (a split datum whose bound held): then no check can overflow.
        """
        rows = np.atleast_2d(values)  # (k, n), a view of values
        bad = None
        if nonnegative:
            bad = ~(np.abs(rows) <= DATA_BOUND) | (rows < -FRICTION_FLOOR * self.scene.material.E)
            rows[~bad & (rows < 0.0)] = 0.0
        elif not all_finite(rows) or np.abs(rows).max(initial=0.0) > DATA_BOUND:
            bad = ~(np.abs(rows) <= DATA_BOUND)  # also NaN
        self._evaluations.append((key, t, values.ndim == 2, nonnegative))
        if self._fault is _NO_FAULT and bad is not None and bad.any():
            component, point = _first_bad(bad, points)
            x, y = points[point]
            value = float(rows[component, point])
            self._fault = (len(self._evaluations) - 1, component, float(x), float(y), value)
        return values

    def check(self) -> None:
        """Raise DataError on every rank if any rank recorded a bad value.  Collective.

        One allreduce; every rank evaluated the same data in the same order, so the
        smallest (evaluation, component, x, y) names the same datum and point whatever
        the number of ranks.
        """
        fault = self.comm.allreduce(self._fault, op=_min_op())
        evaluations, self._evaluations, self._fault = self._evaluations, [], _NO_FAULT
        if fault[0] == math.inf:
            return
        index, component, x, y, value = fault
        key, t, vector, nonnegative = evaluations[int(index)]
        datum = self._describe(key, component if vector else None)
        at = f"at (x, y) = ({x:.6g}, {y:.6g}), t = {t:.6g}"
        if nonnegative and -DATA_BOUND <= value < 0.0:
            raise DataError(f"{datum} is negative ({value:.3g}) {at}: it must be >= 0")
        if math.isfinite(value):
            raise DataError(
                f"{datum} is too large ({value:.3g}) {at}: scene data beyond "
                f"{DATA_BOUND:.0e} in size overflow the energies"
            )
        raise DataError(
            f"{datum} is not finite ({value}) {at}: scene data must be finite at every "
            "point and time of the run"
        )

    def _describe(self, key, component) -> str:
        """ "scene S: loads.f[0] = 'sqrt(x - 2)'", or "...[0] (derived from exact.u)"."""
        value = self.scene.params
        for part in key:
            value = value.get(part) if isinstance(value, dict) else None
        name = ".".join(key)
        if component is not None:
            name += f"[{component}]"
            value = value[component] if isinstance(value, list) else None
        shown = " (derived from exact.u)" if value is None else f" = {value!r}"
        return f"scene {self.scene.name}: {name}{shown}"


class PointDatum:
    """One scene datum at fixed points, evaluated at any t through a :class:`DataGuard`.

    A datum with a time-separable form g = sum_k a_k(t) f_k (``field.separated``, see
    parefg.scene.separable) has its space parts f_k evaluated here once, ``space``
    (K, *components, n); a time then costs the K numbers a_k(t) and one contraction,
    whose values the guard checks as it checks evaluated ones (:meth:`DataGuard.record`).
    A datum without that form, or whose f_k are not all finite at the points, or which
    itself is not finite at every point at t = 0; and any t at which some a_k(t) is not
    finite, sum_k |a_k(t)| max |f_k| exceeds DATA_BOUND, or a nonnegative datum's split
    has a negative value, is evaluated point by point (:meth:`DataGuard.evaluate`): bad
    values are reported with the messages they always had (the split's rewriting can
    cancel a singular term or round a square below zero; the datum as written decides).

    Parameters
    ----------
    guard, key
        The guard and the scene path of the datum (``("loads", "f")``).
    field
        A CompiledField in x, y, t (and nx, ny).
    points
        (n, 2) this rank's points.
    arguments
        name -> (n,) values at the points of each argument of ``field`` but t, in the
        order of its positional arguments, t coming after x and y (``field(x, y, t)``,
        ``field(x, y, t, nx, ny)``: any callable of those arguments will do).
    nonnegative
        As in :meth:`DataGuard.evaluate` (a friction bound).
    comm
        If given, construction is collective and the path taken at each t is the same on
        every rank (what a caller that integrates the values collectively needs); if
        None, nothing is collective.
    """

    def __init__(self, guard, key, field, points, arguments, nonnegative=False, comm=None):
        self.guard, self.key, self.field = guard, key, field
        self.points, self.arguments, self.nonnegative = points, arguments, nonnegative
        self._again: Callable[[], tuple[np.ndarray, dict]] | None = None  # release_space's
        self.space: np.ndarray | None = None  # (K, *components, n) the f_k at the points
        self._flat_space: np.ndarray | None = None  # (K, components * n) a view of space
        self.scale: np.ndarray | None = None  # (K,) max |f_k| (over all ranks with comm)
        self._split = -1  # index of the datum's a_k(t) in guard.splits (with a usable split)
        split = getattr(field, "separated", None)  # a plain callable has none
        if split is None:
            return
        with np.errstate(all="ignore"):
            space = split.space(*(arguments[name] for name in split.space.args))
            flat = space.reshape(len(space), -1)  # (K, components * n)
            # The split rewrites the datum, and the rewriting can cancel a singular term:
            # t (x + 1/x) - t/x becomes t x, finite at x = 0 where the datum is NaN.  So the
            # datum as written must be finite at every point at t = 0 (separable.py refuses
            # products that cancel a denominator, in t as in x).
            usable = all_finite(flat) and all_finite(self._direct(arguments, 0.0))
            scale = np.abs(flat).max(axis=1, initial=0.0)
        if comm is not None:
            from mpi4py import MPI

            usable = comm.allreduce(usable, op=MPI.LAND)
            comm.Allreduce(MPI.IN_PLACE, scale, op=MPI.MAX)
        if usable:
            self.space, self.scale, self._flat_space = space, scale, flat
            self._split = guard.splits.add(split.time, scale)

    def _direct(self, arguments: dict[str, np.ndarray], t: float) -> np.ndarray:
        """The datum evaluated as written at the points of ``arguments``, unchecked.

        Not collective."""
        return np.asarray(self.field(*_at_time(arguments, t)), dtype=float)

    def release_space(self, again: Callable[[], tuple[np.ndarray, dict]] | None = None) -> None:
        """Drop the f_k at the points once the caller has integrated them (a body force:
        its steps need only the a_k(t)); :meth:`values` then evaluates the datum point by
        point.  Not collective.

        With ``again`` (returning the points and arguments anew) and a usable split, the
        points and arguments are dropped too: only a step that evaluates the datum as
        written needs them, and gets them from ``again``.
        """
        self.space = self._flat_space = None
        if again is not None and self.scale is not None:
            self.points = self.arguments = None
            self._again = again

    def coefficients(self, t: float) -> np.ndarray | None:
        """(K,) the a_k(t) when the split gives the values at t, else None (read-only).

        None where some a_k(t) is not finite or sum_k |a_k(t)| max |f_k| exceeds
        DATA_BOUND.  Evaluated with the guard's other split data (:class:`SplitCoefficients`):
        a step asks for it several times (loads, Dirichlet data and their energy shares).
        Not collective."""
        if self.scale is None:  # no usable split (set with space, kept when space is released)
            return None
        return self.guard.splits.at(t)[self._split]

    def values(self, t: float) -> np.ndarray:
        """The datum at the points at t, (*components, n), checked by the guard.  Not collective."""
        a, space, flat = self.coefficients(t), self.space, self._flat_space
        if a is None or space is None or flat is None:
            return self._checked(t)
        # tensordot(a, space, axes=1) as numpy forms it, (1, K) x (K, components * n),
        # without its Python layers; sum_k |a_k| max |f_k| <= DATA_BOUND: nothing overflows
        values = np.dot(a.reshape(1, -1), flat).reshape(space.shape[1:])
        if self.nonnegative and np.any(values < 0.0):
            # the distributed (x - t)^2 has round-off negatives where the square has none:
            # the datum as written decides (and names a really negative value)
            return self._checked(t)
        return self.guard.record(self.key, values, self.points, t, nonnegative=self.nonnegative)

    def _checked(self, t: float) -> np.ndarray:
        """The datum evaluated as written, through the guard.  Not collective."""
        if self.points is None or self.arguments is None:
            assert self._again is not None  # released by release_space(again)
            self.points, self.arguments = self._again()
        args = _at_time(self.arguments, t)
        return self.guard.evaluate(
            self.key, self.field, self.points, t, *args, nonnegative=self.nonnegative
        )


class SplitCoefficients:
    """The a_k(t) of every split datum of a run (:class:`PointDatum`), together.  Not collective.

    A step asks every split datum (body force, tractions, Dirichlet data, friction bound)
    for its a_k(t) at the same t, and the data derived from one solution share their time
    parts (``cos(t) - 1``): at the first call for a t, each distinct time part is evaluated
    once, all under one ``np.errstate``.  The answers of the last CACHED_TIMES times are
    kept (generalized-alpha asks for t_{n-1} and t_n).
    """

    CACHED_TIMES = 2

    def __init__(self) -> None:
        self._parts: dict[object, int] = {}  # key of a time part -> its index in _fields
        self._fields: list[Callable[[float], np.ndarray]] = []  # the distinct time parts
        self._data: list[tuple[int, np.ndarray]] = []  # per datum: its time part, (K,) scale
        self._kept: dict[float, list[np.ndarray | None]] = {}  # t -> per datum a_k(t) or None

    def add(self, time_part, scale: np.ndarray) -> int:
        """Register a datum by its time part (a CompiledField of t) and its (K,) max |f_k|;
        returns the datum's index in the lists of :meth:`at`."""
        texts = getattr(time_part, "texts", None)
        key = time_part if texts is None else (tuple(texts), time_part.args)
        part = self._parts.setdefault(key, len(self._fields))
        if part == len(self._fields):
            self._fields.append(time_part)
        self._data.append((part, scale))
        self._kept.clear()
        return len(self._data) - 1

    def at(self, t: float) -> list[np.ndarray | None]:
        """Per registered datum: its a_k(t) (read-only), or None where some a_k(t) is not
        finite or sum_k |a_k(t)| scale_k exceeds DATA_BOUND."""
        kept = self._kept.get(t)
        if kept is None:
            if len(self._kept) >= self.CACHED_TIMES:
                del self._kept[next(iter(self._kept))]
            kept = self._kept[t] = self._evaluate(t)
        return kept

    def _evaluate(self, t: float) -> list[np.ndarray | None]:
        with np.errstate(all="ignore"):
            parts = [field(t) for field in self._fields]
            finite = [all_finite(a) for a in parts]
            out: list[np.ndarray | None] = []
            for part, scale in self._data:
                a = parts[part]
                out.append(a if finite[part] and np.abs(a) @ scale <= DATA_BOUND else None)
        for a in parts:
            a.flags.writeable = False
        return out


def _at_time(arguments: dict[str, np.ndarray], t: float) -> tuple:
    """A datum's positional arguments at t: (x, y, t) or (x, y, t, nx, ny)."""
    x, y, *normal = arguments.values()
    return (x, y, t, *normal)


def all_finite(values: np.ndarray) -> bool:
    """Whether every entry is finite.  Not collective.

    A NaN or infinity anywhere makes the sum NaN or infinite, so a finite sum settles it
    at the cost of one pass without a temporary; only an overflowing sum of finite
    values needs the entry-wise test.  Call it under ``np.errstate(over="ignore")`` where
    the values may be that large.
    """
    return math.isfinite(values.sum()) or bool(np.all(np.isfinite(values)))


def _first_bad(bad: np.ndarray, points: np.ndarray) -> tuple[int, int]:
    """(component, point) of the bad value with the smallest component, then (x, y)."""
    component = int(np.argmax(bad.any(axis=1)))
    candidates = np.flatnonzero(bad[component])
    order = np.lexsort((points[candidates, 1], points[candidates, 0]))
    return component, int(candidates[order[0]])


def _min_op():
    from mpi4py import MPI

    return MPI.MIN


class RigidModes:
    """Translations and rotation of the body, and their stiffness under a Jacobian.

    Construction is collective: r^T A_const r (3 x 3), r^T r and ||A_const||_inf once,
    and the normal and tangential components of r at this rank's Gamma_C points.
    """

    def __init__(self, comm, disc, a_const: PETSc.Mat, law):
        self.comm = comm
        coords = disc.owned_coords  # (n_owned, 2)
        # Rotation about the cloud's centre: the three modes are then well conditioned.
        centre = comm.allreduce(coords.sum(axis=0)) / disc.n_nodes
        self.centre = centre
        dx, dy = (coords - centre).T
        one, zero = np.ones(len(coords)), np.zeros(len(coords))
        columns = [(one, zero), (zero, one), (-dy, dx)]
        modes = []
        for mx, my in columns:  # MLS reproduces linear fields: nodal parameters = motion
            vec = a_const.createVecRight()
            vec.setArray(np.column_stack([mx, my]).ravel())
            modes.append(vec)
        product = a_const.createVecLeft()
        self.gram = np.zeros((3, 3))  # r_i^T r_j
        self.stiffness = np.zeros((3, 3))  # r_i^T A_const r_j
        for i, mode in enumerate(modes):
            a_const.mult(mode, product)
            for j, other in enumerate(modes):
                self.gram[i, j] = mode.dot(other)
                self.stiffness[i, j] = product.dot(other)
        self.scale = a_const.norm(PETSc.NormType.NORM_INFINITY)
        # (n_c, 3): nu . r and tau . r at this rank's Gamma_C points
        kinematics = [law.kinematics(mode) for mode in modes]
        self.normal = np.column_stack([k[0] for k in kinematics])
        self.tangential = np.column_stack([k[1] for k in kinematics])

    def check(self, t: float, normal_weights, tangential_weights) -> None:
        """Raise SolverError on all ranks when a rigid motion is free under J.  Collective.

        J = A_const + B_nu^T diag(normal_weights) B_nu + B_tau^T diag(tangential_weights)
        B_tau, the weights (n_c,) those of the active set (see ContactLaw.active_weights).
        One allreduce of a 3 x 3 matrix.
        """
        local = self.normal.T @ (normal_weights[:, None] * self.normal)  # (3, 3)
        local += self.tangential.T @ (tangential_weights[:, None] * self.tangential)
        stiffness = self.stiffness + self.comm.allreduce(local)
        values, vectors = scipy.linalg.eigh(stiffness, self.gram)  # ascending
        free = values <= RIGID_TOLERANCE * self.scale
        if not free.any():
            return
        raise SolverError(
            f"singular stiffness at t = {t:.6g}: {self._describe(vectors[:, free])} not "
            "constrained (static scene without Dirichlet part and without closed contact "
            "holding it); add a dirichlet boundary part, or friction, or use "
            'time.scheme = "newmark"'
        )

    def _describe(self, modes: np.ndarray) -> str:
        """What the free modes (3, n_free) of r = a T_x + b T_y + w R are, in words."""
        if modes.shape[1] == 3:
            return "the rigid motions of the body (translations and rotation) are"
        if modes.shape[1] == 2:
            return "two rigid motions of the body are"
        a, b, w = modes[:, 0] / np.max(np.abs(modes[:, 0]))
        extent = math.sqrt(self.gram[2, 2] / self.gram[0, 0])  # rms distance from the centre
        if abs(w) * extent < 1e-3 * math.hypot(a, b):
            norm = math.hypot(a, b) * (1.0 if (a if abs(a) >= abs(b) else b) > 0 else -1.0)
            # 3 decimals: the direction is known to round-off only (+ 0.0 drops a "-0")
            a, b = (round(c / norm, 3) + 0.0 for c in (a, b))
            return f"the rigid translation of the body along ({a:g}, {b:g}) is"
        x, y = self.centre[0] - b / w, self.centre[1] + a / w
        return f"the rigid rotation of the body about ({x:.3g}, {y:.3g}) is"


def require_constraints(scene) -> None:
    """Refuse a static scene with nothing that could hold the body.  Not collective.

    Without a Dirichlet part and without a contact part, K has the rigid motions in its
    kernel and nothing else enters the static Jacobian.
    """
    if scene.time.dynamic:
        return
    kinds = {bc.kind for bc in scene.boundaries.values()}
    if kinds & {BoundaryKind.DIRICHLET, BoundaryKind.CONTACT}:
        return
    raise InputError(
        f'scene {scene.name}: time.scheme = "{scene.time.scheme}" needs a dirichlet or contact '
        "boundary part: without one the rigid motions of the body are not constrained (singular "
        'stiffness); add [boundary.NAME] type = "dirichlet", or use time.scheme = "newmark"'
    )
