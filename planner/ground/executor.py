"""The event-driven executor (thesis Listing 4), with timeouts and drift-control STOP.

:class:`PlanExecutor` publishes a plan one step at a time on ``wheel_instructions`` and
waits on ``command_status`` until ``completed``, each wait bounded by the step's
predicted duration, the round trip and a margin. Whatever ends
:meth:`PlanExecutor.execute` early (a failure status, a timeout, drift, blindness,
``cancel``, an exception) publishes STOP first, repeated until ``stopped`` (bounded).

A :class:`~planner.ground.drift.DriftMonitor`, fed from the pose callbacks, compares
``odom_ground`` (or ``odom`` once POSE is silent, by the topics' own stamps) with the
gate's prediction; a persistent violation publishes STOP from the callback itself. No
pose for a round trip plus ``blind_margin_s`` ends the plan (``blind``). The step's time
rules are the pure :class:`~planner.ground.stepwatch.StepWatch`; every time and wait
goes through ``clock=`` (wall, or lockstep: docs/sim.md). Details: docs/ground.md
"Executor" and "Drift control".
"""

from __future__ import annotations

import logging
import math
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from bridge.ros.rosport import RosPort, Subscription, qos
from bridge.ros.rosport.cdr import odometry_fields
from bridge.ros.rosport.contract import (
    ACCEPTED,
    CLEAR_EMERGENCY_STOP,
    CLEARED,
    COMMAND_STATUS,
    COMPLETED,
    EMERGENCY_STOP,
    STOPPED,
    WHEEL_INSTRUCTIONS,
    ends_step,
    fault,
)
from bridge.ros.rosport.msgs import Bool, Empty, Int16MultiArray, Odometry, String
from firmware_proto.linkio.clock import WALL, Clock
from firmware_proto.model.geometry import wrap_deg
from firmware_proto.model.plan import Plan
from firmware_proto.model.pose import Pose
from firmware_proto.model.rover import RoverDescription
from firmware_proto.model.verdict import Verdict
from planner.ground.drift import DriftEvent, DriftMonitor
from planner.ground.stepwatch import StepWatch

__all__ = [
    "ANCHOR_GAP_S",
    "POSE_SOURCES",
    "REPORTING_FAULTS",
    "REST_SPEED_MPS",
    "REST_YAW_RATE_RAD_S",
    "ExecutionProgress",
    "ExecutionResult",
    "ExecutorConfig",
    "PlanExecutor",
    "StepOutcome",
]

logger = logging.getLogger(__name__)

POSE_SOURCES = ("auto", "odom_ground", "odom")
"""What drift control compares: ``auto`` (POSE while fresh, else ``odom``), POSE, or ``odom``."""

REPORTING_FAULTS = frozenset({fault("pose"), fault("imu")})
"""Statuses of faults the controller only reports (a lost sensor): they do not end a plan."""

ANCHOR_GAP_S = 0.05
"""``odom`` samples further than this from a POSE's time do not tie ``odom`` to the map."""

SILENCE_CONFIRM_S = 0.1
"""A silence of ``odom_ground`` must persist this long (wall s) before drift control falls back: a
lagging ground station reads its backlog in a burst, ``odom`` and POSE in any order."""

REST_SPEED_MPS = 0.01
REST_YAW_RATE_RAD_S = 0.01
"""Below both, an ``odom`` sample says the rover is at rest."""


