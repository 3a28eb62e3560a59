"""The live view's hub in virtual time: the ghost follows the plan its step belongs to
through a whole mission, a STOP and a re-plan, however often a step's ``published`` is
reported before the rover acknowledges it (issue #41: at a 3 s round trip it was
reported three times and the view counted three legs). No thread, no HTTP: the hub is
fed as the ground station's port and executor feed it and driven with ``pump()`` on a
clock of the test's own."""

from __future__ import annotations

import itertools
import json
import math
from typing import Any

from bridge.ros.rosport.msgs import Bool, Int16MultiArray, Odometry, String
from firmware_proto.model.pose import Pose
from firmware_proto.model.rover import load_rover
from firmware_proto.model.verdict import Verdict
from firmware_proto.model.worldmap import load_map
from planner.ground.executor import ExecutionProgress
from planner.plan.orchestrator import Attempt, MissionResult, PlanResult
from planner.plan.planner import HeuristicLowLevelPlanner
from planner.view import ClientQueue, ViewHub
from tests.planner.test_drift import verdict_of

WORLD = load_map("lab")
RTT_S = 3.0
"""The link's round trip (wall s; time scale 1): three ``published`` reports per step."""


class Clock:
    """Wall seconds that pass only when the test says so."""

    def __init__(self) -> None:
        self.now = 1_000.0

    def __call__(self) -> float:
        return self.now


def _line(start: Pose, heading_deg: float, metres: float, seconds: float) -> list[Any]:
    """One step's samples: ``metres`` along ``heading_deg`` in ``seconds``, every 0.1 s."""
    n = round(seconds * 10)
    c, s = math.cos(math.radians(heading_deg)), math.sin(math.radians(heading_deg))
    return [
        (i / 10, Pose(start.x + c * metres * i / n, start.y + s * metres * i / n, heading_deg))
        for i in range(n + 1)
    ]


def _plan(start: Pose, legs: list[float]) -> Verdict:
    """A verdict of drives one after the other (east, then north, ...), 4 s each."""
    steps, at = [], start
    for i, metres in enumerate(legs):
        samples = _line(at, 90.0 * i, metres, 4.0)
        steps.append(samples)
        at = samples[-1][1]
    return verdict_of(steps)


def _mission(verdict: Verdict) -> MissionResult:
    planner = HeuristicLowLevelPlanner(load_rover(), world=WORLD)
    goal = verdict.final_pose
    leg = planner.plan_leg(planner.route(verdict.start_pose, goal))
    return MissionResult(
        goal, verdict.start_pose, (PlanResult(True, (Attempt(0, leg, verdict),), ()),)
    )


def _all_events(client: ClientQueue) -> list[tuple[str, dict[str, Any]]]:
    """Every event waiting, in order: ``(name, data)``."""
    out = []
    for record in client.take(0.0):
        kind, data = record.decode().split("\n", 2)[:2]
        out.append((kind[len("event: ") :], json.loads(data[len("data: ") :])))
    return out


def _events(client: ClientQueue, name: str) -> list[dict[str, Any]]:
    return [data for kind, data in _all_events(client) if kind == name]


def _on_step(verdict: Verdict, step: int, xy: list[float]) -> float:
    """How far ``xy`` is from the prediction of ``step`` (its polyline), m."""
    samples = verdict.trajectory.for_step(step)
    best = math.inf
    for a, b in itertools.pairwise(samples):
        ax, ay, bx, by = a.pose.x, a.pose.y, b.pose.x, b.pose.y
        length2 = (bx - ax) ** 2 + (by - ay) ** 2
        t = 0.0 if length2 == 0 else ((xy[0] - ax) * (bx - ax) + (xy[1] - ay) * (by - ay)) / length2
        t = min(1.0, max(0.0, t))
        best = min(best, math.hypot(xy[0] - (ax + t * (bx - ax)), xy[1] - (ay + t * (by - ay))))
    return best


