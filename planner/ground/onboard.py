"""Plans run on board: the ground's side of the uplink (docs/onboard.md, docs/ground.md).

:class:`OnboardExecutor` (the default of ``rover go`` and ``rover demo``) sends an
approved plan and its verdict as one uplink tagged with the uplink token, resends it
every ``resend_s`` until the rover answers (``busy``, ``latched`` and ``no_fix`` too,
within the plan's budget), then only listens: the rover runs and guards the steps, and
its reports become the step-by-step executor's progress and result (a guard stop is
outcome ``drift``). A plan without a verdict runs step by step.

The ground keeps STOP authority: ``cancel`` or a plan that outlives its time publishes
STOP every ``stop_repeat_s`` until ``stopped``, and a cancel of the plan id until
acknowledged, so a copy still on its way never runs.

Threads: :meth:`OnboardExecutor.execute` blocks its caller (the mission's thread); the
port's lane thread runs the callbacks, which only store what came and wake it.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from bridge.ros.rosport import RosPort, qos
from bridge.ros.rosport.contract import (
    COMPLETED,
    ONBOARD_POSE,
    ONBOARD_REPORT,
    PLAN_ACK,
    PLAN_UPLINK,
)
from bridge.ros.rosport.msgs import Empty, Odometry, String, stamp_s, yaw_rad
from firmware_proto.errors import UplinkError
from firmware_proto.model.downlink import OnboardReport, RestReport, decode_report
from firmware_proto.model.plan import Plan
from firmware_proto.model.pose import Pose
from firmware_proto.model.rover import RoverDescription
from firmware_proto.model.uplink import (
    REFUSED_FOR_NOW,
    CancelUplink,
    DriftLimits,
    PlanUplink,
    UplinkAck,
    decode_ack,
)
from firmware_proto.model.verdict import Verdict
from planner.ground.drift import DriftEvent
from planner.ground.executor import (
    ExecutionProgress,
    ExecutionResult,
    ExecutorConfig,
    PlanExecutor,
    StepOutcome,
)

__all__ = ["EXECUTION_MODES", "OnboardExecutor", "UplinkOptions"]

logger = logging.getLogger(__name__)

EXECUTION_MODES = ("onboard", "step-by-step", "move-and-wait")
"""How ``rover go``/``demo`` run a mission: on board (default), step-by-step, or move-and-wait."""

REST_WAIT_S = 6.0
"""How long beyond the round trip the ground waits for a plan's rest report, s (due within 5 s)."""


@dataclass(frozen=True)
class UplinkOptions:
    """The uplink's settings.

    Attributes:
        token: the uplink token the uplink is tagged with (``None``: untagged);
            ``ROVER_UPLINK_TOKEN``, which ``rover stack up`` and ``rover demo`` make.
        resend_s: an unanswered uplink (or cancel) is sent again this often, wall s
            (``None``: a third of the round trip, at least 0.5 s).
        limits: the drift limits the rover stops at (``None``: the description's).
    """

    token: str | None = None
    resend_s: float | None = None
    limits: DriftLimits | None = None


