"""The one pose: a plan's goal, a map's start and goals, the gate's and the planner's."""

from __future__ import annotations

import math

import pytest

from firmware_proto.model.plan import Goal, Plan
from firmware_proto.model.pose import Pose
from firmware_proto.model.worldmap import load_map


def test_pose_is_the_plans_goal_and_knows_its_finiteness() -> None:
    p = Pose(1.0, 2.0, 90.0)
    stop = {"command": "STOP", "speed": 0, "distance": 0}
    assert Goal is Pose
    assert Plan.from_dict({"goal": p.to_dict(), "commands": [stop]}).goal == p
    assert p.yaw_rad == pytest.approx(math.pi / 2)
    assert not Pose(1.0, math.nan, 0.0).is_finite()


def test_a_maps_start_and_goals_are_poses() -> None:
    lab = load_map("lab")
    assert isinstance(lab.start, Pose)
    goal = lab.goal("behind_table")
    assert goal.pose == Pose(goal.x, goal.y, goal.yaw_deg)
