"""Tokens of gmsh's .geo language, as gmsh 4.8's lexer (Parser/Gmsh.l) cuts them.

:func:`tokenize` splits .geo text into numbers, strings, names and operators,
dropping comments, and refuses what the geometry subset never needs (characters
gmsh has no token for, unterminated strings or comments, control characters).
:func:`render` writes the tokens back, one space apart, each on its original line:
this text, not the user's, is what gmsh reads (:mod:`parefg.geometry.geo`), so no
comment, odd spacing or lexer corner case can make gmsh see other tokens than the
ones that were checked.

Two gmsh quirks shape the rules here.  gmsh skips a false ``If`` branch and an
unentered ``For`` body by scanning raw characters for the words ``If``, ``EndIf``,
``Else``, ``ElseIf``, ``For``, ``EndFor`` (Gmsh.l ``skip``/``skipTest``): inside a
string, or after a digit inside a name, such a word would end the skip and let gmsh
parse the rest of a string as commands.  So names and strings may not contain those
words (:func:`hides_control_word`), and strings may not contain ``//``, ``/*`` or
``*/``, which the same scan takes for comments.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from parefg.errors import InputError

#: every reserved word of gmsh 4.8's lexer (Gmsh.l); a name equal to one is not a variable
KEYWORDS = frozenset(
    """
    Abort Abs AbsolutePath Acos AdaptMesh Affine Alias AliasWithOptions ArcCos Append ArcSin
    ArcTan ArcTan2 Asin Atan Atan2 BSpline Betti Bezier Box Block BooleanCoherence
    BooleanCommon BooleanCut BooleanDifference BooleanFragments BooleanFuse
    BooleanIntersection BooleanSection BooleanUnion BoundingBox Call Catenary CatmullRom Ceil
    CenterOfMass Chamfer Characteristic Circle ClassifySurfaces CodeName Coherence Cohomology
    Color ColorTable Combine Compound Cone Coordinates CopyOptions Cos Cosh Cpu CreateGeometry
    CreateTopology CurrentDir CurrentDirectory CurrentFileName Curve Cylinder DefineConstant
    DefineNumber DefineString Degenerated Delete Dilate DimNameSpace DirName Disk Draw Ellipse
    Ellipsis Ellipsoid Elliptic Else ElseIf EndFor EndIf Error Euclidian Exists Exit Exp
    Extrude Fabs Field FileExists Fillet Find FixRelativePath Floor Fmod For Function
    GMSH_MAJOR_VERSION GMSH_MINOR_VERSION GMSH_PATCH_VERSION GeoEntity GetEnv GetForced
    GetForcedStr GetNumber GetString GetStringValue GetValue GmshExecutableName Hide Hole
    Homology Hypot INTERPOLATION_SCHEME If In Intersect Knots Layers Length Levelset LinSpace
    Line List ListFromFile Log Log10 LogSpace LowerCase LowerCaseIn MPI_Rank MPI_Size Macro
    Mass MatrixOfInertia Max Memory MeshAlgorithm MeshSize MeshSizeFromBoundary Min Modulo N2S
    NameStruct NameToString NewModel Nurbs OnelabAction OnelabRun Order Parametric Parent
    Periodic Physical Pi Plane Plugin Point PolarSphere Printf Quadric Rand Recombine
    Rectangle Recursive RecombineMesh RefineMesh RelocateMesh ReorientMesh RenumberMeshNodes
    RenumberMeshElements Return ReverseMesh Reverse Rotate Round Ruled S2N ScaleLastLayer
    SetChanged SetFactory SetTag SetMaxTag SetNumber SetPartition SetString Sewing
    ShapeFromFile Show Sin Sinh Slide Smoother Sphere Spline Split Sprintf Sqrt Str StrCat
    StrChoice StrCmp StrFind StrLen StrPrefix StrRelative StrReplace StrSub StringToName
    Struct Surface Symmetry SyncModel T2 T3 TIME Tan Tanh TestLevel TextAttributes ThickSolid
    ThruSections Today Torus TotalMemory Transfinite Translate UndefineConstant Unique
    UnsplitWindow UpperCase Using Volume Warning Wedge Wire
    newreg newp newl newc newll news newsl newv newf
    """.split()
)
#: the lexer's keywords written with character classes (QuadTriAddVerts, RecombLaterals, ...)
KEYWORD_PATTERN = re.compile(
    r"Quad[tT]ri[aA]dd[vV]erts|Quad[tT]ri[nN]o[nN]ew[vV]erts|Recomb[lL]aterals|Transf[qQ]uad[tT]ri"
)
#: plain names gmsh's grammar turns into commands ("System \"cmd\";", "Sleep 5;", "Mesh 2;")
COMMAND_NAMES = frozenset(
    """
    Include Print Save Merge MergeWithBoundingBox NonBlockingSystemCall System SystemCall
    SetName CreateDir OptimizeMesh SendToServer Sleep Remesh Mesh SetOrder PartitionMesh
    SetCurrentWindow SplitCurrentWindowHorizontal SplitCurrentWindowVertical View
    """.split()
)
#: the words gmsh's skip scans look for (Gmsh.l skip/skipTest)
CONTROL_WORDS = ("ElseIf", "Else", "EndIf", "If", "EndFor", "For")
_CONTROL_WORD = re.compile(r"(?<![A-Za-z_])(?:ElseIf|Else|EndIf|If|EndFor|For)(?![A-Za-z_])")
#: multi-character operators, longest first (flex takes the longest match)
OPERATORS = (
    "...", "::", "+=", "-=", "*=", "/=", "==", "!=", "<=", ">=", "&&", "||", "++", "--", ">>",
    "<<",
)  # fmt: skip
MAX_STRING = 256  # gmsh keeps at most 1023 characters of a string

# One alternative per token kind, tried in order; gmsh's flex rules take the longest match,
# which these give: comments before '/', numbers before '.', long operators before short.
# Gmsh.l numbers: {digit}+ | {digit}+"."{digit}*({exp})? | {digit}*"."{digit}+({exp})? | ...
_TOKEN = re.compile(
    r"(?P<newline>\n)|(?P<space>[ \t\r\f]+)|(?P<comment>//[^\n]*)|(?P<block>/\*)"
    r"|(?P<quote>[\"'])"
    r"|(?P<num>[0-9]+\.[0-9]*(?:[eE][-+]?[0-9]+)?|\.[0-9]+(?:[eE][-+]?[0-9]+)?"
    r"|[0-9]+(?:[eE][-+]?[0-9]+)?)"
    r"|(?P<name>[A-Za-z_][A-Za-z_0-9]*)"
    r"|(?P<op>" + "|".join(re.escape(op) for op in OPERATORS) + r"|[-+*/^%<>!=(){}\[\],;:.#?|&~])"
)


@dataclass(frozen=True)
class Token:
    """One lexical token: kind "num" | "str" | "name" | "op", its text and its 1-based line.

    For a string, ``text`` is its content and ``quote`` the delimiter it had.
    """

    kind: str
    text: str
    line: int
    quote: str = ""

    def source(self) -> str:
        """The token as gmsh reads it."""
        return f"{self.quote}{self.text}{self.quote}" if self.kind == "str" else self.text


@dataclass(frozen=True)
class Span:
    """Tokens ``start:stop`` of a token list; ``str()`` gives them as gmsh reads them."""

    tokens: list[Token]
    start: int
    stop: int

    def __str__(self) -> str:
        return " ".join(token.source() for token in self.tokens[self.start : self.stop])


def is_keyword(name: str) -> bool:
    """True when gmsh's lexer reads ``name`` as a reserved word, not as a variable."""
    return name in KEYWORDS or KEYWORD_PATTERN.fullmatch(name) is not None


