"""The orchestrator against the real gate: approval, dogleg, goal, yaw and approach
repairs, giving up, bad input, missions."""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from firmware_proto.model.plan import PlanStep
from firmware_proto.model.pose import Pose
from firmware_proto.model.verdict import StallReport
from firmware_proto.model.worldmap import WorldMap
from gate.server import GateServer
from planner.errors import (
    GoalInObstacleError,
    InvalidPoseError,
    OutOfBoundsError,
    RepairError,
    UnreachableGoalError,
)
from planner.plan.gate_client import GateClient, GateOptions
from planner.plan.orchestrator import PlannerOrchestrator
from planner.plan.planner import DRIVE, HeuristicLowLevelPlanner, LegPlan
from planner.plan.repairs import PlannerContext, RepairSettings, stall_repair
from tests.planner.conftest import ring_map, slot_map, start_gate

Make = Callable[..., PlannerOrchestrator]
BLIND = RepairSettings(map_aware=False)


def test_open_field_goal_is_approved_first_try(orchestrator: Make, client: GateClient) -> None:
    orch = orchestrator("scn01")
    result = orch.plan(Pose(4.0, 3.0, 45.0))
    assert result.approved
    assert result.reaches_goal
    assert result.repair_cycles == 0
    assert [a.repair_name for a in result.attempts] == ["initial"]
    assert result.plan is result.attempts[0].plan
    assert result.verdict.approved
    assert result.reason == ""
    assert result.raise_for_status() is result
    assert client.requests == 2  # the map (start pose, checks), then one validation


def test_dogleg_around_the_table(orchestrator: Make) -> None:
    orch = orchestrator("lab")
    goal = orch.world.goal("behind_table").pose
    result = orch.plan(goal)
    assert result.approved
    first, last = result.attempts[0], result.attempts[-1]
    assert first.verdict.failure_type == "collision"
    assert first.verdict.collision is not None
    assert first.verdict.collision.obstacle_id == "table"
    assert result.previous_failures[0].obstacle_id == "table"
    assert result.previous_failures[0].segment == 0
    assert last.repair_name == "dogleg"
    assert last.repair is not None and last.repair.detour is not None
    assert last.repair.detour.obstacle_id == "table"
    assert last.repair.detour.screened
    assert last.leg.route.waypoints  # the detour
    assert result.repair_cycles == 1
    assert math.dist(last.verdict.final_pose.xy, goal.xy) <= last.verdict.tolerances.position_m


def test_thesis_dogleg_without_the_map(orchestrator: Make) -> None:
    """The thesis's blind dogleg (midpoint, side away from the contact, alternating,
    delta growing) gets around scn01's single rock."""
    orch = orchestrator("scn01", repair_settings=BLIND)
    goal = orch.world.goal("behind_rock").pose
    result = orch.plan(goal)
    assert result.approved
    assert result.attempts[0].verdict.failure_type == "collision"
    doglegs = [a.repair.detour for a in result.attempts if a.repair and a.repair.detour]
    assert doglegs
    first = doglegs[0]
    assert first.method == "dogleg"
    assert not first.screened
    assert first.offset_m == pytest.approx(1.0)
    # The waypoint is the thesis's: mid of the segment, side * delta off its bearing.
    (a, b), (w,) = first.segment, first.points
    bearing = math.atan2(b[1] - a[1], b[0] - a[0])
    mid = ((a[0] + b[0]) / 2, (a[1] + b[1]) / 2)
    assert w[0] == pytest.approx(mid[0] + first.side * 1.0 * math.sin(bearing), abs=1e-6)
    assert w[1] == pytest.approx(mid[1] - first.side * 1.0 * math.cos(bearing), abs=1e-6)


def shortened(
    planner: HeuristicLowLevelPlanner, leg: LegPlan, index: int, delta_units: int
) -> LegPlan:
    """``leg`` with step ``index`` longer by ``delta_units`` (shorter when negative)."""
    steps = list(leg.steps)
    ps = steps[index]
    steps[index] = dataclasses.replace(
        ps, step=dataclasses.replace(ps.step, distance=ps.step.distance + delta_units)
    )
    poses = planner.predict(leg.start, [s.step for s in steps])
    steps = [dataclasses.replace(s, end_pose=p) for s, p in zip(steps, poses, strict=True)]
    return planner.make_leg(leg.route, steps, reaches_goal=True)


