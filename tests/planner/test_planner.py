"""The heuristic planner: schema-valid plans within the limits, and how routes
decompose into turns and drives (no gate needed)."""

from __future__ import annotations

import itertools
import math
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_proto.model.geometry import wrap_deg
from firmware_proto.model.plan import Plan, validate_plan
from firmware_proto.model.pose import Pose
from firmware_proto.model.rover import RoverDescription
from firmware_proto.model.worldmap import WorldMap
from planner.errors import (
    GoalInObstacleError,
    InvalidPoseError,
    OutOfBoundsError,
    PlannerError,
    PlanTooLongError,
)
from planner.plan.planner import (
    CORRECTION,
    DRIVE,
    GOAL_TURN,
    NOOP,
    TURN,
    HeuristicLowLevelPlanner,
    LegPlan,
)

coord = st.floats(-40.0, 40.0, allow_nan=False)
yaw = st.floats(-720.0, 720.0, allow_nan=False)
poses = st.builds(Pose, coord, coord, yaw)


def check_leg(leg: LegPlan, rover: RoverDescription) -> None:
    """Every promise a leg's plan makes."""
    data = leg.plan.to_dict()
    assert validate_plan(data) == []
    assert Plan.from_dict(data) == leg.plan
    assert 1 <= len(leg.plan.commands) <= 12
    for step in leg.plan.commands:
        assert step.command in ("FWD", "LEFT", "RIGHT")
        assert 0 <= step.distance <= min(30000, rover.drive.max_distance)
        assert 0 <= step.speed <= min(60, rover.drive.max_speed)
        if step.distance or step.speed:
            assert step.distance > 0 and step.speed > 0
    assert [s.step for s in leg.steps] == list(leg.plan.commands)
    assert leg.wire() == [s.to_wire() for s in leg.plan.commands]


@given(start=poses, goal=poses)
@settings(max_examples=150)
def test_every_leg_is_schema_valid_and_within_limits(
    planner: HeuristicLowLevelPlanner, rover: RoverDescription, start: Pose, goal: Pose
) -> None:
    legs = planner.plan_mission(start, goal)
    for leg in legs:
        check_leg(leg, rover)
    for before, after in itertools.pairwise(legs):
        assert after.start == before.predicted_end
        assert not before.reaches_goal
        assert before.steps[-1].kind == DRIVE  # legs are cut after a drive
    last = legs[-1]
    assert last.reaches_goal
    assert last.goal == Pose(goal.x, goal.y, goal.yaw_deg)
    end = last.predicted_end
    assert math.dist(end.xy, goal.xy) < 0.006
    assert abs(wrap_deg(end.yaw_deg - goal.yaw_deg)) < planner.min_turn_deg + 0.01


@given(start=st.builds(Pose, st.floats(0.5, 11.5), st.floats(0.5, 7.5), yaw), goal=poses)
@settings(max_examples=50)
def test_legs_are_as_few_as_the_route_needs(
    planner: HeuristicLowLevelPlanner, start: Pose, goal: Pose
) -> None:
    steps = planner.steps_for(planner.route(start, goal))
    legs = planner.plan_mission(start, goal)
    assert len(legs) >= math.ceil(len(steps) / 12)
    if len(steps) <= 12:
        assert len(legs) == 1
        if steps:
            assert legs[0].steps == steps
        else:  # already there: a plan still holds one (no-op) step
            assert [s.kind for s in legs[0].steps] == [NOOP]


def test_turn_on_the_spot_left_and_right(
    planner: HeuristicLowLevelPlanner, rover: RoverDescription
) -> None:
    left = planner.plan(Pose(1, 1, 0), Pose(1, 1, 90))
    assert left.to_wire() == [(3, 20, rover.turn_units_for_yaw(math.pi / 2))]
    # 270 degrees to the left is 90 to the right: the shorter way.
    right = planner.plan(Pose(1, 1, 0), Pose(1, 1, 270))
    assert right.to_wire() == [(4, 20, rover.turn_units_for_yaw(math.pi / 2))]
    small = planner.plan(Pose(1, 1, 0), Pose(1, 1, -10))
    assert small.to_wire() == [(4, 10, rover.turn_units_for_yaw(math.radians(10)))]


