"""Named missions played in a :class:`~sim.world.World` (virtual time), each with the
checks that say it went as it must (docs/sim.md, "Whole missions in virtual time").

A mission is a function of a world and a gate client that drives the world's executor
(a plan, a :class:`~planner.ground.mission.MissionRunner`, faults injected into the
controller, the link cut) and records what it expects through a :class:`Checks`.
:func:`play` builds the world, plays the mission and returns a :class:`WorldOutcome`: the
failed checks, the virtual time, a digest of everything that crossed the link, and the
one command line that plays it again (``rover sim --world NAME --seed N ...``), which
a test prints when it fails.

The missions are :data:`MISSIONS`; docs/sim.md's table says what each shows, and each
mission's :meth:`Checks.expect` calls say what it must do.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from firmware_proto.model.plan import Plan
from firmware_proto.model.pose import Pose
from gate.config import GateConfig
from gate.server import GateServer
from planner.ground.executor import ExecutionProgress as Progress
from planner.ground.executor import ExecutionResult
from planner.ground.mission import MissionRunner
from planner.plan.gate_client import GateClient
from planner.plan.orchestrator import PlannerOrchestrator
from planner.plan.planner import HeuristicLowLevelPlanner
from sim.world import World, WorldConfig

__all__ = ["MISSIONS", "Checks", "Mission", "WorldOutcome", "play", "start_gate"]

RTT_S = 3.0
ONE_STEP = {
    "goal": {"x": 0, "y": 0, "yaw_deg": 0},
    "commands": [{"command": "FWD", "speed": 60, "distance": 23000}],
}


@dataclass
class Checks:
    """What a mission expected and what it saw: every failed check, in order, and a line
    for each notable event (shown with a failure)."""

    failed: list[str] = field(default_factory=list)
    lines: list[str] = field(default_factory=list)

    def expect(self, ok: bool, what: str) -> bool:
        """Record ``what`` as failed unless ``ok``; returns ``ok``."""
        if not ok:
            self.failed.append(what)
        return ok

    def say(self, line: str) -> None:
        """Note an event."""
        self.lines.append(line)


Play = Callable[[World, GateClient, Checks], None]


@dataclass(frozen=True)
class Mission:
    """A named mission: what it shows, how it is played, and its world's settings
    (``world`` overrides :class:`~sim.world.WorldConfig`'s defaults)."""

    name: str
    what: str
    play: Play
    world: tuple[tuple[str, Any], ...] = ()
    own_gate: bool = False
    """The mission stops the gate: it gets one of its own."""


@dataclass(frozen=True)
class WorldOutcome:
    """How a mission went.

    Attributes:
        config: the world it ran in (with the mission's name).
        failed: the checks that failed (empty: it passed).
        lines: what happened, in words.
        digest: :meth:`World.digest <sim.world.World.digest>` at the end.
        sim_s: virtual time simulated, s.
        wall_s: wall time it took, s.
        cpu_s: CPU time this process spent on it, s (beside other work on the machine,
            the fairer measure of its speed).
    """

    config: WorldConfig
    failed: tuple[str, ...]
    lines: tuple[str, ...]
    digest: str
    sim_s: float
    wall_s: float
    cpu_s: float

    @property
    def ok(self) -> bool:
        """Every check held."""
        return not self.failed

    @property
    def reproducer(self) -> str:
        """The command line that plays it again."""
        return self.config.reproducer

    def report(self) -> str:
        """``ok``/``FAIL`` with the reproducer, the failed checks and the events."""
        head = f"{'ok' if self.ok else 'FAIL'} {self.reproducer}"
        speed = self.sim_s / self.cpu_s if self.cpu_s > 0 else math.inf
        head += (
            f"  ({self.sim_s:.1f} s simulated in {self.wall_s:.2f} s, {self.cpu_s:.2f} s of "
            f"CPU: {speed:.0f}x)"
        )
        out = [head, *(f"  failed: {f}" for f in self.failed)]
        if self.failed:
            out += [f"  | {line}" for line in self.lines]
        return "\n".join(out)


def start_gate() -> GateServer:
    """A gate on 127.0.0.1 (free port, one worker thread, the shipped maps); close it after."""
    return GateServer(GateConfig(port=0, pool="thread", workers=1, queue_depth=4)).start()


def play(
    name: str, config: WorldConfig | None = None, *, gate_url: str | None = None
) -> WorldOutcome:
    """Play mission ``name`` in a world of ``config`` (the mission's own settings first),
    against the gate at ``gate_url`` (default: one started for it).

    Raises:
        KeyError: an unknown mission (the message lists the known ones).
    """
    if name not in MISSIONS:
        raise KeyError(f"unknown mission {name!r}; known: {', '.join(MISSIONS)}")
    mission = MISSIONS[name]
    base = config or WorldConfig()
    cfg = base.with_(**(dict(mission.world) | {"mission": name}))
    checks = Checks()
    started, cpu = time.monotonic(), time.process_time()
    gate = start_gate() if gate_url is None or mission.own_gate else None
    try:
        url = gate.url if gate is not None else str(gate_url)
        with World(cfg) as world, GateClient(url, retries=1, timeout_s=30.0) as client:
            world.gate = gate
            t0 = world.now_s
            mission.play(world, client, checks)
            checks.expect(world.callback_errors() == 0, "no ROS callback raised (see the log)")
            sim_s, digest = world.now_s - t0, world.digest()
    finally:
        if gate is not None:
            gate.close()
    return WorldOutcome(
        cfg,
        tuple(checks.failed),
        tuple(checks.lines),
        digest,
        sim_s,
        time.monotonic() - started,
        time.process_time() - cpu,
    )


# -- the missions -------------------------------------------------------------------------------
def _quarter_turn(world: World) -> int:
    return world.rover.turn_units_for_yaw(math.pi / 2)


def _south_plan(world: World) -> dict[str, Any]:
    s = world.map.start  # lab: (1.2, 3.0) facing +x; turn south, drive 2 m in the open
    return {
        "goal": {"x": s.x, "y": s.y - 2.0, "yaw_deg": -90.0},
        "commands": [
            {
                "command": "RIGHT",
                "speed": 30,
                "distance": world.rover.turn_units_for_yaw(math.pi / 2),
            },
            {"command": "FWD", "speed": 60, "distance": 23000},
            {"command": "FWD", "speed": 60, "distance": 23000},
        ],
    }


def _approved(world: World, client: GateClient, c: Checks) -> None:
    plan = _south_plan(world)
    verdict = client.validate(plan, map_name=world.config.map_name)
    if not c.expect(verdict.approved, f"the gate approves the plan ({verdict.summary()})"):
        return
    result = world.executor.execute(Plan.from_dict(plan), verdict)
    c.say(f"{result.outcome}: {result.reason}")
    c.expect(result.completed, f"the plan completes ({result.outcome}: {result.reason})")
    c.expect([s.status for s in result.steps] == ["completed"] * 3, "each step completed")
    truth = world.truth()
    goal = plan["goal"]
    error_m = math.hypot(truth.x_m - goal["x"], truth.y_m - goal["y"])
    c.expect(error_m < 0.10, f"the rover ends within 0.10 m of the goal ({error_m:.3f} m)")
    c.expect(abs(truth.yaw_deg - goal["yaw_deg"]) < 3.0, f"and 3 deg ({truth.yaw_deg:.1f} deg)")
    c.expect(result.worst_drift[0] < 0.15, f"it followed the ghost ({result.worst_drift[0]:.3f} m)")
    c.expect(result.reported_pose is not None, "the rover reported its pose")


def _slip(world: World, client: GateClient, c: Checks) -> None:
    s = world.map.start
    plan = {
        "goal": {"x": s.x + 1.5, "y": s.y, "yaw_deg": 0.0},
        "commands": [
            {"command": "FWD", "speed": 60, "distance": 23000},
            {"command": "FWD", "speed": 60, "distance": 11500},
        ],
    }
    verdict = client.validate(plan, map_name=world.config.map_name)
    if not c.expect(verdict.approved, "the gate approves the plan"):
        return
    world.inject("slip:both=0.1")  # the encoders still report the full travel
    result = world.executor.execute(Plan.from_dict(plan), verdict)
    c.say(f"{result.outcome}: {result.reason}")
    if not c.expect(result.outcome == "drift", f"drift control stops it ({result.outcome})"):
        return
    assert result.drift is not None
    c.expect(result.drift.linear_m > 0.25, f"past 0.25 m ({result.drift.linear_m:.3f} m)")
    c.expect(result.stop_latency_s is not None, "STOP was sent from the detection")
    c.expect(result.stopped_s is not None, "the rover confirmed the STOP")
    c.expect(world.run_until(world.at_rest, 5.0), "the rover comes to rest")
    truth = world.truth()
    c.expect(truth.stop_latched, "and stays latched")
    rover = world.rover
    braking = rover.max_speed_mps**2 / (2 * rover.drive.wheel_accel_limit_mps2)
    predicted = result.drift.predicted
    off = math.hypot(truth.x_m - predicted.x, truth.y_m - predicted.y)
    c.expect(
        off < 0.25 + braking + 0.1,
        f"it stops near the predicted pose at detection ({off:.3f} m off)",
    )
    c.expect(len(result.steps) == 1, "the rest of the plan was purged (never published)")


def _rejected(world: World, client: GateClient, c: Checks) -> None:
    c.expect(world.executor.stop(), "the rover confirms a STOP")
    result = world.executor.execute(
        Plan.from_dict(ONE_STEP | {"commands": [{"command": "FWD", "speed": 10, "distance": 100}]})
    )
    c.say(f"{result.outcome}: {result.reason}")
    c.expect(
        result.outcome == "rejected" and "stop_latched" in result.reason,
        f"the bridge refuses the step under the latch ({result.outcome}: {result.reason})",
    )
    c.expect(result.stopped_s is not None, "the plan ends with a confirmed STOP")


def _dark(world: World, client: GateClient, c: Checks) -> None:
    world.relay.close()  # the link goes dark: no status, no confirmation
    executor = world.executor
    timeout = executor.step_timeout_s(0, (1, 60, 23000), None)
    result = executor.execute(Plan.from_dict(ONE_STEP))
    c.say(f"{result.outcome}: {result.reason} after {result.elapsed_s:.2f} s")
    c.expect(result.outcome == "timeout", f"the step times out ({result.outcome})")
    c.expect("STOP not confirmed" in result.reason, "and the STOP is reported unconfirmed")
    cfg = executor.config
    bound = timeout + cfg.link_rtt_s + cfg.step_margin_s + 0.1
    c.expect(
        timeout <= result.elapsed_s < bound,
        f"after its whole budget and no longer than bounded ({result.elapsed_s:.2f} s)",
    )


def _dead(world: World, client: GateClient, c: Checks) -> None:
    world.controller.close()  # the controller dies: the bridge loses it
    executor = world.executor
    result = executor.execute(Plan.from_dict(ONE_STEP))
    c.say(f"{result.outcome}: {result.reason} after {result.elapsed_s:.2f} s")
    c.expect(
        result.outcome in ("fault", "rejected", "timeout"),
        f"the plan ends with a fault, a refusal or a timeout ({result.outcome})",
    )
    budget = executor.step_timeout_s(0, (1, 60, 23000), None)
    c.expect(result.elapsed_s < budget + 1.0, "within the step's budget")


def _orchestrator(world: World, client: GateClient) -> PlannerOrchestrator:
    planner = HeuristicLowLevelPlanner(world.rover, world=world.map)
    return PlannerOrchestrator(planner, client, map_name=world.config.map_name, world=world.map)


GOAL_AHEAD = (1.5, 0.0)
"""The replan missions' goal, from the map's start: 1.5 m straight ahead."""


def _goal_ahead(world: World) -> Pose:
    s = world.map.start
    return Pose(s.x + GOAL_AHEAD[0], s.y + GOAL_AHEAD[1], 0.0)


def _replan(world: World, client: GateClient, c: Checks) -> None:
    events: list[tuple[str, bool]] = []

    def event(line: str) -> None:
        c.say(line)
        events.append((line, world.truth().stop_latched))

    def out_of_the_sand(result: ExecutionResult) -> None:
        world.inject("clear:slip")

    world.inject("slip:both=0.1")
    runner = MissionRunner(
        _orchestrator(world, client), world.executor, on_drift=out_of_the_sand, on_event=event
    )
    report = runner.run(_goal_ahead(world))
    c.say(report.summary())
    c.expect(len(report.drift_events) == 1, f"one drift STOP ({len(report.drift_events)})")
    if not c.expect(report.reached, f"the mission arrives ({report.reason})"):
        return
    lines = [line for line, _ in events]
    replanned = next((i for i, x in enumerate(lines) if x.startswith("at rest; re-planning")), -1)
    approved = next((i for i, x in enumerate(lines) if "STOP latch released" in x), -1)
    planned_again = next(
        (i for i in range(max(replanned, 0), len(lines)) if lines[i].startswith("planned")), -1
    )
    c.expect(
        0 <= replanned < planned_again < approved,
        "rest, then the re-plan, then the latch released",
    )
    if replanned >= 0 and planned_again >= 0:
        c.expect(
            events[replanned][1] and events[planned_again][1],
            "latched while re-planning",
        )
    c.expect(not world.truth().stop_latched, "released at the end")
    summary = report.summary()
    c.expect("re-plan 1:" in summary, "the summary shows the re-plan")
    c.expect("attempt 1 (initial): approved" in summary, "and names the repair of each attempt")
    first = report.runs[0].execution
    done = sum(1 for s in first.steps if s.status == "completed")
    c.expect(done == len(first.steps) - 1, "the stopped run counts the steps it completed")
    c.expect(
        f"run 1: {done}/{len(report.runs[0].plan.commands)} steps completed, drift" in summary,
        "and says so",
    )


def _replan_fails(world: World, client: GateClient, c: Checks) -> None:
    gate = getattr(world, "gate", None)

    def gate_goes_down(result: ExecutionResult) -> None:
        if gate is not None:
            gate.close()

    world.inject("slip:both=0.1")
    runner = MissionRunner(_orchestrator(world, client), world.executor, on_drift=gate_goes_down)
    report = runner.run(_goal_ahead(world))
    c.say(report.summary())
    c.expect(not report.reached, "the mission does not arrive")
    c.expect(
        report.reason.startswith("re-planning failed: the gate at"),
        f"because re-planning failed ({report.reason})",
    )
    c.expect(
        report.reason.endswith("the rover stays stopped (STOP latched)"), "and says it is latched"
    )
    c.expect(len(report.plannings) == 1 and len(report.runs) == 1, "one planning, one run")
    c.expect(report.runs[0].execution.outcome == "drift", "the run ended on drift")
    c.expect(world.run_until(world.at_rest, 5.0), "the rover comes to rest")
    c.expect(world.truth().stop_latched, "and stays latched")
    c.expect("STOP latched" in report.summary(), "the summary says so")


def _cancel(world: World, client: GateClient, c: Checks) -> None:
    cancel = threading.Event()

    def progress(p: Progress) -> None:
        if any(abs(v) > 0.05 for v in world.truth().wheel_mps):
            cancel.set()

    runner = MissionRunner(
        _orchestrator(world, client), world.executor, on_progress=progress, cancel=cancel
    )
    report = runner.run(_goal_ahead(world))
    c.say(report.summary())
    c.expect(report.cancelled and not report.reached, "the mission is cancelled")
    c.expect("NOT REACHED (cancelled by the operator" in report.summary(), "the summary says so")
    c.expect(report.runs[-1].execution.stopped_s is not None, "the STOP was confirmed")
    c.expect(world.truth().stop_latched, "the rover is latched")


def _demo(world: World, client: GateClient, c: Checks) -> None:
    goal_name = "behind_table"
    goal = next((g for g in world.map.goals if g.name == goal_name), None)
    if not c.expect(goal is not None, f"the map has the goal {goal_name}"):
        return
    assert goal is not None
    slipped: list[str] = []

    def progress(p: Progress) -> None:
        if p.status == "completed" and p.step == 0 and not slipped:
            slipped.append(str(world.inject("slip:left=0.05")))
            c.say("INJECTING slip:left=0.05")

    def out_of_the_sand(result: ExecutionResult) -> None:
        world.inject("clear:slip")

    runner = MissionRunner(
        _orchestrator(world, client),
        world.executor,
        on_progress=progress,
        on_drift=out_of_the_sand,
        on_event=c.say,
    )
    report = runner.run(goal.pose)
    text = report.summary()
    c.say(text)
    c.expect("collision at step" in text and "(dogleg): approved" in text, "a detour")
    c.expect(bool(slipped), "slip was injected after the first step")
    c.expect("drift STOP:" in text and "detection to STOP" in text, "drift control stopped it")
    c.expect("re-plan 1:" in text, "it re-planned")
    c.expect(report.reached, f"and arrived ({report.reason})")


MISSIONS: dict[str, Mission] = {
    m.name: m
    for m in (
        Mission("approved", "an approved plan reaches its goal", _approved),
        Mission("slip", "slip trips drift control, which stops the rover", _slip),
        Mission("rejected", "a step under the latch is refused", _rejected),
        Mission("dark", "a dark link times the step out", _dark),
        Mission("dead", "a dead controller ends the plan", _dead),
        Mission("replan", "re-plan after a drift STOP, latch released after approval", _replan),
        Mission(
            "replan-fails", "the gate gone at re-planning leaves the rover latched",
            _replan_fails, own_gate=True,
        ),
        Mission("cancel", "a cancelled mission stops the rover", _cancel),
        Mission("demo", "rover demo's mission", _demo),
    )
}  # fmt: skip
"""Every mission, by name."""
