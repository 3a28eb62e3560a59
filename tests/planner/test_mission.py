"""Move-and-wait, the thesis's baseline, against the whole rover side in virtual time
(sim/world.py): the operator's increments, their progress and the summary. The gated
missions (plan, drift STOP, re-plan, latch released after approval, a failed re-plan, a
cancel) are tests/sim/test_world.py's named missions."""

from __future__ import annotations

import itertools

from firmware_proto.model.plan import Plan
from firmware_proto.model.pose import Pose
from planner.ground.executor import ExecutionProgress
from planner.ground.mission import MoveAndWait, split_for_move_and_wait
from planner.plan.planner import HeuristicLowLevelPlanner
from sim.world import World, WorldConfig


def test_move_and_wait_reports_increments_and_only_the_figures_it_has() -> None:
    """Issue #41: every 0.5 m increment printed as ``step 1/1``, and the summary gave a
    ``worst drift 0.000 m`` move-and-wait never measured and ``planning 0.00 s`` for a
    route planned beforehand. Now progress counts increments over the whole drive, the
    ETA is the drive's, and the summary says what move-and-wait is and how long the
    route's planning took."""
    seen: list[ExecutionProgress] = []
    with World(WorldConfig(seed=5, rtt_s=0.4)) as w:
        start = w.map.start
        goal = Pose(start.x + 1.5, start.y, 0.0)  # 1.5 m straight ahead
        planner = HeuristicLowLevelPlanner(w.rover, world=w.map)
        plan: Plan = planner.plan(start, goal)  # one 1.5 m drive
        n = len(split_for_move_and_wait(plan, w.rover.m_to_units(0.5)))
        report = MoveAndWait(w.executor, decision_s=0.4, on_progress=seen.append).drive(
            goal, start, (plan,), planning_s=0.25
        )
    assert report.reached, report.summary()
    assert n >= 3
    assert {p.unit for p in seen} == {"increment"} and {p.steps for p in seen} == {n}
    assert [p.step for p in seen if p.final] == list(range(n))
    assert all(p.drift_linear_m is None for p in seen)
    assert seen[0].line().startswith(f"increment 1/{n} published, ETA ")
    finals = [p.eta_s for p in seen if p.final]
    # The whole drive's ETA, counting down to 0 at the last increment's end.
    assert all(a > b for a, b in itertools.pairwise(finals)) and finals[-1] == 0.0
    text = report.summary()
    assert f"move-and-wait: {n}/{n} increments completed" in text and "no drift control" in text
    assert "worst drift" not in text and "run 1:" not in text
    assert "of which planning 0.25 s (wall; the route was not validated on the gate)" in text
