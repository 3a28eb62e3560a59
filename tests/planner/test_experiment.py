"""The planning part of the thesis's experiment, on the real gate."""

from __future__ import annotations

from collections.abc import Callable

import pytest

from firmware_proto.model.pose import Pose
from firmware_proto.model.worldmap import WorldMap
from planner.plan.experiment import (
    ExperimentResult,
    footprint_hits,
    run_planning_experiment,
    trial_goals,
)
from planner.plan.orchestrator import PlannerOrchestrator
from planner.plan.planner import HeuristicLowLevelPlanner


def test_footprint_check(planner: HeuristicLowLevelPlanner, worlds: dict[str, WorldMap]) -> None:
    lab = worlds["lab"]
    straight = planner.route(lab.start, Pose(6.2, 3.0, 0.0), world=lab)
    assert footprint_hits(planner, lab, straight) == "table"
    around = planner.route(lab.start, Pose(6.2, 3.0, 0.0), [(3.0, 4.8), (5.0, 4.8)], world=lab)
    assert footprint_hits(planner, lab, around) is None
    # Turning on the spot next to the wall: the corners sweep into it.
    tight = planner.route(Pose(0.4, 3.0, 0.0), Pose(0.4, 3.0, 90.0))
    assert footprint_hits(planner, lab, tight) == "bounds"
    assert footprint_hits(planner, lab, tight, margin_m=0.0) == "bounds"


def test_trial_goals_are_seeded_and_feasible(
    planner: HeuristicLowLevelPlanner, worlds: dict[str, WorldMap]
) -> None:
    world = worlds["scn02"]
    goals = trial_goals(world, planner, 8, seed=3)
    assert goals == trial_goals(world, planner, 8, seed=3)
    assert goals != trial_goals(world, planner, 8, seed=4)
    assert [name for name, _ in goals[:2]] == ["behind_rock", "far_side"]
    need = planner.rover.footprint_radius_m + 0.1
    for _, goal in goals[2:]:
        assert world.clearance(goal.xy)[0] >= need
        assert goal.distance_to((world.start.x, world.start.y)) >= 3.0
        assert -180.0 <= goal.yaw_deg < 180.0
    assert all(
        n.startswith("random_") for n, _ in trial_goals(world, planner, 3, include_suggested=False)
    )


def test_experiment_on_scn01(orchestrator: Callable[..., PlannerOrchestrator]) -> None:
    orch = orchestrator("scn01")
    goals = [("behind_rock", Pose(10.5, 4.0, 0.0)), ("open", Pose(4.0, 6.0, 90.0))]
    result = run_planning_experiment(orch, goals=goals)
    assert isinstance(result, ExperimentResult)
    assert result.map_name == "scn01"
    rock, open_goal = result.trials
    assert rock.geometric_collision and rock.hit == "rock_1"
    assert rock.first_failure == "collision" and rock.intercepted
    assert rock.approved and rock.repair_cycles >= 1
    assert not open_goal.geometric_collision and open_goal.first_failure is None
    assert open_goal.approved and open_goal.repair_cycles == 0
    assert result.collision_share == 0.5
    assert result.geometric_share == 0.5
    assert result.interception_share == 1.0
    assert result.approved_share == 1.0
    assert result.mean_repair_cycles == rock.repair_cycles
    assert result.mean_repair_cycles_all == pytest.approx(rock.repair_cycles / 2)
    table = result.table()
    assert "map scn01: 2 goals" in table
    assert "intercepted 100 %" in table


def test_experiment_with_random_goals(orchestrator: Callable[..., PlannerOrchestrator]) -> None:
    result = run_planning_experiment(orchestrator("scn02"), n_goals=3, seed=1)
    assert len(result.trials) == 3
    assert result.interception_share in (None, 1.0)
    for t in result.trials:
        assert t.attempts >= 1 + t.repair_cycles - 0
        assert t.approved == (t.reason == "")