def test_drive_splits_into_equal_steps_and_slows_into_the_goal(
    planner: HeuristicLowLevelPlanner,
) -> None:
    plan = planner.plan(Pose(0, 0, 0), Pose(3, 0, 0))
    assert plan.to_wire() == [(1, 60, 23000), (1, 60, 23000), (1, 30, 23000)]
    odd = planner.plan(Pose(0, 0, 0), Pose(2.0, 0, 0))  # 46000 units: two steps
    assert [s.distance for s in odd.commands] == [23000, 23000]
    uneven = planner.plan(Pose(0, 0, 0), Pose(1.5, 0, 0))  # 34500 units
    assert [s.distance for s in uneven.commands] == [17250, 17250]


def test_turn_drive_turn(planner: HeuristicLowLevelPlanner, rover: RoverDescription) -> None:
    leg = planner.plan_leg(planner.route(Pose(0, 0, 0), Pose(0, 2, 180)))
    assert [s.kind for s in leg.steps] == [TURN, DRIVE, DRIVE, GOAL_TURN]
    quarter = rover.turn_units_for_yaw(math.pi / 2)
    wire = leg.wire()
    assert wire[:3] == [(3, 20, quarter), (1, 60, 23000), (1, 30, 23000)]
    # The second turn makes up for the rounding of the first.
    assert wire[3][:2] == (3, 20)
    assert abs(wire[3][2] - quarter) <= 1
    assert leg.predicted_end.x == pytest.approx(0, abs=1e-3)
    assert leg.predicted_end.y == pytest.approx(2, abs=1e-4)


def test_half_turn_is_split(planner: HeuristicLowLevelPlanner, rover: RoverDescription) -> None:
    units = rover.turn_units_for_yaw(math.pi)
    assert units > 30000
    plan = planner.plan(Pose(0, 0, 0), Pose(0, 0, 180))
    assert [s.command for s in plan.commands] == ["RIGHT", "RIGHT"]
    assert sum(s.distance for s in plan.commands) == units
    assert max(s.distance for s in plan.commands) <= 30000


def test_waypoints(planner: HeuristicLowLevelPlanner) -> None:
    leg = planner.plan_leg(planner.route(Pose(0, 0, 0), Pose(1.6, 0, 0), [(0.8, 0.8)]))
    assert [s.step.command for s in leg.steps] == ["LEFT", "FWD", "RIGHT", "FWD", "LEFT"]
    assert [s.segment for s in leg.steps] == [0, 0, 1, 1, 1]
    assert [s.kind for s in leg.steps] == [TURN, DRIVE, TURN, DRIVE, GOAL_TURN]
    assert leg.steps[1].end_pose.x == pytest.approx(0.8, abs=1e-3)
    assert leg.steps[1].end_pose.y == pytest.approx(0.8, abs=1e-3)


def test_negligible_moves_are_skipped(planner: HeuristicLowLevelPlanner) -> None:
    still = planner.plan_leg(planner.route(Pose(1, 1, 30), Pose(1.002, 1, 30.1)))
    assert [s.kind for s in still.steps] == [NOOP]
    assert still.wire() == [(1, 0, 0)]
    # A 0.1 degree misalignment over 10 cm is skipped; over 10 m it is not.
    short = planner.plan(Pose(0, 0, 0.1), Pose(0.1, 0, 0.1))
    assert [s.command for s in short.commands] == ["FWD"]
    far = planner.plan(Pose(0, 0, 0.1), Pose(10, 0, 0.1))
    assert far.commands[0].command == "RIGHT"


def test_long_routes_become_legs(planner: HeuristicLowLevelPlanner) -> None:
    start, goal = Pose(0, 0, 0), Pose(20, 0, 90)
    with pytest.raises(PlanTooLongError) as err:
        planner.plan(start, goal)
    assert err.value.steps == 17
    assert isinstance(err.value, PlannerError)
    legs = planner.plan_mission(start, goal)
    assert [len(leg.steps) for leg in legs] == [12, 5]
    assert legs[0].goal == legs[0].predicted_end
    # 460000 units in 16 equal drives of 28750; the first leg holds 12 of them.
    assert [s.distance for s in legs[0].plan.commands] == [28750] * 12
    assert legs[0].goal.x == pytest.approx(15.0, abs=1e-5)


