"""The planar pose every part shares: a plan's goal, a map's start, the gate's poses, the
planner's. Metres in the map frame (x east, y north), yaw in degrees counter-clockwise
from +x. (The twin's ``Pose2D`` uses radians, as pymunk and the wire's POSE do; it is
converted at the gate's boundary.) Pure: no I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, NamedTuple

from firmware_proto.model.jsoncodec import spec

__all__ = ["Point", "Pose", "frame_in"]


class Point(NamedTuple):
    """A point in the map frame, metres. A tuple, so ``math.dist`` and unpacking work."""

    x: float
    y: float

    def to_dict(self) -> dict[str, Any]:
        """``{"x": ..., "y": ...}``."""
        return {"x": self.x, "y": self.y}


@dataclass(frozen=True)
class Pose:
    """A planar pose: metres in the map frame, yaw in degrees counter-clockwise from +x
    (the shape of a plan's ``goal``, a map's ``start`` and every pose in a verdict)."""

    x: float = field(metadata=spec("Metres east in the map frame."))
    y: float = field(metadata=spec("Metres north in the map frame."))
    yaw_deg: float = field(metadata=spec("Degrees counter-clockwise from +x."))

    @property
    def yaw_rad(self) -> float:
        """The yaw in radians."""
        return math.radians(self.yaw_deg)

    @property
    def xy(self) -> Point:
        """The position as a point."""
        return Point(self.x, self.y)

    def is_finite(self) -> bool:
        """Whether every coordinate is a finite number."""
        return all(math.isfinite(v) for v in (self.x, self.y, self.yaw_deg))

    def distance_to(self, point: tuple[float, float]) -> float:
        """Euclidean distance to ``point``, m."""
        return math.hypot(point[0] - self.x, point[1] - self.y)

    def to_dict(self) -> dict[str, Any]:
        """``{"x": ..., "y": ..., "yaw_deg": ...}`` (the JSON of plans, maps and verdicts)."""
        return {"x": self.x, "y": self.y, "yaw_deg": self.yaw_deg}

    def __str__(self) -> str:
        return f"({self.x:.3f}, {self.y:.3f}, {self.yaw_deg:.1f} deg)"


def frame_in(body_in_parent: Pose, body_in_frame: Pose) -> Pose:
    """Where a frame lies in a parent frame, given one body's pose in each: ``map -> odom``
    (REP 105) from the rover's pose in the map (a ground-seeing POSE) and in ``odom``, so
    that composed with ``odom -> base_link`` it gives the map pose. Metres, degrees."""
    yaw = math.radians(body_in_parent.yaw_deg - body_in_frame.yaw_deg)
    c, s = math.cos(yaw), math.sin(yaw)
    return Pose(
        body_in_parent.x - (c * body_in_frame.x - s * body_in_frame.y),
        body_in_parent.y - (s * body_in_frame.x + c * body_in_frame.y),
        math.degrees(math.atan2(math.sin(yaw), math.cos(yaw))),
    )
