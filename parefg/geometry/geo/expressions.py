"""Expressions and lists of the .geo subset: a recursive-descent parser base class.

:class:`ExpressionParser` walks the tokens of :mod:`parefg.geometry.geo.tokens` and builds
the trees that :mod:`parefg.geometry.geo.bounds` evaluates: ``("num", v)``, ``("var",
name)``, ``("element", name, index)``, ``("unknown",)`` (a value only gmsh knows:
``newp``, ``#a[]``, ``Mesh.MeshSizeMax``), ``("unary-", e)``, ``("call", name,
args)``, ``("chain", first, [(op, operand), ...])``; lists are ``("items", [...])``
of expressions, ``("whole", name)`` (``a[]``) and ``("range", a, b[, step])``.
Operator precedence is gmsh's (Parser/Gmsh.y).  Nesting is limited to MAX_NESTING,
so no input can exhaust Python's stack.
"""

from __future__ import annotations

from parefg.errors import InputError
from parefg.geometry.geo.arithmetic import FUNCTIONS
from parefg.geometry.geo.bounds import MESH_SIZE_MAX  # a name no .geo variable has
from parefg.geometry.geo.tokens import COMMAND_NAMES, Span, Token, hides_control_word, is_keyword

MAX_NESTING = 40  # parentheses, unary operators and If/For blocks inside each other
MESH_SIZE_OPTIONS = (
    "MeshSizeMax", "CharacteristicLengthMax", "MeshSizeMin", "CharacteristicLengthMin",
)  # fmt: skip
MESH_SIZE_MAX_ALIASES = ("MeshSizeMax", "CharacteristicLengthMax")
NEW_TAGS = ("newp", "newl", "newc", "newll", "news", "newsl", "newv", "newf", "newreg")
#: binary operator -> (precedence, right-associative), as declared in Gmsh.y
BINARY = {
    "||": (1, False), "&&": (2, False), "==": (3, False), "!=": (3, False), "<": (4, False),
    ">": (4, False), "<=": (4, False), ">=": (4, False), "+": (5, False), "-": (5, False),
    "*": (6, False), "/": (6, False), "%": (6, False), "^": (8, True),
}  # fmt: skip
UNARY_PRECEDENCE = 7  # between '*' and '^': -2^2 = -(2^2), -a*b = (-a)*b
SUBSET = (
    "parefg accepts only geometry: SetFactory, Point, Line/Curve, Circle, Ellipse, Spline, "
    "BSpline, Bezier, Curve Loop, Plane Surface, Surface, Rectangle, Disk, Boolean*, Physical, "
    "MeshSize, Characteristic Length, Transfinite, Recombine, Field, Background Field, "
    "numeric variables, If, For with a known range"
)


