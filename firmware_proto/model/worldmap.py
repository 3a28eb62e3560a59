"""Maps: walls, obstacles, traction regions, start pose and goals; the one map model that
the twin, the gate and the planner all read (docs/twin.md, Maps).

A map is a JSON document checked against ``data/maps/map.schema.json`` (JSON Schema
2020-12), then for what a schema cannot say (:func:`validate_map`); every violation is
reported with its JSON pointer in one :class:`~firmware_proto.errors.MapError`.

Coordinates are metres in the map frame (x east, y north), yaw in degrees
counter-clockwise from +x. The bounds are walls; obstacles (:data:`Obstacle`) are simple
polygons, circles, or segments with a half thickness. :meth:`WorldMap.digest` hashes the
canonical content so that a verdict names the exact map. The clearance queries are
planning aids, linear in the number of obstacles: the gate's playback stays the judge.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
from dataclasses import dataclass
from functools import cache, cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, NamedTuple

from firmware_proto.errors import MapError
from firmware_proto.model.geometry import (
    Point,
    point_in_polygon,
    point_segment_distance,
    polygon_crossing,
    segment_polygon_distance,
    segment_segment_distance,
    signed_area,
)
from firmware_proto.model.pose import Pose

if TYPE_CHECKING:
    from jsonschema import Draft202012Validator

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
    "list_maps",
    "load_map",
    "map_schema",
    "validate_map",
]

logger = logging.getLogger(__name__)

MAPS_DIR = Path(__file__).resolve().parent / "data" / "maps"
"""Directory of the shipped maps and of ``map.schema.json``."""

BOUNDS_ID = "bounds"
"""Obstacle id of the walls formed by the bounds (reserved: no obstacle may use it)."""

_EPS = 1e-12

Box = tuple[float, float, float, float]


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

    def distance(self, p: Point) -> float:
        """Distance from ``p`` to the nearest wall, m (negative outside)."""
        return min(p[0] - self.min_x, self.max_x - p[0], p[1] - self.min_y, self.max_y - p[1])

    def __str__(self) -> str:
        return f"x {self.min_x:g}..{self.max_x:g}, y {self.min_y:g}..{self.max_y:g}"


class _Outline:
    """The bounding box and the shadow on a line, from an obstacle's ``points`` and
    ``radius_m``; an obstacle class provides those, ``kind``, ``distance`` and
    ``segment_distance``."""

    if TYPE_CHECKING:

        @property
        def points(self) -> tuple[Point, ...]:
            """The outline's points."""

        @property
        def radius_m(self) -> float:
            """How far the surface lies beyond the points, m."""

    @cached_property
    def box(self) -> Box:
        """Axis-aligned bounding box ``(min_x, min_y, max_x, max_y)``, m."""
        r = self.radius_m
        xs = [q[0] for q in self.points]
        ys = [q[1] for q in self.points]
        return min(xs) - r, min(ys) - r, max(xs) + r, max(ys) + r

    def extent_along(self, origin: Point, direction: Point) -> tuple[float, float]:
        """The obstacle's shadow on the line ``origin + s * direction`` (``direction`` a
        unit vector): ``(s_min, s_max)``, m."""
        ux, uy = direction
        proj = [(q[0] - origin[0]) * ux + (q[1] - origin[1]) * uy for q in self.points]
        return min(proj) - self.radius_m, max(proj) + self.radius_m


@dataclass(frozen=True)
class PolygonObstacle(_Outline):
    """A simple polygon (convex or not), vertices in file order."""

    id: str
    points: tuple[Point, ...]
    kind: ClassVar[str] = "polygon"

    @property
    def radius_m(self) -> float:
        """0: the surface is the outline."""
        return 0.0

    def distance(self, p: Point) -> float:
        """Distance from ``p`` to the surface, m; negative inside."""
        pts = self.points
        n = len(pts)
        edge = min(point_segment_distance(p, pts[i], pts[(i + 1) % n]) for i in range(n))
        return -edge if point_in_polygon(p, pts) else edge

    def segment_distance(self, a: Point, b: Point) -> float:
        """Distance from segment ``a``-``b`` to the surface, m (0 when it touches or enters it)."""
        return segment_polygon_distance(a, b, self.points)


@dataclass(frozen=True)
class CircleObstacle(_Outline):
    """A disc: centre and radius, m."""

    id: str
    center: Point
    radius_m: float
    kind: ClassVar[str] = "circle"

    @property
    def points(self) -> tuple[Point, ...]:
        """The centre, alone."""
        return (self.center,)

    def distance(self, p: Point) -> float:
        """Distance from ``p`` to the surface, m; negative inside."""
        return math.hypot(p[0] - self.center[0], p[1] - self.center[1]) - self.radius_m

    def segment_distance(self, a: Point, b: Point) -> float:
        """Distance from segment ``a``-``b`` to the surface, m (<= 0 when touching or inside)."""
        return point_segment_distance(self.center, a, b) - self.radius_m


