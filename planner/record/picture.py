"""A top-down picture of a mission: the map with its obstacles' names, each plan's
predicted trajectory (the ghost), the rover's reported trajectory, drift stops (a red
octagon), where rejected plans collided (a black X), the goal, a legend and a scale bar.

Drawn with Pillow from the planner's own map data
(:class:`~firmware_proto.model.worldmap.WorldMap`), without the twin or the gate's
renderer. Pure apart from :func:`save`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from PIL import Image, ImageDraw

from firmware_proto.model.pose import Pose
from firmware_proto.model.worldmap import WorldMap
from planner.ground.mission import MissionReport

__all__ = ["MissionPicture", "draw", "fresh_path", "label_point", "picture_of", "save"]

Point = tuple[float, float]
ToPixels = Callable[[Point], tuple[float, float]]

_BACKGROUND = (250, 250, 247)
_WALL = (60, 60, 60)
_OBSTACLE = (120, 120, 130)
_GHOSTS = [(70, 130, 220), (150, 90, 200), (40, 170, 160)]
_ACTUAL = (225, 110, 30)
_DRIFT = (210, 30, 30)
_GOAL = (30, 150, 60)
_COLLISION = (20, 20, 20)
_LABEL = (255, 255, 255)
_LABEL_EDGE = (60, 60, 70)
"""The outline of a name: legible over the obstacle and over the floor beside it."""


@dataclass
class MissionPicture:
    """What to draw: predicted paths (one per executed plan), the reported trace, the
    drift stops and the goal."""

    world: WorldMap
    goal: Pose
    start: Pose
    predicted: list[Sequence[Point]] = field(default_factory=list)
    actual: list[Point] = field(default_factory=list)
    drift_stops: list[Point] = field(default_factory=list)
    title: str = ""
    collisions: list[tuple[Point, str]] = field(default_factory=list)
    """Where a rejected plan would have hit, and what (not where the rover went)."""


def draw(picture: MissionPicture, *, px_per_m: float = 80.0, margin_px: int = 20) -> Image.Image:
    """Render the picture (y up, like the map)."""
    b = picture.world.bounds
    width = round((b.max_x - b.min_x) * px_per_m) + 2 * margin_px
    legend_px = 18
    height = (
        round((b.max_y - b.min_y) * px_per_m)
        + 2 * margin_px
        + (22 if picture.title else 0)
        + legend_px
    )
    top = 22 if picture.title else 0
    image = Image.new("RGB", (width, height), _BACKGROUND)
    pen = ImageDraw.Draw(image)

    def px(p: Point) -> tuple[float, float]:
        return (
            margin_px + (p[0] - b.min_x) * px_per_m,
            top + margin_px + (b.max_y - p[1]) * px_per_m,
        )

    pen.rectangle([px((b.min_x, b.max_y)), px((b.max_x, b.min_y))], outline=_WALL, width=3)
    for ob in picture.world.obstacles:
        if ob.kind == "circle":
            cx, cy = px(ob.points[0])
            r = ob.radius_m * px_per_m
            pen.ellipse([cx - r, cy - r, cx + r, cy + r], fill=_OBSTACLE)
        elif ob.kind == "segment":
            pen.line(
                [px(ob.points[0]), px(ob.points[1])],
                fill=_OBSTACLE,
                width=max(2, round(2 * ob.radius_m * px_per_m)),
            )
        else:
            pen.polygon([px(p) for p in ob.points], fill=_OBSTACLE)
    for i, path in enumerate(picture.predicted):
        if len(path) > 1:
            pen.line([px(p) for p in path], fill=_GHOSTS[i % len(_GHOSTS)], width=3)
    if len(picture.actual) > 1:
        pen.line([px(p) for p in picture.actual], fill=_ACTUAL, width=2)
    for ob in picture.world.obstacles:
        x, y = px(label_point(ob.points) if ob.kind == "polygon" else _mean(ob.points))
        pen.text(
            (x - pen.textlength(ob.id) / 2, y - 5),
            ob.id,
            fill=_LABEL,
            stroke_width=2,
            stroke_fill=_LABEL_EDGE,
        )
    for p, _what in picture.collisions:
        _cross(pen, px(p), _COLLISION)
    for p in picture.drift_stops:
        _octagon(pen, px(p), _DRIFT)
    _pose_mark(pen, px, picture.start, (0, 0, 0))
    _pose_mark(pen, px, picture.goal, _GOAL)
    if picture.title:
        pen.text((margin_px, 4), picture.title, fill=(0, 0, 0))
    legend: list[tuple[str, tuple[int, int, int], str]] = [
        ("predicted (ghost)", _GHOSTS[0], "box"),
        ("reported by the rover", _ACTUAL, "box"),
        ("drift STOP", _DRIFT, "octagon"),
        ("collision (rejected plan)", _COLLISION, "cross"),
        ("goal", _GOAL, "box"),
    ]
    x, y = margin_px, height - legend_px  # a band below the map, never over it
    for text, colour, mark in legend:
        if mark == "octagon":
            _octagon(pen, (x + 5, y + 6), colour, radius=5)
        elif mark == "cross":
            _cross(pen, (x + 5, y + 6), colour, half=4)
        else:
            pen.rectangle([x, y + 2, x + 10, y + 10], fill=colour)
        pen.text((x + 14, y), text, fill=(0, 0, 0))
        x += 14 + round(pen.textlength(text)) + 18
    _scale_bar(pen, width - margin_px, height - legend_px + 6, px_per_m)
    return image


def _mean(points: Sequence[Point]) -> Point:
    return (sum(p[0] for p in points) / len(points), sum(p[1] for p in points) / len(points))


def _inside(p: Point, polygon: Sequence[Point]) -> bool:
    """Even-odd rule."""
    inside = False
    for (ax, ay), (bx, by) in zip(polygon, [*polygon[1:], polygon[0]], strict=True):
        if (ay > p[1]) != (by > p[1]) and p[0] < ax + (p[1] - ay) * (bx - ax) / (by - ay):
            inside = not inside
    return inside


def _edge_distance(p: Point, polygon: Sequence[Point]) -> float:
    best = math.inf
    for (ax, ay), (bx, by) in zip(polygon, [*polygon[1:], polygon[0]], strict=True):
        length2 = (bx - ax) ** 2 + (by - ay) ** 2
        t = 0.0 if length2 == 0 else ((p[0] - ax) * (bx - ax) + (p[1] - ay) * (by - ay)) / length2
        t = min(1.0, max(0.0, t))
        best = min(best, math.hypot(p[0] - ax - t * (bx - ax), p[1] - ay - t * (by - ay)))
    return best


def label_point(polygon: Sequence[Point], grid: int = 24) -> Point:
    """Where a polygon's name goes: of a ``grid`` x ``grid`` sampling of its bounding
    box, the point inside it farthest from its edges (the vertices' mean may lie outside
    a concave shape), nearest the middle among those as deep; the mean where no sample
    is inside."""
    xs, ys = [p[0] for p in polygon], [p[1] for p in polygon]
    centre = _mean(polygon)
    best, best_score = centre, -math.inf
    for i in range(grid):
        for j in range(grid):
            p = (
                min(xs) + (i + 0.5) * (max(xs) - min(xs)) / grid,
                min(ys) + (j + 0.5) * (max(ys) - min(ys)) / grid,
            )
            if not _inside(p, polygon):
                continue
            # Of points as deep inside, the one nearest the middle (a rectangle's axis).
            score = _edge_distance(p, polygon) - 1e-3 * math.dist(p, centre)
            if score > best_score:
                best, best_score = p, score
    return best


def _octagon(
    pen: ImageDraw.ImageDraw, at: tuple[float, float], colour: Any, radius: float = 8.0
) -> None:
    """A stop sign: a filled octagon."""
    x, y = at
    corners = [
        (x + radius * math.cos(math.pi / 8 + k * math.pi / 4),
         y + radius * math.sin(math.pi / 8 + k * math.pi / 4))
        for k in range(8)
    ]  # fmt: skip
    pen.polygon(corners, fill=colour, outline=(255, 255, 255))


def _cross(pen: ImageDraw.ImageDraw, at: tuple[float, float], colour: Any, half: float = 7) -> None:
    x, y = at
    pen.line([x - half, y - half, x + half, y + half], fill=colour, width=3)
    pen.line([x - half, y + half, x + half, y - half], fill=colour, width=3)


def _scale_bar(pen: ImageDraw.ImageDraw, right: float, y: float, px_per_m: float) -> None:
    """A 1 m bar (2 m when 1 m is under 40 px) ending at ``right``, labelled."""
    metres = 1 if px_per_m >= 40 else 2
    left = right - metres * px_per_m
    pen.line([left, y, right, y], fill=(0, 0, 0), width=2)
    for end in (left, right):
        pen.line([end, y - 4, end, y + 4], fill=(0, 0, 0), width=2)
    label = f"{metres} m"
    pen.text((left - pen.textlength(label) - 6, y - 6), label, fill=(0, 0, 0))


def _pose_mark(
    pen: ImageDraw.ImageDraw, px: ToPixels, pose: Pose, colour: tuple[int, int, int]
) -> None:
    x, y = px((pose.x, pose.y))
    pen.ellipse([x - 6, y - 6, x + 6, y + 6], outline=colour, width=3)
    tip = px((pose.x + 0.3 * math.cos(pose.yaw_rad), pose.y + 0.3 * math.sin(pose.yaw_rad)))
    pen.line([(x, y), tip], fill=colour, width=3)


def picture_of(report: MissionReport, world: WorldMap, title: str) -> MissionPicture:
    """The picture of a mission: each executed plan's ghost, the reported trace, the
    drift stops, and where the rejected attempts collided."""
    ghosts = [
        [(s.pose.x, s.pose.y) for s in r.verdict.trajectory.samples]
        for r in report.runs
        if r.verdict
    ]
    return MissionPicture(
        world,
        report.goal,
        report.start,
        predicted=list(ghosts),
        actual=[(x, y) for r in report.runs for _, x, y in r.execution.trace],
        drift_stops=[(e.measured.x, e.measured.y) for e in report.drift_events],
        title=title,
        collisions=[
            (
                (a.verdict.collision.contact[0], a.verdict.collision.contact[1]),
                a.verdict.collision.obstacle_id,
            )
            for planning in report.plannings
            for a in planning.attempts
            if a.verdict.collision is not None
        ],
    )


def save(picture: MissionPicture, path: str | Path) -> Path:
    """Render and write a PNG; returns the path."""
    out = Path(path)
    draw(picture).save(out, format="PNG")
    return out


def fresh_path(stem: str, directory: Path, wall_s: float) -> Path:
    """``<directory>/<stem>-YYYYmmdd-HHMMSS.png`` for the local time ``wall_s``, with
    ``-2``, ``-3``, ... where that file exists: never overwrites another mission's."""
    name = f"{stem}-{time.strftime('%Y%m%d-%H%M%S', time.localtime(wall_s))}"
    path = directory / f"{name}.png"
    n = 2
    while path.exists():
        path = directory / f"{name}-{n}.png"
        n += 1
    return path
