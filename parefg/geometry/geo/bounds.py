"""Run a checked .geo program abstractly: bounded loops, bounded lists, safe arithmetic.

:mod:`parefg.geometry.geo.statements` parses a .geo file into :class:`Node` trees; this
module executes them the way gmsh 4.8 would (Parser/Gmsh.y), but only for what
decides how much work gmsh will do: the values of numeric variables, the
iterations of For loops and the lengths of lists.  Values are computed with
gmsh's own arithmetic (C doubles, ``%`` on ints, ``Round(x) = floor(x + 0.5)``,
``Hypot(a, b) = sqrt(a*a + b*b)``); a value that depends on the model (``newp``,
a list element, ``Mesh.MeshSizeMax`` unless h is given) is unknown (None).  Refused, with the line:

- a For loop whose range is unknown, not finite or has step 0; loops running more
  than MAX_LOOP_ITERATIONS iterations in total; a loop body assigning its own loop
  variable or reusing it in an inner loop (gmsh's counter *is* that variable, so
  either would loop forever);
- a list (a range ``a:b:c``, a concatenation, ``a[i] = ...`` with gmsh resizing
  the list to i + 1) that may exceed MAX_LIST_LENGTH, or an unknown or negative
  index in ``a[i] = ...``;
- ``a % b`` unless b is known and its integer part is neither 0 nor -1 (gmsh
  computes ``(int)a % (int)b``, and both crash the process);
- Transfinite Curve counts unknown once h is (Mesh.MeshSizeMax), or putting more than
  MAX_TRANSFINITE_CURVE_NODES nodes on the curves in all, and Transfinite Surfaces that
  may hold more than MAX_TRANSFINITE_SURFACE_NODES (gmsh places transfinite nodes
  whatever the mesh sizes: a count of 1e9 exhausts the machine inside gmsh);
- more than MAX_WORK statements executed and list items produced in all (the
  checker itself stays fast on any input).

An If whose condition is known takes its branch; otherwise every branch runs on
a copy of the state and the copies merge (a variable keeps its value only where
all branches agree; a list keeps its largest possible length).
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field

from parefg.errors import InputError
from parefg.geometry.geo.arithmetic import FUNCTIONS, binary, combine, finite, unary

MAX_LOOP_ITERATIONS = 10_000
MAX_LIST_LENGTH = 100_000
MAX_WORK = 500_000
BOOLEAN_RESULT_LENGTH = 10_000  # bound on the entity list a boolean operation returns
INT_LIMIT = 2**31  # gmsh casts to a C int
# Nodes that Transfinite counts may make in all: gmsh places them whatever the mesh sizes,
# so Mesh.MeshSizeMin cannot bound them (parefg's budget then judges the node cloud).  On
# curves: gmsh 4.8 meshes a unit square with 10^4 nodes on one side in ~15 s, and aborts
# the process (an exception in its OpenMP 2D mesher) with 10^5.  On surfaces (structured
# grids, cheap for gmsh): 1000 x 1000.
MAX_TRANSFINITE_CURVE_NODES = 20_000
MAX_TRANSFINITE_SURFACE_NODES = 1_000_000
MESH_SIZE_MAX = "Mesh.MeshSizeMax"  # the variable holding h (parefg.geometry.geo.expressions)


@dataclass
class Node:
    """One parsed statement: kind "statement" | "assign" | "if" | "for".

    ``exprs`` and ``lists`` are the expression and list trees the statement
    evaluates; "assign" adds ``name``, ``op``, ``value``, ``target`` ("scalar",
    "list", "index") and ``index``; "if" has ``branches`` [(condition, body)] and
    ``otherwise``; "for" has ``name`` (None for ``For (a:b)``), ``exprs`` = [start,
    stop(, step)] and ``body``.
    """

    kind: str
    line: int
    text: object  # the statement, as a str or a parefg.geometry.geo.tokens.Span
    exprs: list = field(default_factory=list)
    lists: list = field(default_factory=list)
    name: str | None = None
    op: str = "="
    value: tuple | None = None
    target: str = "scalar"
    index: tuple | None = None
    branches: list = field(default_factory=list)
    otherwise: list | None = None
    body: list = field(default_factory=list)


@dataclass
class _Budget:
    """Work done so far, shared by every branch of the run."""

    iterations: int = 0
    work: int = 0


@dataclass
class _State:
    """Known numeric values and list-length bounds of the variables, and the active loops."""

    values: dict = field(default_factory=dict)
    lengths: dict = field(default_factory=dict)
    scalars: set = field(default_factory=set)  # names gmsh certainly holds as scalars
    loop_names: tuple = ()


def run_program(program: list[Node], mesh_size_max: float | None = None) -> int:
    """Execute the program abstractly; return the number of For iterations gmsh will run.

    ``mesh_size_max`` is the h gmsh will be given as Mesh.MeshSizeMax: with it, every
    Transfinite Curve count must be known; without it (a scene checked before its h is
    known) counts that depend on h are left to the check with h.

    Raises InputError for the first unbounded or unsafe statement (see the module doc).
    """
    run = _Run(strict=mesh_size_max is not None)
    state = _State()
    if mesh_size_max is not None:
        state.values[MESH_SIZE_MAX], state.lengths[MESH_SIZE_MAX] = mesh_size_max, 1
    run.block(program, state)
    run.check_transfinite_surfaces()
    return run.budget.iterations


class _Run:
    def __init__(self, strict: bool = False):
        self.budget = _Budget()
        self.node = Node("statement", 0, "")  # the statement being run, for messages
        self.strict = strict
        self.curve_nodes = 0.0  # nodes the Transfinite Curves put on curves, in all
        self.largest_count = 0.0  # the largest Transfinite Curve count
        self.surfaces: list[tuple[Node, int]] = []  # Transfinite Surface statements, lengths

    def error(self, why: str) -> InputError:
        statement = str(self.node.text)
        statement = statement if len(statement) <= 70 else statement[:67] + "..."
        return InputError(f"line {self.node.line}: {why}: {statement}")

    def charge(self, work: int) -> None:
        self.budget.work += work
        if self.budget.work > MAX_WORK:
            raise self.error(f"the file does more than {MAX_WORK} steps of work (loops, lists)")

    # ----------------------------------------------------------------- statements

    def block(self, nodes: list[Node], state: _State) -> None:
        for node in nodes:
            self.node = node
            self.charge(1)
            getattr(self, "run_" + node.kind)(node, state)

    def run_statement(self, node: Node, state: _State) -> None:
        for expr in node.exprs:
            self.value(expr, state)
        for items in node.lists:
            self.length(items, state)

    def run_transfinite(self, node: Node, state: _State) -> None:
        """Bound the nodes gmsh puts on Transfinite curves (any count, whatever the sizes).

        A curve gets |n| nodes, a transfinite surface the product of its opposite sides'
        counts: at most the largest count squared, checked once all counts are known
        (:meth:`check_transfinite_surfaces`).
        """
        length = self.length(node.lists[0], state)
        for items in node.lists[1:]:
            self.length(items, state)
        values = [self.value(expr, state) for expr in node.exprs]
        if node.name == "Surface":
            self.surfaces.append((node, length))
            return
        count = values[0]
        if count is None:
            if self.strict:
                raise self.error(
                    "a Transfinite Curve count must be known before gmsh runs (numbers, "
                    "Mesh.MeshSizeMax and variables assigned them)"
                )
            return
        count = abs(count)
        self.largest_count = max(self.largest_count, count)
        self.curve_nodes += count * length
        if self.curve_nodes > MAX_TRANSFINITE_CURVE_NODES:
            raise self.error(
                f"Transfinite Curves would put more than {MAX_TRANSFINITE_CURVE_NODES} nodes "
                "on curves in all"
            )

    def check_transfinite_surfaces(self) -> None:
        """Refuse Transfinite Surfaces that may hold more than MAX_TRANSFINITE_SURFACE_NODES."""
        nodes = 0.0
        for node, length in self.surfaces:
            self.node = node
            nodes += length * self.largest_count**2
            if nodes > MAX_TRANSFINITE_SURFACE_NODES:
                raise self.error(
                    f"Transfinite Surfaces of up to {self.largest_count:.0f} nodes a side may "
                    f"have more than {MAX_TRANSFINITE_SURFACE_NODES} nodes in all"
                )

    def run_assign(self, node: Node, state: _State) -> None:
        """Track the value and the length bound of the assigned variable (Gmsh.y Affectation).

        gmsh keeps a flag "is a list" per variable: ``x = e`` makes x a scalar, a loop
        makes its variable one, anything else may make a list; ``x += e`` appends to a
        list and adds to a scalar.  Where that flag is unsure here, the length bound
        assumes a list and the value is unknown.
        """
        name, tree = str(node.name), node.value or ("items", [])
        if name in state.loop_names:
            raise self.error(f"assigns the loop variable {name!r} inside its loop")
        previous = state.lengths.get(name, 0)
        if node.target == "index":
            index = self.value(node.index or ("unknown",), state)
            if index is None or not 0 <= math.trunc(index) < MAX_LIST_LENGTH:
                raise self.error(
                    f"the index must be known and in 0..{MAX_LIST_LENGTH - 1} before gmsh runs"
                )
            self.value(tree, state)
            self._set(state, name, None, max(previous, math.trunc(index) + 1), scalar=False)
            return
        value: float | None = None
        if tree[0] == "boolean":
            for items in tree[1]:
                self.length(items, state)
            length = BOOLEAN_RESULT_LENGTH
        elif _is_single(tree):
            value, length = self.value(tree[1][0], state), 1
        else:
            length = self.length(tree, state)
        single = node.target == "scalar" and length == 1 and _is_single(tree)
        if single and (node.op == "=" or name in state.scalars):
            self._set(state, name, combine(node.op, state.values.get(name), value), 1, True)
        elif node.op == "=":
            self._set(state, name, None, length, scalar=False)
        else:  # append (+=), remove (-=) or an error (*=, /= on a list): at most one more
            grown = previous + length if node.op == "+=" else previous
            self._set(state, name, None, max(grown, 1), scalar=False)

    def _set(self, state: _State, name: str, value, length: int, scalar: bool) -> None:
        if length > MAX_LIST_LENGTH:
            raise self.error(f"list {name!r} may grow beyond {MAX_LIST_LENGTH} items")
        state.values[name], state.lengths[name] = value, length
        if scalar:
            state.scalars.add(name)
        else:
            state.scalars.discard(name)

    def run_if(self, node: Node, state: _State) -> None:
        taken, certain = [], False
        for condition, body in node.branches:
            known = self.value(condition, state)
            if known is None:
                taken.append(body)
            elif known:  # C truth: any nonzero double
                taken.append(body)
                certain = True
                break
        if not certain:
            taken.append(node.otherwise or [])
        if len(taken) == 1:
            self.block(taken[0], state)
            return
        outcomes = []
        for body in taken:
            self.charge(len(state.values) + len(state.lengths))
            branch = copy.deepcopy(state)
            self.block(body, branch)
            outcomes.append(branch)
        _merge(state, outcomes)

    def run_for(self, node: Node, state: _State) -> None:
        why = (
            "a For range must be known before gmsh runs (numbers, and variables "
            "assigned numbers earlier)"
        )
        bounds = self.known(node.exprs, state, why)
        start, stop, step = bounds if len(bounds) == 3 else (*bounds, 1.0)
        if step == 0:
            raise self.error("the For step is 0")
        if node.name is not None and node.name in state.loop_names:
            raise self.error(f"an inner loop reuses the loop variable {node.name!r}")
        # Gmsh.y Loop: skipped when the range is empty; at EndFor the counter steps and
        # jumps back while it is within the range.
        inside = state.loop_names
        if node.name is not None:
            state.loop_names = (*inside, node.name)
        counter = start
        while (step > 0 and counter <= stop) or (step < 0 and counter >= stop):
            self.budget.iterations += 1
            if self.budget.iterations > MAX_LOOP_ITERATIONS:
                raise self.error(f"For loops run more than {MAX_LOOP_ITERATIONS} iterations")
            if node.name is not None:
                self._set(state, node.name, counter, 1, scalar=True)
            self.block(node.body, state)
            self.node = node
            counter += step
        state.loop_names = inside
        if node.name is not None:  # gmsh leaves the last stepped value (start if skipped)
            self._set(state, node.name, counter, 1, scalar=True)

    # ----------------------------------------------------------------- values

    def length(self, items: tuple, state: _State) -> int:
        """Upper bound of the number of items of a list tree ("items", [...])."""
        total = 0
        for item in items[1]:
            if item[0] == "whole":
                total += state.lengths.get(item[1], 1)
            elif item[0] == "range":
                total += self.range_length(item, state)
            else:
                self.value(item, state)
                total += 1
        if total > MAX_LIST_LENGTH:
            raise self.error(f"a list may have more than {MAX_LIST_LENGTH} items")
        return total

    def known(self, exprs, state: _State, why: str) -> list[float]:
        """The values of ``exprs``, all of which must be known (else InputError ``why``)."""
        values = [self.value(expr, state) for expr in exprs]
        finite = [v for v in values if v is not None and math.isfinite(v)]
        if len(finite) < len(values):
            raise self.error(why)
        return finite

    def range_length(self, item: tuple, state: _State) -> int:
        """Items of ``a:b`` or ``a:b:step``, counted as gmsh's loop builds them."""
        bounds = self.known(item[1:], state, "a range a:b must have bounds known before gmsh runs")
        if len(bounds) == 2:
            start, stop = bounds
            step = 1.0 if start < stop else -1.0
        else:
            start, stop, step = bounds
            if step == 0:
                raise self.error("the step of a range is 0")
        count, value = 0, start
        while (step > 0 and value <= stop) or (step < 0 and value >= stop):
            count += 1
            if count > MAX_LIST_LENGTH:
                raise self.error(f"a range has more than {MAX_LIST_LENGTH} items")
            value += step
        self.charge(count)
        return count

    def value(self, expr: tuple, state: _State) -> float | None:
        """The value gmsh computes for an expression tree, or None when unknown."""
        kind = expr[0]
        if kind == "num":
            return expr[1]
        if kind == "var":
            return state.values.get(expr[1])
        if kind == "element":
            self.value(expr[2], state)
            return None
        if kind == "unknown":
            return None
        if kind.startswith("unary"):
            return finite(unary(kind[-1], self.value(expr[1], state)))
        if kind == "call":
            return self.call(expr[1], [self.value(arg, state) for arg in expr[2]])
        # ("chain", first, [(op, operand), ...]): gmsh evaluates both sides of every operator
        result = self.value(expr[1], state)
        for op, operand in expr[2]:
            right = self.value(operand, state)
            if op == "%":
                result = self.modulo(result, right)
            else:
                result = finite(binary(op, result, right))
        return result

    def modulo(self, left: float | None, right: float | None) -> float | None:
        if right is None or not abs(right) < INT_LIMIT or math.trunc(right) in (0, -1):
            raise self.error(
                "a % b needs a b known before gmsh runs, with integer part not 0 or -1"
            )
        if left is None or not abs(left) < INT_LIMIT:
            return None
        return float(math.fmod(math.trunc(left), math.trunc(right)))

    def call(self, name: str, args: list) -> float | None:
        function = FUNCTIONS[name][1]
        if function is None or any(arg is None for arg in args):
            return None
        try:
            return finite(float(function(*args)))
        except (ValueError, OverflowError):  # C returns NaN or inf: unknown here
            return None


def _merge(state: _State, outcomes: list[_State]) -> None:
    """After an If of unknown condition: keep what all branches agree on, the longest lists."""
    names = set().union(*(o.values for o in outcomes))
    state.values = {
        name: outcomes[0].values.get(name)
        if all(o.values.get(name) == outcomes[0].values.get(name) for o in outcomes)
        else None
        for name in names
    }
    lengths = set().union(*(o.lengths for o in outcomes))
    state.lengths = {name: max(o.lengths.get(name, 0) for o in outcomes) for name in lengths}
    state.scalars = set.intersection(*(o.scalars for o in outcomes))


def _is_single(value: tuple) -> bool:
    """A list tree of exactly one plain expression (gmsh then assigns a number)."""
    return value[0] == "items" and len(value[1]) == 1 and value[1][0][0] not in ("whole", "range")
