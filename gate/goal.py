"""The final pose against the goal: signed longitudinal, lateral and yaw errors.

Pure arithmetic, no twin. The longitudinal error is measured along the *approach
heading*: the heading of the last step that translated the rover (FWD as is, REV
reversed), because that is the step a goal repair lengthens (undershoot) or shortens
(overshoot). A plan that never drives is measured along the bearing from its start to
the goal (or the start heading when the goal is the start).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from firmware_proto.model.geometry import wrap_deg
from firmware_proto.wire.messages import Command

__all__ = ["GoalError", "approach_heading_rad", "goal_error"]

_EPS_M = 1e-9


@dataclass(frozen=True)
class GoalError:
    """Goal minus final pose.

    Attributes:
        longitudinal_m: along the approach heading; positive = short of the goal.
        lateral_m: across it; positive = the goal lies to the left.
        distance_m: Euclidean distance, >= 0.
        yaw_deg: goal yaw minus final yaw, wrapped to ``[-180, 180)``.
        approach_heading_rad: the heading used, rad.
    """

    longitudinal_m: float
    lateral_m: float
    distance_m: float
    yaw_deg: float
    approach_heading_rad: float


def approach_heading_rad(
    step_commands: Sequence[int],
    step_start_yaws_rad: Sequence[float],
    start: tuple[float, float, float],
    goal: tuple[float, float],
) -> float:
    """The heading the longitudinal error is measured along, rad.

    Args:
        step_commands: command codes of the steps played, in order.
        step_start_yaws_rad: the rover's yaw when each of them started.
        start: start pose ``(x, y, yaw_rad)``.
        goal: goal position ``(x, y)``.
    """
    for command, yaw in zip(reversed(step_commands), reversed(step_start_yaws_rad), strict=True):
        if command == Command.FWD:
            return yaw
        if command == Command.REV:
            return yaw + math.pi
    dx, dy = goal[0] - start[0], goal[1] - start[1]
    if math.hypot(dx, dy) > _EPS_M:
        return math.atan2(dy, dx)
    return start[2]


def goal_error(
    final: tuple[float, float, float], goal: tuple[float, float, float], heading_rad: float
) -> GoalError:
    """Errors of ``final`` ``(x, y, yaw_deg)`` against ``goal`` ``(x, y, yaw_deg)``."""
    ex, ey = goal[0] - final[0], goal[1] - final[1]
    c, s = math.cos(heading_rad), math.sin(heading_rad)
    return GoalError(
        longitudinal_m=ex * c + ey * s,
        lateral_m=-ex * s + ey * c,
        distance_m=math.hypot(ex, ey),
        yaw_deg=wrap_deg(goal[2] - final[2]),
        approach_heading_rad=heading_rad,
    )