def hides_control_word(text: str) -> bool:
    """True when gmsh's skip scan would take a word inside ``text`` for If/Else/For/...

    The scan matches a control word that no letter or '_' precedes or follows, so
    "If2", "a1EndFor" and the string "x EndIf y" hide one; "Force" and "Iff" do not.
    """
    return _CONTROL_WORD.search(text) is not None


def tokenize(text: str) -> list[Token]:
    """The tokens of a .geo text, comments dropped.

    Raises
    ------
    InputError
        ``line N: ...`` for a character gmsh has no token for (or that the subset
        refuses), an unterminated string or comment, or a string with a control
        character, a quote, a comment marker or more than MAX_STRING characters.
    """
    tokens: list[Token] = []
    position, line = 0, 1
    while position < len(text):
        match = _TOKEN.match(text, position)
        if match is None:
            raise InputError(f"line {line}: character {text[position]!r} is not allowed")
        kind, position = match.lastgroup, match.end()
        if kind == "newline":
            line += 1
        elif kind == "block":
            end = text.find("*/", position)
            if end < 0:
                raise InputError(f"line {line}: comment '/*' is never closed")
            line += text.count("\n", position, end)
            position = end + 2
        elif kind == "quote":
            token, position = _string(text, position - 1, line)
            tokens.append(token)
        elif kind in ("num", "name", "op"):
            tokens.append(Token(kind, match.group(), line))
    return tokens


def _string(text: str, start: int, line: int) -> tuple[Token, int]:
    """The string token opening at ``start`` (gmsh has no escapes: it ends at the next quote)."""
    quote = text[start]
    end = text.find(quote, start + 1)
    if end < 0:
        raise InputError(f"line {line}: string {text[start : start + 20]!r}... is never closed")
    content = text[start + 1 : end]
    problem = None
    if len(content) > MAX_STRING:
        problem = f"is longer than {MAX_STRING} characters"
    elif not content.isprintable() or any(q in content for q in "\"'"):
        problem = "contains a control character or a quote"
    elif any(marker in content for marker in ("//", "/*", "*/")):
        problem = "contains a comment marker (//, /* or */)"
    elif hides_control_word(content):
        problem = f"contains one of the words {', '.join(CONTROL_WORDS)}"
    if problem:
        raise InputError(f"line {line}: string {content[:40]!r} {problem}")
    return Token("str", content, line, quote), end + 1


def render(tokens: list[Token]) -> str:
    """The tokens as .geo text: one space apart, each on the line it came from."""
    lines: list[list[str]] = [[]]
    for token in tokens:
        while len(lines) < token.line:
            lines.append([])
        lines[-1].append(token.source())
    return "\n".join(" ".join(words) for words in lines) + "\n"
