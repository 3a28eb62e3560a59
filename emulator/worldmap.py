"""Map files of the twin: walls, obstacles, traction regions, start pose and goals.

A map is a JSON document checked against ``emulator/maps/map.schema.json`` (JSON Schema
2020-12, ``additionalProperties: false`` everywhere) and then for what a schema cannot
say (ids unique, polygons simple, bounds non-empty, start and goals inside the bounds).
Every violation is reported with its JSON pointer; :func:`load_map` raises
:class:`~emulator.errors.MapError` carrying them all.

Coordinates are metres in the map frame (x east, y north), yaw in degrees
counter-clockwise from +x. The bounds are walls; obstacles are polygons (simple, convex
or not), circles, or segments with an optional radius (half the wall thickness).

Shipped maps live in ``emulator/maps/<name>.json``: :func:`list_maps` names them and
:func:`load_map` takes a bare name (``"lab"``) or a path. :meth:`WorldMap.digest` hashes
the canonical content so that a verdict can name the exact map it was computed on.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

from jsonschema import Draft202012Validator

from emulator.errors import MapError
from firmware_proto.pose import Pose
from firmware_proto.schemacheck import schema_violations

__all__ = [
    "BOUNDS_ID",
    "MAPS_DIR",
    "Bounds",
    "CircleObstacle",
    "Clearance",
    "MapGoal",
    "Obstacle",
    "PolygonObstacle",
    "SegmentObstacle",
    "TractionRegion",
    "WorldMap",
    "convex_parts",
    "list_maps",
    "load_map",
    "map_schema",
    "point_in_polygon",
    "validate_map",
]

logger = logging.getLogger(__name__)

MAPS_DIR = Path(__file__).resolve().parent / "maps"
"""Directory of the shipped maps and of ``map.schema.json``."""

BOUNDS_ID = "bounds"
"""Obstacle id of the walls formed by the bounds (reserved: no obstacle may use it)."""

Point = tuple[float, float]

_EPS = 1e-12


# -- values --------------------------------------------------------------------------


@dataclass(frozen=True)
class Bounds:
    """The room, metres; its four sides are walls."""

    min_x: float
    min_y: float
    max_x: float
    max_y: float

    @property
    def width_m(self) -> float:
        """Extent along x, m."""
        return self.max_x - self.min_x

    @property
    def height_m(self) -> float:
        """Extent along y, m."""
        return self.max_y - self.min_y

    def contains(self, x: float, y: float) -> bool:
        """Whether the point lies strictly inside the walls."""
        return self.min_x < x < self.max_x and self.min_y < y < self.max_y


@dataclass(frozen=True)
class PolygonObstacle:
    """A simple polygon (convex or not), vertices in file order."""

    id: str
    points: tuple[Point, ...]


@dataclass(frozen=True)
class CircleObstacle:
    """A disc: centre and radius, m."""

    id: str
    center: Point
    radius: float


@dataclass(frozen=True)
class SegmentObstacle:
    """A wall from ``a`` to ``b`` with half thickness ``radius`` (0: an ideal line), m."""

    id: str
    a: Point
    b: Point
    radius: float = 0.0


Obstacle = PolygonObstacle | CircleObstacle | SegmentObstacle


@dataclass(frozen=True)
class TractionRegion:
    """Ground whose friction is ``mu_scale`` times the rover's (later regions win)."""

    id: str
    polygon: tuple[Point, ...]
    mu_scale: float


@dataclass(frozen=True)
class MapGoal:
    """A suggested goal: a name, a pose (metres, degrees) and a note for people."""

    name: str
    x: float
    y: float
    yaw_deg: float
    note: str = ""


@dataclass(frozen=True)
class Clearance:
    """Distance from a point to the nearest obstacle surface or wall, m.

    Negative inside an obstacle (or outside the walls). ``obstacle_id`` names it
    (:data:`BOUNDS_ID` for the walls, ``""`` for a map without any).
    """

    distance_m: float
    obstacle_id: str


