"""The gate's verdict vocabulary, beside the plan schema (:mod:`firmware_proto.plan`):
the one definition that the gate (which gives verdicts) and the planner (which reads
them over HTTP and may not import the gate) share."""

from __future__ import annotations

from typing import Final

__all__ = ["FAILURE_TYPES"]

FAILURE_TYPES: Final = (
    "collision",
    "start_in_collision",
    "stalled",
    "goal_not_reached",
    "yaw_not_reached",
)
"""Values of a verdict's ``failure_type`` when a plan is rejected, in order of
precedence:

- ``collision``: the margin-inflated footprint touched an obstacle or a wall; playback
  stopped at the first contact (``collision`` says where and with what);
- ``start_in_collision``: the start pose already touches something; no plan from this
  pose can be approved, so repairing the plan will not help;
- ``stalled``: a step made no progress (a side that should turn did not) or ran past
  its time limit (``stall`` says which and why);
- ``goal_not_reached``: the plan ran to the end but the final position is farther from
  the goal than the position tolerance;
- ``yaw_not_reached``: the position is within tolerance but the final yaw is not.
"""
