"""Planar geometry of the planner: angle wrapping, distances between segments (the pose
type is :class:`firmware_proto.pose.Pose`, shared with the gate and the maps).

Frames and units are those of the maps and plans (DESIGN.md): metres in the map frame,
x east, y north; yaw counter-clockwise from +x, in degrees where a name says ``_deg``
and radians where it says ``_rad``. Points are plain ``(x, y)`` tuples so that the
inner loops of the clearance checks stay cheap. Pure functions, no I/O.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

__all__ = [
    "Point",
    "bearing_rad",
    "closest_point_on_segment",
    "point_in_polygon",
    "point_segment_distance",
    "segment_polygon_distance",
    "segment_segment_distance",
    "segments_intersect",
    "wrap_deg",
    "wrap_rad",
]

Point = tuple[float, float]
"""A point in the map frame, ``(x, y)`` in metres."""


def wrap_deg(angle_deg: float) -> float:
    """``angle_deg`` wrapped to ``[-180, 180)``."""
    return (angle_deg + 180.0) % 360.0 - 180.0


def wrap_rad(angle_rad: float) -> float:
    """``angle_rad`` wrapped to ``[-pi, pi)``."""
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


def _orient(a: Point, b: Point, c: Point) -> float:
    return (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])


def segments_intersect(a: Point, b: Point, c: Point, d: Point) -> bool:
    """Whether segments ``a``-``b`` and ``c``-``d`` share a point (touching counts)."""
    d1, d2 = _orient(c, d, a), _orient(c, d, b)
    d3, d4 = _orient(a, b, c), _orient(a, b, d)
    if ((d1 > 0 > d2) or (d1 < 0 < d2)) and ((d3 > 0 > d4) or (d3 < 0 < d4)):
        return True

    def on(p: Point, q: Point, r: Point) -> bool:
        return min(p[0], q[0]) <= r[0] <= max(p[0], q[0]) and min(p[1], q[1]) <= r[1] <= max(
            p[1], q[1]
        )

    return (
        (d1 == 0 and on(c, d, a))
        or (d2 == 0 and on(c, d, b))
        or (d3 == 0 and on(a, b, c))
        or (d4 == 0 and on(a, b, d))
    )


def segment_segment_distance(a: Point, b: Point, c: Point, d: Point) -> float:
    """Shortest distance between segments ``a``-``b`` and ``c``-``d``, m (0 when they
    cross)."""
    if segments_intersect(a, b, c, d):
        return 0.0
    return min(
        point_segment_distance(a, c, d),
        point_segment_distance(b, c, d),
        point_segment_distance(c, a, b),
        point_segment_distance(d, a, b),
    )


def point_in_polygon(p: Point, polygon: Sequence[Point]) -> bool:
    """Whether ``p`` lies strictly inside ``polygon`` (simple, either winding; even-odd
    rule, points on an edge may go either way)."""
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
