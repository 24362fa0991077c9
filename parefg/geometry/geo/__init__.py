"""Untrusted .geo files: accept only the geometry subset of gmsh's language (SPEC 9).

gmsh's .geo language can run programs (``System``, ``OnelabRun``, the
``ExternalProcess`` field), write files (``Printf > "f"``, ``Save``, ``Print``,
``CreateDir``), read others (``Include``, ``Merge``, ``GetEnv``), end the process
(``Exit``) and loop forever.  A scene's .geo file is therefore parsed here, by a
whitelist grammar, before gmsh sees it:

- ``SetFactory("Built-in" | "OpenCASCADE")``;
- Point, Line/Curve, Circle, Ellipse, Spline, BSpline, Bezier, Curve/Line Loop,
  Plane Surface, Surface, Rectangle, Disk, and the booleans BooleanUnion,
  BooleanIntersection, BooleanDifference, BooleanFragments (OpenCASCADE);
- Physical Point/Curve/Line/Surface with a numeric or string name;
- MeshSize, Characteristic Length, Transfinite Curve/Line/Surface, Recombine Surface;
- ``Field[n] = <type>`` for the size fields of FIELD_TYPES, their options, and
  ``Background Field``;
- numeric variables and lists (``x = 1; a[] = {...}; a[i] = ...; #a[]``),
  arithmetic, the math functions of FUNCTIONS, ``Pi``, ``newp``..., and reading
  ``Mesh.MeshSizeMax`` (parefg sets it to h before gmsh reads the file);
- If/ElseIf/Else/EndIf, and For/EndFor loops whose range is known before gmsh
  runs (numbers, and variables assigned numbers earlier).

Everything else is an :class:`InputError` naming the line and the statement
(:mod:`parefg.geometry.geo.statements`).  The accepted statements are then run abstractly
(:mod:`parefg.geometry.geo.bounds`): loop ranges and list lengths are evaluated with gmsh's
own arithmetic, and a file whose loops would run more than MAX_LOOP_ITERATIONS times
in total, or build a list longer than MAX_LIST_LENGTH, is refused.  :func:`load_geo`
returns the checked tokens rendered as text (:func:`parefg.geometry.geo.tokens.render`); that
text, written to a private temporary file, is what gmsh reads, so what runs is
exactly what was checked.
"""

from __future__ import annotations

import os
import stat

from parefg.errors import InputError
from parefg.geometry.geo.bounds import MAX_LIST_LENGTH, MAX_LOOP_ITERATIONS, run_program
from parefg.geometry.geo.statements import StatementParser
from parefg.geometry.geo.tokens import render, tokenize

__all__ = [
    "MAX_GEO_BYTES", "MAX_LIST_LENGTH", "MAX_LOOP_ITERATIONS", "load_geo", "read_geo",
    "sanitize_geo",
]  # fmt: skip

MAX_GEO_BYTES = 1_000_000


def load_geo(path: str, mesh_size_max: float | None = None) -> str:
    """The checked text of the .geo file at ``path`` (not collective).

    ``mesh_size_max``: the h gmsh will be given (see :func:`sanitize_geo`).

    Raises
    ------
    InputError
        ``cannot read ...`` / ``line N: ...: statement`` (see :func:`sanitize_geo`).
    """
    return sanitize_geo(read_geo(path), mesh_size_max)


def read_geo(path: str) -> str:
    """The text of a regular file of at most MAX_GEO_BYTES bytes of UTF-8.

    Opened without blocking and checked after opening (a FIFO or a device never
    blocks the read, and a file swapped after a check is still checked).
    """
    try:
        descriptor = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except OSError as exc:
        raise InputError(f"cannot read it: {exc.strerror}") from None
    with os.fdopen(descriptor, "rb") as stream:
        info = os.fstat(stream.fileno())
        if not stat.S_ISREG(info.st_mode):
            raise InputError("is not a regular file")
        data = stream.read(MAX_GEO_BYTES + 1)
    if len(data) > MAX_GEO_BYTES:
        raise InputError(f"is larger than {MAX_GEO_BYTES} bytes")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputError(f"is not UTF-8 text (byte {exc.start})") from None


def sanitize_geo(text: str, mesh_size_max: float | None = None) -> str:
    """Check .geo text against the geometry subset and return it as gmsh should read it.

    With ``mesh_size_max``, the h that gmsh will read as Mesh.MeshSizeMax, values computed
    from it are known, and every Transfinite Curve count must be (without it, a count
    that depends on h is checked later, with h, right before gmsh reads the file).

    The result has the same tokens on the same lines, comments removed, one space
    between tokens (:func:`parefg.geometry.geo.tokens.render`).

    Raises
    ------
    InputError
        ``line N: what is wrong: the statement`` for the first statement outside the
        subset, an unbounded or too long loop, a too long list, or Transfinite counts
        that may make too many nodes (:mod:`parefg.geometry.geo.bounds`).
    """
    tokens = tokenize(text)
    run_program(StatementParser(tokens).program(), mesh_size_max)
    return render(tokens)
