"""Polygon checks: simple (no crossing, touching or folded edges) and counter-clockwise.

One gate for every polygon a scene may give (``[domain] shape = "polygon"``) and for the
built-in outlines: the polygon shape's check (:data:`parefg.geometry.shapes.SHAPES`) calls
:func:`polygon_problem` when the scene is validated, before anything is created, and the
gmsh builder calls it again before gmsh sees the points (gmsh aborts the process on a
self-intersecting outline).  Not collective.
"""

from __future__ import annotations

import numpy as np

from parefg.geometry.cloud import signed_areas

AREA_TOLERANCE = 1e-12  # relative to the size squared: a polygon with less area is degenerate


def polygon_problem(vertices) -> str | None:
    """What is wrong with the polygon through ``vertices`` (n, 2), as a phrase, or None.

    The polygon must be simple (:func:`polygon_defect`) and run counter-clockwise
    (:func:`orientation_defect`); the phrase completes "domain.vertices: ...".
    """
    defect = polygon_defect(vertices)
    if defect is not None:
        return f"must be a simple polygon: {defect}"
    return orientation_defect(vertices)


def orientation_defect(vertices) -> str | None:
    """None when the polygon runs counter-clockwise with an area above round-off, else why.

    Shoelace formula on the vertices shifted to the first one (less cancellation):
    positive signed area <=> counter-clockwise.  An area at round-off of the polygon's
    size squared (collinear vertices) has no sign to trust.
    """
    xy = np.asarray(vertices, dtype=float)  # (n_vertices, 2)
    xy = xy - xy[0]
    area = signed_areas(xy, np.arange(len(xy))[None, :])[0]
    if not area > AREA_TOLERANCE * np.max(np.ptp(xy, axis=0)) ** 2:
        return "must run counter-clockwise (positive area)"
    return None


PAIRS_PER_CHUNK = 200_000  # candidate edge pairs tested at once by polygon_defect
MAX_POLYGON_VERTICES = 5000  # worst case (every pair a candidate): 7 s on a busy 2-core VM


def polygon_defect(vertices) -> str | None:
    """Why the closed polyline through ``vertices`` is not a simple polygon, or None.

    Edge i runs from vertex i to vertex i + 1 (the last back to vertex 0).  A
    simple polygon has no zero-length edge, no two coincident vertices, no two
    non-adjacent edges that cross or touch and no two adjacent edges that overlap
    (fold back).  Distances below 1e-9 times the polygon's extent count as touching,
    so the answer does not hang on round-off.  gmsh aborts the process on a
    self-intersecting curve loop: this is its gate.

    Only edge pairs whose ranges overlap along x (or y) are tested (edges sorted by
    their smallest coordinate, found with searchsorted), vectorized over
    PAIRS_PER_CHUNK pairs at a time; the worst case stays quadratic, hence
    MAX_POLYGON_VERTICES.
    """
    xy = np.asarray(vertices, dtype=float)  # (n, 2)
    n = len(xy)
    if n > MAX_POLYGON_VERTICES:
        return f"it has {n} vertices, at most {MAX_POLYGON_VERTICES} are allowed"
    ends = np.roll(xy, -1, axis=0)  # (n, 2) end of edge i
    tol = 1e-9 * float(np.ptp(xy, axis=0).max())
    short = np.flatnonzero(np.linalg.norm(ends - xy, axis=1) <= tol)
    if len(short):
        i = int(short[0])
        return f"edge {i} has zero length (vertices {i} and {(i + 1) % n} coincide)"
    low, high = np.minimum(xy, ends), np.maximum(xy, ends)  # (n, 2) edge bounding boxes
    # Along the axis that gives fewer candidates, edge order[k] can only meet the edges
    # order[k + 1 : reach[k]] that start before it ends.
    sweeps = []
    for axis in (0, 1):
        order = np.argsort(low[:, axis], kind="stable")
        reach = np.searchsorted(low[order, axis], high[order, axis] + tol, side="right")
        sweeps.append((order, reach - np.arange(n) - 1))  # (n,), (n,) >= 0
    order, counts = min(sweeps, key=lambda sweep: int(sweep[1].sum()))
    ends_before = np.cumsum(counts)  # (n,) pairs of rows 0..k
    start = 0
    while start < n:
        before = ends_before[start] - counts[start]
        stop = max(start + 1, int(np.searchsorted(ends_before, before + PAIRS_PER_CHUNK, "right")))
        rows = np.arange(start, stop)
        k = np.repeat(rows, counts[rows])  # (p,) sorted position of the first edge
        offsets = np.arange(len(k)) - np.repeat(
            np.cumsum(counts[rows]) - counts[rows], counts[rows]
        )
        defect = _pairs_defect(xy, ends, low, high, order[k], order[k + 1 + offsets], tol)
        if defect is not None:
            return defect
        start = stop
    return None


def _pairs_defect(xy, ends, low, high, e, f, tol) -> str | None:
    """The first defect among the edge pairs (e, f), each (p,) int."""
    n = len(xy)
    e, f = np.minimum(e, f), np.maximum(e, f)
    near = np.all((low[e] <= high[f] + tol) & (low[f] <= high[e] + tol), axis=1)
    e, f = e[near], f[near]
    coincide = np.linalg.norm(xy[e] - xy[f], axis=1) <= tol
    if np.any(coincide):
        k = np.lexsort((f[coincide], e[coincide]))[0]
        a, b = int(e[coincide][k]), int(f[coincide][k])
        return f"vertices {a} and {b} coincide ({_point(xy[a])})"
    a, b, c, d = xy[e], ends[e], xy[f], ends[f]  # (p, 2)
    following = f == e + 1  # edge f starts where edge e ends: c = b
    closing = (e == 0) & (f == n - 1)  # edge f ends where edge e starts: d = a
    # Adjacent edges overlap when the far end of one lies on the other.
    fold = following & ((_segment_distance(d, a, b) <= tol) | (_segment_distance(a, c, d) <= tol))
    fold |= closing & ((_segment_distance(c, a, b) <= tol) | (_segment_distance(b, c, d) <= tol))
    crossing = (_cross(b - a, c - a) * _cross(b - a, d - a) < 0) & (
        _cross(d - c, a - c) * _cross(d - c, b - c) < 0
    )
    gap = np.minimum.reduce(
        [_segment_distance(c, a, b), _segment_distance(d, a, b), _segment_distance(a, c, d),
         _segment_distance(b, c, d)]
    )  # fmt: skip
    bad = fold | (~following & ~closing & (crossing | (gap <= tol)))
    if not np.any(bad):
        return None
    k = np.lexsort((f[bad], e[bad]))[0]
    first, second = int(e[bad][k]), int(f[bad][k])
    how = "overlap" if fold[bad][k] else "cross or touch"
    return (
        f"edges {first} and {second} {how} ({_point(xy[first])} -> {_point(ends[first])} and "
        f"{_point(xy[second])} -> {_point(ends[second])})"
    )


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(...,) z-component of u x v for (..., 2) vectors."""
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(...,) distance from points p to segments [a, b], all (..., 2) (b != a)."""
    ab = b - a
    t = np.clip(np.sum((p - a) * ab, axis=-1) / np.sum(ab * ab, axis=-1), 0.0, 1.0)
    return np.linalg.norm(p - a - t[..., None] * ab, axis=-1)


def _point(p: np.ndarray) -> str:
    return f"[{p[0]:g}, {p[1]:g}]"
