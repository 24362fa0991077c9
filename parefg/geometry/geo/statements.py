"""Statements of the .geo subset: the whitelist grammar (SPEC 9).

:class:`StatementParser` accepts only the statements listed in :mod:`parefg.geometry.geo`,
in gmsh 4.8's syntax (Parser/Gmsh.y), and returns them as :class:`Node` trees;
anything else is an :class:`InputError` ``line N: why: statement``.  If and For
blocks must nest properly and close before the end of the file.
"""

from __future__ import annotations

from parefg.geometry.geo.bounds import Node
from parefg.geometry.geo.expressions import SUBSET, ExpressionParser
from parefg.geometry.geo.tokens import COMMAND_NAMES, hides_control_word, is_keyword

FACTORIES = ("Built-in", "OpenCASCADE")
#: entity keyword -> the word that may follow it ("Curve Loop", "Plane Surface")
ENTITIES = {
    "Point": None, "Line": "Loop", "Curve": "Loop", "Circle": None, "Ellipse": None,
    "Spline": None, "BSpline": None, "Bezier": None, "Plane": "Surface", "Surface": None,
    "Rectangle": None, "Disk": None,
}  # fmt: skip
PHYSICAL_DIMENSIONS = ("Point", "Curve", "Line", "Surface")
SHAPE_KINDS = ("Point", "Curve", "Line", "Surface")
BOOLEANS = ("BooleanUnion", "BooleanIntersection", "BooleanDifference", "BooleanFragments")
#: mesh-size fields that compute a size from the geometry (no Structured: it reads a
#: file; no ExternalProcess: it runs a program; no PostView: it needs post-processing)
FIELD_TYPES = (
    "Attractor", "Ball", "BoundaryLayer", "Box", "Curvature", "Cylinder", "Distance", "Frustum",
    "Gradient", "Laplacian", "MathEval", "Max", "Mean", "Min", "Param", "Restrict", "Threshold",
)  # fmt: skip
FIELD_STRING_OPTIONS = ("F", "FX", "FY", "FZ")  # the formulas of MathEval and Param
TRANSFINITE_TYPES = ("Progression", "Power", "Bump", "Beta")
ARRANGEMENTS = ("Left", "Right", "Alternate", "AlternateLeft", "AlternateRight")
ASSIGNMENTS = ("=", "+=", "-=", "*=", "/=")