@dataclass(frozen=True)
class WorldMap:
    """A validated map; build it with :func:`load_map` or :meth:`from_dict`."""

    name: str
    description: str
    bounds: Bounds
    obstacles: tuple[Obstacle, ...]
    traction_regions: tuple[TractionRegion, ...]
    start: Pose
    goals: tuple[MapGoal, ...] = ()

    @classmethod
    def from_dict(cls, obj: Any, source: str = "<map>") -> WorldMap:
        """Validate a parsed map document and build the map.

        Raises:
            MapError: with every violation and its JSON pointer.
        """
        violations = validate_map(obj)
        if violations:
            raise MapError(source, violations)
        return _build(obj)

    def to_dict(self) -> dict[str, Any]:
        """The map as schema-valid plain data (numbers as floats, defaults filled in)."""
        b = self.bounds
        out: dict[str, Any] = {
            "name": self.name,
            "description": self.description,
            "bounds": {
                "min_x": float(b.min_x),
                "min_y": float(b.min_y),
                "max_x": float(b.max_x),
                "max_y": float(b.max_y),
            },
            "obstacles": [_obstacle_dict(o) for o in self.obstacles],
            "traction_regions": [
                {"id": r.id, "polygon": _points(r.polygon), "mu_scale": float(r.mu_scale)}
                for r in self.traction_regions
            ],
            "start": {
                "x": float(self.start.x),
                "y": float(self.start.y),
                "yaw_deg": float(self.start.yaw_deg),
            },
        }
        if self.goals:
            out["goals"] = [
                {"name": g.name, "x": float(g.x), "y": float(g.y), "yaw_deg": float(g.yaw_deg)}
                | ({"note": g.note} if g.note else {})
                for g in self.goals
            ]
        return out

    def to_json(self) -> str:
        """Canonical JSON text: sorted keys, no spaces (what :meth:`digest` hashes)."""
        return json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))

    def digest(self) -> str:
        """SHA-256 (hex) of :meth:`to_json`: equal content gives an equal digest,
        whatever the file's layout or number spelling (``1`` vs ``1.0``)."""
        return hashlib.sha256(self.to_json().encode()).hexdigest()

    def goal(self, name: str) -> MapGoal:
        """The suggested goal called ``name``.

        Raises:
            KeyError: no such goal (the message lists the known ones).
        """
        for g in self.goals:
            if g.name == name:
                return g
        known = ", ".join(g.name for g in self.goals) or "none"
        raise KeyError(f"map {self.name!r} has no goal {name!r} (known: {known})")

    def obstacle(self, obstacle_id: str) -> Obstacle:
        """The obstacle with this id.

        Raises:
            KeyError: no such obstacle.
        """
        for o in self.obstacles:
            if o.id == obstacle_id:
                return o
        raise KeyError(f"map {self.name!r} has no obstacle {obstacle_id!r}")

    def clearance(self, x: float, y: float) -> Clearance:
        """Signed distance from ``(x, y)`` to the nearest obstacle surface or wall, m.

        Pure geometry, linear in the number of obstacle edges: meant for planning
        aids and tests, not for every physics step.
        """
        b = self.bounds
        best = min(x - b.min_x, b.max_x - x, y - b.min_y, b.max_y - y)
        best_id = BOUNDS_ID
        for o in self.obstacles:
            d = _distance_to_obstacle(o, x, y)
            if d < best:
                best, best_id = d, o.id
        return Clearance(best, best_id)

    def region_scale_at(self, x: float, y: float) -> float:
        """Friction scale of the ground at ``(x, y)``: the last region containing it,
        else 1.0."""
        scale = 1.0
        for r in self.traction_regions:
            if point_in_polygon(x, y, r.polygon):
                scale = r.mu_scale
        return scale


# -- loading -------------------------------------------------------------------------


@cache
def map_schema() -> dict[str, Any]:
    """The map JSON schema as a dict. Do not mutate it."""
    schema: dict[str, Any] = json.loads((MAPS_DIR / "map.schema.json").read_text())
    return schema


@cache
def _validator() -> Draft202012Validator:
    return Draft202012Validator(map_schema())


def list_maps() -> tuple[str, ...]:
    """Names of the shipped maps, sorted (``load_map`` accepts each)."""
    return tuple(sorted(p.stem for p in MAPS_DIR.glob("*.json") if p.name != "map.schema.json"))


def load_map(name_or_path: str | Path) -> WorldMap:
    """Read and validate a map.

    Args:
        name_or_path: a shipped map's bare name (``"lab"`` -> ``emulator/maps/lab.json``)
            or the path of a JSON file (a :class:`~pathlib.Path`, or a string containing a
            path separator or ending in ``.json``).

    Raises:
        MapError: unknown name (listing the shipped ones), unreadable file, not JSON, or
            invalid; ``violations`` holds ``(json_pointer, message)`` pairs.
    """
    text_arg = str(name_or_path)
    if isinstance(name_or_path, Path) or "/" in text_arg or text_arg.endswith(".json"):
        path = Path(name_or_path)
    else:
        known = list_maps()
        if text_arg not in known:
            raise MapError(
                text_arg, [("", f"no shipped map {text_arg!r}; known: {', '.join(known)}")]
            )
        path = MAPS_DIR / f"{text_arg}.json"
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise MapError(str(path), [("", f"cannot read: {exc}")]) from exc
    try:
        obj = json.loads(text)
    except ValueError as exc:
        raise MapError(str(path), [("", f"not valid JSON: {exc}")]) from exc
    world = WorldMap.from_dict(obj, str(path))
    logger.debug("loaded map %s from %s (%s)", world.name, path, world.digest()[:12])
    return world