@dataclass(frozen=True)
class ExecutorConfig:
    """Executor settings (times are wall seconds).

    Attributes:
        link_rtt_s: the link's round trip (3 s Earth-Moon).
        step_margin_s: added to every step's timeout.
        duration_factor: predicted duration multiplier in the timeout (slip, jitter).
        time_scale: twin seconds per wall second (1 on the real rover).
        pose_source: one of :data:`POSE_SOURCES`.
        pose_stale_s: with ``auto``, POSE silent this long -> drift control uses ``odom``
            (by the topics' stamps: an ``odom`` this much newer than the last POSE).
        drift_linear_m, drift_angular_deg, drift_persistence: drift control thresholds.
        drift_control: compare poses with the prediction at all.
        blind_stop: end the plan (STOP, outcome ``blind``) when drift control hears no
            pose for ``link_rtt_s + blind_margin_s`` while a step runs.
        blind_margin_s: see ``blind_stop``; more than ``pose_stale_s``, so that the
            fall-back to ``odom`` comes first.
        progress_period_s: ``on_progress`` is called this often while a step runs.
        stop_repeat_s: STOP is published again this often until ``stopped`` arrives.

    Raises:
        ValueError: an unknown pose source, or a number that is not finite and positive
            (``link_rtt_s`` may be 0).
    """

    link_rtt_s: float = 3.0
    step_margin_s: float = 2.0
    duration_factor: float = 1.5
    time_scale: float = 1.0
    pose_source: str = "auto"
    pose_stale_s: float = 0.5
    drift_linear_m: float = 0.25
    drift_angular_deg: float = 12.0
    drift_persistence: int = 3
    drift_control: bool = True
    blind_stop: bool = True
    blind_margin_s: float = 1.0
    progress_period_s: float = 1.0
    stop_repeat_s: float = 0.5

    def __post_init__(self) -> None:
        if self.pose_source not in POSE_SOURCES:
            raise ValueError(
                f"pose_source must be one of {', '.join(POSE_SOURCES)}, got {self.pose_source!r}"
            )
        if not (math.isfinite(self.link_rtt_s) and self.link_rtt_s >= 0):
            raise ValueError(f"link_rtt_s must be finite and >= 0, got {self.link_rtt_s}")
        for name in (
            "step_margin_s",
            "duration_factor",
            "time_scale",
            "pose_stale_s",
            "drift_linear_m",
            "drift_angular_deg",
            "blind_margin_s",
            "progress_period_s",
            "stop_repeat_s",
        ):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be finite and > 0, got {value}")
        if self.drift_persistence < 1:
            raise ValueError(f"drift_persistence must be >= 1, got {self.drift_persistence}")
        if self.blind_margin_s <= self.pose_stale_s:
            raise ValueError("blind_margin_s must exceed pose_stale_s (fall back before blind)")

    @property
    def blind_after_s(self) -> float:
        """No pose for this long while a step runs: drift control is blind."""
        return self.link_rtt_s + self.blind_margin_s


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
class ExecutionProgress:
    """What the operator sees while a plan runs.

    ``status``: ``published`` (again every ``progress_period_s`` until acknowledged),
    ``accepted``, ``running`` (every ``progress_period_s``), then the final status
    (``completed``, ``rejected:...``, ``drift``...). ``eta_s``: expected wall time to
    the end of the plan, s; drift figures: the latest sample. ``verdict``: the gate's
    verdict of this step's plan (``None`` without one), by which a viewer tells one plan
    from the next. ``unit``: what is counted (``step``, or move-and-wait's
    ``increment``).
    """

    step: int
    steps: int
    status: str
    eta_s: float
    drift_linear_m: float | None
    drift_angular_deg: float | None
    verdict: Verdict | None = field(default=None, compare=False, repr=False)
    unit: str = "step"

    @property
    def final(self) -> bool:
        """The step has ended (not ``published``, ``accepted`` or ``running``)."""
        return self.status not in ("published", "accepted", "running")

    def line(self, time_scale: float = 1.0) -> str:
        """``step 3/8 completed, ETA 24 s, drift 0.031 m 1.2 deg`` (ETA in mission time;
        the drift only where drift control runs)."""
        text = (
            f"{self.unit} {self.step + 1}/{self.steps} {self.status}, "
            f"ETA {self.eta_s * time_scale:.0f} s"
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
            ``drift``, ``blind`` (drift control heard no pose) or ``cancelled``.
        reason: human-readable cause.
        steps: each step that was published, in order.
        drift: the drift event that stopped the plan, if any.
        stop_latency_s: drift detection to STOP handed to the port, s.
        stopped_s: when the rover confirmed the STOP (``stopped`` came back), if it did.
        elapsed_s: wall time from the first publish to the end.
        reported_pose: the rover's last reported pose (map frame), if any.
        worst_drift: largest linear (m) and angular (deg) errors seen.
        trace: every pose drift control used, ``(stamp_s, x_m, y_m)``.
        notes: what the operator should know although the plan went on.
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
    notes: tuple[str, ...] = field(default=())


def _stated_sigma(cov: tuple[float, ...]) -> tuple[float, float] | None:
    """The 1-sigma errors an ``odom_ground`` message states in its pose covariance ``cov``
    (row major 6x6, m^2 and rad^2): the larger of x's and y's, m, and the heading's, deg;
    ``None`` where it states none (zero, or not a finite number)."""
    var_xy, var_yaw = max(float(cov[0]), float(cov[7])), float(cov[35])
    if not (0.0 < var_xy < math.inf and 0.0 < var_yaw < math.inf):
        return None
    return math.sqrt(var_xy), math.degrees(math.sqrt(var_yaw))


class PlanExecutor:
    """Runs approved plans on the rover over a ROS port.

    One plan at a time; :meth:`execute` blocks the calling thread until it ends.
    Subscribes to ``command_status``, the pose topics of ``pose_source``, and ``odom``
    (whose twist says when the rover is at rest).
    """

    def __init__(
        self,
        port: RosPort,
        rover: RoverDescription,
        config: ExecutorConfig | None = None,
        *,
        clock: Clock = WALL,
    ) -> None:
        """``port``: the ground's ROS port; ``rover``: the description (nominal step
        durations); ``clock``: every time and wait (``WALL``, or lockstep: virtual time)."""
        self.port = port
        self.rover = rover
        self.config = config or ExecutorConfig()
        self.clock = clock
        self._steps_pub = port.publisher(WHEEL_INSTRUCTIONS, Int16MultiArray, qos.COMMAND)
        self._stop_pub = port.publisher(EMERGENCY_STOP, Bool, qos.STOP)
        self._clear_pub = port.publisher(CLEAR_EMERGENCY_STOP, Empty, qos.STOP)
        # Re-entrant: in lockstep a wait advances the world with the lock held, and the
        # callbacks it runs take it again on the same thread.
        self._lock = threading.RLock()
        self._monitor_lock = threading.RLock()  # pose callbacks may run on two threads
        self._event = threading.Event()
        self._status: str | None = None
        self._accepted: float | None = None
        self._accepted_wall: float | None = None
        self._stopped_at: float | None = None
        self._cleared = threading.Event()
        self._stopped = threading.Event()
        self._pose_cond = threading.Condition(self._lock)
        """Notified on a pose, ``odom``, step end, ``stopped``, ``cleared``; every wait uses it."""
        self._reported_stamp = -math.inf
        self._monitor: DriftMonitor | None = None
        self._drift: DriftEvent | None = None
        self._stop_latency: float | None = None
        self._stop_published: float | None = None
        self._running = False
        self.reported_pose: Pose | None = None
        self.reported_sigma: tuple[float, float] | None = None
        """The 1-sigma errors the rover stated with :attr:`reported_pose` (its
        ``odom_ground`` covariance: m per position axis, the larger; heading, deg);
        ``None`` for a pose from ``odom`` or one stated with no error (a dropout's)."""
        self._trace: list[tuple[float, float, float]] = []
        self._notes: list[str] = []
        created = self.clock.now()
        self._ground_rx = created  # "never heard" counts from here, once a plan runs
        self._ground_heard = False
        self._ground_stamp = -math.inf  # the last odom_ground's stamp (the rover's clock, s)
        self._silence_seen: float | None = None  # when an odom first found it silent (wall)
        self._pose_rx = created  # last pose drift control could use
        self._on_odom_source = self.config.pose_source == "odom"
        self._odom_history: deque[tuple[float, Pose]] = deque(maxlen=64)
        self._odom_anchor: tuple[Pose, Pose] | None = None  # (odom frame, map frame)
        self._motion: tuple[float, float, float] | None = None  # stamp, v, yaw rate
        self._plan_start: Pose | None = None
        self._subs: list[Subscription[Any]] = [
            port.subscribe(COMMAND_STATUS, String, self._on_status, qos.STATUS)
        ]
        # odom_ground first: rclpy takes waiting messages in subscription order, so a
        # POSE is read before the odom beside it (which would find it silent).
        # Over DDS read in place from the bytes (bridge/ros/rosport/cdr.py: /odom comes with
        # every encoder sample; docs/rosport.md, "Serialized messages").
        raw = port.carries_serialized
        if self.config.pose_source != "odom":
            self._subs.append(
                port.subscribe("odom_ground", Odometry, self._on_ground, qos.SENSOR, serialized=raw)
            )
        self._subs.append(
            port.subscribe("odom", Odometry, self._on_odom, qos.SENSOR, serialized=raw)
        )

    def wait_for_rover(self, timeout_s: float = 10.0) -> bool:
        """Wait until the executor's publishers reach a subscriber (the bridge or the
        relay); False when ``timeout_s`` passed first."""
        deadline = self.clock.now() + timeout_s
        return all(
            pub.wait_for_subscribers(1, max(0.0, deadline - self.clock.now()))
            for pub in (self._steps_pub, self._stop_pub, self._clear_pub)
        )

    @property
    def latest_drift(self) -> tuple[float, float] | None:
        """The latest drift sample of the running plan, ``(linear_m, angular_deg)``;
        ``None`` when no plan runs or drift control has not compared a pose yet."""
        with self._lock:
            monitor = self._monitor
        if monitor is None:
            return None
        with self._monitor_lock:
            last = monitor.history[-1] if monitor.history else None
        return (last.linear_m, last.angular_deg) if last is not None else None

    @property
    def pose_source_in_use(self) -> str:
        """``odom_ground`` or ``odom``: what drift control compares right now."""
        with self._lock:
            return "odom" if self._on_odom_source else "odom_ground"

    def settled_pose(self, timeout_s: float | None = None, *, after_s: float = 0.0) -> Pose | None:
        """The latest reported pose, after waiting (at most a round trip + 1 s +
        ``after_s``) for one stamped ``after_s`` s or more after the rover sent its last
        status."""
        cfg = self.config
        wait_s = timeout_s if timeout_s is not None else cfg.link_rtt_s + 1.0 + after_s
        since = self.clock.time() - cfg.link_rtt_s / 2.0 + after_s
        with self._pose_cond:
            self.clock.wait_for(self._pose_cond, lambda: self._reported_stamp >= since, wait_s)
            return self.reported_pose

    def wait_for_rest(self, timeout_s: float | None = None) -> bool:
        """Wait for an ``odom`` sample measured after now minus half the round trip that
        says the rover is at rest (under 1 cm/s and 0.01 rad/s); False after
        ``timeout_s`` (default: round trip + ``step_margin_s``) without one."""
        cfg = self.config
        wait_s = timeout_s if timeout_s is not None else cfg.link_rtt_s + cfg.step_margin_s
        since = self.clock.time() - cfg.link_rtt_s / 2.0

        def at_rest() -> bool:
            motion = self._motion
            return (
                motion is not None
                and motion[0] >= since
                and abs(motion[1]) < REST_SPEED_MPS
                and abs(motion[2]) < REST_YAW_RATE_RAD_S
            )

        with self._pose_cond:
            return self.clock.wait_for(self._pose_cond, at_rest, wait_s)

    def close(self) -> None:
        """Stop listening (the port stays open)."""
        for sub in self._subs:
            sub.close()

    # -- callbacks (ROS port threads) ------------------------------------------------------
    def _on_status(self, msg: String) -> None:
        text = msg.data
        now = self.clock.now()
        with self._lock:
            if text == STOPPED:
                self._stopped_at = now
                self._stopped.set()
                self._pose_cond.notify_all()
            elif text == CLEARED:
                self._cleared.set()
                self._pose_cond.notify_all()
            if not self._running:
                return
            if text == ACCEPTED:
                self._accepted = now
                self._accepted_wall = self.clock.time()
                return
            if text in REPORTING_FAULTS:
                self._note(f"the rover reported {text} (it keeps driving)")
                return
            if ends_step(text):
                self._status = text
                self._event.set()
                self._pose_cond.notify_all()

    def _on_ground(self, msg: Odometry | bytes) -> None:
        f = odometry_fields(msg)
        pose = Pose(f.x_m, f.y_m, math.degrees(f.yaw_rad))
        stamp = f.stamp_s
        with self._lock:
            self._ground_rx = self.clock.now()
            self._ground_heard = True
            self._ground_stamp = stamp
            self._silence_seen = None
            if self.config.pose_source == "auto":
                self._anchor_odom(pose, stamp)
                if self._on_odom_source:
                    self._on_odom_source = False
                    # As loud as the fall-back was: whoever saw one must see the other.
                    self._note("odom_ground came back: drift control uses it again")
        self._use_pose(pose, stamp, _stated_sigma(f.covariance))

    def _on_odom(self, msg: Odometry | bytes) -> None:
        f = odometry_fields(msg)
        raw = Pose(f.x_m, f.y_m, math.degrees(f.yaw_rad))
        stamp = f.stamp_s
        cfg = self.config
        with self._lock:
            self._odom_history.append((stamp, raw))
            self._motion = (stamp, f.v_mps, f.yaw_rate_rad_s)
            self._pose_cond.notify_all()
            auto = cfg.pose_source == "auto"
            if auto and not self._on_odom_source and self._ground_silent(stamp):
                self._on_odom_source = True
                self._note(
                    f"odom_ground silent for more than {cfg.pose_stale_s:g} s: drift "
                    "control fell back to odom (encoders + IMU, blind to slip)"
                )
            if not self._on_odom_source:
                return
            if self._odom_anchor is None:
                if not (self._running and self._plan_start is not None):
                    return  # odom is not in the map frame yet: not a pose to report
                self._odom_anchor = (raw, self._plan_start)
            pose = self._odom_to_map(raw)
        self._use_pose(pose, stamp)

    def _ground_silent(self, odom_stamp: float) -> bool:
        """Whether ``odom_ground`` has been silent for ``pose_stale_s`` as of an ``odom``
        stamped ``odom_stamp`` (lock held): by the rover's stamps, confirmed by an
        ``odom`` read :data:`SILENCE_CONFIRM_S` (wall) earlier with no ``odom_ground``
        since; before the first ``odom_ground``, by wall time since the executor began."""
        stale = self.config.pose_stale_s
        now = self.clock.now()
        if not self._ground_heard:
            return self._running and now - self._ground_rx > stale
        if odom_stamp - self._ground_stamp <= stale:
            return False
        if self._silence_seen is None:
            self._silence_seen = now
        return now - self._silence_seen >= SILENCE_CONFIRM_S

    def _note(self, text: str, level: int = logging.WARNING) -> None:
        """Log ``text`` and, during a plan, note it in the result once (lock held)."""
        if text in self._notes:
            return
        logger.log(level, "%s", text)
        if self._running:
            self._notes.append(text)

    def _use_pose(self, pose: Pose, stamp: float, sigma: tuple[float, float] | None = None) -> None:
        """A pose (map frame) for the operator and drift control, with the errors the
        rover stated for it (:attr:`reported_sigma`), if any."""
        with self._lock:
            self.reported_pose = pose
            self.reported_sigma = sigma
            self._reported_stamp = stamp
            self._pose_rx = self.clock.now()
            self._trace.append((stamp, pose.x, pose.y))
            self._pose_cond.notify_all()
            monitor = self._monitor if self._running else None
        if monitor is None or not self.config.drift_control:
            return
        # Pose stamps (measurement time) and the monitor's step times are both wall clock.
        with self._monitor_lock:
            event = monitor.update(pose.x, pose.y, pose.yaw_deg, stamp)
        if event is not None:
            self._on_drift(event)

    def _anchor_odom(self, ground: Pose, stamp: float) -> None:
        """Tie ``odom`` to the map at a POSE's measurement time (``odom`` interpolated
        there; lock held), so a fall-back continues where POSE left off; unchanged
        without an ``odom`` within :data:`ANCHOR_GAP_S`."""
        history = self._odom_history
        after = next((i for i, (t, _) in enumerate(history) if t >= stamp), None)
        if after is None:  # odom has not caught up with this POSE yet
            t, raw = history[-1] if history else (-math.inf, ground)
            if stamp - t <= ANCHOR_GAP_S:
                self._odom_anchor = (raw, ground)
            return
        t1, p1 = history[after]
        if after == 0:
            if t1 - stamp <= ANCHOR_GAP_S:
                self._odom_anchor = (p1, ground)
            return
        t0, p0 = history[after - 1]
        if t1 - t0 > 2 * ANCHOR_GAP_S:
            return
        f = (stamp - t0) / (t1 - t0) if t1 > t0 else 1.0
        raw = Pose(
            p0.x + f * (p1.x - p0.x),
            p0.y + f * (p1.y - p0.y),
            wrap_deg(p0.yaw_deg + f * wrap_deg(p1.yaw_deg - p0.yaw_deg)),
        )
        self._odom_anchor = (raw, ground)

    def _odom_to_map(self, pose: Pose) -> Pose:
        """``odom`` starts where the bridge started; express it in the map frame through
        the anchor (caller holds the lock and has set one)."""
        assert self._odom_anchor is not None
        odom0, map0 = self._odom_anchor
        dyaw = math.radians(map0.yaw_deg - odom0.yaw_deg)
        dx, dy = pose.x - odom0.x, pose.y - odom0.y
        return Pose(
            map0.x + dx * math.cos(dyaw) - dy * math.sin(dyaw),
            map0.y + dx * math.sin(dyaw) + dy * math.cos(dyaw),
            (pose.yaw_deg + map0.yaw_deg - odom0.yaw_deg + 180.0) % 360.0 - 180.0,
        )

    def _on_drift(self, event: DriftEvent) -> None:
        detected = self.clock.now()
        self._publish_stop()  # first: the purge and the report can wait
        published = self.clock.now()
        with self._lock:
            self._drift = event
            self._stop_latency = published - detected
            self._status = "drift"
            self._event.set()
            self._pose_cond.notify_all()
        logger.warning(
            "%s; STOP sent %.3f ms after detection", event.reason, (published - detected) * 1e3
        )

    # -- STOP and clear ------------------------------------------------------------------------
    def _publish_stop(self) -> None:
        self._stop_pub.publish(Bool(data=True))
        self._stop_published = self.clock.now()

    def stop(self, timeout_s: float | None = None) -> bool:
        """Publish STOP every ``stop_repeat_s`` until the rover confirms (``stopped``) or
        ``timeout_s`` passes (default: round trip + margin). Returns whether it did."""
        cfg = self.config
        deadline = self.clock.now() + (
            timeout_s if timeout_s is not None else cfg.link_rtt_s + cfg.step_margin_s
        )
        while True:
            self._publish_stop()
            left = deadline - self.clock.now()
            if self._wait(self._stopped.is_set, max(0.0, min(cfg.stop_repeat_s, left))):
                return True
            if self.clock.now() >= deadline:
                return False

    def _wait(self, ready: Callable[[], bool], timeout_s: float) -> bool:
        """Wait through the clock until ``ready()`` (checked whenever a callback notifies)
        or ``timeout_s`` passed; whether it became true."""
        with self._pose_cond:
            return self.clock.wait_for(self._pose_cond, ready, timeout_s)

    def clear_stop(self, timeout_s: float | None = None) -> bool:
        """Ask the rover to release its latch; True when ``cleared`` came back in time."""
        timeout_s = (
            timeout_s
            if timeout_s is not None
            else self.config.link_rtt_s + self.config.step_margin_s
        )
        self._cleared.clear()
        self._clear_pub.publish(Empty())
        return self._wait(self._cleared.is_set, timeout_s)

    # -- execution -----------------------------------------------------------------------------
    def step_timeout_s(
        self, index: int, step: tuple[int, int, int], verdict: Verdict | None
    ) -> float:
        """Wall seconds to wait for one step's ``completed``."""
        cfg = self.config
        predicted = self._predicted_s(index, step, verdict)
        return predicted * cfg.duration_factor / cfg.time_scale + cfg.link_rtt_s + cfg.step_margin_s

    def _predicted_s(
        self, index: int, step: tuple[int, int, int], verdict: Verdict | None
    ) -> float:
        """A step's predicted duration, twin seconds (the gate's, else nominal)."""
        if verdict is not None and index < len(verdict.steps):
            return verdict.steps[index].expected_duration_s
        return self.rover.step_duration_s(step[1], step[2])

    def execute(
        self,
        plan: Plan,
        verdict: Verdict | None = None,
        *,
        on_progress: Callable[[ExecutionProgress], None] | None = None,
        cancel: threading.Event | None = None,
    ) -> ExecutionResult:
        """Run ``plan`` step by step; blocks until it completes or ends early.

        Whatever ends it early sends STOP first; an exception (from ``on_progress``,
        ``KeyboardInterrupt``) is re-raised after STOP's confirmation was awaited for at
        most a round trip plus ``step_margin_s``.

        Args:
            plan: the approved plan.
            verdict: the gate's verdict on it (its prediction drives drift control and
                the timeouts); ``None`` runs without drift control.
            on_progress: called on the executing thread: when a step is published,
                accepted, about every ``progress_period_s`` while it runs, and when it
                ends (see :class:`ExecutionProgress`).
            cancel: set it to stop the plan from another thread (STOP is sent; the
                outcome is ``cancelled``).
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
        t_begin = self.clock.now()
        with self._lock:
            self._status = None  # nothing of the previous plan carries over
            self._drift = None
            self._stop_latency = None
            self._stopped_at = None
            self._stopped.clear()
            self._trace = []
            self._notes = []
            self._plan_start = verdict.start_pose if verdict is not None else None
            if self._on_odom_source and cfg.pose_source == "auto":
                self._notes.append(
                    "odom_ground silent: drift control used odom (encoders + IMU, blind to slip)"
                )
            if verdict is not None and (cfg.pose_source == "odom" or self._odom_anchor is None):
                # Without POSE to tie odom to the map, the plan starts where it was planned
                # from (no odom yet: the first one that comes is tied there).
                self._odom_anchor = (
                    (self._odom_history[-1][1], verdict.start_pose) if self._odom_history else None
                )
            self._monitor = monitor
            self._running = True
        outcomes: list[StepOutcome] = []
        outcome, reason = "completed", "all steps completed"
        try:
            for index, step in enumerate(steps):
                if cancel is not None and cancel.is_set():
                    outcome, reason = "cancelled", "cancelled by the operator"
                    break
                status, published, accepted = self._run_step(
                    index, step, steps, verdict, monitor, cancel, on_progress, t_begin
                )
                outcomes.append(
                    StepOutcome(index, step, status, published, accepted, self.clock.now())
                )
                if on_progress is not None:
                    on_progress(self._progress(index, status, steps, verdict, monitor, None))
                if status == COMPLETED:
                    continue
                outcome, reason = self._classify(status, index, len(steps))
                break
        except BaseException as exc:
            self._end_run()
            logger.warning(
                "plan interrupted at step %d (%s); sending STOP",
                len(outcomes),
                type(exc).__name__,
            )
            try:
                if not self.stop():
                    logger.warning("STOP not confirmed within the round trip")
            except Exception:
                logger.exception("could not send STOP")
            raise
        self._end_run()
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
            notes = tuple(self._notes)
        return ExecutionResult(
            completed=outcome == "completed",
            outcome=outcome,
            reason=drift.reason if drift is not None else reason,
            steps=tuple(outcomes),
            drift=drift,
            stop_latency_s=latency,
            stopped_s=stopped,
            elapsed_s=self.clock.now() - t_begin,
            reported_pose=pose,
            worst_drift=monitor.worst if monitor is not None else (0.0, 0.0),
            trace=trace,
            notes=notes,
        )

    def _end_run(self) -> None:
        with self._lock:
            self._running = False
            self._monitor = None

    def _run_step(
        self,
        index: int,
        step: tuple[int, int, int],
        steps: list[tuple[int, int, int]],
        verdict: Verdict | None,
        monitor: DriftMonitor | None,
        cancel: threading.Event | None,
        on_progress: Callable[[ExecutionProgress], None] | None,
        plan_started: float,
    ) -> tuple[str, float, float | None]:
        cfg = self.config
        with self._lock:
            if self._status == "drift":
                return "drift", self.clock.now(), None
            self._event.clear()
            self._status = None
            self._accepted = None
            self._accepted_wall = None
        published = self.clock.now()
        published_wall = self.clock.time()
        if monitor is not None:
            with self._monitor_lock:
                monitor.step_published(index, published_wall)
        self._steps_pub.publish(Int16MultiArray(data=step))

        def report(status: str, started: float | None) -> None:
            if on_progress is not None:
                on_progress(self._progress(index, status, steps, verdict, monitor, started))

        report("published", None)
        watch = StepWatch(
            published,
            self.step_timeout_s(index, step, verdict),
            cfg.progress_period_s,
            cfg.blind_after_s if monitor is not None and cfg.blind_stop else None,
            plan_started,
        )
        while True:
            if watch.expired(self.clock.now()):
                return "timeout", published, self._accepted
            if self._wait(self._event.is_set, watch.wait_s(self.clock.now())):
                break
            if cancel is not None and cancel.is_set():
                return "cancelled", published, self._accepted
            with self._lock:
                heard = self._pose_rx
            acc, acc_wall = self._accepted_times()
            said = watch.poll(self.clock.now(), last_pose_s=heard, accepted_s=acc)
            if said.end is not None:
                return said.end, published, self._accepted
            if said.accepted_now and monitor is not None and acc_wall is not None:
                with self._monitor_lock:
                    monitor.step_accepted(index, published_wall, acc_wall)
            if said.report is not None:
                report(said.report, said.started_s)
        accepted_seen = watch.accepted_seen
        with self._lock:
            status = self._status or "timeout"
        acc, acc_wall = self._accepted_times()
        if monitor is not None and acc_wall is not None and not accepted_seen:
            with self._monitor_lock:
                monitor.step_accepted(index, published_wall, acc_wall)
        return status, published, acc

    def _accepted_times(self) -> tuple[float | None, float | None]:
        """When ``accepted`` came for the current step: (monotonic, wall), set by the
        status callback on the port's thread."""
        with self._lock:
            return self._accepted, self._accepted_wall

    def _classify(self, status: str, index: int, count: int) -> tuple[str, str]:
        """The outcome and its reason; steps are numbered from 1, as progress says them."""
        step = f"step {index + 1}/{count}"
        if status == "drift":
            return "drift", "drift control stopped the rover"
        if status == "blind":
            return "blind", (
                f"drift control blind: no pose from {self._sources()} for "
                f"{self.config.blind_after_s:.1f} s during {step}"
            )
        if status == "timeout":
            return "timeout", f"{step} got no 'completed' in time (rover silent or too slow)"
        if status == "cancelled":
            return "cancelled", "cancelled by the operator"
        kind = status.split(":", 1)[0]
        return kind, f"{step}: {status}"

    def _sources(self) -> str:
        return {"auto": "odom_ground or odom", "odom_ground": "odom_ground", "odom": "odom"}[
            self.config.pose_source
        ]

    def _progress(
        self,
        index: int,
        status: str,
        steps: list[tuple[int, int, int]],
        verdict: Verdict | None,
        monitor: DriftMonitor | None,
        started: float | None,
    ) -> ExecutionProgress:
        """The operator's view; ``started``: when the rover began this step (monotonic),
        ``None`` before it is known (or once the step ended)."""
        cfg = self.config
        final = status not in ("published", "accepted", "running")
        later = sum(
            self._predicted_s(i, s, verdict) / cfg.time_scale + cfg.link_rtt_s
            for i, s in enumerate(steps)
            if i > index
        )
        current = 0.0
        if not final:
            duration = self._predicted_s(index, steps[index], verdict) / cfg.time_scale
            if started is None:
                current = duration + cfg.link_rtt_s
            else:
                # From the rover's start: the step's rest, then its 'completed' coming back.
                elapsed = self.clock.now() - started
                current = max(0.0, duration - elapsed) + cfg.link_rtt_s / 2.0
        last = monitor.history[-1] if monitor is not None and monitor.history else None
        return ExecutionProgress(
            index,
            len(steps),
            status,
            current + later,
            last.linear_m if last else None,
            last.angular_deg if last else None,
            verdict,
        )