class StatementParser(ExpressionParser):
    """The whitelist grammar: :meth:`program` is the list of top-level statements."""

    def program(self) -> list[Node]:
        return self.block(())[0]

    def block(self, ends: tuple[str, ...]) -> tuple[list[Node], str | None]:
        """Statements up to one of ``ends`` (consumed and returned) or the end of the file."""
        nodes: list[Node] = []
        opening = self.start
        while (token := self.peek()) is not None:
            self.start = self.at
            if token.kind == "name" and token.text in ends:
                self.take()
                return nodes, token.text
            nodes.append(self.statement())
        if ends:
            self.start = opening
            raise self.error(f"no {ends[-1]} closes this block")
        return nodes, None

    def statement(self) -> Node:
        token = self.take()
        line, word = token.line, token.text
        if token.kind != "name":
            raise self.error(f"a statement cannot start with {token.source()!r}")
        handlers = {
            "SetFactory": self.set_factory, "Physical": self.physical, "MeshSize": self.mesh_size,
            "Characteristic": self.characteristic, "Transfinite": self.transfinite,
            "Recombine": self.recombine, "Field": self.field, "Background": self.background,
            "If": self.if_block, "For": self.for_block,
        }  # fmt: skip
        if word in handlers:
            return handlers[word](line)
        if word in ENTITIES:
            return self.entity(line, word)
        if word in BOOLEANS:
            return self.boolean_statement(line)
        if word in ("EndIf", "ElseIf", "Else", "EndFor"):
            raise self.error(f"{word} without a matching {'For' if word == 'EndFor' else 'If'}")
        if self.is_("."):
            raise self.error(
                f"setting gmsh options ({word}.*) is not allowed: parefg sets the mesh options"
            )
        if not is_keyword(word) and word not in COMMAND_NAMES:
            return self.assignment(line, word)
        raise self.error(f"{word!r} is not allowed in a .geo file ({SUBSET})")

    def end(self) -> None:
        self.expect(";")

    def set_factory(self, line: int) -> Node:
        self.expect("(")
        factory = self.take()
        if factory.kind != "str" or factory.text not in FACTORIES:
            raise self.error(f"the factory must be one of {', '.join(map(repr, FACTORIES))}")
        self.expect(")")
        self.end()
        return Node("statement", line, self.text())

    def entity(self, line: int, word: str) -> Node:
        follower = ENTITIES[word]
        if follower is not None and (word == "Plane" or self.is_(follower)):
            self.expect(follower)
        exprs = [self.parenthesized()]
        self.expect("=")
        lists = [self.list_()]
        self.end()
        return Node("statement", line, self.text(), exprs=exprs, lists=lists)

    def physical(self, line: int) -> Node:
        self.expect(*PHYSICAL_DIMENSIONS)
        self.expect("(")
        exprs = []
        token = self.peek()
        if token is not None and token.kind == "str":
            self.take()
            if self.is_(","):
                self.take()
                exprs.append(self.expr())
        else:
            exprs.append(self.expr())
        self.expect(")")
        self.expect("=", "+=", "-=")
        lists = [self.list_()]
        self.end()
        return Node("statement", line, self.text(), exprs=exprs, lists=lists)

    def mesh_size(self, line: int) -> Node:
        lists = [self.list_(allow_all=True)]
        self.expect("=")
        exprs = [self.expr()]
        self.end()
        return Node("statement", line, self.text(), exprs=exprs, lists=lists)

    def characteristic(self, line: int) -> Node:
        self.expect("Length")
        return self.mesh_size(line)

    def transfinite(self, line: int) -> Node:
        """``Transfinite Curve|Line {list} = n [Using ...];`` or ``Transfinite Surface {list}``.

        A "transfinite" node: gmsh puts n nodes on each curve whatever the mesh sizes,
        so :mod:`parefg.geometry.geo.bounds` bounds the counts; ``{:}`` (every entity, a number
        not known before gmsh runs) is refused.
        """
        kind = self.expect("Curve", "Line", "Surface").text
        if self.is_("{") and self.is_(":", 1):
            raise self.error(f"Transfinite {kind}{{:}} cannot be bounded: list the entities")
        lists, exprs = [self.list_()], []
        if kind == "Surface":
            if self.is_("="):
                self.take()
                lists.append(self.list_())
            if self.next_is(ARRANGEMENTS):
                self.take()
        else:
            self.expect("=")
            exprs.append(self.expr())
            if self.is_("Using"):
                self.take()
                self.expect(*TRANSFINITE_TYPES)
                exprs.append(self.expr())
        self.end()
        name = "Surface" if kind == "Surface" else "Curve"
        return Node("transfinite", line, self.text(), exprs=exprs, lists=lists, name=name)

    def recombine(self, line: int) -> Node:
        self.expect("Surface")
        lists, exprs = [self.list_(allow_all=True)], []
        if self.is_("="):
            self.take()
            exprs.append(self.expr())
        self.end()
        return Node("statement", line, self.text(), exprs=exprs, lists=lists)

    def field(self, line: int) -> Node:
        self.expect("[")
        exprs, lists = [self.expr()], []
        self.expect("]")
        if self.is_("="):
            self.take()
            kind = self.take()
            if kind.kind != "name" or kind.text not in FIELD_TYPES:
                raise self.error(f"field type must be one of {', '.join(FIELD_TYPES)}")
        else:
            self.expect(".")
            option = self.take()
            if option.kind != "name" or hides_control_word(option.text):
                raise self.error("expected a field option name")
            self.expect("=")
            value = self.peek()
            if value is not None and value.kind == "str":
                if option.text not in FIELD_STRING_OPTIONS:
                    raise self.error(
                        f"only the options {', '.join(FIELD_STRING_OPTIONS)} take a string"
                    )
                self.take()
            elif self.is_("{"):
                lists.append(self.list_())
            else:
                exprs.append(self.expr())
        self.end()
        return Node("statement", line, self.text(), exprs=exprs, lists=lists)

    def background(self, line: int) -> Node:
        self.expect("Field")
        self.expect("=")
        lists = [self.list_()]
        self.end()
        return Node("statement", line, self.text(), lists=lists)

    def boolean_statement(self, line: int) -> Node:
        exprs = []
        if self.is_("("):
            exprs.append(self.parenthesized())
            self.expect("=")
        lists = self.boolean_operands()
        self.end()
        return Node("statement", line, self.text(), exprs=exprs, lists=lists)

    def boolean_operands(self) -> list:
        """The object and tool shape lists ``{ Surface{...}; ... [Delete;] }`` of a boolean."""
        lists = []
        for _ in range(2):
            self.expect("{")
            while self.next_is(SHAPE_KINDS):
                self.take()
                lists.append(self.braced())
                self.end()
            if self.is_("Delete"):
                self.take()
                self.end()
            self.expect("}")
        return lists

    def if_block(self, line: int) -> Node:
        self.nest()
        branches: list = []
        ending: str | None = "ElseIf"
        while ending == "ElseIf":
            condition = self.parenthesized()
            body, ending = self.block(("ElseIf", "Else", "EndIf"))
            branches.append((condition, body))
        otherwise = None
        if ending == "Else":
            otherwise, _ = self.block(("EndIf",))
        self.depth -= 1
        return Node("if", line, "If", branches=branches, otherwise=otherwise)

    def for_block(self, line: int) -> Node:
        self.nest()
        variable = None
        if self.is_("("):
            self.take()
            bounds = self.range_bounds(")")
        else:
            variable = self.variable_name(self.take())
            self.expect("In")
            self.expect("{")
            bounds = self.range_bounds("}")
        text = self.text()
        body, _ = self.block(("EndFor",))
        self.depth -= 1
        return Node("for", line, text, name=variable, exprs=bounds, body=body)

    def range_bounds(self, closing: str) -> list:
        bounds = [self.expr()]
        self.expect(":")
        bounds.append(self.expr())
        if self.is_(":"):
            self.take()
            bounds.append(self.expr())
        self.expect(closing)
        return bounds

    def assignment(self, line: int, name: str) -> Node:
        self.variable_name(self.tokens[self.at - 1])
        if self.is_("++") or self.is_("--"):
            step = 1.0 if self.take().text == "++" else -1.0
            self.end()
            return Node("assign", line, self.text(), name=name, op="+=", value=("num", step))
        target, index = "scalar", None
        if self.is_("[") and self.is_("]", 1):
            self.take(), self.take()
            target = "list"
        elif self.is_("["):
            self.take()
            index = self.expr()
            self.expect("]")
            target = "index"
        op = self.expect(*ASSIGNMENTS).text
        if target == "index":
            value = self.expr()
        elif target == "list" and self.next_is(BOOLEANS):
            self.take()
            value = ("boolean", self.boolean_operands())
        else:
            value = self.list_()
        self.end()
        return Node(
            "assign", line, self.text(), name=name, op=op, value=value, target=target,
            index=index,
        )  # fmt: skip
