"""The planner's pose, and a map's poses as planner poses."""

from __future__ import annotations

import math

import pytest

from firmware_proto.worldmap import load_map
from planner.geometry import Pose, pose_in_map


def test_pose_round_trip_and_finiteness() -> None:
    p = Pose(1.0, 2.0, 90.0)
    assert Pose.from_goal(p.to_goal()) == p
    assert p.yaw_rad == pytest.approx(math.pi / 2)
    assert not Pose(1.0, math.nan, 0.0).is_finite()


def test_a_maps_start_and_goals_as_poses() -> None:
    lab = load_map("lab")
    assert pose_in_map(lab.start) == Pose(lab.start.x, lab.start.y, lab.start.yaw_deg)
    goal = lab.goal("behind_table")
    assert pose_in_map(goal) == Pose(goal.x, goal.y, goal.yaw_deg)