def validate_map(obj: Any) -> list[tuple[str, str]]:
    """Every violation of ``obj`` as ``(json_pointer, message)``, sorted by pointer.

    First the schema; when that passes, the checks a schema cannot express: numbers
    finite, bounds non-empty, ids and goal names unique (``"bounds"`` is reserved),
    polygons simple with non-zero area, segments of non-zero length, the start and the
    goals strictly inside the bounds.
    """
    found = schema_violations(_validator(), obj)
    if not found:
        found += _semantic_violations(obj)
    return sorted(set(found))


def _semantic_violations(obj: dict[str, Any]) -> list[tuple[str, str]]:
    found: list[tuple[str, str]] = []
    b = obj["bounds"]
    if not b["max_x"] > b["min_x"]:
        found.append(("/bounds/max_x", "must be greater than min_x"))
    if not b["max_y"] > b["min_y"]:
        found.append(("/bounds/max_y", "must be greater than min_y"))
    bounds = Bounds(b["min_x"], b["min_y"], b["max_x"], b["max_y"])

    seen: dict[str, int] = {}
    for i, o in enumerate(obj["obstacles"]):
        ptr = f"/obstacles/{i}"
        oid = o["id"]
        if oid == BOUNDS_ID:
            found.append((ptr + "/id", f"{BOUNDS_ID!r} is reserved for the walls"))
        elif oid in seen:
            found.append((ptr + "/id", f"duplicate id {oid!r} (first at /obstacles/{seen[oid]})"))
        else:
            seen[oid] = i
        if o["type"] == "polygon":
            found += _polygon_violations(o["points"], ptr + "/points")
        elif o["type"] == "segment" and tuple(o["a"]) == tuple(o["b"]):
            found.append((ptr + "/b", "segment has zero length (a == b)"))

    seen = {}
    for i, r in enumerate(obj["traction_regions"]):
        ptr = f"/traction_regions/{i}"
        if r["id"] in seen:
            found.append((ptr + "/id", f"duplicate id {r['id']!r}"))
        seen.setdefault(r["id"], i)
        found += _polygon_violations(r["polygon"], ptr + "/polygon")

    s = obj["start"]
    if not bounds.contains(s["x"], s["y"]):
        found.append(("/start", "start must lie inside the bounds"))
    names: set[str] = set()
    for i, g in enumerate(obj.get("goals", [])):
        if g["name"] in names:
            found.append((f"/goals/{i}/name", f"duplicate goal name {g['name']!r}"))
        names.add(g["name"])
        if not bounds.contains(g["x"], g["y"]):
            found.append((f"/goals/{i}", "goal must lie inside the bounds"))
    return found


def _polygon_violations(raw: list[list[float]], ptr: str) -> list[tuple[str, str]]:
    pts = [(float(p[0]), float(p[1])) for p in raw]
    n = len(pts)
    for i in range(n):
        j = (i + 1) % n
        if pts[i] == pts[j]:
            if j == 0:
                return [(f"{ptr}/{i}", "repeats the first point (do not close polygons)")]
            return [(f"{ptr}/{j}", "repeats the previous point")]
    crossing = _self_intersection(pts)
    if crossing is not None:
        i, j = crossing
        return [(ptr, f"polygon is not simple: edge {i} crosses edge {j}")]
    if abs(_signed_area(pts)) < _EPS:
        return [(ptr, "polygon has zero area")]
    return []


def _build(obj: dict[str, Any]) -> WorldMap:
    def pt(p: list[float]) -> Point:
        return (float(p[0]), float(p[1]))

    obstacles: list[Obstacle] = []
    for o in obj["obstacles"]:
        if o["type"] == "polygon":
            obstacles.append(PolygonObstacle(o["id"], tuple(pt(p) for p in o["points"])))
        elif o["type"] == "circle":
            obstacles.append(CircleObstacle(o["id"], pt(o["center"]), float(o["radius"])))
        else:
            obstacles.append(
                SegmentObstacle(o["id"], pt(o["a"]), pt(o["b"]), float(o.get("radius", 0.0)))
            )
    b, s = obj["bounds"], obj["start"]
    return WorldMap(
        name=obj["name"],
        description=obj["description"],
        bounds=Bounds(float(b["min_x"]), float(b["min_y"]), float(b["max_x"]), float(b["max_y"])),
        obstacles=tuple(obstacles),
        traction_regions=tuple(
            TractionRegion(r["id"], tuple(pt(p) for p in r["polygon"]), float(r["mu_scale"]))
            for r in obj["traction_regions"]
        ),
        start=Pose(float(s["x"]), float(s["y"]), float(s["yaw_deg"])),
        goals=tuple(
            MapGoal(g["name"], float(g["x"]), float(g["y"]), float(g["yaw_deg"]), g.get("note", ""))
            for g in obj.get("goals", [])
        ),
    )