def test_leg_cut_keeps_the_waypoints_ahead(planner: HeuristicLowLevelPlanner) -> None:
    route = planner.route(Pose(0, 0, 0), Pose(0, 0, 0), [(20, 0), (20, 5)])
    leg = planner.plan_leg(route)
    assert not leg.reaches_goal
    assert leg.remaining == ((20.0, 0.0), (20.0, 5.0))  # still on the first segment
    short = planner.plan_leg(planner.route(Pose(0, 0, 0), Pose(0, 0, 0), [(10, 0), (10, 5)]))
    assert short.remaining == ((10.0, 5.0),)  # the first waypoint is behind
    second = planner.plan_leg(planner.route(leg.predicted_end, route.goal, leg.remaining))
    assert second.steps[0].kind in (DRIVE, TURN)


def test_bad_input_is_refused(
    planner: HeuristicLowLevelPlanner, worlds: dict[str, WorldMap]
) -> None:
    lab = worlds["lab"]
    for bad in (math.nan, math.inf, -math.inf):
        with pytest.raises(InvalidPoseError, match="goal: coordinates must be finite"):
            planner.plan(Pose(1, 1, 0), Pose(bad, 1, 0))
        with pytest.raises(InvalidPoseError, match="start"):
            planner.plan(Pose(1, 1, bad), Pose(2, 1, 0))
    with pytest.raises(ValueError, match="via"):
        planner.route(Pose(1, 1, 0), Pose(2, 2, 0), [(math.nan, 0)])
    with pytest.raises(OutOfBoundsError, match=r"goal: \(9, 3\) lies outside map 'lab'"):
        planner.route(lab.start, Pose(9, 3, 0), world=lab)
    with pytest.raises(OutOfBoundsError, match="via"):
        planner.route(lab.start, Pose(5, 1, 0), [(3, -1)], world=lab)
    with pytest.raises(GoalInObstacleError) as err:
        planner.route(lab.start, Pose(4.0, 3.0, 0), world=lab)
    assert err.value.obstacle_id == "table"
    assert "inside obstacle 'table'" in str(err.value)
    with pytest.raises(GoalInObstacleError, match="too close to the wall"):
        planner.route(lab.start, Pose(0.1, 3.0, 0), world=lab)


def test_a_planner_with_a_map_checks_goals(
    rover: RoverDescription, worlds: dict[str, WorldMap]
) -> None:
    p = HeuristicLowLevelPlanner(rover, world=worlds["lab"])
    with pytest.raises(GoalInObstacleError):
        p.plan(Pose(1.2, 3, 0), Pose(5.6, 1.4, 0))  # the pillar
    assert p.plan(Pose(1.2, 3, 0), Pose(2.2, 3, 0)).commands


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"drive_speed": 0}, "drive_speed"),
        ({"turn_speed": 61}, "turn_speed"),
        ({"max_step_units": 30001}, "max_step_units"),
        ({"max_steps": 13}, "max_steps"),
        ({"min_turn_deg": -1}, "min_turn_deg"),
    ],
)
def test_settings_are_checked(
    rover: RoverDescription, kwargs: dict[str, Any], message: str
) -> None:
    with pytest.raises(ValueError, match=message):
        HeuristicLowLevelPlanner(rover, **kwargs)


def test_smaller_step_limits_are_kept(rover: RoverDescription) -> None:
    p = HeuristicLowLevelPlanner(rover, max_step_units=10000, max_steps=6)
    legs = p.plan_mission(Pose(0, 0, 0), Pose(5, 5, 0))
    assert all(len(leg.steps) <= 6 for leg in legs)
    assert all(s.distance <= 10000 for leg in legs for s in leg.plan.commands)


def test_make_leg_keeps_a_given_goal(planner: HeuristicLowLevelPlanner) -> None:
    leg = planner.plan_leg(planner.route(Pose(0, 0, 0), Pose(1, 0, 0)))
    moved = planner.make_leg(leg.route, leg.steps, reaches_goal=False, goal=Pose(5, 5, 5))
    assert moved.goal == Pose(5, 5, 5)
    assert CORRECTION not in [s.kind for s in moved.steps]
