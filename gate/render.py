"""Top-down picture of a verdict: map, planned path, predicted trajectory, footprint.

Only imported when a request asks for a picture (``render=1``), so Pillow costs nothing
otherwise. The picture is deterministic (same verdict, same bytes).

What is drawn, north up, and in which colours: docs/gate.md (the paragraph on
``render=1``); below the map, a legend of those colours and a 1 m scale bar.
"""

from __future__ import annotations

import io
import math

from PIL import Image, ImageDraw

from emulator.drive import yaw_for_turn_units
from firmware_proto.model.plan import Plan
from firmware_proto.model.pose import Pose
from firmware_proto.model.rover import RoverDescription
from firmware_proto.model.verdict import Verdict
from firmware_proto.model.worldmap import CircleObstacle, PolygonObstacle, WorldMap

__all__ = ["LEGEND_PX", "MAX_IMAGE_PX", "planned_path", "render_png"]

MAX_IMAGE_PX = 1000
"""Longest side of the picture, pixels (at most 100 px per metre)."""

_PAD_PX = 24
LEGEND_PX = 20
"""Height of the legend band below the map, pixels."""
_BACKGROUND = (250, 250, 247)
_WALL = (60, 60, 60)
_OBSTACLE = (150, 150, 150)
_REGION = (236, 214, 160)
_PLANNED = (40, 90, 200)
_PREDICTED = (235, 120, 20)
_START = (30, 150, 60)
_GOAL = (130, 50, 160)
_FAIL = (210, 30, 30)
_TEXT = (20, 20, 20)


def planned_path(rover: RoverDescription, start: Pose, plan: Plan) -> list[tuple[float, float]]:
    """Positions along the plan with ideal kinematics (no slip), from ``start``: one point
    per step end (turns do not move the point)."""
    x, y, yaw = start.x, start.y, math.radians(start.yaw_deg)
    points = [(x, y)]
    for step in plan.commands:
        if step.command in ("FWD", "REV"):
            d = rover.units_to_m(step.distance) * (1.0 if step.command == "FWD" else -1.0)
            if step.speed > 0:
                x, y = x + d * math.cos(yaw), y + d * math.sin(yaw)
        elif step.command in ("LEFT", "RIGHT") and step.speed > 0:
            turn = yaw_for_turn_units(rover, step.distance)
            yaw += turn if step.command == "LEFT" else -turn
        points.append((x, y))
    return points


def _footprint(
    rover: RoverDescription, pose: Pose, inflate_m: float = 0.0
) -> list[tuple[float, float]]:
    half_l = rover.geometry.chassis_length_m / 2.0 + inflate_m
    half_w = rover.geometry.chassis_width_m / 2.0 + inflate_m
    c, s = math.cos(math.radians(pose.yaw_deg)), math.sin(math.radians(pose.yaw_deg))
    corners = [(half_l, half_w), (-half_l, half_w), (-half_l, -half_w), (half_l, -half_w)]
    return [(pose.x + c * px - s * py, pose.y + s * px + c * py) for px, py in corners]


def _legend(draw: ImageDraw.ImageDraw, top: float, width: int, scale: float) -> None:
    """The legend band below the map (``top``: its upper edge) and a scale bar."""
    entries = [
        ("planned", _PLANNED),
        ("predicted (twin)", _PREDICTED),
        ("start / approved end", _START),
        ("goal and tolerance", _GOAL),
        ("collision", _FAIL),
        ("obstacle", _OBSTACLE),
        ("sand", _REGION),
    ]
    x, y = float(_PAD_PX), top + 2
    for text, colour in entries:
        if colour == _FAIL:
            draw.line([x, y + 2, x + 10, y + 12], fill=colour, width=3)
            draw.line([x, y + 12, x + 10, y + 2], fill=colour, width=3)
        else:
            draw.rectangle([x, y + 3, x + 10, y + 11], fill=colour)
        draw.text((x + 14, y + 1), text, fill=_TEXT)
        x += 14 + draw.textlength(text) + 14
    right = width - _PAD_PX
    left = right - scale  # 1 m
    bar_y = y + 7
    draw.line([left, bar_y, right, bar_y], fill=_TEXT, width=2)
    for end in (left, right):
        draw.line([end, bar_y - 4, end, bar_y + 4], fill=_TEXT, width=2)
    draw.text((left - draw.textlength("1 m") - 6, y + 1), "1 m", fill=_TEXT)


