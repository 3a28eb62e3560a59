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


def test_frame_in_composes_back_to_the_pose_it_came_from() -> None:
    """``map -> odom`` from one body pose in each frame: composed with ``odom ->
    base_link`` it gives the body's map pose again (what /tf's tree must do)."""
    import math
    import random

    from firmware_proto.model.pose import Pose, frame_in

    rng = random.Random(41)
    for _ in range(200):
        in_map = Pose(rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(-180, 180))
        in_odom = Pose(rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(-180, 180))
        odom = frame_in(in_map, in_odom)
        c, s = math.cos(odom.yaw_rad), math.sin(odom.yaw_rad)
        x = odom.x + c * in_odom.x - s * in_odom.y
        y = odom.y + s * in_odom.x + c * in_odom.y
        yaw = (odom.yaw_deg + in_odom.yaw_deg - in_map.yaw_deg + 180.0) % 360.0 - 180.0
        assert math.hypot(x - in_map.x, y - in_map.y) < 1e-9 and abs(yaw) < 1e-9
        assert -180.0 <= odom.yaw_deg <= 180.0
