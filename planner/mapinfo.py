"""What the planner knows of a map: bounds, obstacle shapes, start pose, suggested goals.

The planner never imports the emulator (DESIGN.md): it reads a map as the JSON document
the gate serves at ``GET /maps/{name}`` (the twin's map format, docs/twin.md), or from a
file of that format. :class:`MapInfo` answers the two questions the planner asks of it:
how far a point is from the nearest obstacle surface (:meth:`MapInfo.clearance`), and
how far a straight drive passes from it (:meth:`MapInfo.segment_clearance`). It is a
planning aid: the gate, which plays the plan on the twin, stays the judge.

Units: metres in the map frame (x east, y north), yaw in degrees.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

from firmware_proto.pose import Pose
from planner.errors import GateProtocolError
from planner.geometry import (
    Point,
    point_in_polygon,
    point_segment_distance,
    segment_polygon_distance,
    segment_segment_distance,
)

__all__ = ["BOUNDS_ID", "Bounds", "MapGoal", "MapInfo", "Obstacle", "TractionRegion"]

BOUNDS_ID = "bounds"
"""Obstacle id of the map's walls (as the gate reports them)."""


@dataclass(frozen=True)
class Bounds:
    """The room, metres; its four sides are walls."""

    min_x: float
    min_y: float
    max_x: float
    max_y: float

    def contains(self, x: float, y: float) -> bool:
        """Whether ``(x, y)`` lies strictly inside."""
        return self.min_x < x < self.max_x and self.min_y < y < self.max_y

    def distance(self, p: Point) -> float:
        """Distance from ``p`` to the nearest wall, m (negative outside)."""
        return min(p[0] - self.min_x, self.max_x - p[0], p[1] - self.min_y, self.max_y - p[1])

    def __str__(self) -> str:
        return f"x {self.min_x:g}..{self.max_x:g}, y {self.min_y:g}..{self.max_y:g}"


@dataclass(frozen=True)
class Obstacle:
    """One obstacle.

    Attributes:
        id: its map id.
        kind: ``"circle"`` (``points`` is the centre), ``"segment"`` (the two ends) or
            ``"polygon"`` (the vertices).
        points: see ``kind``.
        radius_m: circle radius, or half the thickness of a segment; 0 for a polygon.
    """

    id: str
    kind: str
    points: tuple[Point, ...]
    radius_m: float = 0.0

    def distance(self, p: Point) -> float:
        """Distance from ``p`` to the obstacle's surface, m; negative inside."""
        if self.kind == "circle":
            c = self.points[0]
            return math.hypot(p[0] - c[0], p[1] - c[1]) - self.radius_m
        if self.kind == "segment":
            return point_segment_distance(p, self.points[0], self.points[1]) - self.radius_m
        pts = self.points
        edge = min(
            point_segment_distance(p, pts[i], pts[(i + 1) % len(pts)]) for i in range(len(pts))
        )
        return -edge if point_in_polygon(p, pts) else edge

    def segment_distance(self, a: Point, b: Point) -> float:
        """Distance from segment ``a``-``b`` to the obstacle's surface, m (<= 0 when it
        touches or enters it)."""
        if self.kind == "circle":
            return point_segment_distance(self.points[0], a, b) - self.radius_m
        if self.kind == "segment":
            p, q = self.points
            return segment_segment_distance(a, b, p, q) - self.radius_m
        return segment_polygon_distance(a, b, self.points)

    @cached_property
    def box(self) -> tuple[float, float, float, float]:
        """Axis-aligned bounding box ``(min_x, min_y, max_x, max_y)``, m."""
        r = self.radius_m
        xs = [p[0] for p in self.points]
        ys = [p[1] for p in self.points]
        return min(xs) - r, min(ys) - r, max(xs) + r, max(ys) + r

    def extent_along(self, origin: Point, direction: Point) -> tuple[float, float]:
        """The obstacle's shadow on the line ``origin + s * direction`` (``direction`` a
        unit vector): ``(s_min, s_max)``, m."""
        ux, uy = direction
        proj = [(q[0] - origin[0]) * ux + (q[1] - origin[1]) * uy for q in self.points]
        return min(proj) - self.radius_m, max(proj) + self.radius_m


