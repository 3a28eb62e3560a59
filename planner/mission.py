"""Missions: plan, validate, execute leg by leg, and re-plan after a drift STOP; and the
move-and-wait operator the thesis compares against.

:class:`MissionRunner` is what ``rover go`` and ``rover demo`` run: the orchestrator
plans and validates the whole mission on the gate (repairing rejected plans), the
executor drives each approved leg against its prediction, and when drift control stops
the rover the runner (if allowed) clears the latch and re-plans from the rover's reported
pose, which is the thesis's future-work item 3, kept simple.

:class:`MoveAndWait` is the baseline of the thesis's comparison: no gate and no twin.
The operator sends one short command, waits for its confirmation through the whole round
trip, looks at the delayed picture (``decision_s``), and sends the next. Lacking a
prediction to trust, drives are cut into increments the operator can check
(``increment_m``). It drives the same route as the gated mission, so the comparison
measures the cost of moving and waiting, not of getting lost.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from firmware_proto.messages import Command
from firmware_proto.plan import Plan, PlanStep
from planner.drift import DriftEvent
from planner.executor import ExecutionResult, PlanExecutor, Progress
from planner.geometry import Pose, wrap_deg
from planner.orchestrator import MissionResult, PlannerOrchestrator
from planner.verdict import Verdict

__all__ = ["LegRun", "MissionReport", "MissionRunner", "MoveAndWait", "split_for_move_and_wait"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class LegRun:
    """One executed plan: the plan, its verdict (``None`` without a gate) and the result."""

    plan: Plan
    verdict: Verdict | None
    execution: ExecutionResult


@dataclass(frozen=True)
class MissionReport:
    """How a mission went.

    Attributes:
        goal, start: the mission's goal and where it started.
        plannings: each :class:`MissionResult` (the first, then one per re-plan).
        runs: each executed plan, in order.
        reached: every leg completed.
        reason: why it stopped short (``""`` when reached).
        final_pose: the rover's last reported pose.
        position_error_m, yaw_error_deg: final pose against the goal.
        elapsed_s: wall time from the first plan to the end.
        planning_s: wall time spent planning and validating.
    """

    goal: Pose
    start: Pose
    plannings: tuple[MissionResult, ...]
    runs: tuple[LegRun, ...]
    reached: bool
    reason: str
    final_pose: Pose | None
    position_error_m: float | None
    yaw_error_deg: float | None
    elapsed_s: float
    planning_s: float

    @property
    def drift_events(self) -> tuple[DriftEvent, ...]:
        """Every drift STOP, in order."""
        return tuple(r.execution.drift for r in self.runs if r.execution.drift is not None)

    @property
    def repair_cycles(self) -> int:
        """Repairs the orchestrator made over every planning."""
        return sum(p.repair_cycles for p in self.plannings)

    @property
    def steps_executed(self) -> int:
        """Steps published over the whole mission."""
        return sum(len(r.execution.steps) for r in self.runs)

    def summary(self, time_scale: float = 1.0) -> str:
        """A few lines for the operator (times in mission seconds: wall x ``time_scale``)."""
        lines = [
            f"mission to ({self.goal.x:.2f}, {self.goal.y:.2f}, {self.goal.yaw_deg:.0f} deg): "
            + ("REACHED" if self.reached else f"NOT REACHED ({self.reason})")
        ]
        for i, planning in enumerate(self.plannings):
            what = "plan" if i == 0 else f"re-plan {i}"
            tried = len(planning.attempts)
            verdict = "approved" if planning.approved else planning.reason
            lines.append(
                f"  {what}: {len(planning.legs)} leg(s), {tried} attempt(s), "
                f"{planning.repair_cycles} repair(s); {verdict}"
            )
            for attempt in planning.attempts:
                lines.append(
                    f"    attempt {attempt.index + 1}: {attempt.verdict.summary()}"
                    + (f" -> {attempt.repair_name}" if attempt.repair_name else "")
                )
        for i, run in enumerate(self.runs):
            ex = run.execution
            worst_m, worst_deg = ex.worst_drift
            took = ex.elapsed_s * time_scale
            lines.append(
                f"  run {i + 1}: {len(ex.steps)}/{len(run.plan.commands)} steps, {ex.outcome}"
                f" in {took:.1f} s; worst drift {worst_m:.3f} m, {worst_deg:.1f} deg"
            )
            if ex.drift is not None:
                latency = (
                    f"{ex.stop_latency_s * 1e3:.3f} ms" if ex.stop_latency_s is not None else "n/a"
                )
                lines.append(f"    drift STOP: {ex.drift.reason}; detection to STOP {latency}")
        if self.final_pose is not None:
            lines.append(
                f"  final pose ({self.final_pose.x:.3f}, {self.final_pose.y:.3f}, "
                f"{self.final_pose.yaw_deg:.1f} deg): {self.position_error_m:.3f} m and "
                f"{self.yaw_error_deg:.1f} deg from the goal"
            )
        total = self.elapsed_s * time_scale
        lines.append(f"  time: {total:.1f} s, of which planning {self.planning_s:.2f} s (wall)")
        return "\n".join(lines)


@dataclass
class MissionRunner:
    """Runs missions: see the module docstring.

    Attributes:
        orchestrator: plans and validates (its gate client and map).
        executor: drives plans over ROS.
        replans: drift STOPs after which the runner re-plans (0: stop there).
        on_progress: called after each step with the executor's progress.
        on_drift: called after a drift STOP, before the latch is cleared (the demo uses
            it to take the rover out of the sand; an operator would look first).
        on_event: called with one line for each notable event.
    """

    orchestrator: PlannerOrchestrator
    executor: PlanExecutor
    replans: int = 1
    on_progress: Callable[[Progress], None] | None = None
    on_drift: Callable[[ExecutionResult], None] | None = None
    on_event: Callable[[str], None] = field(default=lambda line: None)

    def run(self, goal: Pose, *, start: Pose | None = None) -> MissionReport:
        """Plan and drive to ``goal`` from ``start`` (default: the map's start)."""
        t0 = time.monotonic()
        start = start or self.orchestrator.world.start
        plannings: list[MissionResult] = []
        runs: list[LegRun] = []
        planning_s = 0.0
        replans = self.replans
        where = start
        while True:
            tp = time.monotonic()
            mission = self.orchestrator.plan_mission(goal, start=where)
            planning_s += time.monotonic() - tp
            plannings.append(mission)
            outcome = "approved" if mission.approved else "REJECTED"
            self.on_event(
                f"planned: {len(mission.legs)} leg(s), {len(mission.attempts)} attempt(s), "
                f"{mission.repair_cycles} repair(s), {outcome}"
            )
            if not mission.approved:
                return self._report(
                    goal,
                    start,
                    plannings,
                    runs,
                    False,
                    mission.reason or "not approved",
                    t0,
                    planning_s,
                )
            replanned = False
            for plan, verdict in zip(mission.plans, mission.verdicts, strict=True):
                result = self.executor.execute(plan, verdict, on_progress=self.on_progress)
                runs.append(LegRun(plan, verdict, result))
                if result.completed:
                    continue
                self.on_event(f"execution ended: {result.outcome}: {result.reason}")
                if result.outcome == "drift" and replans > 0 and result.reported_pose is not None:
                    replans -= 1
                    if self.on_drift is not None:
                        self.on_drift(result)
                    if not self.executor.clear_stop():
                        return self._report(
                            goal,
                            start,
                            plannings,
                            runs,
                            False,
                            "the rover did not confirm CLEAR_STOP",
                            t0,
                            planning_s,
                        )
                    # The STOP took half a round trip to reach the rover, which braked
                    # after that: re-plan from where it came to rest, not from where it
                    # was when the drift was seen.
                    where = self.executor.settled_pose() or result.reported_pose
                    self.on_event(
                        f"re-planning from the reported pose ({where.x:.2f}, {where.y:.2f}, "
                        f"{where.yaw_deg:.0f} deg)"
                    )
                    replanned = True
                    break
                return self._report(
                    goal, start, plannings, runs, False, result.reason, t0, planning_s
                )
            if not replanned:
                return self._report(goal, start, plannings, runs, True, "", t0, planning_s)

    def _report(
        self,
        goal: Pose,
        start: Pose,
        plannings: list[MissionResult],
        runs: list[LegRun],
        reached: bool,
        reason: str,
        t0: float,
        planning_s: float,
    ) -> MissionReport:
        final = self.executor.settled_pose()
        return _report(
            goal, start, plannings, runs, reached, reason, final, time.monotonic() - t0, planning_s
        )


def _report(
    goal: Pose,
    start: Pose,
    plannings: list[MissionResult],
    runs: list[LegRun],
    reached: bool,
    reason: str,
    final: Pose | None,
    elapsed_s: float,
    planning_s: float,
) -> MissionReport:
    err = yaw_err = None
    if final is not None:
        err = math.hypot(final.x - goal.x, final.y - goal.y)
        yaw_err = abs(wrap_deg(final.yaw_deg - goal.yaw_deg))
    return MissionReport(
        goal,
        start,
        tuple(plannings),
        tuple(runs),
        reached,
        reason,
        final,
        err,
        yaw_err,
        elapsed_s,
        planning_s,
    )


def split_for_move_and_wait(plan: Plan, increment_units: int) -> list[PlanStep]:
    """The plan's steps with every drive cut into increments of at most
    ``increment_units`` (turns unchanged)."""
    steps: list[PlanStep] = []
    for step in plan.commands:
        if step.code in (Command.FWD, Command.REV) and step.distance > increment_units:
            left = step.distance
            while left > 0:
                part = min(increment_units, left)
                steps.append(PlanStep(step.command, step.speed, part))
                left -= part
        else:
            steps.append(step)
    return steps


@dataclass
class MoveAndWait:
    """The move-and-wait operator (see the module docstring).

    Attributes:
        executor: sends each command and waits for its confirmation (drift control off:
            there is no prediction to compare with).
        increment_m: longest drive the operator sends without looking, m.
        decision_s: the operator's time to look at the delayed picture and decide, per
            command, in mission (twin) seconds.
        time_scale: twin seconds per wall second (the benchmark runs sped up).
    """

    executor: PlanExecutor
    increment_m: float = 0.5
    decision_s: float = 2.0
    time_scale: float = 1.0

    def drive(self, goal: Pose, start: Pose, plans: tuple[Plan, ...]) -> MissionReport:
        """Drive ``plans`` (the same route as the gated mission) one confirmed command at a
        time."""
        t0 = time.monotonic()
        units = self.executor.rover.m_to_units(self.increment_m)
        runs: list[LegRun] = []
        for plan in plans:
            for step in split_for_move_and_wait(plan, units):
                single = Plan(plan.goal, (step,))
                result = self.executor.execute(single, None)
                runs.append(LegRun(single, None, result))
                if not result.completed:
                    return _report(
                        goal,
                        start,
                        [],
                        runs,
                        False,
                        result.reason,
                        self.executor.settled_pose(),
                        time.monotonic() - t0,
                        0.0,
                    )
                time.sleep(self.decision_s / self.time_scale)
        return _report(
            goal,
            start,
            [],
            runs,
            True,
            "",
            self.executor.settled_pose(),
            time.monotonic() - t0,
            0.0,
        )
