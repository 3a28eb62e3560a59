"""The map and the gate's plans as ``visualization_msgs/MarkerArray``, for recordings
that Foxglove or RViz draws (frame ``map``).

- :func:`map_markers`: the map's bounds (a line strip), each obstacle (circles as
  cylinders, segments and polygons as line strips) with its name as text, the start and
  the goal as arrows with their names;
- :func:`plan_markers`: each attempt of a planning, its predicted trajectory as a line
  strip (green approved, red rejected) and, for a collision, a red sphere where it hit
  with the obstacle's name.

Pure: builds generated ROS 2 messages (``visualization_msgs`` from the ROS 2 message
wheels), publishes nothing.
"""

from __future__ import annotations

import importlib
import math
from collections.abc import Sequence
from typing import Any

from firmware_proto.model.pose import Pose
from firmware_proto.model.worldmap import WorldMap
from planner.plan.orchestrator import MissionResult

__all__ = ["MAP_NS", "PLAN_NS", "map_markers", "plan_markers"]

MAP_NS = "map"
PLAN_NS = "plan"

_ARROW, _CYLINDER, _SPHERE, _LINE_STRIP, _TEXT = 0, 3, 2, 4, 9
_GREY = (0.55, 0.55, 0.6, 1.0)
_WALL = (0.25, 0.25, 0.25, 1.0)
_TEXT_COLOUR = (0.1, 0.1, 0.1, 1.0)
_START = (0.0, 0.0, 0.0, 1.0)
_GOAL = (0.12, 0.6, 0.25, 1.0)
_APPROVED = (0.2, 0.5, 0.9, 1.0)
_REJECTED = (0.85, 0.15, 0.15, 1.0)


def _msgs() -> Any:
    return importlib.import_module("visualization_msgs.msg")


def _geometry() -> Any:
    return importlib.import_module("geometry_msgs.msg")


def _marker(
    ns: str, ident: int, kind: int, stamp: Any, colour: tuple[float, float, float, float]
) -> Any:
    vis, geo = _msgs(), _geometry()
    marker = vis.Marker()
    marker.header.frame_id = "map"
    marker.header.stamp = stamp
    marker.ns, marker.id, marker.type, marker.action = ns, ident, kind, 0
    marker.pose.orientation = geo.Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)
    marker.color.r, marker.color.g, marker.color.b, marker.color.a = colour
    return marker


def _strip(
    ns: str,
    ident: int,
    stamp: Any,
    points: Sequence[tuple[float, float]],
    colour: tuple[float, float, float, float],
    width_m: float,
) -> Any:
    geo = _geometry()
    marker = _marker(ns, ident, _LINE_STRIP, stamp, colour)
    marker.scale.x = width_m
    marker.points = [geo.Point(x=float(x), y=float(y), z=0.0) for x, y in points]
    return marker


def _text(ns: str, ident: int, stamp: Any, at: tuple[float, float], text: str) -> Any:
    marker = _marker(ns, ident, _TEXT, stamp, _TEXT_COLOUR)
    marker.pose.position.x, marker.pose.position.y, marker.pose.position.z = at[0], at[1], 0.4
    marker.scale.z = 0.2
    marker.text = text
    return marker


def _arrow(ns: str, ident: int, stamp: Any, pose: Pose, colour: Any) -> Any:
    marker = _marker(ns, ident, _ARROW, stamp, colour)
    marker.pose.position.x, marker.pose.position.y = pose.x, pose.y
    half = math.radians(pose.yaw_deg) / 2.0
    marker.pose.orientation.z, marker.pose.orientation.w = math.sin(half), math.cos(half)
    marker.scale.x, marker.scale.y, marker.scale.z = 0.4, 0.08, 0.08
    return marker


def map_markers(world: WorldMap, goal: Pose | None, stamp: Any) -> Any:
    """The map as a ``MarkerArray`` stamped ``stamp``."""
    b = world.bounds
    out: list[Any] = [
        _strip(
            MAP_NS,
            0,
            stamp,
            [(b.min_x, b.min_y), (b.max_x, b.min_y), (b.max_x, b.max_y), (b.min_x, b.max_y),
             (b.min_x, b.min_y)],
            _WALL,
            0.05,
        )
    ]  # fmt: skip
    ident = 1
    for ob in world.obstacles:
        pts = [(float(p[0]), float(p[1])) for p in ob.points]
        if ob.kind == "circle":
            marker = _marker(MAP_NS, ident, _CYLINDER, stamp, _GREY)
            marker.pose.position.x, marker.pose.position.y = pts[0]
            marker.scale.x = marker.scale.y = 2.0 * ob.radius_m
            marker.scale.z = 0.3
        elif ob.kind == "segment":
            marker = _strip(MAP_NS, ident, stamp, pts, _GREY, max(0.02, 2.0 * ob.radius_m))
        else:
            marker = _strip(MAP_NS, ident, stamp, [*pts, pts[0]], _GREY, 0.04)
        out.append(marker)
        cx = sum(x for x, _ in pts) / len(pts)
        cy = sum(y for _, y in pts) / len(pts)
        out.append(_text(MAP_NS, ident + 1, stamp, (cx, cy), ob.id))
        ident += 2
    out.append(_arrow(MAP_NS, ident, stamp, world.start, _START))
    out.append(_text(MAP_NS, ident + 1, stamp, (world.start.x, world.start.y), "start"))
    ident += 2
    if goal is not None:
        out.append(_arrow(MAP_NS, ident, stamp, goal, _GOAL))
        out.append(_text(MAP_NS, ident + 1, stamp, (goal.x, goal.y), "goal"))
    return _msgs().MarkerArray(markers=out)


def plan_markers(mission: MissionResult, planning: int, stamp: Any) -> Any:
    """Each attempt of one planning (numbered ``planning`` from 1) as markers: its
    predicted trajectory, and where it collided."""
    geo = _geometry()
    out: list[Any] = []
    ns = f"{PLAN_NS}-{planning}"
    for attempt in mission.attempts:
        verdict = attempt.verdict
        colour = _APPROVED if verdict.approved else _REJECTED
        samples = [(s.pose.x, s.pose.y) for s in verdict.trajectory.samples]
        base = 10 * attempt.index
        if len(samples) > 1:
            out.append(_strip(ns, base, stamp, samples, colour, 0.03))
        collision = verdict.collision
        if collision is not None:
            hit = _marker(ns, base + 1, _SPHERE, stamp, _REJECTED)
            hit.pose.position = geo.Point(
                x=float(collision.contact[0]), y=float(collision.contact[1]), z=0.0
            )
            hit.scale.x = hit.scale.y = hit.scale.z = 0.15
            out.append(hit)
            out.append(
                _text(
                    ns,
                    base + 2,
                    stamp,
                    (collision.contact[0], collision.contact[1]),
                    f"attempt {attempt.index + 1}: collision with {collision.obstacle_id}",
                )
            )
    return _msgs().MarkerArray(markers=out)