@dataclass(frozen=True)
class MapGoal:
    """A goal the map suggests: its name, pose and note."""

    name: str
    pose: Pose
    note: str = ""


@dataclass(frozen=True)
class TractionRegion:
    """A region of other ground (the twin scales friction there by ``mu_scale``). The
    planner does not plan around it; the live view draws it."""

    id: str
    polygon: tuple[Point, ...]
    mu_scale: float


def _point(obj: Any, where: str) -> Point:
    if (
        not isinstance(obj, list)
        or len(obj) != 2
        or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in obj)
    ):
        raise GateProtocolError(f"map: {where} is not a point [x, y]", [where])
    return (float(obj[0]), float(obj[1]))


def _pose(obj: Any, where: str) -> Pose:
    try:
        return Pose(float(obj["x"]), float(obj["y"]), float(obj.get("yaw_deg", 0.0)))
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise GateProtocolError(f"map: {where} is not a pose", [where]) from exc


def _obstacle(obj: Any, where: str) -> Obstacle:
    if not isinstance(obj, dict):
        raise GateProtocolError(f"map: {where} is not an object", [where])
    kind = obj.get("type")
    oid = str(obj.get("id", ""))
    try:
        if kind == "circle":
            return Obstacle(
                oid, "circle", (_point(obj["center"], where + "/center"),), float(obj["radius"])
            )
        if kind == "segment":
            ends = (_point(obj["a"], where + "/a"), _point(obj["b"], where + "/b"))
            return Obstacle(oid, "segment", ends, float(obj.get("radius", 0.0)))
        if kind == "polygon":
            pts = tuple(_point(p, f"{where}/points/{i}") for i, p in enumerate(obj["points"]))
            if len(pts) < 3:
                raise GateProtocolError(f"map: {where} has fewer than 3 points", [where])
            return Obstacle(oid, "polygon", pts)
    except (KeyError, TypeError, ValueError) as exc:
        raise GateProtocolError(f"map: {where} is malformed: {exc}", [where]) from exc
    raise GateProtocolError(f"map: {where} has unknown type {kind!r}", [where + "/type"])


