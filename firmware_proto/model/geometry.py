"""Planar geometry of the map frame: angles, segments and polygons; the one set of
geometry helpers of the project.

Metres in the map frame, x east, y north; angles counter-clockwise from +x, in degrees
where a name says ``_deg`` and radians where it says ``_rad``. Points are plain ``(x,
y)`` tuples (cheap in the inner loops of clearance checks). Polygons are simple, either
winding, not closed (the last vertex joins the first). Pure functions, no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

__all__ = [
    "Point",
    "bearing_rad",
    "closest_point_on_segment",
    "convex_parts",
    "point_in_polygon",
    "point_segment_distance",
    "polygon_crossing",
    "segment_polygon_distance",
    "segment_segment_distance",
    "segments_intersect",
    "signed_area",
    "wrap_deg",
    "wrap_rad",
]

Point = tuple[float, float]
"""A point in the map frame, ``(x, y)`` in metres."""

_EPS = 1e-12
"""Cross products this close to zero count as collinear (decimal map coordinates are inexact)."""


def wrap_deg(angle_deg: float) -> float:
    """``angle_deg`` wrapped to ``[-180, 180)``."""
    return (angle_deg + 180.0) % 360.0 - 180.0


def wrap_rad(angle_rad: float) -> float:
    """``angle_rad`` wrapped to ``[-pi, pi)``; returned unchanged (bit for bit) when it
    is in range already, so that wrapping never perturbs a deterministic run."""
    if -math.pi <= angle_rad < math.pi:
        return angle_rad
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi


def bearing_rad(a: Point, b: Point) -> float:
    """Heading from ``a`` to ``b``, rad in ``[-pi, pi]`` (0 when they coincide)."""
    return math.atan2(b[1] - a[1], b[0] - a[0])


def closest_point_on_segment(p: Point, a: Point, b: Point) -> tuple[Point, float]:
    """The point of segment ``a``-``b`` nearest ``p``, and its parameter ``t`` in
    ``[0, 1]`` (0 at ``a``)."""
    dx, dy = b[0] - a[0], b[1] - a[1]
    length2 = dx * dx + dy * dy
    if length2 == 0.0:
        return a, 0.0
    t = ((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / length2
    t = min(1.0, max(0.0, t))
    return (a[0] + t * dx, a[1] + t * dy), t


def point_segment_distance(p: Point, a: Point, b: Point) -> float:
    """Distance from ``p`` to segment ``a``-``b``, m."""
    ax, ay = a
    dx, dy = b[0] - ax, b[1] - ay
    px, py = p[0] - ax, p[1] - ay
    length2 = dx * dx + dy * dy
    if length2 > 0.0:
        t = (px * dx + py * dy) / length2
        if t > 1.0:
            t = 1.0
        elif t < 0.0:
            t = 0.0
        px -= t * dx
        py -= t * dy
    return math.sqrt(px * px + py * py)


def _cross(o: Point, a: Point, b: Point) -> float:
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])


def _on_segment(a: Point, b: Point, p: Point) -> bool:
    """Whether ``p``, collinear with ``a``-``b`` within :data:`_EPS`, lies on it."""
    return (
        min(a[0], b[0]) <= p[0] <= max(a[0], b[0])
        and min(a[1], b[1]) <= p[1] <= max(a[1], b[1])
        and abs(_cross(a, b, p)) < _EPS
    )


def segments_intersect(a: Point, b: Point, c: Point, d: Point) -> bool:
    """Whether segments ``a``-``b`` and ``c``-``d`` share a point (touching counts)."""
    d1, d2 = _cross(c, d, a), _cross(c, d, b)
    d3, d4 = _cross(a, b, c), _cross(a, b, d)
    if ((d1 > 0 > d2) or (d1 < 0 < d2)) and ((d3 > 0 > d4) or (d3 < 0 < d4)):
        return True
    return (
        _on_segment(c, d, a) or _on_segment(c, d, b) or _on_segment(a, b, c) or _on_segment(a, b, d)
    )


def segment_segment_distance(a: Point, b: Point, c: Point, d: Point) -> float:
    """Shortest distance between segments ``a``-``b`` and ``c``-``d``, m (0 when they
    cross or touch)."""
    if segments_intersect(a, b, c, d):
        return 0.0
    return min(
        point_segment_distance(a, c, d),
        point_segment_distance(b, c, d),
        point_segment_distance(c, a, b),
        point_segment_distance(d, a, b),
    )


def point_in_polygon(p: Point, polygon: Sequence[Point]) -> bool:
    """Whether ``p`` lies inside ``polygon`` (even-odd rule; a point on an edge may go
    either way)."""
    x, y = p
    inside = False
    n = len(polygon)
    for i in range(n):
        x1, y1 = polygon[i]
        x2, y2 = polygon[(i + 1) % n]
        if (y1 > y) != (y2 > y) and x < x1 + (y - y1) * (x2 - x1) / (y2 - y1):
            inside = not inside
    return inside


def segment_polygon_distance(a: Point, b: Point, polygon: Sequence[Point]) -> float:
    """Distance from segment ``a``-``b`` to a polygon's area, m: 0 when the segment
    touches, crosses or lies inside it."""
    if point_in_polygon(a, polygon) or point_in_polygon(b, polygon):
        return 0.0
    n = len(polygon)
    return min(segment_segment_distance(a, b, polygon[i], polygon[(i + 1) % n]) for i in range(n))


def signed_area(polygon: Sequence[Point]) -> float:
    """The polygon's area, m^2: positive when its vertices run counter-clockwise."""
    n = len(polygon)
    return 0.5 * sum(
        polygon[i][0] * polygon[(i + 1) % n][1] - polygon[(i + 1) % n][0] * polygon[i][1]
        for i in range(n)
    )


