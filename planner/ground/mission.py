"""Missions: plan, validate, execute leg by leg, and re-plan after a drift STOP; and the
move-and-wait operator the thesis compares against (docs/ground.md "Missions").

:class:`MissionRunner` is what ``rover go`` and ``rover demo`` run: the whole mission is
planned on the gate and each approved leg driven against its prediction; after a drift
STOP it re-plans from where the rover rested and releases the latch only once the new
plan is approved (the thesis's future-work item 3). :class:`MoveAndWait` is the thesis's
baseline: no gate, no twin, drives cut into increments each confirmed through the round
trip. It drives the gated mission's route, so the comparison measures moving and
waiting, not getting lost.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from bridge.ros.rosport.contract import COMPLETED
from firmware_proto.linkio.clock import Clock, is_lockstep
from firmware_proto.model.geometry import wrap_deg
from firmware_proto.model.plan import Plan, PlanStep
from firmware_proto.model.pose import Pose
from firmware_proto.model.verdict import Verdict
from firmware_proto.wire.messages import Command
from planner.errors import PlannerError
from planner.ground.drift import DriftEvent
from planner.ground.executor import ExecutionProgress, ExecutionResult, PlanExecutor
from planner.plan.orchestrator import MissionResult, PlannerOrchestrator

__all__ = [
    "CANCELLED",
    "LegRun",
    "MissionReport",
    "MissionRunner",
    "MoveAndWait",
    "split_for_move_and_wait",
]

logger = logging.getLogger(__name__)

CANCELLED = "cancelled by the operator"
"""The reason of a mission the operator cancelled."""


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
        elapsed_s: the executor's clock's time from the first plan to the end, s.
        planning_s: wall time spent planning and validating, s (not the clock's).
        cancelled: the operator cancelled the mission (the rover was sent STOP).
        move_and_wait: the runs are move-and-wait's increments (:class:`MoveAndWait`):
            no prediction was driven against, so no drift was measured; ``decision_s``
            is the operator's time per increment (mission s).
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
    cancelled: bool = False
    move_and_wait: bool = False
    decision_s: float = 0.0

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
                # The repair named is the one that produced this attempt's plan.
                lines.append(
                    f"    attempt {attempt.index + 1} ({attempt.repair_name}): "
                    f"{attempt.verdict.summary()}"
                )
        if self.move_and_wait:
            lines.extend(self._increments(time_scale))
        for i, run in enumerate(() if self.move_and_wait else self.runs):
            ex = run.execution
            worst_m, worst_deg = ex.worst_drift
            took = ex.elapsed_s * time_scale
            done = sum(1 for s in ex.steps if s.status == COMPLETED)
            lines.append(
                f"  run {i + 1}: {done}/{len(run.plan.commands)} steps completed, {ex.outcome}"
                f" in {took:.1f} s; worst drift {worst_m:.3f} m, {worst_deg:.1f} deg"
            )
            if ex.drift is not None:
                latency = (
                    f"{ex.stop_latency_s * 1e3:.3f} ms" if ex.stop_latency_s is not None else "n/a"
                )
                lines.append(f"    drift STOP: {ex.drift.reason}; detection to STOP {latency}")
            elif not ex.completed:
                lines.append(f"    {ex.outcome}: {ex.reason}")
            lines.extend(f"    note: {note}" for note in ex.notes)
        if self.final_pose is not None:
            lines.append(
                f"  final pose ({self.final_pose.x:.3f}, {self.final_pose.y:.3f}, "
                f"{self.final_pose.yaw_deg:.1f} deg): {self.position_error_m:.3f} m and "
                f"{self.yaw_error_deg:.1f} deg from the goal"
            )
        total = self.elapsed_s * time_scale
        unchecked = "; the route was not validated on the gate" * (
            self.move_and_wait and not self.plannings
        )
        lines.append(
            f"  time: {total:.1f} s, of which planning {self.planning_s:.2f} s (wall{unchecked})"
        )
        return "\n".join(lines)

    def _increments(self, time_scale: float) -> list[str]:
        """Move-and-wait's runs as increments, without drift figures (no prediction)."""
        done = sum(1 for r in self.runs if r.execution.completed)
        took = sum(r.execution.elapsed_s for r in self.runs) * time_scale
        lines = [
            f"  move-and-wait: {done}/{len(self.runs)} increments completed, {took:.1f} s "
            f"driving and confirming, {self.decision_s:g} s to decide after each; no drift "
            "control (no prediction to compare with)"
        ]
        last = self.runs[-1].execution if self.runs else None
        if last is not None and not last.completed:
            lines.append(f"    increment {len(self.runs)}: {last.outcome}: {last.reason}")
        return lines