class ExpressionParser:
    """Token access, error messages, lists and expressions; statements are in a subclass."""

    def __init__(self, tokens: list[Token]):
        self.tokens = tokens
        self.at = 0
        self.depth = 0
        self.start = 0  # first token of the statement being parsed

    # ----------------------------------------------------------------- token access

    def peek(self, ahead: int = 0) -> Token | None:
        index = self.at + ahead
        return self.tokens[index] if index < len(self.tokens) else None

    def next_is(self, words) -> bool:
        """True when the next token is a name or operator among ``words``."""
        token = self.peek()
        return token is not None and token.kind in ("op", "name") and token.text in words

    def is_(self, text: str, ahead: int = 0) -> bool:
        token = self.peek(ahead)
        return token is not None and token.kind in ("op", "name") and token.text == text

    def take(self) -> Token:
        token = self.peek()
        if token is None:
            raise self.error("the file ends inside this statement")
        self.at += 1
        return token

    def expect(self, *texts: str) -> Token:
        token = self.peek()
        if token is None or token.kind not in ("op", "name") or token.text not in texts:
            found = "the end of the file" if token is None else repr(token.source())
            raise self.error(f"expected {' or '.join(map(repr, texts))}, found {found}")
        return self.take()

    def error(self, why: str) -> InputError:
        """``line N: why: statement`` for the statement being parsed."""
        anchor = self.tokens[min(self.start, len(self.tokens) - 1)]
        words = []
        for token in self.tokens[self.start : self.start + 16]:
            words.append(token.source())
            if token.text == ";" and token.kind == "op":
                break
        statement = " ".join(words)
        statement = statement if len(statement) <= 70 else statement[:67] + "..."
        return InputError(f"line {anchor.line}: {why}: {statement}")

    def nest(self) -> None:
        self.depth += 1
        if self.depth > MAX_NESTING:
            raise self.error(f"nested more than {MAX_NESTING} levels deep")

    def variable_name(self, token: Token) -> str:
        name = token.text
        if token.kind != "name" or is_keyword(name) or name in COMMAND_NAMES:
            raise self.error(f"{token.source()!r} is not allowed here ({SUBSET})")
        if hides_control_word(name):
            raise self.error(f"variable name {name!r} contains a word gmsh reads as If/For")
        return name

    def text(self) -> Span:
        """The statement parsed so far, rendered only if an error names it."""
        return Span(self.tokens, self.start, self.at)

    # ----------------------------------------------------------------- lists

    def list_(self, allow_all: bool = False):
        """A list value: ``{items}``, ``-{items}``, ``name[]``, ``-name[]`` or one expression."""
        if allow_all and self.is_("{") and self.is_(":", 1) and self.is_("}", 2):
            self.at += 3
            return ("items", [])
        if self.is_("-") and (self.is_("{", 1) or self.is_whole_list(1)):
            self.take()
        if self.is_("{"):
            return self.braced()
        if self.is_whole_list(0):
            return ("items", [self.item()])
        return ("items", [self.expr()])

    def braced(self):
        self.expect("{")
        items = []
        if not self.is_("}"):
            items.append(self.item())
            while self.is_(","):
                self.take()
                items.append(self.item())
        self.expect("}")
        return ("items", items)

    def is_whole_list(self, ahead: int) -> bool:
        token = self.peek(ahead)
        return (
            token is not None and token.kind == "name" and self.is_("[", ahead + 1)
            and self.is_("]", ahead + 2)
        )  # fmt: skip

    def item(self):
        """One list item: ``name[]``, ``-name[]``, ``a : b [: step]`` or an expression."""
        if self.is_("-") and self.is_whole_list(1):
            self.take()
        if self.is_whole_list(0):
            name = self.variable_name(self.take())
            self.at += 2
            return ("whole", name)
        first = self.expr()
        if not self.is_(":"):
            return first
        self.take()
        bounds = [first, self.expr()]
        if self.is_(":"):
            self.take()
            bounds.append(self.expr())
        return ("range", *bounds)

    # ----------------------------------------------------------------- expressions

    def parenthesized(self):
        self.expect("(")
        value = self.expr()
        self.expect(")")
        return value

    def expr(self, min_precedence: int = 0):
        """Precedence climbing over BINARY.

        The operators this call folds to the left are kept flat, ``("chain", first,
        [(op, operand), ...])`` applied in order, so that a long sum is a shallow tree.
        """
        self.nest()
        first, rest = self.unary(), []
        while (token := self.peek()) is not None and token.kind == "op" and token.text in BINARY:
            precedence, right_associative = BINARY[token.text]
            if precedence < min_precedence:
                break
            self.take()
            rest.append((token.text, self.expr(precedence + (not right_associative))))
        self.depth -= 1
        return ("chain", first, rest) if rest else first

    def unary(self):
        if self.peek() is not None and self.peek().kind == "op" and self.peek().text in "-+!":
            op = self.take().text
            self.nest()
            operand = self.expr(UNARY_PRECEDENCE + 1)
            self.depth -= 1
            return ("unary" + op, operand)
        return self.primary()

    def primary(self):
        token = self.take()
        if token.kind == "num":
            return ("num", float(token.text))
        if token.kind == "str":
            raise self.error("a string is allowed only as a physical name or a field formula")
        if token.text == "(":
            value = self.expr()
            self.expect(")")
            return value
        if token.text == "#" and self.is_whole_list(0):
            self.variable_name(self.take())
            self.at += 2
            return ("unknown",)
        if token.kind != "name":
            raise self.error(f"unexpected {token.source()!r} in an expression")
        return self.name_value(token)

    def name_value(self, token: Token):
        """Pi, newp..., Mesh.MeshSizeMax, a function call, ``a[i]`` or a variable."""
        name = token.text
        if name == "Pi":
            return ("num", 3.141592653589793)
        if name in NEW_TAGS:
            return ("unknown",)
        if name == "Mesh":
            self.expect(".")
            option = self.expect(*MESH_SIZE_OPTIONS).text
            # parefg sets Mesh.MeshSizeMax = h before gmsh reads the file: known when h is
            return ("var", MESH_SIZE_MAX) if option in MESH_SIZE_MAX_ALIASES else ("unknown",)
        if name in FUNCTIONS:
            n_args, _ = FUNCTIONS[name]
            closing = ")" if self.expect("(", "[").text == "(" else "]"
            args = [self.expr()]
            for _ in range(n_args - 1):
                self.expect(",")
                args.append(self.expr())
            self.expect(closing)
            return ("call", name, args)
        self.variable_name(token)
        if self.is_("["):
            self.take()
            index = self.expr()
            self.expect("]")
            return ("element", name, index)
        return ("var", name)