def _odom(pose: Pose) -> Odometry:
    msg = Odometry()
    msg.pose.pose.position.x = pose.x
    msg.pose.pose.position.y = pose.y
    msg.pose.pose.orientation.w = 1.0
    return msg


class Mission:
    """Feeds the hub what the ground station would, one step at a time."""

    def __init__(self, hub: ViewHub, clock: Clock, client: ClientQueue) -> None:
        self.hub, self.clock, self.client = hub, clock, client
        self.ghosts: list[tuple[Verdict, int, list[float], dict[str, Any]]] = []
        self.progress: dict[str, Any] = {}

    def advance(self, seconds: float, verdict: Verdict, step: int) -> None:
        """Let ``seconds`` pass in ticks of 0.1 s, noting each ghost beside the plan
        and step it should be on."""
        for _ in range(round(seconds * 10)):
            self.clock.now += 0.1
            self.hub.pump()
            for kind, data in _all_events(self.client):
                if kind == "progress":
                    self.progress = data
                elif kind == "tick" and data["ghost"] is not None and not data["halted"]:
                    self.ghosts.append((verdict, step, data["ghost"], dict(self.progress)))

    def report(self, verdict: Verdict, step: int, steps: int, status: str) -> None:
        self.hub.progress(ExecutionProgress(step, steps, status, 10.0, None, None, verdict))

    def step(self, verdict: Verdict, step: int, steps: int, *, ends: str = "completed") -> None:
        """One step as ``rover go`` runs it over a 3 s round trip: published (and said so
        again every second until acknowledged), accepted after the round trip, running,
        then ``ends``."""
        self.hub.tap("sent", "/ground/wheel_instructions", Int16MultiArray(data=[1, 30, 9000]))
        self.report(verdict, step, steps, "published")
        for _ in range(3):
            self.advance(1.0, verdict, step)
            self.report(verdict, step, steps, "published")
        self.hub.tap("received", "/ground/command_status", String(data="accepted"))
        self.report(verdict, step, steps, "accepted")
        self.advance(2.0, verdict, step)
        self.report(verdict, step, steps, "running")
        self.advance(1.0, verdict, step)
        if ends != "completed":
            return
        self.advance(1.0, verdict, step)  # the rest of the step, then its status comes back
        self.hub.tap("received", "/ground/command_status", String(data="completed"))
        self.report(verdict, step, steps, "completed")
        self.advance(0.2, verdict, step)


def test_the_ghost_stays_on_the_plan_through_a_mission_a_stop_and_a_replan() -> None:
    clock = Clock()
    hub = ViewHub(WORLD, rtt_s=RTT_S, time_scale=1.0, clock=clock)
    client = hub.subscribe()
    run = Mission(hub, clock, client)
    first = _plan(WORLD.start, [1.0, 0.8, 1.0])
    hub.planned(_mission(first))
    hub.tap("received", "/ground/odom_ground", _odom(WORLD.start))
    run.step(first, 0, 3)
    run.step(first, 1, 3, ends="drift")
    # Drift control stops the rover half way through step 2 of 3.
    hub.tap("sent", "/ground/emergency_stop", Bool(data=True))
    hub.pump()
    halted = [t for t in _events(client, "tick") if t["halted"]]
    assert halted, "the ghost did not stop with the rover"
    ghost = halted[-1]["ghost"]
    # Where it stopped is on the step it followed, not at the start of the mission.
    assert _on_step(first, 1, ghost) < 1e-3, ghost
    start_xy = first.trajectory.for_step(0)[0].pose
    assert math.hypot(ghost[0] - start_xy.x, ghost[1] - start_xy.y) > 0.9
    hub.tap("received", "/ground/command_status", String(data="aborted:stop"))
    hub.tap("received", "/ground/command_status", String(data="stopped"))
    run.advance(2.0, first, 1)
    assert all(t["ghost"] == ghost for t in _events(client, "tick"))  # and stays there
    # Re-planned from where the rover settled: a new plan, and the ghost follows it.
    second = _plan(Pose(ghost[0], ghost[1], 90.0), [0.5, 1.0])
    hub.planned(_mission(second))
    hub.tap("received", "/ground/command_status", String(data="cleared"))
    run.step(second, 0, 2)
    run.step(second, 1, 2)
    hub.result(True, "mission: REACHED")
    run.advance(0.5, second, 1)

    assert run.ghosts, "no ghost was drawn"
    off = [(s, g, _on_step(v, s, g)) for v, s, g, _ in run.ghosts if _on_step(v, s, g) > 1e-3]
    assert not off, f"{len(off)} of {len(run.ghosts)} ghosts off their plan's step: {off[:3]}"
    # Every plan's steps were followed to their ends.
    for verdict in (first, second):
        seen = [g for v, _, g, _ in run.ghosts if v is verdict]
        assert seen, "a plan the ghost never followed"
    end = second.trajectory.samples[-1].pose
    assert math.hypot(run.ghosts[-1][2][0] - end.x, run.ghosts[-1][2][1] - end.y) < 1e-3
    # The page says which plan: one leg each, the second planning a re-plan.
    legs = {(p["planning"], p["leg"], p["legs"]) for _, _, _, p in run.ghosts}
    assert legs == {(1, 0, 1), (2, 0, 1)}, legs
    state = hub.state()
    assert state["progress"]["planning"] == 2 and state["progress"]["step"] == 1