def render_png(world: WorldMap, rover: RoverDescription, plan: Plan, verdict: Verdict) -> bytes:
    """The picture of ``verdict`` (for ``plan`` on ``world``) as PNG bytes."""
    b = world.bounds
    scale = min(100.0, (MAX_IMAGE_PX - 2 * _PAD_PX) / max(b.width_m, b.height_m))
    width = round(b.width_m * scale) + 2 * _PAD_PX
    height = round(b.height_m * scale) + 2 * _PAD_PX

    def px(x: float, y: float) -> tuple[float, float]:
        return (_PAD_PX + (x - b.min_x) * scale, height - _PAD_PX - (y - b.min_y) * scale)

    image = Image.new("RGB", (width, height + LEGEND_PX), _BACKGROUND)
    draw = ImageDraw.Draw(image)
    for region in world.traction_regions:
        draw.polygon([px(*p) for p in region.polygon], fill=_REGION)
    for o in world.obstacles:
        if isinstance(o, PolygonObstacle):
            draw.polygon([px(*p) for p in o.points], fill=_OBSTACLE, outline=_WALL)
        elif isinstance(o, CircleObstacle):
            cx, cy = px(*o.center)
            r = o.radius_m * scale
            draw.ellipse((cx - r, cy - r, cx + r, cy + r), fill=_OBSTACLE, outline=_WALL)
        else:
            thickness = max(2, round(2 * o.radius_m * scale))
            draw.line([px(*o.a), px(*o.b)], fill=_OBSTACLE, width=thickness)
    draw.rectangle((*px(b.min_x, b.max_y), *px(b.max_x, b.min_y)), outline=_WALL, width=3)

    path = [px(*p) for p in planned_path(rover, verdict.start_pose, plan)]
    if len(path) > 1:
        draw.line(path, fill=_PLANNED, width=2)
    for p in path:
        draw.ellipse((p[0] - 3, p[1] - 3, p[0] + 3, p[1] + 3), outline=_PLANNED)
    trail = [px(s.pose.x, s.pose.y) for s in verdict.trajectory.samples]
    if len(trail) > 1:
        draw.line(trail, fill=_PREDICTED, width=3)

    draw.polygon([px(*p) for p in _footprint(rover, verdict.start_pose)], outline=_START)
    goal = verdict.goal
    gx, gy = px(goal.x, goal.y)
    tol = verdict.tolerances.position_m * scale
    draw.ellipse((gx - tol, gy - tol, gx + tol, gy + tol), outline=_GOAL, width=2)
    yaw = math.radians(goal.yaw_deg)
    draw.line(
        [(gx, gy), (gx + 0.4 * scale * math.cos(yaw), gy - 0.4 * scale * math.sin(yaw))],
        fill=_GOAL,
        width=2,
    )

    if verdict.collision is not None:
        c = verdict.collision
        margin = verdict.tolerances.safety_margin_m
        if margin > 0:
            draw.polygon([px(*p) for p in _footprint(rover, c.pose, margin)], outline=_FAIL)
        draw.polygon([px(*p) for p in _footprint(rover, c.pose)], outline=_FAIL, width=3)
        cx, cy = px(c.contact.x, c.contact.y)
        draw.line([(cx - 7, cy - 7), (cx + 7, cy + 7)], fill=_FAIL, width=3)
        draw.line([(cx - 7, cy + 7), (cx + 7, cy - 7)], fill=_FAIL, width=3)
    else:
        colour = _START if verdict.approved else _PREDICTED
        draw.polygon(
            [px(*p) for p in _footprint(rover, verdict.final_pose)], outline=colour, width=3
        )

    status = "APPROVED" if verdict.approved else f"REJECTED: {verdict.failure_type}"
    draw.text((_PAD_PX, 4), f"{world.name}  {status}", fill=_TEXT)
    _legend(draw, height, width, scale)
    buffer = io.BytesIO()
    image.save(buffer, format="PNG", optimize=False)
    return buffer.getvalue()