@dataclass(frozen=True)
class SegmentObstacle(_Outline):
    """A wall from ``a`` to ``b`` with half thickness ``radius_m`` (0: an ideal line), m."""

    id: str
    a: Point
    b: Point
    radius_m: float = 0.0
    kind: ClassVar[str] = "segment"

    @property
    def points(self) -> tuple[Point, ...]:
        """The two ends."""
        return (self.a, self.b)

    def distance(self, p: Point) -> float:
        """Distance from ``p`` to the surface, m; negative inside."""
        return point_segment_distance(p, self.a, self.b) - self.radius_m

    def segment_distance(self, a: Point, b: Point) -> float:
        """Distance from segment ``a``-``b`` to the surface, m (<= 0 when touching or inside)."""
        return segment_segment_distance(a, b, self.a, self.b) - self.radius_m


Obstacle = PolygonObstacle | CircleObstacle | SegmentObstacle
"""An obstacle of any kind (each has ``id``, ``kind``, ``points``, ``radius_m``,
``box``, ``distance``, ``segment_distance`` and ``extent_along``)."""


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

    @property
    def pose(self) -> Pose:
        """Where the goal is, as a pose."""
        return Pose(self.x, self.y, self.yaw_deg)


class Clearance(NamedTuple):
    """Distance from a point (or a segment) to the nearest obstacle surface or wall, m,
    negative inside an obstacle (or outside the walls), and that obstacle's id
    (:data:`BOUNDS_ID` for the walls; ``""`` when a query's ``max_m`` found nothing closer)."""

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
        """The suggested goal called ``name``; KeyError listing the known ones if none is."""
        for g in self.goals:
            if g.name == name:
                return g
        known = ", ".join(g.name for g in self.goals) or "none"
        raise KeyError(f"map {self.name!r} has no goal {name!r} (known: {known})")

    def obstacle(self, obstacle_id: str) -> Obstacle | None:
        """The obstacle with this id; ``None`` for the walls (:data:`BOUNDS_ID`) or no such id."""
        for o in self.obstacles:
            if o.id == obstacle_id:
                return o
        return None

    def clearance(self, p: Point, max_m: float = math.inf) -> Clearance:
        """Signed distance from ``p`` to the nearest obstacle surface or wall, m
        (negative inside), and that obstacle's id; at most ``max_m`` (then with the id
        ``""``: nothing that close)."""
        best, best_id = max_m, ""
        wall = self.bounds.distance(p)
        if wall < best:
            best, best_id = wall, BOUNDS_ID
        for o in self.obstacles:
            x0, y0, x1, y1 = o.box
            reach = max(best, 0.0)  # a point outside the walls may still be inside o
            if p[0] < x0 - reach or p[0] > x1 + reach or p[1] < y0 - reach or p[1] > y1 + reach:
                continue
            d = o.distance(p)
            if d < best:
                best, best_id = d, o.id
        return Clearance(best, best_id)

    def segment_clearance(self, a: Point, b: Point, max_m: float = math.inf) -> Clearance:
        """Least distance between segment ``a``-``b`` and any obstacle surface or wall,
        m (<= 0 when it touches or crosses one), and that obstacle's id; at most
        ``max_m`` (then with the id ``""``)."""
        best, best_id = max_m, ""
        wall = min(self.bounds.distance(a), self.bounds.distance(b))
        if wall < best:
            best, best_id = wall, BOUNDS_ID
        for o in self.obstacles:
            x0, y0, x1, y1 = o.box
            reach = max(best, 0.0)
            if (
                max(a[0], b[0]) < x0 - reach
                or min(a[0], b[0]) > x1 + reach
                or max(a[1], b[1]) < y0 - reach
                or min(a[1], b[1]) > y1 + reach
            ):
                continue
            d = o.segment_distance(a, b)
            if d < best:
                best, best_id = d, o.id
        return Clearance(best, best_id)

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

    def region_scale_at(self, x: float, y: float) -> float:
        """Friction scale of the ground at ``(x, y)``: the last region containing it, else 1.0."""
        scale = 1.0
        for r in self.traction_regions:
            if point_in_polygon((x, y), r.polygon):
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
    from jsonschema import Draft202012Validator  # noqa: PLC0415 - on first use: most never do

    return Draft202012Validator(map_schema())


def list_maps() -> tuple[str, ...]:
    """Names of the shipped maps, sorted (``load_map`` accepts each)."""
    return tuple(sorted(p.stem for p in MAPS_DIR.glob("*.json") if p.name != "map.schema.json"))


def load_map(name_or_path: str | Path) -> WorldMap:
    """Read and validate a map: a shipped map's bare name (``"lab"``: ``lab.json`` in
    :data:`MAPS_DIR`) or the path of a JSON file (a :class:`~pathlib.Path`, or a string with
    a path separator or ending in ``.json``).

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

    First the schema; when that passes, what a schema cannot express: bounds non-empty,
    ids and goal names unique (``"bounds"`` reserved), polygons simple with non-zero area,
    segments of non-zero length, the start and the goals strictly inside the bounds.
    """
    from firmware_proto.model.schemacheck import schema_violations  # noqa: PLC0415 - jsonschema

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
    crossing = polygon_crossing(pts)
    if crossing is not None:
        i, j = crossing
        return [(ptr, f"polygon is not simple: edge {i} crosses edge {j}")]
    if abs(signed_area(pts)) < _EPS:
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
        return {"id": o.id, "type": "circle", "center": list(o.center), "radius": o.radius_m}
    return {
        "id": o.id,
        "type": "segment",
        "a": list(o.a),
        "b": list(o.b),
        "radius": float(o.radius_m),
    }