def test_without_a_verdict_there_is_no_ghost() -> None:
    """Move-and-wait runs without a prediction: the view draws no ghost for it."""
    clock = Clock()
    hub = ViewHub(WORLD, rtt_s=RTT_S, clock=clock)
    client = hub.subscribe()
    hub.planned(_mission(_plan(WORLD.start, [1.0])))
    hub.tap("sent", "/ground/wheel_instructions", Int16MultiArray(data=[1, 30, 9000]))
    hub.progress(ExecutionProgress(0, 1, "published", 5.0, None, None))
    hub.tap("received", "/ground/command_status", String(data="accepted"))
    for _ in range(10):
        clock.now += 0.1
        hub.pump()
    ticks = _events(client, "tick")
    assert ticks and all(t["ghost"] is None for t in ticks)


def test_a_plan_run_on_board_moves_the_ghost_and_a_replan_frees_it() -> None:
    """On board (docs/onboard.md) no step is sent from the ground: the rover's reports,
    half a round trip old, say which step runs. The ghost follows them; stopped by a STOP
    it stays until the next plan runs, then follows that one."""
    clock = Clock()
    hub = ViewHub(WORLD, rtt_s=RTT_S, clock=clock)
    client = hub.subscribe()
    first = _plan(WORLD.start, [1.0, 1.0])
    hub.planned(_mission(first))

    def report(verdict: Verdict, step: int, status: str, seconds: float) -> list[Any]:
        hub.progress(ExecutionProgress(step, 2, status, 10.0, None, None, verdict))
        ghosts = []
        for _ in range(round(seconds * 10)):
            clock.now += 0.1
            hub.pump()
            ghosts += [t for t in _events(client, "tick") if t["ghost"] is not None]
        return ghosts

    moving = report(first, 0, "running", 2.0)
    # Reported half a round trip after it began: already 1.5 s into the step's 4 s.
    assert _on_step(first, 0, moving[0]["ghost"]) < 1e-3
    assert moving[0]["ghost"][0] > WORLD.start.x + 0.3
    assert moving[-1]["ghost"][0] > moving[0]["ghost"][0]  # and on along it
    hub.tap("sent", "/ground/emergency_stop", Bool(data=True))
    stopped = report(first, 0, "running", 1.0)
    assert stopped[-1]["halted"] and stopped[-1]["ghost"] == stopped[0]["ghost"]
    second = _plan(Pose(1.9, 3.0, 90.0), [0.8, 0.8])
    hub.planned(_mission(second))
    again = report(second, 0, "running", 1.0)
    assert not again[-1]["halted"]
    assert all(_on_step(second, 0, t["ghost"]) < 1e-3 for t in again)
