"""The planner's pose, and how a map's poses become one.

Frames and units are those of the maps and plans (docs/architecture.md, Contracts):
metres in the map frame, x east, y north; yaw counter-clockwise from +x, in degrees
where a name says ``_deg`` and radians where it says ``_rad``. The geometry helpers
(angles, segments, polygons) are :mod:`firmware_proto.geometry`'s; ``Point`` and
``wrap_deg`` are named here too for the modules that import them from here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from firmware_proto.geometry import Point, wrap_deg
from firmware_proto.plan import Goal

if TYPE_CHECKING:
    from firmware_proto.worldmap import MapGoal, MapPose

__all__ = ["Point", "Pose", "pose_in_map", "wrap_deg"]


@dataclass(frozen=True)
class Pose:
    """A planar pose: metres in the map frame, yaw in degrees counter-clockwise from +x
    (the shape of a plan's ``goal`` and of the gate's poses)."""

    x: float
    y: float
    yaw_deg: float

    @property
    def yaw_rad(self) -> float:
        """The yaw in radians."""
        return math.radians(self.yaw_deg)

    @property
    def xy(self) -> Point:
        """The position as a point."""
        return (self.x, self.y)

    def is_finite(self) -> bool:
        """Whether every coordinate is a finite number."""
        return all(math.isfinite(v) for v in (self.x, self.y, self.yaw_deg))

    def distance_to(self, point: Point) -> float:
        """Euclidean distance to ``point``, m."""
        return math.hypot(point[0] - self.x, point[1] - self.y)

    def to_goal(self) -> Goal:
        """The pose as a plan goal."""
        return Goal(self.x, self.y, self.yaw_deg)

    @classmethod
    def from_goal(cls, goal: Goal) -> Pose:
        """A plan goal as a pose."""
        return cls(goal.x, goal.y, goal.yaw_deg)

    def __str__(self) -> str:
        return f"({self.x:.3f}, {self.y:.3f}, {self.yaw_deg:.1f} deg)"


def pose_in_map(where: MapPose | MapGoal) -> Pose:
    """A map's start pose or one of its goals as a planner pose."""
    return Pose(where.x, where.y, where.yaw_deg)