def _points(points: tuple[Point, ...]) -> list[list[float]]:
    return [[float(x), float(y)] for x, y in points]


def _obstacle_dict(o: Obstacle) -> dict[str, Any]:
    if isinstance(o, PolygonObstacle):
        return {"id": o.id, "type": "polygon", "points": _points(o.points)}
    if isinstance(o, CircleObstacle):
        return {"id": o.id, "type": "circle", "center": list(o.center), "radius": o.radius}
    return {
        "id": o.id,
        "type": "segment",
        "a": list(o.a),
        "b": list(o.b),
        "radius": float(o.radius),
    }


# -- geometry (pure) ------------------------------------------------------------------


def _signed_area(pts: list[Point] | tuple[Point, ...]) -> float:
    n = len(pts)
    return 0.5 * sum(
        pts[i][0] * pts[(i + 1) % n][1] - pts[(i + 1) % n][0] * pts[i][1] for i in range(n)
    )


def _cross(o: Point, a: Point, b: Point) -> float:
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])


def _segments_intersect(p1: Point, p2: Point, q1: Point, q2: Point) -> bool:
    d1 = _cross(q1, q2, p1)
    d2 = _cross(q1, q2, p2)
    d3 = _cross(p1, p2, q1)
    d4 = _cross(p1, p2, q2)
    if ((d1 > 0) != (d2 > 0)) and ((d3 > 0) != (d4 > 0)) and d1 and d2 and d3 and d4:
        return True

    def on(a: Point, b: Point, c: Point) -> bool:
        return (
            min(a[0], b[0]) <= c[0] <= max(a[0], b[0])
            and min(a[1], b[1]) <= c[1] <= max(a[1], b[1])
            and abs(_cross(a, b, c)) < _EPS
        )

    return on(q1, q2, p1) or on(q1, q2, p2) or on(p1, p2, q1) or on(p1, p2, q2)


def _self_intersection(pts: list[Point]) -> tuple[int, int] | None:
    n = len(pts)
    for i in range(n):
        a1, a2 = pts[i], pts[(i + 1) % n]
        for j in range(i + 1, n):
            if j == i + 1 or (i == 0 and j == n - 1):
                continue  # neighbours share a vertex
            if _segments_intersect(a1, a2, pts[j], pts[(j + 1) % n]):
                return i, j
    return None


def point_in_polygon(x: float, y: float, polygon: tuple[Point, ...]) -> bool:
    """Whether ``(x, y)`` lies inside ``polygon`` (even-odd rule; simple polygons)."""
    inside = False
    n = len(polygon)
    j = n - 1
    for i in range(n):
        xi, yi = polygon[i]
        xj, yj = polygon[j]
        if (yi > y) != (yj > y) and x < (xj - xi) * (y - yi) / (yj - yi) + xi:
            inside = not inside
        j = i
    return inside


def _is_convex(pts: list[Point]) -> bool:
    n = len(pts)
    signs = {_cross(pts[i], pts[(i + 1) % n], pts[(i + 2) % n]) > 0 for i in range(n)}
    return len(signs) == 1


def convex_parts(points: tuple[Point, ...]) -> list[tuple[Point, ...]]:
    """Split a simple polygon into convex pieces (counter-clockwise).

    A convex polygon comes back whole; a concave one is ear-clipped into triangles.
    Deterministic: the same polygon always gives the same pieces in the same order.
    """
    pts = list(points)
    if _signed_area(pts) < 0:
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


def _point_in_triangle(p: Point, a: Point, b: Point, c: Point) -> bool:
    return _cross(a, b, p) >= 0 and _cross(b, c, p) >= 0 and _cross(c, a, p) >= 0


def _distance_to_segment(x: float, y: float, a: Point, b: Point) -> float:
    ax, ay = a
    dx, dy = b[0] - ax, b[1] - ay
    length2 = dx * dx + dy * dy
    t = 0.0 if length2 == 0 else max(0.0, min(1.0, ((x - ax) * dx + (y - ay) * dy) / length2))
    return math.hypot(x - (ax + t * dx), y - (ay + t * dy))


def _distance_to_obstacle(o: Obstacle, x: float, y: float) -> float:
    if isinstance(o, CircleObstacle):
        return math.hypot(x - o.center[0], y - o.center[1]) - o.radius
    if isinstance(o, SegmentObstacle):
        return _distance_to_segment(x, y, o.a, o.b) - o.radius
    n = len(o.points)
    d = min(_distance_to_segment(x, y, o.points[i], o.points[(i + 1) % n]) for i in range(n))
    return -d if point_in_polygon(x, y, o.points) else d
