"""The ground's two other executors in the wire simulator's virtual time, beside the plan
run on board (:class:`sim.mission.MissionRig`), for ``benchmarks/bench_onboard.py``.

:class:`GroundRig` is a :class:`~sim.mission.MissionRig` whose ground does not uplink:
it runs the step-by-step executor (a step across the link, wait for its ``completed``,
then the next; drift control on the ground with
:class:`planner.ground.drift.DriftMonitor` on the POSE that comes down, its STOP
repeated until ``stopped``) or the move-and-wait operator (0.5 m drives, each confirmed
through the round trip, then 2 s to decide; no drift control). The rover side is the
same. The ground's logic is the executor's, re-stated here in virtual time (the real
one waits on threads).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import partial
from typing import Any

from bridge.link.linktypes import StepRequest
from bridge.link.odometry import ground_pose
from bridge.ros.rosport.contract import COMPLETED, ends_step
from firmware_proto.model.pose import Pose
from firmware_proto.model.uplink import PlanUplink
from firmware_proto.wire.messages import Command, PoseMsg
from planner.ground.drift import DriftMonitor
from sim.mission import UPLINK_AT_S, MissionRig, MissionScenario, _Channel
from sim.rig import _ACTION

__all__ = ["GroundRig", "RunFigures"]


@dataclass
class RunFigures:
    """What one run measured (virtual s, m)."""

    mode: str
    reached: bool = False
    mission_s: float = math.nan
    """From the first send to the ground knowing the plan completed."""
    detected_s: float | None = None
    """The stamp of the pose that confirmed the drift (rover clock)."""
    steps_twice: int = 0
    plans_twice: int = 0
    stop_sent_s: float | None = None
    stop_reached_s: float | None = None
    fixes: list[tuple[float, float, float]] = field(default_factory=list)
    """Every POSE the rover measured: ``(stamp, x, y)``, its stamped ``odom_ground``."""
    truth: list[tuple[float, float, float]] = field(default_factory=list)
    """The twin's pose at every control tick: ``(t, x, y)``, the ground truth."""


class _VerdictOf:
    """What :class:`DriftMonitor` reads of a verdict, from an uplink's prediction."""

    def __init__(self, uplink: PlanUplink) -> None:
        self.uplink = uplink
        self.start_pose = uplink.start
        self.final_pose = Pose(
            uplink.prediction[-1].x, uplink.prediction[-1].y, uplink.prediction[-1].yaw_deg
        )
        self.trajectory = self
        ends = {}
        for s in uplink.prediction:
            ends[s.step] = s.pose
        self.steps = [_End(ends[k]) for k in range(len(uplink.steps))]

    def pose_at(self, step: int, step_t_s: float) -> Pose | None:
        try:
            return self.uplink.pose_at(step, step_t_s)
        except IndexError:
            return None


@dataclass
class _End:
    end_pose: Pose


