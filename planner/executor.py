"""The event-driven executor (thesis Listing 4), with timeouts and drift-control STOP.

:class:`PlanExecutor` publishes a plan one step at a time on ``wheel_instructions`` and
waits on ``command_status`` with a ``threading.Event`` until ``completed`` — never
forever: each step's timeout is its predicted duration (the gate's, else the nominal
profile) scaled to wall time, plus the link's round trip, plus a margin. ``rejected:``,
``aborted:``, ``fault:`` or a timeout ends the plan: the executor publishes STOP on
``emergency_stop`` (repeated until ``stopped`` comes back) and reports why.

While steps run, a :class:`~planner.drift.DriftMonitor` compares the rover's best pose
(``odom_ground``, the ground-seeing POSE, or ``odom`` when configured) with the gate's
prediction. A persistent violation purges the rest of the plan and publishes STOP at
once, from the pose callback itself, the shortest path there is; the detection-to-STOP
latency is measured from the sample that confirmed the violation to the STOP being
handed to the ROS port.

After a drift STOP the operator can re-plan from :attr:`PlanExecutor.reported_pose`
(the rover's last reported pose) and, once the cause is understood, resume with
:meth:`PlanExecutor.clear_stop`.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from bridge.rosport import Bool, Empty, Int16MultiArray, Odometry, RosPort, String, Subscription
from firmware_proto.plan import Plan
from firmware_proto.rover import RoverDescription
from planner.drift import DriftEvent, DriftMonitor
from planner.geometry import Pose
from planner.verdict import Verdict

__all__ = ["ExecutionResult", "ExecutorConfig", "PlanExecutor", "Progress", "StepOutcome"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class ExecutorConfig:
    """Executor settings.

    Attributes:
        link_rtt_s: the link's round trip, wall seconds (3 s Earth-Moon).
        step_margin_s: added to every step's timeout, wall seconds.
        duration_factor: predicted duration multiplier in the timeout (slip, jitter).
        time_scale: twin seconds per wall second (1 on the real rover).
        pose_source: ``odom_ground`` (the ground-seeing POSE) or ``odom`` (encoders+IMU).
        drift_linear_m, drift_angular_deg, drift_persistence: drift control thresholds.
        drift_control: compare poses with the prediction at all.
        stop_repeat_s: STOP is published again this often until ``stopped`` arrives.
    """

    link_rtt_s: float = 3.0
    step_margin_s: float = 2.0
    duration_factor: float = 1.5
    time_scale: float = 1.0
    pose_source: str = "odom_ground"
    drift_linear_m: float = 0.25
    drift_angular_deg: float = 12.0
    drift_persistence: int = 3
    drift_control: bool = True
    stop_repeat_s: float = 0.5


@dataclass(frozen=True)
class StepOutcome:
    """One step as executed: its final status and times (wall clock)."""

    index: int
    step: tuple[int, int, int]
    status: str
    published_s: float
    accepted_s: float | None
    ended_s: float


@dataclass(frozen=True)
class Progress:
    """What the operator sees while a plan runs."""

    step: int
    steps: int
    status: str
    eta_s: float
    drift_linear_m: float | None
    drift_angular_deg: float | None

    def line(self, time_scale: float = 1.0) -> str:
        """``step 3/8 completed, ETA 24 s, drift 0.031 m 1.2 deg`` (ETA in mission time)."""
        text = (
            f"step {self.step + 1}/{self.steps} {self.status}, ETA {self.eta_s * time_scale:.0f} s"
        )
        if self.drift_linear_m is not None and self.drift_angular_deg is not None:
            text += f", drift {self.drift_linear_m:.3f} m {self.drift_angular_deg:.1f} deg"
        return text


@dataclass(frozen=True)
class ExecutionResult:
    """How a plan ended.

    Attributes:
        completed: every step completed.
        outcome: ``completed``, ``rejected``, ``aborted``, ``fault``, ``timeout``,
            ``drift`` or ``cancelled``.
        reason: human-readable cause.
        steps: each step that was published, in order.
        drift: the drift event that stopped the plan, if any.
        stop_latency_s: drift detection to STOP handed to the port, s.
        stopped_s: when the rover confirmed the STOP (``stopped`` came back), if it did.
        elapsed_s: wall time from the first publish to the end.
        reported_pose: the rover's last reported pose (map frame), if any.
        worst_drift: largest linear (m) and angular (deg) errors seen.
    """

    completed: bool
    outcome: str
    reason: str
    steps: tuple[StepOutcome, ...]
    drift: DriftEvent | None
    stop_latency_s: float | None
    stopped_s: float | None
    elapsed_s: float
    reported_pose: Pose | None
    worst_drift: tuple[float, float]
    trace: tuple[tuple[float, float, float], ...] = field(default=())


def _yaw_deg(msg: Odometry) -> float:
    q = msg.pose.pose.orientation
    return math.degrees(2.0 * math.atan2(q.z, q.w))


def _stamp_s(msg: Odometry) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


class PlanExecutor:
    """Runs approved plans on the rover over a ROS port; see the module docstring.

    One plan at a time; :meth:`execute` blocks the calling thread until it ends.
    """

    def __init__(
        self, port: RosPort, rover: RoverDescription, config: ExecutorConfig | None = None
    ) -> None:
        self.port = port
        self.rover = rover
        self.config = config or ExecutorConfig()
        if self.config.pose_source not in ("odom_ground", "odom"):
            raise ValueError("pose_source must be odom_ground or odom")
        self._steps_pub = port.publisher("wheel_instructions", Int16MultiArray)
        self._stop_pub = port.publisher("emergency_stop", Bool)
        self._clear_pub = port.publisher("clear_emergency_stop", Empty)
        self._lock = threading.Lock()
        self._event = threading.Event()
        self._status: str | None = None
        self._accepted: float | None = None
        self._accepted_wall: float | None = None
        self._stopped_at: float | None = None
        self._cleared = threading.Event()
        self._stopped = threading.Event()
        self._pose_cond = threading.Condition(self._lock)
        self._reported_stamp = -math.inf
        self._monitor: DriftMonitor | None = None
        self._drift: DriftEvent | None = None
        self._stop_latency: float | None = None
        self._stop_published: float | None = None
        self._odom_origin: tuple[Pose, Pose] | None = None
        self._running = False
        self.reported_pose: Pose | None = None
        self._trace: list[tuple[float, float, float]] = []
        self._subs: list[Subscription[Any]] = [
            port.subscribe("command_status", String, self._on_status),
            port.subscribe(self.config.pose_source, Odometry, self._on_pose),
        ]

    def settled_pose(self, timeout_s: float | None = None) -> Pose | None:
        """The rover's pose measured after it reported its last status: waits (at most a
        round trip plus a second) for a pose stamped after the moment the rover must have
        sent what came back last; returns the latest reported pose either way."""
        cfg = self.config
        wait_s = timeout_s if timeout_s is not None else cfg.link_rtt_s + 1.0
        since = time.time() - cfg.link_rtt_s / 2.0  # rover time of the last status we heard
        deadline = time.monotonic() + wait_s
        with self._pose_cond:
            while self._reported_stamp < since:
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                self._pose_cond.wait(left)
            return self.reported_pose

    def close(self) -> None:
        """Stop listening (the port stays open)."""
        for sub in self._subs:
            sub.close()

    # -- callbacks (ROS port thread) -------------------------------------------------------
    def _on_status(self, msg: String) -> None:
        text = msg.data
        now = time.monotonic()
        with self._lock:
            if text == "stopped":
                self._stopped_at = now
                self._stopped.set()
            elif text == "cleared":
                self._cleared.set()
            if not self._running:
                return
            if text == "accepted":
                self._accepted = now
                self._accepted_wall = time.time()
                return
            if text == "completed" or text.startswith(("rejected:", "aborted:", "fault:")):
                self._status = text
                self._event.set()

    def _on_pose(self, msg: Odometry) -> None:
        pose = Pose(msg.pose.pose.position.x, msg.pose.pose.position.y, _yaw_deg(msg))
        if self.config.pose_source == "odom":
            pose = self._odom_to_map(pose)
        stamp = _stamp_s(msg)
        with self._lock:
            self.reported_pose = pose
            self._reported_stamp = stamp
            self._trace.append((stamp, pose.x, pose.y))
            self._pose_cond.notify_all()
            monitor = self._monitor if self._running else None
        if monitor is None or not self.config.drift_control:
            return
        # Pose stamps are wall clock (the rover's measurement time), as are the step
        # times the executor gives the monitor.
        event = monitor.update(pose.x, pose.y, pose.yaw_deg, stamp)
        if event is not None:
            self._on_drift(event)

    def _odom_to_map(self, pose: Pose) -> Pose:
        """``odom`` starts at the bridge's start; anchor it on the plan's start pose."""
        if self._odom_origin is None:
            return pose
        odom0, map0 = self._odom_origin
        dyaw = math.radians(map0.yaw_deg - odom0.yaw_deg)
        dx, dy = pose.x - odom0.x, pose.y - odom0.y
        return Pose(
            map0.x + dx * math.cos(dyaw) - dy * math.sin(dyaw),
            map0.y + dx * math.sin(dyaw) + dy * math.cos(dyaw),
            (pose.yaw_deg + map0.yaw_deg - odom0.yaw_deg + 180.0) % 360.0 - 180.0,
        )

    def _on_drift(self, event: DriftEvent) -> None:
        detected = time.monotonic()
        self._publish_stop()  # first: the purge and the report can wait
        published = time.monotonic()
        with self._lock:
            self._drift = event
            self._stop_latency = published - detected
            self._status = "drift"
            self._event.set()
        logger.warning(
            "%s; STOP sent %.3f ms after detection", event.reason, (published - detected) * 1e3
        )

    # -- STOP and clear ------------------------------------------------------------------------
    def _publish_stop(self) -> None:
        self._stop_pub.publish(Bool(data=True))
        self._stop_published = time.monotonic()

    def stop(self, timeout_s: float | None = None) -> bool:
        """Publish STOP every ``stop_repeat_s`` until the rover confirms (``stopped``) or
        ``timeout_s`` passes (default: round trip + margin). Returns whether it did."""
        cfg = self.config
        deadline = time.monotonic() + (
            timeout_s if timeout_s is not None else cfg.link_rtt_s + cfg.step_margin_s
        )
        while True:
            self._publish_stop()
            left = deadline - time.monotonic()
            if self._stopped.wait(max(0.0, min(cfg.stop_repeat_s, left))):
                return True
            if time.monotonic() >= deadline:
                return False

    def clear_stop(self, timeout_s: float | None = None) -> bool:
        """Ask the rover to release its latch; True when ``cleared`` came back in time."""
        timeout_s = (
            timeout_s
            if timeout_s is not None
            else self.config.link_rtt_s + self.config.step_margin_s
        )
        self._cleared.clear()
        self._clear_pub.publish(Empty())
        return self._cleared.wait(timeout_s)

    # -- execution -----------------------------------------------------------------------------
    def step_timeout_s(
        self, index: int, step: tuple[int, int, int], verdict: Verdict | None
    ) -> float:
        """Wall seconds to wait for one step's ``completed``."""
        cfg = self.config
        if verdict is not None and index < len(verdict.steps):
            predicted = verdict.steps[index].expected_duration_s
        else:
            predicted = self.rover.step_duration_s(step[1], step[2])
        return predicted * cfg.duration_factor / cfg.time_scale + cfg.link_rtt_s + cfg.step_margin_s

    def execute(
        self,
        plan: Plan,
        verdict: Verdict | None = None,
        *,
        on_progress: Callable[[Progress], None] | None = None,
        cancel: threading.Event | None = None,
    ) -> ExecutionResult:
        """Run ``plan`` step by step; blocks until it completes or ends early.

        Args:
            plan: the approved plan.
            verdict: the gate's verdict on it (its prediction drives drift control and
                the timeouts); ``None`` runs without drift control.
            on_progress: called on the executing thread after each status.
            cancel: set it to stop the plan from another thread (STOP is sent).
        """
        cfg = self.config
        monitor = None
        if verdict is not None and cfg.drift_control:
            monitor = DriftMonitor(
                verdict,
                linear_limit_m=cfg.drift_linear_m,
                angular_limit_deg=cfg.drift_angular_deg,
                persistence=cfg.drift_persistence,
                one_way_delay_s=cfg.link_rtt_s / 2.0,
                time_scale=cfg.time_scale,
            )
        steps = plan.to_wire()
        with self._lock:
            self._monitor = monitor
            self._status = None  # nothing of the previous plan carries over
            self._drift = None
            self._stop_latency = None
            self._stopped_at = None
            self._stopped.clear()
            self._running = True
            self._trace = []
            if cfg.pose_source == "odom" and self.reported_pose is not None and verdict is not None:
                self._odom_origin = (self.reported_pose, verdict.start_pose)
        outcomes: list[StepOutcome] = []
        t_begin = time.monotonic()
        outcome, reason = "completed", "all steps completed"
        try:
            for index, step in enumerate(steps):
                if cancel is not None and cancel.is_set():
                    outcome, reason = "cancelled", "cancelled by the operator"
                    break
                status, published, accepted = self._run_step(index, step, verdict, monitor, cancel)
                outcomes.append(
                    StepOutcome(index, step, status, published, accepted, time.monotonic())
                )
                if on_progress is not None:
                    on_progress(self._progress(index, len(steps), status, steps, verdict, monitor))
                if status == "completed":
                    continue
                outcome, reason = self._classify(status, index)
                break
        finally:
            with self._lock:
                self._running = False
                self._monitor = None
        if outcome != "completed":
            if outcome != "drift":
                logger.warning("plan ended at step %d: %s; sending STOP", len(outcomes) - 1, reason)
            confirmed = self.stop()
            if not confirmed:
                reason += "; STOP not confirmed within the round trip"
        with self._lock:
            drift, latency, stopped, pose = (
                self._drift,
                self._stop_latency,
                self._stopped_at,
                self.reported_pose,
            )
            trace = tuple(self._trace)
        return ExecutionResult(
            completed=outcome == "completed",
            outcome=outcome,
            reason=drift.reason if drift is not None else reason,
            steps=tuple(outcomes),
            drift=drift,
            stop_latency_s=latency,
            stopped_s=stopped,
            elapsed_s=time.monotonic() - t_begin,
            reported_pose=pose,
            worst_drift=monitor.worst if monitor is not None else (0.0, 0.0),
            trace=trace,
        )

    def _run_step(
        self,
        index: int,
        step: tuple[int, int, int],
        verdict: Verdict | None,
        monitor: DriftMonitor | None,
        cancel: threading.Event | None,
    ) -> tuple[str, float, float | None]:
        with self._lock:
            if self._status == "drift":
                return "drift", time.monotonic(), None
            self._event.clear()
            self._status = None
            self._accepted = None
            self._accepted_wall = None
        published = time.monotonic()
        published_wall = time.time()
        if monitor is not None:
            monitor.step_published(index, published_wall)
        self._steps_pub.publish(Int16MultiArray(data=step))
        deadline = published + self.step_timeout_s(index, step, verdict)
        accepted_seen = False
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                return "timeout", published, self._accepted
            waited = min(left, 0.1)
            if self._event.wait(waited):
                break
            if cancel is not None and cancel.is_set():
                return "cancelled", published, self._accepted
            acc_wall = self._accepted_times()[1]
            if acc_wall is not None and not accepted_seen:
                accepted_seen = True
                if monitor is not None:
                    monitor.step_accepted(index, published_wall, acc_wall)
        with self._lock:
            status = self._status or "timeout"
        acc, acc_wall = self._accepted_times()
        if monitor is not None and acc_wall is not None and not accepted_seen:
            monitor.step_accepted(index, published_wall, acc_wall)
        return status, published, acc

    def _accepted_times(self) -> tuple[float | None, float | None]:
        """When ``accepted`` came for the current step: (monotonic, wall), set by the
        status callback on the port's thread."""
        with self._lock:
            return self._accepted, self._accepted_wall

    @staticmethod
    def _classify(status: str, index: int) -> tuple[str, str]:
        if status == "drift":
            return "drift", "drift control stopped the rover"
        if status == "timeout":
            return "timeout", f"step {index} got no 'completed' in time (rover silent or too slow)"
        if status == "cancelled":
            return "cancelled", "cancelled by the operator"
        kind = status.split(":", 1)[0]
        return kind, f"step {index}: {status}"

    def _progress(
        self,
        index: int,
        total: int,
        status: str,
        steps: list[tuple[int, int, int]],
        verdict: Verdict | None,
        monitor: DriftMonitor | None,
    ) -> Progress:
        eta = sum(
            self.step_timeout_s(i, s, verdict) - self.config.step_margin_s
            for i, s in enumerate(steps)
            if i > index
        )
        last = monitor.history[-1] if monitor is not None and monitor.history else None
        return Progress(
            index,
            total,
            status,
            eta,
            last.linear_m if last else None,
            last.angular_deg if last else None,
        )