@pytest.mark.parametrize(("delta_m", "sign"), [(-0.3, 1), (0.25, -1)])
def test_goal_repair_converges(
    orchestrator: Make, planner: HeuristicLowLevelPlanner, delta_m: float, sign: int
) -> None:
    """An undershoot (a drive cut short) gets a FWD appended; an overshoot gets the
    last drive shortened."""
    orch = orchestrator("scn01")
    route = planner.route(Pose(1.0, 4.0, 0.0), Pose(3.0, 4.0, 0.0))
    leg = planner.plan_leg(route)
    last_drive = max(i for i, s in enumerate(leg.steps) if s.kind == DRIVE)
    units = round(delta_m * planner.rover.drive.distance_units_per_m)
    result = orch.run_leg(shortened(planner, leg, last_drive, units))
    first = result.attempts[0].verdict
    assert first.failure_type == "goal_not_reached"
    assert sign * first.position_error_m == pytest.approx(abs(delta_m), abs=0.03)
    assert result.approved
    assert [a.repair_name for a in result.attempts] == ["initial", "goal_repair"]
    repaired = result.attempts[1].plan.commands
    before = leg.plan.commands
    if sign > 0:  # undershoot: one more FWD after the last drive, about 0.3 m long
        assert len(repaired) == len(before) + 1
        extra = repaired[last_drive + 1]
        assert extra.command == "FWD"
        assert extra.distance == pytest.approx(-units, rel=0.1)
    else:  # overshoot: the last drive is shorter again
        assert len(repaired) == len(before)
        assert repaired[last_drive].distance < before[last_drive].distance + units