class OnboardExecutor(PlanExecutor):
    """Runs approved plans on board, behind the step-by-step executor's interface (and
    as one, for plans without a verdict)."""

    def __init__(
        self,
        port: RosPort,
        rover: RoverDescription,
        config: ExecutorConfig | None = None,
        uplink: UplinkOptions | None = None,
    ) -> None:
        super().__init__(port, rover, config)
        self.uplink = uplink or UplinkOptions()
        self._uplink_pub = port.publisher(PLAN_UPLINK, String, qos.COMMAND)
        self._answer = threading.Condition()
        self._acks: dict[int, UplinkAck] = {}
        self._reports: dict[int, OnboardReport] = {}
        """The answers and latest report of the plan in hand (:attr:`_current`) only."""
        self._current = 0
        self._boot = ""
        """The boot id of the rover's onboard program, from its latest report."""
        self._onboard_pose: tuple[float, Pose] | None = None
        self._last_id = 0
        self.last_report: OnboardReport | None = None
        """The latest report of the last plan run on board."""
        self._subs += [
            port.subscribe(PLAN_ACK, String, self._on_ack, qos.STATUS),
            port.subscribe(ONBOARD_REPORT, String, self._on_report, qos.STATUS),
            port.subscribe(ONBOARD_POSE, Odometry, self._on_onboard_pose, qos.SENSOR),
        ]

    # -- what comes down -------------------------------------------------------------------
    def _on_ack(self, msg: String) -> None:
        try:
            ack = decode_ack(msg.data)
        except UplinkError as exc:
            logger.warning("an answer that is no ack: %s", exc)
            return
        with self._answer:
            if ack.plan_id == self._current:
                self._acks[ack.plan_id] = ack
            self._answer.notify_all()

    def _on_report(self, msg: String) -> None:
        try:
            report = decode_report(msg.data)
        except UplinkError as exc:
            logger.warning("a report that is no report: %s", exc)
            return
        with self._answer:
            if report.boot:
                self._boot = report.boot
            if report.plan_id != 0 and report.plan_id == self._current:
                known = self._reports.get(report.plan_id)
                if known is None or report.seq > known.seq or report.boot != known.boot:
                    self._reports[report.plan_id] = report
            self._answer.notify_all()

    @property
    def boot(self) -> str:
        """The boot id of the rover's onboard program, from its latest report (``""``:
        none heard yet)."""
        with self._answer:
            return self._boot

    def _wait_boot(self, deadline: float, cancel: threading.Event | None) -> str:
        """The boot id to sign for: the latest report's, waited for until ``deadline``
        (monotonic) when none came yet (``""``: none came, or ``cancel`` was set)."""
        with self._answer:
            while not self._boot:
                left = deadline - time.monotonic()
                if left <= 0 or (cancel is not None and cancel.is_set()):
                    break
                self._answer.wait(min(0.1, left))
            return self._boot

    def _on_onboard_pose(self, msg: Odometry) -> None:
        p = msg.pose.pose
        pose = Pose(p.position.x, p.position.y, math.degrees(yaw_rad(p.orientation)))
        with self._answer:
            self._onboard_pose = (stamp_s(msg.header.stamp), pose)

    @property
    def onboard_estimate(self) -> Pose | None:
        """The rover's latest estimate (``onboard_pose``), ``None`` before one came."""
        with self._answer:
            return self._onboard_pose[1] if self._onboard_pose else None

    # -- the rest, as the rover reported it -----------------------------------------------
    def _rest(self) -> RestReport | None:
        report = self.last_report
        return report.rest if report is not None else None

    def settled_pose(self, timeout_s: float | None = None, *, after_s: float = 0.0) -> Pose | None:
        """Where the rover came to rest after the last plan run on board: its own
        estimate (the EKF of encoders, IMU and POSE); before any, the ground's reading
        of ``odom_ground`` (:meth:`PlanExecutor.settled_pose`)."""
        rest = self._rest()
        if rest is not None:
            return rest.pose
        return super().settled_pose(timeout_s, after_s=after_s)

    @property
    def settled_covariance(self) -> tuple[float, ...] | None:
        """The covariance (3x3 of x, y, yaw, row-major) of :meth:`settled_pose` when the
        rover reported it, else ``None``."""
        rest = self._rest()
        return rest.covariance if rest is not None else None

    def wait_for_rest(self, timeout_s: float | None = None) -> bool:
        """The rover reported its rest after the last plan (it waits for the wheels to
        stand before it does); else the step-by-step executor's wait on ``odom``."""
        rest = self._rest()
        if rest is not None:
            return rest.at_rest
        return super().wait_for_rest(timeout_s)

    def clear_stop(self, timeout_s: float | None = None) -> bool:
        """Release the rover's latch: CLEAR every ``resend_s`` until ``cleared`` comes
        back (a lossy link loses some), at most ``timeout_s`` (default three round trips
        plus the step margin)."""
        cfg = self.config
        deadline = time.monotonic() + (
            timeout_s if timeout_s is not None else 3 * cfg.link_rtt_s + cfg.step_margin_s
        )
        self._cleared.clear()
        while True:
            self._clear_pub.publish(Empty())
            left = deadline - time.monotonic()
            if self._cleared.wait(max(0.0, min(self._resend_s(), left))):
                return True
            if time.monotonic() >= deadline:
                return False

    def _resend_s(self) -> float:
        if self.uplink.resend_s is not None:
            return self.uplink.resend_s
        return max(0.5, self.config.link_rtt_s / 3.0)

    def next_plan_id(self) -> int:
        """A new plan id: the wall clock's milliseconds, and always more than the last."""
        self._last_id = max(self._last_id + 1, time.time_ns() // 1_000_000)
        return self._last_id

    # -- execution -----------------------------------------------------------------------------
    def execute(
        self,
        plan: Plan,
        verdict: Verdict | None = None,
        *,
        on_progress: Callable[[ExecutionProgress], None] | None = None,
        cancel: threading.Event | None = None,
    ) -> ExecutionResult:
        """Run ``plan`` on board; without a verdict, step by step. Blocks until the rover
        reports the end and its rest, the plan times out, or ``cancel`` is set (STOP and
        a cancel are sent, outcome ``cancelled``)."""
        if verdict is None:
            return super().execute(plan, verdict, on_progress=on_progress, cancel=cancel)
        cfg = self.config
        limits = self.uplink.limits or DriftLimits(cfg.drift_linear_m, cfg.drift_angular_deg)
        pid = self.next_plan_id()
        with self._answer:
            self._current = pid
            self._acks.clear()
            self._reports.clear()
        t_begin = time.monotonic()
        unanswered_s = 3 * cfg.link_rtt_s + 5.0
        boot = self._wait_boot(t_begin + unanswered_s, cancel)
        uplink = PlanUplink.from_verdict(pid, plan.to_wire(), verdict, limits, boot)
        envelope = uplink.envelope(self.uplink.token)
        steps = plan.to_wire()
        budget = (
            uplink.expected_duration_s * cfg.duration_factor / cfg.time_scale
            + 2 * cfg.link_rtt_s
            + cfg.step_margin_s * len(steps)
            + REST_WAIT_S
        )
        deadline = t_begin + budget
        self._stopped.clear()
        self.last_report = None
        tracker = _Progress(steps, verdict, cfg, on_progress, t_begin)
        logger.info("uplink of plan %d: %d steps, verdict %s", pid, len(steps), uplink.verdict[:12])
        sent = 0
        next_send = t_begin
        outcome = reason = ""
        report: OnboardReport | None = None
        ended_at: float | None = None
        try:
            while True:
                now = time.monotonic()
                if cancel is not None and cancel.is_set():
                    outcome, reason = "cancelled", "cancelled by the operator"
                    break
                with self._answer:
                    ack = self._acks.get(pid)
                    report = self._reports.get(pid)
                if report is not None:
                    self.last_report = report
                    tracker.update(report)
                    if report.ended and ended_at is None:
                        ended_at = now
                    if ended_at is not None and (
                        report.rest is not None or now > ended_at + cfg.link_rtt_s + REST_WAIT_S
                    ):
                        break
                if (
                    ack is not None
                    and ack.result == "refused"
                    and ack.reason not in REFUSED_FOR_NOW
                ):
                    outcome = "rejected"
                    reason = f"the rover refused the plan: {ack.reason}: {ack.detail}"
                    if ack.reason in ("unauthenticated", "bad_tag"):
                        reason += " (the uplink token is $ROVER_UPLINK_TOKEN: rover stack env)"
                    break
                taken = report is not None or (ack is not None and ack.taken)
                if not taken and ack is None and now - t_begin > unanswered_s:
                    outcome = "rejected"
                    heard = (
                        f"no answer to the uplink of plan {pid}"
                        if boot
                        else "no report from rover onboard (nothing to sign the plan for)"
                    )
                    reason = (
                        f"{heard} in {unanswered_s:.0f} s: is rover onboard running beside "
                        "the bridge? (--step-by-step runs without it)"
                    )
                    break
                if not taken and now >= next_send:
                    self._uplink_pub.publish(String(data=envelope))
                    sent += 1
                    next_send = now + self._resend_s()
                if now >= deadline and ended_at is None:
                    outcome = "timeout"
                    reason = f"plan {pid} did not end on board within {budget:.0f} s"
                    break
                with self._answer:
                    self._answer.wait(0.1)
        except BaseException:
            self._abandon(pid)
            raise
        if outcome in ("cancelled", "timeout") or (outcome == "rejected" and sent and ack is None):
            logger.warning("plan %d: %s; sending STOP and a cancel", pid, reason)
            if not self._abandon(pid):
                reason += "; STOP not confirmed within the round trip"
        result = self._result(plan, uplink, report, outcome, reason, t_begin, tracker, sent)
        logger.info("plan %d on board: %s (%s)", pid, result.outcome, result.reason)
        return result

    def _abandon(self, pid: int) -> bool:
        """STOP (repeated until ``stopped``) and a cancel of ``pid`` (resent until it is
        acknowledged, bounded); whether the rover confirmed the STOP."""
        envelope = CancelUplink(pid).envelope(self.uplink.token)
        with self._answer:
            self._current = pid
        self._stopped.clear()
        stopped = self.stop()
        deadline = time.monotonic() + 2 * self.config.link_rtt_s + self.config.step_margin_s
        while time.monotonic() < deadline:
            self._uplink_pub.publish(String(data=envelope))
            with self._answer:
                ack = self._acks.get(pid)
                if ack is not None and ack.result == "cancelled":
                    break
                self._answer.wait(self._resend_s())
        return stopped

    def _result(
        self,
        plan: Plan,
        uplink: PlanUplink,
        report: OnboardReport | None,
        outcome: str,
        reason: str,
        t_begin: float,
        tracker: _Progress,
        sent: int,
    ) -> ExecutionResult:
        guard = report.guard if report is not None else None
        drift = None
        latency = None
        if not outcome:
            assert report is not None
            outcome, reason = _outcome(report)
        if guard is not None:
            drift = DriftEvent(
                guard.stamp_s,
                guard.step,
                guard.linear_m,
                guard.angular_deg,
                guard.pose,
                guard.predicted,
                self.config.drift_persistence,
            )
            latency = max(0.0, guard.stop_s - guard.stamp_s)
            reason = guard.reason
        extra = report.extra if report is not None else {}
        worst = (
            float(extra.get("worst_linear_m", 0.0)),
            float(extra.get("worst_angular_deg", 0.0)),
        )
        rest = report.rest if report is not None else None
        pose = rest.pose if rest is not None else self.reported_pose
        notes = [f"run on board as plan {uplink.plan_id}; the uplink sent {sent} time(s)"]
        if rest is not None:
            notes.append(
                f"at rest ({rest.pose.x:.3f}, {rest.pose.y:.3f}, {rest.pose.yaw_deg:.1f} deg)"
                f" +- {rest.sigma_xy_m:.3f} m, {rest.sigma_yaw_deg:.1f} deg; "
                f"{rest.moved_m:.3f} m and {rest.time_to_rest_s:.2f} s after the end"
            )
        return ExecutionResult(
            completed=outcome == "completed",
            outcome=outcome,
            reason=reason,
            steps=tracker.outcomes(report),
            drift=drift,
            stop_latency_s=latency,
            stopped_s=None,
            elapsed_s=time.monotonic() - t_begin,
            reported_pose=pose,
            worst_drift=worst,
            notes=tuple(notes),
        )


def _outcome(report: OnboardReport) -> tuple[str, str]:
    """The step-by-step executor's outcome for a plan's end on board."""
    kind = report.outcome
    if kind == "completed":
        return "completed", "all steps completed"
    if kind == "guard":
        return "drift", report.reason
    if kind == "blind":
        return "blind", report.reason
    if kind == "ground_stop":
        return "aborted", f"stopped from the ground: {report.reason}"
    if kind == "cancelled":
        return "cancelled", report.reason
    status = report.status
    what = status.split(":", 1)[0] if ":" in status else "fault"
    return (what if what in ("rejected", "aborted", "fault") else "fault"), report.reason


class _Progress:
    """Reports turned into the step-by-step executor's progress (on the caller's thread):
    a step's ``completed`` when the rover moved past it, ``running`` while it runs."""

    def __init__(
        self,
        steps: list[tuple[int, int, int]],
        verdict: Verdict,
        cfg: ExecutorConfig,
        on_progress: Callable[[ExecutionProgress], None] | None,
        t_begin: float,
    ) -> None:
        self.steps = steps
        self.verdict = verdict
        self.cfg = cfg
        self.on_progress = on_progress
        self.t_begin = t_begin
        self.done = 0
        """Steps reported completed so far."""
        self.seq = -1
        self.times: dict[int, float] = {}

    def _eta(self, step: int) -> float:
        rest = sum(s.expected_duration_s for s in self.verdict.steps[step:])
        return rest / self.cfg.time_scale + self.cfg.link_rtt_s / 2.0

    def _say(self, step: int, status: str, report: OnboardReport) -> None:
        if self.on_progress is None:
            return
        self.on_progress(
            ExecutionProgress(
                step,
                len(self.steps),
                status,
                self._eta(step),
                report.drift_linear_m,
                report.drift_angular_deg,
                self.verdict,
            )
        )

    def update(self, report: OnboardReport) -> None:
        if report.seq <= self.seq:
            return
        self.seq = report.seq
        finished = report.step + (1 if report.outcome == "completed" else 0)
        while self.done < finished:
            self.times[self.done] = time.monotonic()
            self._say(self.done, COMPLETED, report)
            self.done += 1
        if report.state == "running":
            self._say(report.step, "running", report)
        elif report.ended and report.outcome != "completed":
            self._say(report.step, report.status or report.outcome, report)

    def outcomes(self, report: OnboardReport | None) -> tuple[StepOutcome, ...]:
        out = []
        last = report.step if report is not None else -1
        for i, step in enumerate(self.steps):
            if i > last:
                break
            status = COMPLETED if i < self.done else (report.status if report else "")
            ended = self.times.get(i, time.monotonic())
            out.append(StepOutcome(i, step, status or "sent", self.t_begin, None, ended))
        return tuple(out)