def polygon_crossing(polygon: Sequence[Point]) -> tuple[int, int] | None:
    """The first two edges of ``polygon`` that cross or touch (edge ``i`` runs from
    vertex ``i`` to the next), or ``None`` when it is simple. Neighbouring edges share
    their vertex and do not count."""
    n = len(polygon)
    for i in range(n):
        a1, a2 = polygon[i], polygon[(i + 1) % n]
        for j in range(i + 1, n):
            if j == i + 1 or (i == 0 and j == n - 1):
                continue
            if segments_intersect(a1, a2, polygon[j], polygon[(j + 1) % n]):
                return i, j
    return None


def _is_convex(pts: Sequence[Point]) -> bool:
    n = len(pts)
    return len({_cross(pts[i], pts[(i + 1) % n], pts[(i + 2) % n]) > 0 for i in range(n)}) == 1


def _point_in_triangle(p: Point, a: Point, b: Point, c: Point) -> bool:
    return _cross(a, b, p) >= 0 and _cross(b, c, p) >= 0 and _cross(c, a, p) >= 0


def convex_parts(polygon: Sequence[Point]) -> list[tuple[Point, ...]]:
    """Split a simple polygon into convex pieces (counter-clockwise).

    A convex polygon comes back whole; a concave one is ear-clipped into triangles.
    Deterministic: the same polygon always gives the same pieces in the same order.

    Raises:
        ValueError: the polygon is not simple (it cannot be ear-clipped).
    """
    pts = list(polygon)
    if signed_area(pts) < 0:
        pts.reverse()
    if _is_convex(pts):
        return [tuple(pts)]
    triangles: list[tuple[Point, ...]] = []
    idx = list(range(len(pts)))
    while len(idx) > 3:
        for k in range(len(idx)):
            i0, i1, i2 = idx[k - 1], idx[k], idx[(k + 1) % len(idx)]
            a, b, c = pts[i0], pts[i1], pts[i2]
            if _cross(a, b, c) <= _EPS:
                continue  # reflex or degenerate corner: not an ear
            if any(_point_in_triangle(pts[m], a, b, c) for m in idx if m not in (i0, i1, i2)):
                continue
            triangles.append((a, b, c))
            del idx[k]
            break
        else:  # pragma: no cover - impossible for a simple polygon
            raise ValueError("polygon could not be triangulated (not simple?)")
    triangles.append(tuple(pts[i] for i in idx))
    return triangles