def test_yaw_repair(orchestrator: Make, planner: HeuristicLowLevelPlanner) -> None:
    orch = orchestrator("lab")
    leg = planner.plan_leg(planner.route(Pose(1.2, 3.0, 0.0), Pose(1.2, 3.0, 90.0)))
    short = shortened(planner, leg, 0, -leg.steps[0].step.distance // 5)
    result = orch.run_leg(short)
    assert result.attempts[0].verdict.failure_type == "yaw_not_reached"
    assert result.attempts[0].verdict.yaw_error_deg == pytest.approx(18.0, abs=1.0)
    assert result.approved
    assert result.attempts[1].repair_name == "yaw_repair"
    assert len(result.attempts[1].plan.commands) == 1  # the turn was rescaled


@pytest.fixture
def ring_gate(tmp_path: Path) -> Iterator[GateServer]:
    """A gate whose default map walls its goal in."""
    with start_gate(default_map=str(ring_map(tmp_path / "ring.json", (6.0, 6.0), 1.2))) as g:
        yield g


@pytest.mark.parametrize("settings", [RepairSettings(), BLIND], ids=["map", "blind"])
def test_gives_up_after_max_attempts_with_every_verdict(
    ring_gate: GateServer, planner: HeuristicLowLevelPlanner, settings: RepairSettings
) -> None:
    with GateClient(ring_gate.url) as client:
        orch = PlannerOrchestrator(planner, client, map_name="ring", repair_settings=settings)
        assert orch.max_attempts == planner.rover.safety.max_repair_attempts == 4
        result = orch.plan(Pose(6.0, 6.0, 0.0))
        assert not result.approved
        assert result.plan is None and result.leg is None
        assert len(result.attempts) == 4
        assert len(result.verdicts) == 4
        assert [v.failure_type for v in result.verdicts] == ["collision"] * 4
        assert all(
            v.collision and v.collision.obstacle_id.startswith("wall_") for v in result.verdicts
        )
        assert [f.attempt for f in result.previous_failures] == [0, 1, 2, 3]
        assert result.attempts[0].repair_name == "initial"
        assert "gave up after 4 attempts" in result.reason
        assert "collision" in result.reason
        with pytest.raises(UnreachableGoalError) as err:
            result.raise_for_status()
        assert err.value.result is result
        assert client.requests == 5  # the map, then four plans

        two = PlannerOrchestrator(planner, client, map_name="ring", max_attempts=2)
        assert len(two.plan(Pose(6.0, 6.0, 0.0)).attempts) == 2


def test_blind_doglegs_alternate_and_grow(
    ring_gate: GateServer, planner: HeuristicLowLevelPlanner
) -> None:
    with GateClient(ring_gate.url) as client:
        orch = PlannerOrchestrator(planner, client, map_name="ring", repair_settings=BLIND)
        result = orch.plan(Pose(6.0, 6.0, 0.0))
    detours = [a.repair.detour for a in result.attempts[1:] if a.repair and a.repair.detour]
    repeats = [d for d in detours if d.obstacle_id == detours[0].obstacle_id]
    assert len(repeats) >= 2
    assert [d.tries for d in repeats] == list(range(len(repeats)))
    assert [d.side for d in repeats] == [repeats[0].side * (-1) ** i for i in range(len(repeats))]
    assert [d.offset_m for d in repeats] == pytest.approx([1.5**i for i in range(len(repeats))])


def test_bad_goals_are_refused_before_the_gate(
    planner: HeuristicLowLevelPlanner, client: GateClient, worlds: dict[str, WorldMap]
) -> None:
    orch = PlannerOrchestrator(planner, client, map_name="lab", world=worlds["lab"])
    for goal in (Pose(math.nan, 3, 0), Pose(3, math.inf, 0), Pose(3, 3, -math.inf)):
        with pytest.raises(InvalidPoseError):
            orch.plan(goal)
    with pytest.raises(OutOfBoundsError):
        orch.plan(Pose(8.5, 3.0, 0.0))
    with pytest.raises(OutOfBoundsError):
        orch.plan_mission(Pose(3.0, 3.0, 0.0), start=Pose(-1.0, 3.0, 0.0))
    with pytest.raises(GoalInObstacleError, match="table"):
        orch.plan_mission(Pose(4.0, 3.0, 0.0))
    assert client.requests == 0


def test_start_in_collision_is_not_repaired(orchestrator: Make) -> None:
    orch = orchestrator("lab")
    result = orch.plan(Pose(2.0, 3.0, 0.0), start=Pose(3.3, 3.0, 0.0))
    assert not result.approved
    assert len(result.attempts) == 1
    assert result.verdict.failure_type == "start_in_collision"
    assert "start pose already touches" in result.reason


def test_repairs_can_be_replaced_or_removed(orchestrator: Make) -> None:
    def refuse(ctx: PlannerContext) -> object:
        raise RepairError(
            f"no detour today around {ctx.verdict.collision and ctx.verdict.collision.obstacle_id}"
        )

    goal = Pose(6.2, 3.0, 0.0)
    result = orchestrator("lab", repairs={"collision": refuse}).plan(goal)
    assert len(result.attempts) == 1
    assert "no detour today around table" in result.reason
    result = orchestrator("lab", repairs={"collision": None}).plan(goal)
    assert "no repair for failure type 'collision'" in result.reason


def test_mission_leg_by_leg(orchestrator: Make, client: GateClient) -> None:
    orch = orchestrator("scn01")
    start, goal = Pose(1.0, 1.0, 0.0), Pose(11.0, 7.0, 180.0)
    mission = orch.plan_mission(goal, start=start)
    assert mission.approved
    assert len(mission.legs) >= 2
    assert mission.start == start and mission.goal == goal
    assert all(len(p.commands) <= 12 for p in mission.plans)
    for before, after in itertools.pairwise(mission.legs):
        assert not before.reaches_goal
        assert after.attempts[0].leg.start == before.verdict.final_pose
    end = mission.predicted_end
    assert end is not None and math.dist(end.xy, goal.xy) <= 0.1
    assert len(mission.verdicts) == len(mission.plans) == len(mission.legs)
    assert mission.raise_for_status() is mission


def test_stall_repair_slows_a_turn_and_bypasses_a_drive(
    orchestrator: Make, planner: HeuristicLowLevelPlanner
) -> None:
    """A stall cannot be produced on the shipped maps (no traction that low), so the
    repair is fed a real verdict relabelled as a stall."""
    orch = orchestrator("scn01")
    leg = planner.plan_leg(planner.route(Pose(1.0, 4.0, 0.0), Pose(3.0, 5.0, 0.0)))
    verdict = orch.gate.validate(leg.plan, map_name="scn01", start=leg.start)

    def stalled_at(step: int) -> PlannerContext:
        v = dataclasses.replace(
            verdict,
            approved=False,
            failure_type="stalled",
            failed_step=step,
            stall=StallReport(step, "no_encoder_progress", "both", 1.0),
        )
        return PlannerContext(planner, leg, v, 0, (), (), orch.world, RepairSettings())

    turn = stall_repair(stalled_at(0))
    assert turn.leg.plan.commands[0] == PlanStep(
        "LEFT", planner.fine_turn_speed, leg.plan.commands[0].distance
    )
    drive = stall_repair(stalled_at(1))
    assert drive.detour is not None and drive.detour.obstacle_id == "stall"
    assert drive.leg.route.waypoints


@pytest.mark.parametrize("settings", [RepairSettings(), BLIND], ids=["map", "blind"])
def test_approach_into_a_slot(
    tmp_path: Path, planner: HeuristicLowLevelPlanner, settings: RepairSettings
) -> None:
    """A goal the rover cannot turn at gets an approach waypoint on its yaw axis."""
    with (
        start_gate(default_map=str(slot_map(tmp_path / "slot.json"))) as gate,
        GateClient(gate.url) as client,
    ):
        orch = PlannerOrchestrator(planner, client, map_name="slot", repair_settings=settings)
        result = orch.plan(Pose(6.0, 6.0, 90.0))
    assert result.approved
    assert result.attempts[0].verdict.failure_type == "collision"
    names = [a.repair_name for a in result.attempts]
    assert "approach" in names
    last = result.attempts[-1].leg
    wx, wy = last.route.waypoints[-1]
    assert wx == pytest.approx(6.0, abs=1e-6)
    assert wy < 5.3  # outside the slot, straight below the goal
    assert abs(result.verdict.final_pose.x - 6.0) < 0.1


# Seconds of CPU (an uncertain verdict's samples): out of the fast lane, in the test
# command's background part.
@pytest.mark.slow
@pytest.mark.virtual
def test_a_collision_probability_above_the_limit_is_a_collision_to_repair(
    orchestrator: Make,
) -> None:
    """The route around the table, its plans played on 40 twins of the gate's default
    spread: with no collision allowed, a plan the nominal twin approves but some samples
    see touching is rejected as a collision on the obstacle they hit most, and the
    orchestrator repairs it; with any allowed, the first approval stands."""
    goal = Pose(6.2, 3.0, 0.0)
    options = GateOptions(samples=40, seed=2)
    lenient = orchestrator("lab", options=options, max_collision_p=1.0).plan(goal)
    assert lenient.approved and lenient.verdict.uncertainty is not None
    assert lenient.verdict.uncertainty.samples == 40
    strict = orchestrator("lab", options=options, max_collision_p=0.0).plan(goal)
    by_chance = [
        a for a in strict.attempts if a.verdict.failure_reason.startswith("collision probability")
    ]
    assert by_chance, [a.verdict.summary() for a in strict.attempts]
    first = by_chance[0].verdict
    u = first.uncertainty
    assert u is not None and u.collision_probability > 0.0 and u.collisions
    assert first.failure_type == "collision" and first.collision is not None
    assert first.collision.obstacle_id == u.collisions[0].obstacle_id
    if strict.approved:
        assert strict.verdict.uncertainty is not None
        assert strict.verdict.uncertainty.collision_probability == 0.0


def test_a_collision_limit_needs_samples(orchestrator: Make) -> None:
    with pytest.raises(ValueError, match="samples"):
        orchestrator("lab", max_collision_p=0.1)


def test_a_given_plan_is_validated_once_as_it_is(orchestrator: Make, client: GateClient) -> None:
    # rover go --plan FILE: the plan the operator wrote, approved or not, never repaired.
    from firmware_proto.model.plan import Plan

    orch = orchestrator("lab")
    quarter = orch.planner.rover.turn_units_for_yaw(math.pi / 2)
    steps = [{"command": "FWD", "speed": 40, "distance": 11500}]
    steps.append({"command": "LEFT", "speed": 30, "distance": quarter})
    plan = Plan.from_dict({"goal": {"x": 1.7, "y": 3.0, "yaw_deg": 90.0}, "commands": steps})
    start = Pose(1.2, 3.0, 0.0)
    assert orch.world.name == "lab"  # the map, from the gate
    before = client.requests
    approved = orch.check_plan(plan, start=start)
    assert approved.approved and approved.reason == ""
    assert approved.plans == (plan,) and approved.repair_cycles == 0
    leg = approved.legs[0].attempts[0].leg
    assert [s.kind for s in leg.steps] == [DRIVE, "turn"]
    assert leg.steps[0].end_pose.x == pytest.approx(1.7) and leg.steps[1].yaw_change_deg == (
        pytest.approx(90.0, abs=0.01)
    )
    # Into the table: rejected with the gate's reason, and nothing repaired.
    rejected = orch.check_plan(plan, start=Pose(3.0, 3.0, 0.0))
    assert not rejected.approved and not rejected.plans
    assert len(rejected.attempts) == 1 and "collision at step 0" in rejected.reason
    assert "'table'" in rejected.reason
    assert client.requests - before == 2
    with pytest.raises(OutOfBoundsError):
        orch.check_plan(plan, start=Pose(9.5, 3.0, 0.0))