class GroundRig(MissionRig):
    """One plan run by the ground step by step, or by move-and-wait (see the module docstring)."""

    def __init__(
        self,
        mission: MissionScenario,
        mode: str,
        *,
        increment_m: float = 0.5,
        decision_s: float = 2.0,
    ) -> None:
        super().__init__(mission)
        self.mode = mode
        self.decision_s = decision_s
        self.down["pose"] = _Channel(self, "pose", False)
        units = self.rover.m_to_units(increment_m)
        steps: list[tuple[int, int, int]] = []
        for c, s, d in mission.steps:
            if mode == "move-and-wait" and c in (Command.FWD, Command.REV) and d > units:
                left = d
                while left > 0:
                    steps.append((c, s, min(units, left)))
                    left -= min(units, left)
            else:
                steps.append((c, s, d))
        self.wire_steps = steps
        rtt = 2 * mission.one_way_s
        work = sum(self.rover.step_duration_s(s, d) + rtt + decision_s + 1.0 for _, s, d in steps)
        self.end_s = max(self.end_s, 2 * work + 30.0)
        self.monitor = (
            DriftMonitor(_VerdictOf(self.uplink), one_way_delay_s=mission.one_way_s)  # type: ignore[arg-type]
            if mode == "step-by-step"
            else None
        )
        self.figures = RunFigures(mode)
        self._index = -1
        self._published = 0.0
        self._accepted = False
        self._deadline_at = math.inf
        self._ended = False

    # -- the ground executor ------------------------------------------------------------------
    def _ground_start(self) -> None:
        self._send(0)

    def _send(self, index: int) -> None:
        if self._ended:
            return
        self._index = index
        self._accepted = False
        self._published = self.now
        step = self.wire_steps[index]
        if self.monitor is not None:
            self.monitor.step_published(index, self.now)
        rtt = 2 * self.mission.one_way_s
        duration = self.rover.step_duration_s(step[1], step[2])
        deadline = self.now + duration * 1.5 + rtt + 2.0
        self._deadline_at = deadline
        self._at(deadline, _ACTION, partial(self._timeout, index, deadline))
        self.up["plan"].send(partial(self._rover_step, step, index))

    def _rover_step(self, step: tuple[int, int, int], index: int) -> None:
        sc = self.mission
        if sc.slip is not None and not self._slipped and index == sc.slip[0]:
            # as on board: the slip starts a share of the step's duration after it arrives
            k, frac, side, scale = sc.slip
            self._slipped = True
            at = self.now + frac * self.uplink.durations_s[k]
            self._at(at, _ACTION, partial(self._slip, side, scale))
        self.ledger.submitted += 1
        self.core.submit_step(StepRequest(*step), self.now)
        self._host_after()

    def _timeout(self, index: int, deadline: float) -> None:
        if self._ended or index != self._index or deadline != self._deadline_at:
            return
        self._end(False)
        self._ground_stop()

    def _end(self, reached: bool) -> None:
        if self._ended:
            return
        self._ended = True
        self.figures.reached = reached
        if reached:
            self.figures.mission_s = self.now - UPLINK_AT_S
        self._at(self.now + 2 * self.mission.one_way_s + 3.0, _ACTION, self._finish)

    def _ground_status(self, text: str) -> None:
        super()._ground_status(text)
        if self._ended or self._index < 0:
            return
        if text == "accepted" and not self._accepted:
            self._accepted = True
            if self.monitor is not None:
                self.monitor.step_accepted(self._index, self._published, self.now)
            return
        if text == COMPLETED:
            nxt = self._index + 1
            if nxt >= len(self.wire_steps):
                self._end(True)
            elif self.mode == "move-and-wait":
                self._deadline_at = math.inf
                self._at(self.now + self.decision_s, _ACTION, partial(self._send, nxt))
            else:
                self._send(nxt)
            return
        if ends_step(text) and not text.startswith("fault:pose"):
            self._end(False)
            self._ground_stop()

    def _ground_stop(self) -> None:
        if self.figures.stop_sent_s is None:
            self.figures.stop_sent_s = self.now
        super()._ground_stop()

    def _on_sample(self, msg: Any) -> None:
        super()._on_sample(msg)
        if isinstance(msg, PoseMsg):
            fix = ground_pose(msg)
            if fix is None:
                return
            stamp = self.now - fix.age_s
            self.figures.fixes.append((stamp, fix.x_m, fix.y_m))
            if self.monitor is not None:
                pose = (fix.x_m, fix.y_m, math.degrees(fix.yaw_rad), stamp)
                self.down["pose"].send(partial(self._ground_pose, *pose))

    def _tick(self) -> None:
        super()._tick()
        pose = self.ctl.twin.pose
        self.figures.truth.append((self.now, pose.x_m, pose.y_m))

    def _ground_pose(self, x: float, y: float, yaw_deg: float, stamp: float) -> None:
        if self._ended or self.monitor is None or self._index < 0:
            return
        event = self.monitor.update(x, y, yaw_deg, stamp)
        if event is not None:
            self.figures.detected_s = event.t_s
            self._end(False)
            self._ground_stop()

    def _final(self) -> list[Any]:
        return []  # the onboard invariants are not this ground's

    def run_ground(self) -> RunFigures:
        """Play it; the figures."""
        outcome = self.play()
        fig = self.figures
        fig.steps_twice = sum(1 for v in outcome.violations if v.rule == "once")
        fig.stop_reached_s = self.stop_reached_s
        return fig


def run_onboard(mission: MissionScenario) -> RunFigures:
    """The plan run on board, with the same figures."""
    rig = _OnboardFigures(mission)
    outcome = rig.play()
    fig = rig.figures
    fig.steps_twice = sum(1 for v in outcome.violations if v.rule in ("once", "step-once"))
    fig.plans_twice = sum(1 for v in outcome.violations if v.rule == "plan-once")
    fig.reached = outcome.ended == "completed"
    fig.stop_reached_s = rig.stop_reached_s
    last = rig.onboard.last_report
    if last is not None and last.guard is not None:
        fig.detected_s = last.guard.stamp_s
    return fig


class _OnboardFigures(MissionRig):
    def __init__(self, mission: MissionScenario) -> None:
        super().__init__(mission)
        self.figures = RunFigures("onboard")

    def _on_sample(self, msg: Any) -> None:
        super()._on_sample(msg)
        if isinstance(msg, PoseMsg):
            fix = ground_pose(msg)
            if fix is not None:
                self.figures.fixes.append((self.now - fix.age_s, fix.x_m, fix.y_m))

    def _tick(self) -> None:
        super()._tick()
        pose = self.ctl.twin.pose
        self.figures.truth.append((self.now, pose.x_m, pose.y_m))

    def _ground_report(self, text: str) -> None:
        super()._ground_report(text)
        mine = self.ground_reports.get(self.uplink.plan_id)
        if mine is not None and mine.outcome == "completed" and math.isnan(self.figures.mission_s):
            self.figures.mission_s = self.now - UPLINK_AT_S

    def _ground_stop(self) -> None:
        if self.figures.stop_sent_s is None:
            self.figures.stop_sent_s = self.now
        super()._ground_stop()