@dataclass
class MissionRunner:
    """Runs missions (docs/ground.md "Missions").

    Attributes:
        replans: drift STOPs after which the runner re-plans (0: stop there).
        on_progress: called with the executor's progress, on the executing thread.
        on_drift: called after a drift STOP, before the re-plan and the latch release.
        on_event: called with one line for each notable event.
        on_planned: called with each planning as soon as the gate has judged it,
            approved or not.
        cancel: set it (from a signal handler, another thread) to end the mission: the
            running plan is stopped (STOP) and nothing more is planned or sent.
    """

    orchestrator: PlannerOrchestrator
    executor: PlanExecutor
    replans: int = 1
    on_progress: Callable[[ExecutionProgress], None] | None = None
    on_drift: Callable[[ExecutionResult], None] | None = None
    on_event: Callable[[str], None] = field(default=lambda line: None)
    cancel: threading.Event | None = None
    on_planned: Callable[[MissionResult], None] | None = None

    def run(self, goal: Pose, *, start: Pose | None = None) -> MissionReport:
        """Plan and drive to ``goal`` from ``start`` (default: the map's start).

        After a drift STOP (at most ``replans`` times): ``on_drift``, wait for rest,
        re-plan from there, and release the latch only once the gate approved. No rest
        reported, or a re-plan not approved or failed: the mission ends with the rover
        latched, and the reason says so.

        Raises:
            InvalidPoseError, OutOfBoundsError, GoalInObstacleError: bad goal or start.
            GateCallError: the gate failed on the first planning (nothing was sent to
                the rover).
        """
        t0 = self.executor.clock.now()
        start = start or self.orchestrator.world.start
        plannings: list[MissionResult] = []
        runs: list[LegRun] = []
        planning_s = 0.0
        replans = self.replans
        where = start
        latched = False  # by a drift STOP this runner means to recover from

        def end(reason: str, *, reached: bool = False, cancelled: bool = False) -> MissionReport:
            if latched:
                reason += "; the rover stays stopped (STOP latched)"
            return self._report(
                goal, start, plannings, runs, reached, reason, t0, planning_s, cancelled
            )

        while True:
            if self._cancelled():
                return end(CANCELLED, cancelled=True)
            tp = time.monotonic()
            try:
                mission = self.orchestrator.plan_mission(goal, start=where)
            except PlannerError as exc:
                if not latched:
                    raise
                planning_s += time.monotonic() - tp
                self.on_event(f"re-planning failed: {exc}")
                return end(f"re-planning failed: {exc}")
            planning_s += time.monotonic() - tp
            plannings.append(mission)
            if self.on_planned is not None:
                self.on_planned(mission)
            outcome = "approved" if mission.approved else "REJECTED"
            self.on_event(
                f"planned: {len(mission.legs)} leg(s), {len(mission.attempts)} attempt(s), "
                f"{mission.repair_cycles} repair(s), {outcome}"
            )
            if not mission.approved:
                what = "re-plan not approved" if latched else "not approved"
                return end(f"{what}: {mission.reason}" if mission.reason else what)
            if self._cancelled():
                return end(CANCELLED, cancelled=True)
            if latched:
                if not self.executor.clear_stop():
                    return end("the rover did not confirm CLEAR_STOP")
                latched = False
                self.on_event("re-plan approved: STOP latch released")
            replanned = False
            for plan, verdict in zip(mission.plans, mission.verdicts, strict=True):
                result = self.executor.execute(
                    plan, verdict, on_progress=self.on_progress, cancel=self.cancel
                )
                runs.append(LegRun(plan, verdict, result))
                if result.completed:
                    continue
                self.on_event(f"execution ended: {result.outcome}: {result.reason}")
                if result.outcome == "cancelled":
                    return end(CANCELLED, cancelled=True)
                if result.outcome == "drift" and replans > 0 and result.reported_pose is not None:
                    replans -= 1
                    latched = True
                    if self.on_drift is not None:
                        self.on_drift(result)
                    # Re-plan from where the rover came to rest, not where it drifted.
                    if not self.executor.wait_for_rest():
                        return end("the rover did not report coming to rest after the drift STOP")
                    where = self.executor.settled_pose() or result.reported_pose
                    self.on_event(
                        f"at rest; re-planning from the reported pose ({where.x:.2f}, "
                        f"{where.y:.2f}, {where.yaw_deg:.0f} deg), STOP still latched"
                    )
                    replanned = True
                    break
                return end(result.reason)
            if not replanned:
                return end("", reached=True)

    def run_plan(self, plan: Plan, *, start: Pose | None = None) -> MissionReport:
        """``rover go --plan FILE``: validate a given plan once, without repair
        (:meth:`PlannerOrchestrator.check_plan`), and drive it from ``start`` (default:
        the map's start); a drift STOP ends it (no re-plan); ``reached``: every step
        completed.

        Raises:
            InvalidPoseError, OutOfBoundsError: a start off the map.
            GateCallError: the gate failed (nothing was sent to the rover).
        """
        t0 = self.executor.clock.now()
        tp = time.monotonic()
        where = start or self.orchestrator.world.start
        mission = self.orchestrator.check_plan(plan, start=where)
        planning_s = time.monotonic() - tp
        plannings = [mission]
        runs: list[LegRun] = []
        if self.on_planned is not None:
            self.on_planned(mission)
        self.on_event(
            f"the plan ({len(plan.commands)} steps): "
            + ("approved" if mission.approved else f"REJECTED: {mission.reason}")
        )

        def end(reason: str, *, reached: bool = False, cancelled: bool = False) -> MissionReport:
            return self._report(
                mission.goal, where, plannings, runs, reached, reason, t0, planning_s, cancelled
            )

        if not mission.approved:
            return end(f"not approved: {mission.reason}")
        if self._cancelled():
            return end(CANCELLED, cancelled=True)
        verdict = mission.verdicts[0]
        result = self.executor.execute(
            plan, verdict, on_progress=self.on_progress, cancel=self.cancel
        )
        runs.append(LegRun(plan, verdict, result))
        if result.completed:
            return end("", reached=True)
        self.on_event(f"execution ended: {result.outcome}: {result.reason}")
        if result.outcome == "cancelled":
            return end(CANCELLED, cancelled=True)
        return end(result.reason)

    def _cancelled(self) -> bool:
        return self.cancel is not None and self.cancel.is_set()

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
        cancelled: bool = False,
    ) -> MissionReport:
        final = self.executor.settled_pose()
        return _report(
            goal,
            start,
            plannings,
            runs,
            reached,
            reason,
            final,
            self.executor.clock.now() - t0,
            planning_s,
            cancelled,
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
    cancelled: bool = False,
    *,
    move_and_wait: bool = False,
    decision_s: float = 0.0,
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
        cancelled,
        move_and_wait,
        decision_s,
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
    """The move-and-wait operator.

    Attributes:
        executor: sends each command and waits for its confirmation (no drift control).
        increment_m: longest drive the operator sends without looking, m.
        decision_s: the operator's time to decide, per command, mission (twin) s.
        time_scale: twin seconds per wall second.
        on_progress: called with the executor's progress.
        cancel: set it to end the drive (STOP is sent).
    """

    executor: PlanExecutor
    increment_m: float = 0.5
    decision_s: float = 2.0
    time_scale: float = 1.0
    on_progress: Callable[[ExecutionProgress], None] | None = None
    cancel: threading.Event | None = None

    def drive(
        self,
        goal: Pose,
        start: Pose,
        plans: tuple[Plan, ...],
        *,
        plannings: tuple[MissionResult, ...] = (),
        planning_s: float = 0.0,
    ) -> MissionReport:
        """Drive ``plans`` one confirmed command at a time, progress per increment;
        ``plannings`` and ``planning_s`` (wall s) say how the route was planned, for the
        report."""
        clock = self.executor.clock
        t0 = clock.now() - planning_s
        units = self.executor.rover.m_to_units(self.increment_m)
        runs: list[LegRun] = []
        cancel = self.cancel or threading.Event()
        increments = [
            (plan, step) for plan in plans for step in split_for_move_and_wait(plan, units)
        ]
        cfg = self.executor.config

        def each_s(step: PlanStep) -> float:
            duration = self.executor.rover.step_duration_s(step.speed, step.distance)
            return (duration + self.decision_s) / self.time_scale + cfg.link_rtt_s

        def end(reached: bool, reason: str) -> MissionReport:
            return _report(
                goal,
                start,
                list(plannings),
                runs,
                reached,
                reason,
                self.executor.settled_pose(),
                clock.now() - t0,
                planning_s,
                reason == CANCELLED,
                move_and_wait=True,
                decision_s=self.decision_s,
            )

        for k, (plan, step) in enumerate(increments):
            later = sum(each_s(s) for _, s in increments[k + 1 :])

            def progress(p: ExecutionProgress, k: int = k, later: float = later) -> None:
                if self.on_progress is not None:
                    self.on_progress(
                        ExecutionProgress(
                            k,
                            len(increments),
                            p.status,
                            p.eta_s + later,
                            None,
                            None,
                            None,
                            unit="increment",
                        )
                    )

            single = Plan(plan.goal, (step,))
            result = self.executor.execute(single, None, on_progress=progress, cancel=cancel)
            runs.append(LegRun(single, None, result))
            if not result.completed:
                if result.outcome == "cancelled":
                    return end(False, CANCELLED)
                # The executor numbers the one step it ran; the operator counts increments.
                where = f"increment {k + 1}/{len(increments)}"
                return end(False, result.reason.replace("step 1/1", where, 1))
            if _pause(clock, cancel, self.decision_s / self.time_scale):
                return end(False, CANCELLED)
        return end(True, "")


def _pause(clock: Clock, cancel: threading.Event, seconds: float) -> bool:
    """Let ``seconds`` pass on ``clock``; whether ``cancel`` was set (at once on the wall
    clock; after the pause in lockstep, where nothing outside the clock's thread runs)."""
    if is_lockstep(clock):
        clock.sleep(seconds)
        return cancel.is_set()
    return cancel.wait(seconds)
