"""Missions on the real rig and a real gate: after a drift STOP the runner waits for the
rover to come to rest, re-plans from there, and releases the STOP latch only once the
new mission is approved; a re-plan that fails leaves the rover latched, and says so."""

from __future__ import annotations

import itertools
import threading
from collections.abc import Iterator

import pytest

from firmware_proto.model.pose import Pose
from firmware_proto.model.rover import load_rover
from firmware_proto.model.worldmap import load_map
from gate.server import GateServer
from planner.ground.executor import ExecutionResult
from planner.ground.mission import MissionRunner
from planner.plan.gate_client import GateClient
from planner.plan.orchestrator import PlannerOrchestrator
from planner.plan.planner import HeuristicLowLevelPlanner
from tests.planner.conftest import start_gate
from tests.rig import HilRig

# Missions in real time on an in-process rig (emulator, bridge and relay threads in this
# worker): run after the rest, as the whole-mission tests are (marker serial: two at a
# time, never beside the host part's tests). Its emulator and bridge threads are
# real-time, but they share this process's interpreter lock with threads that are not:
# beside the host part's tests the bridge's heartbeats came 255 ms late (watchdog trips
# in 5 tests of one run).
pytestmark = pytest.mark.serial

GOAL = Pose(1.2 + 1.5, 3.0, 0.0)  # 1.5 m straight ahead of the lab map's start


@pytest.fixture
def own_gate() -> Iterator[GateServer]:
    """A gate of this test alone (it may stop it)."""
    with start_gate() as server:
        yield server


@pytest.fixture
def slipping_rig() -> Iterator[HilRig]:
    """The lab rig with both sides slipping from the start: the first run drifts."""
    with HilRig("lab", speed=4.0, rtt_s=0.4, seed=5, faults=("slip:both=0.1",)) as rig:
        yield rig


def orchestrator(client: GateClient) -> PlannerOrchestrator:
    world = load_map("lab")
    planner = HeuristicLowLevelPlanner(load_rover(), world=world)
    return PlannerOrchestrator(planner, client, map_name="lab", world=world)


def test_the_latch_is_released_only_once_the_replan_is_approved(
    own_gate: GateServer, slipping_rig: HilRig
) -> None:
    rig = slipping_rig
    events: list[tuple[str, bool]] = []
    cleared_slip = threading.Event()

    def event(line: str) -> None:
        events.append((line, rig.emulator.status().stop_latched))

    def out_of_the_sand(result: ExecutionResult) -> None:
        rig.emulator.inject("clear:slip")
        cleared_slip.set()

    with GateClient(own_gate.url) as client:
        runner = MissionRunner(
            orchestrator(client), rig.executor, on_drift=out_of_the_sand, on_event=event
        )
        report = runner.run(GOAL)
    assert cleared_slip.is_set() and len(report.drift_events) == 1
    assert report.reached, report.summary()
    lines = [line for line, _ in events]
    replanned = next(i for i, line in enumerate(lines) if line.startswith("at rest; re-planning"))
    approved = next(i for i, line in enumerate(lines) if "STOP latch released" in line)
    planned_again = next(i for i in range(replanned, len(lines)) if lines[i].startswith("planned"))
    assert replanned < planned_again < approved
    assert events[replanned][1] and events[planned_again][1]  # latched while re-planning
    assert not rig.emulator.status().stop_latched
    summary = report.summary(4.0)
    assert "re-plan 1:" in summary
    assert "attempt 1 (initial): approved" in summary  # the repair names what made it
    # The run that drift control stopped counts the steps it completed, not those sent.
    first = report.runs[0].execution
    done = sum(1 for s in first.steps if s.status == "completed")
    assert done == len(first.steps) - 1
    assert f"run 1: {done}/{len(report.runs[0].plan.commands)} steps completed, drift" in summary


def test_a_replan_that_fails_leaves_the_rover_latched(
    own_gate: GateServer, slipping_rig: HilRig
) -> None:
    rig = slipping_rig

    def gate_goes_down(result: ExecutionResult) -> None:
        own_gate.close()

    with GateClient(own_gate.url, retries=1, timeout_s=5.0) as client:
        runner = MissionRunner(orchestrator(client), rig.executor, on_drift=gate_goes_down)
        report = runner.run(GOAL)
    assert not report.reached
    assert report.reason.startswith("re-planning failed: the gate at")
    assert report.reason.endswith("the rover stays stopped (STOP latched)")
    assert len(report.plannings) == 1 and len(report.runs) == 1
    assert report.runs[0].execution.outcome == "drift"
    status = rig.emulator.status()
    assert status.stop_latched and status.wheel_mps == (0.0, 0.0)
    assert "STOP latched" in report.summary()


def test_a_cancelled_mission_stops_the_rover(own_gate: GateServer) -> None:
    with (
        HilRig("lab", speed=4.0, rtt_s=0.4, seed=5, progress_period_s=0.1) as rig,
        GateClient(own_gate.url) as client,
    ):
        cancel = threading.Event()

        def progress(p: object) -> None:
            if any(abs(v) > 0.05 for v in rig.emulator.status().wheel_mps):
                cancel.set()

        runner = MissionRunner(
            orchestrator(client), rig.executor, on_progress=progress, cancel=cancel
        )
        report = runner.run(GOAL)
        assert report.cancelled and not report.reached
        assert "NOT REACHED (cancelled by the operator" in report.summary()
        assert report.runs[-1].execution.stopped_s is not None
        assert rig.emulator.status().stop_latched


def test_move_and_wait_reports_increments_and_only_the_figures_it_has() -> None:
    """Issue #41: every 0.5 m increment printed as ``step 1/1``, and the summary gave a
    ``worst drift 0.000 m`` move-and-wait never measured and ``planning 0.00 s`` for a
    route planned beforehand. Now progress counts increments over the whole drive, the
    ETA is the drive's, and the summary says what move-and-wait is and how long the
    route's planning took."""
    from firmware_proto.model.plan import Plan
    from planner.ground.executor import ExecutionProgress
    from planner.ground.mission import MoveAndWait, split_for_move_and_wait

    seen: list[ExecutionProgress] = []
    with HilRig("lab", speed=2.0, rtt_s=0.4, seed=5) as rig:
        planner = HeuristicLowLevelPlanner(rig.rover, world=rig.world)
        plan: Plan = planner.plan(rig.world.start, GOAL)  # one 1.5 m drive
        n = len(split_for_move_and_wait(plan, rig.rover.m_to_units(0.5)))
        report = MoveAndWait(
            rig.executor, decision_s=0.2, time_scale=2.0, on_progress=seen.append
        ).drive(GOAL, rig.world.start, (plan,), planning_s=0.25)
    assert report.reached, report.summary(2.0)
    assert n >= 3
    assert {p.unit for p in seen} == {"increment"} and {p.steps for p in seen} == {n}
    assert [p.step for p in seen if p.final] == list(range(n))
    assert all(p.drift_linear_m is None for p in seen)
    assert seen[0].line().startswith(f"increment 1/{n} published, ETA ")
    finals = [p.eta_s for p in seen if p.final]
    # The whole drive's ETA, counting down to 0 at the last increment's end.
    assert all(a > b for a, b in itertools.pairwise(finals)) and finals[-1] == 0.0
    text = report.summary(2.0)
    assert f"move-and-wait: {n}/{n} increments completed" in text and "no drift control" in text
    assert "worst drift" not in text and "run 1:" not in text
    assert "of which planning 0.25 s (wall; the route was not validated on the gate)" in text