@dataclass(frozen=True)
class MapInfo:
    """A map as the planner sees it; build it with :meth:`from_dict` or :meth:`load`."""

    name: str
    bounds: Bounds
    obstacles: tuple[Obstacle, ...]
    start: Pose
    goals: tuple[MapGoal, ...] = ()
    traction_regions: tuple[TractionRegion, ...] = ()

    @classmethod
    def from_dict(cls, obj: Mapping[str, Any]) -> MapInfo:
        """Read the map document (the twin's map format, as ``GET /maps/{name}`` serves
        it). Unknown keys (description) are ignored.

        Raises:
            GateProtocolError: a field the planner needs is missing or malformed, with
                its JSON pointer.
        """
        try:
            b = obj["bounds"]
            bounds = Bounds(
                float(b["min_x"]), float(b["min_y"]), float(b["max_x"]), float(b["max_y"])
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise GateProtocolError("map: /bounds is missing or malformed", ["/bounds"]) from exc
        raw = obj.get("obstacles", [])
        if not isinstance(raw, list):
            raise GateProtocolError("map: /obstacles is not a list", ["/obstacles"])
        obstacles = tuple(_obstacle(o, f"/obstacles/{i}") for i, o in enumerate(raw))
        start = _pose(obj.get("start"), "/start")
        goals = tuple(
            MapGoal(
                str(g.get("name", f"goal_{i}")), _pose(g, f"/goals/{i}"), str(g.get("note", ""))
            )
            for i, g in enumerate(obj.get("goals", []) or [])
        )
        try:
            regions = tuple(
                TractionRegion(
                    str(r.get("id", f"region_{i}")),
                    tuple(_point(p, f"/traction_regions/{i}/polygon") for p in r["polygon"]),
                    float(r.get("mu_scale", 1.0)),
                )
                for i, r in enumerate(obj.get("traction_regions", []) or [])
            )
        except (AttributeError, KeyError, TypeError, ValueError) as exc:
            raise GateProtocolError(
                "map: /traction_regions is malformed", ["/traction_regions"]
            ) from exc
        return cls(str(obj.get("name", "")), bounds, obstacles, start, goals, regions)

    @classmethod
    def load(cls, path: str | Path) -> MapInfo:
        """Read a map file.

        Raises:
            OSError: it cannot be read. GateProtocolError: it is not a map.
        """
        text = Path(path).read_text(encoding="utf-8")
        try:
            obj = json.loads(text)
        except ValueError as exc:
            raise GateProtocolError(f"map {path}: not JSON: {exc}") from exc
        if not isinstance(obj, dict):
            raise GateProtocolError(f"map {path}: not a JSON object")
        return cls.from_dict(obj)

    def obstacle(self, obstacle_id: str) -> Obstacle | None:
        """The obstacle with this id (``None`` for the walls or an unknown id)."""
        for o in self.obstacles:
            if o.id == obstacle_id:
                return o
        return None

    def clearance(self, p: Point, max_m: float = math.inf) -> tuple[float, str]:
        """Distance from ``p`` to the nearest obstacle surface or wall, m (negative
        inside), and that obstacle's id (:data:`BOUNDS_ID` for a wall); at most
        ``max_m`` (then with the id ``""``: nothing that close)."""
        best, best_id = max_m, ""
        wall = self.bounds.distance(p)
        if wall < best:
            best, best_id = wall, BOUNDS_ID
        for o in self.obstacles:
            x0, y0, x1, y1 = o.box
            if p[0] < x0 - best or p[0] > x1 + best or p[1] < y0 - best or p[1] > y1 + best:
                continue
            d = o.distance(p)
            if d < best:
                best, best_id = d, o.id
        return best, best_id

    def point_blocked(self, p: Point, radius_m: float) -> str | None:
        """The id of an obstacle (or wall) closer to ``p`` than ``radius_m``, else
        ``None``: whether a disc of that radius fits there."""
        if self.bounds.distance(p) < radius_m:
            return BOUNDS_ID
        for o in self.obstacles:
            x0, y0, x1, y1 = o.box
            if p[0] < x0 - radius_m or p[0] > x1 + radius_m:
                continue
            if p[1] < y0 - radius_m or p[1] > y1 + radius_m:
                continue
            if o.distance(p) < radius_m:
                return o.id
        return None

    def segment_blocked(self, a: Point, b: Point, radius_m: float) -> str | None:
        """The id of an obstacle (or wall) closer to segment ``a``-``b`` than
        ``radius_m``, else ``None``: whether a disc of that radius can slide along it."""
        if min(self.bounds.distance(a), self.bounds.distance(b)) < radius_m:
            return BOUNDS_ID
        lo_x, hi_x = min(a[0], b[0]) - radius_m, max(a[0], b[0]) + radius_m
        lo_y, hi_y = min(a[1], b[1]) - radius_m, max(a[1], b[1]) + radius_m
        for o in self.obstacles:
            x0, y0, x1, y1 = o.box
            if x1 < lo_x or x0 > hi_x or y1 < lo_y or y0 > hi_y:
                continue
            if o.segment_distance(a, b) < radius_m:
                return o.id
        return None

    def segment_clearance(self, a: Point, b: Point, max_m: float = math.inf) -> tuple[float, str]:
        """Least distance between segment ``a``-``b`` and any obstacle surface or wall,
        m (<= 0 when it touches or crosses one), and that obstacle's id; at most
        ``max_m`` (then with the id ``""``)."""
        best, best_id = max_m, ""
        wall = min(self.bounds.distance(a), self.bounds.distance(b))
        if wall < best:
            best, best_id = wall, BOUNDS_ID
        for o in self.obstacles:
            x0, y0, x1, y1 = o.box
            if (
                max(a[0], b[0]) < x0 - best
                or min(a[0], b[0]) > x1 + best
                or max(a[1], b[1]) < y0 - best
                or min(a[1], b[1]) > y1 + best
            ):
                continue
            d = o.segment_distance(a, b)
            if d < best:
                best, best_id = d, o.id
        return best, best_id
