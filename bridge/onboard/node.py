"""The onboard program's ROS 2 shell around :class:`~bridge.onboard.core.OnboardCore` and
:class:`~bridge.onboard.ekf.PoseEkf` (``rover onboard``, docs/onboard.md).

It runs beside the bridge, on the bridge's unchanged topics (docs/onboard.md, "The
program", says more of its threads and clocks):

- the port's default lane runs the callbacks of ``plan_uplink``, ``command_status``,
  ``odom`` and ``odom_ground``, its STOP lane ``emergency_stop``'s (the ground's STOP
  never waits behind a pose); each feeds the core under one lock and publishes what it
  decided, STOP first, from the same thread (a sample that leaves the estimate as it was
  feeds nothing: :meth:`PoseEkf.take_estimate`);
- ``onboard-timer`` runs :meth:`OnboardCore.tick` at its next deadline, at least every
  :data:`TICK_MAX_S`, and beats the stall monitor; a turn :data:`LATE_TURN_S` after the
  last (the program stalled) holds the deadlines :data:`BACKLOG_GRACE_S` more, so that
  what queued meanwhile is read first (:meth:`OnboardNode.step`);
- the core runs on the monotonic clock (no step of the system clock moves a deadline):
  estimates' stamps (ROS time) are moved into it, and reports' times back, by the two
  clocks' offset.

Not a ROS node class of rclpy: the port is the seam (docs/rosport.md); in lockstep
:meth:`OnboardNode.step` replaces the timer thread.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import replace
from types import TracebackType
from typing import Any

from bridge.onboard.core import (
    Action,
    OnboardConfig,
    OnboardCore,
    SayStatus,
    SendAck,
    SendReport,
    SendStep,
    SendStop,
    decode_screened,
    screen_uplink,
)
from bridge.onboard.ekf import EkfConfig, Estimate, Mat, PoseEkf
from bridge.ros.rosport import STOP_LANE, RosPort, Subscription, qos
from bridge.ros.rosport.cdr import odometry_fields
from bridge.ros.rosport.contract import (
    COMMAND_STATUS,
    EMERGENCY_STOP,
    ONBOARD_POSE,
    ONBOARD_REPORT,
    PLAN_ACK,
    PLAN_UPLINK,
    WHEEL_INSTRUCTIONS,
)
from bridge.ros.rosport.msgs import (
    Bool,
    Header,
    Int16MultiArray,
    Odometry,
    Point,
    Pose,
    PoseWithCovariance,
    String,
    Twist,
    TwistWithCovariance,
    Vector3,
    quaternion_from_yaw,
    stamp,
)
from firmware_proto.model.rover import RoverDescription
from firmware_proto.runtime import stall

__all__ = ["TICK_MAX_S", "TIMER_FAILURES_STOP", "OnboardNode"]

logger = logging.getLogger(__name__)

TICK_MAX_S = 0.05
"""The timer thread runs the core at least this often, s."""
TIMER_FAILURES_STOP = 3
"""Turns of the timer thread that failed in a row before the program stops the rover."""
LATE_TURN_S = 0.25
"""A timer turn this late after the one before (due within :data:`TICK_MAX_S`): a stall, s."""
BACKLOG_GRACE_S = 0.05
"""After such a stall the core's deadlines wait this long, s, for the samples queued meanwhile:
the blind check judges silent sensors, not the program's stall (docs/onboard.md)."""
ONBOARD_POSE_PERIOD_S = 0.1
"""``onboard_pose`` goes out for each estimate that took a new POSE fix, and for an
odometry-only estimate once this much later (estimate stamps, s) than the one before:
10 Hz, not the odometry's 50 (200 a second at ``--speed 4``), for the link and the ground.
The guard itself acts on every estimate."""


_COV3 = (0, 1, 5, 6, 7, 11, 30, 31, 35)
"""The places of x, y and yaw's 3x3 in a row-major 6x6 covariance."""


def _cov3(c: tuple[float, ...]) -> Mat:
    """x, y, yaw of a 6x6 pose covariance (row-major), as a row-major 3x3."""
    a, b, d, e, f, g, h, i, j = (float(c[k]) for k in _COV3)
    return (a, b, d, e, f, g, h, i, j)


class OnboardNode:
    """The onboard program on a ROS port (see the module docstring); a context manager.

    Args:
        port: the ROS port, in the rover's namespace (the bridge's).
        rover: the rover description (its limits bound the uplink's).
        config: the core's settings (token, time scale, ...).
        map_frame: ``onboard_pose``'s frame id.
        wall, monotonic: the system clock (ROS time) and the monotonic clock, s (tests
            step the first).
    """

    def __init__(
        self,
        port: RosPort,
        rover: RoverDescription,
        config: OnboardConfig | None = None,
        *,
        ekf: EkfConfig | None = None,
        map_frame: str = "map",
        wall: Callable[[], float] = time.time,
        monotonic: Callable[[], float] = time.monotonic,
    ) -> None:
        self.port = port
        self._wall = wall
        self._mono = monotonic
        self.core = OnboardCore(rover, config)
        self.ekf = PoseEkf(ekf)
        self.map_frame = map_frame
        self._lock = threading.Lock()
        self._wake = threading.Condition(self._lock)
        self._closed = False
        self.published_stops = 0
        self.late_turns = 0
        """Turns of the timer that found the program had stalled (:data:`LATE_TURN_S`)."""
        self._last_turn_s = monotonic()
        self._backlog_until = -math.inf
        self._timer_due = -math.inf
        """When the waiting timer thread wakes by itself (monotonic clock, s); ``-inf``
        while it is not waiting (it reads the core's deadline afresh before it waits)."""
        self._steps = port.publisher(WHEEL_INSTRUCTIONS, Int16MultiArray, qos.COMMAND)
        self._stop = port.publisher(EMERGENCY_STOP, Bool, qos.STOP)
        self._ack = port.publisher(PLAN_ACK, String, qos.STATUS)
        self._report = port.publisher(ONBOARD_REPORT, String, qos.STATUS)
        self._status = port.publisher(COMMAND_STATUS, String, qos.STATUS)
        self._pose = port.publisher(ONBOARD_POSE, Odometry, qos.TELEMETRY)
        #: ``(stamp_s, pose_stamp_s)`` of the last estimate published on ``onboard_pose``.
        self._published: tuple[float, float] | None = None
        #: Estimates sent on ``onboard_pose`` (:data:`ONBOARD_POSE_PERIOD_S`).
        self.poses_published = 0
        # Over DDS odometry is read in place from its bytes (bridge/ros/rosport/cdr.py):
        # /odom comes with every encoder sample, and building each nested message cost
        # more than the estimator's own step.
        serialized = port.carries_serialized
        self._subs: list[Subscription[Any]] = [
            port.subscribe(EMERGENCY_STOP, Bool, self._on_stop, qos.STOP, lane=STOP_LANE),
            port.subscribe(PLAN_UPLINK, String, self._on_uplink, qos.COMMAND),
            port.subscribe(COMMAND_STATUS, String, self._on_status, qos.STATUS),
            # odom_ground before odom: a backlog read late takes the POSE first
            port.subscribe(
                "odom_ground", Odometry, self._on_ground, qos.SENSOR, serialized=serialized
            ),
            port.subscribe("odom", Odometry, self._on_odom, qos.SENSOR, serialized=serialized),
        ]
        self._thread = threading.Thread(target=self._timer, name="onboard-timer", daemon=True)

    def start(self) -> OnboardNode:
        """Start the timer thread."""
        with self._lock:
            self._last_turn_s = self._mono()
        self._thread.start()
        return self

    def wait_for_bridge(self, timeout_s: float = 10.0) -> bool:
        """Wait until the steps and the STOP reach the bridge: ``wheel_instructions``
        one subscriber, ``emergency_stop`` two (the program hears its own STOP too).
        ``False``: not within ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        return all(
            pub.wait_for_subscribers(count, max(0.0, deadline - time.monotonic()))
            for pub, count in ((self._steps, 1), (self._stop, 2))
        )

    # -- inputs (the port's lanes) -------------------------------------------------------------
    def _offset(self) -> float:
        """ROS time minus the monotonic clock, now, s."""
        return self._wall() - self._mono()

    def _feed(self, fn: str, *args: Any) -> None:
        now = self._mono()
        with self._lock:
            getattr(self.core, fn)(*args, now)
            actions = self.core.take_actions()
            self._wake.notify()
        self._act(actions)

    def _on_stop(self, msg: Bool) -> None:
        if msg.data:
            self._feed("on_ground_stop")

    def _on_uplink(self, msg: String) -> None:
        """An uplink: screened (cheap), then decoded; the two pure steps run outside the
        lock, so that a large plan or a flood of junk never holds up the estimates, the
        timer or a STOP."""
        screened = screen_uplink(msg.data, self.core.config.token)
        with self._lock:
            answered = self.core.on_screened(screened, self._mono())
            actions = self.core.take_actions()
        self._act(actions)
        if answered:
            return
        decoded = decode_screened(screened, self.core.rover)
        with self._lock:
            self.core.on_decoded(screened, decoded, self._mono())
            actions = self.core.take_actions()
            self._wake.notify()
        self._act(actions)

    def _on_status(self, msg: String) -> None:
        self._feed("on_status", msg.data)

    def _on_odom(self, msg: Odometry | bytes) -> None:
        f = odometry_fields(msg)
        with self._lock:
            self.ekf.predict(f.stamp_s, f.x_m, f.y_m, f.yaw_rad, f.v_mps, f.yaw_rate_rad_s)
        self._estimated()

    def _on_ground(self, msg: Odometry | bytes) -> None:
        f = odometry_fields(msg)
        with self._lock:
            self.ekf.correct(f.stamp_s, f.x_m, f.y_m, f.yaw_rad, _cov3(f.covariance))
        self._estimated()

    def _estimated(self) -> None:
        with self._lock:
            estimate = self.ekf.take_estimate()
            if estimate is None:
                return
            now = self._mono()
            offset = self._offset()
            on_core_clock = replace(
                estimate,
                stamp_s=estimate.stamp_s - offset,
                pose_stamp_s=estimate.pose_stamp_s - offset,
            )
            self.core.on_estimate(on_core_clock, now)
            actions = self.core.take_actions()
            # Wake the timer only when it must run sooner than it would by itself: a
            # deadline due now or earlier than its wake (200 estimates a second at
            # --speed 4 would otherwise wake it for nothing).
            due = max(self.core.next_deadline(now), self._backlog_until)
            if due <= now or due < self._timer_due:
                self._wake.notify()
            pose_due = self._pose_due(estimate)
        self._act(actions)
        if pose_due:
            self._pose.publish(self._odometry(estimate))

    def _pose_due(self, est: Estimate) -> bool:
        """Whether ``est`` goes out on ``onboard_pose`` (:data:`ONBOARD_POSE_PERIOD_S`),
        counted as sent if so; the caller holds the lock."""
        last = self._published
        due = (
            last is None
            or est.pose_stamp_s != last[1]  # a new POSE fix
            or not last[0] <= est.stamp_s < last[0] + ONBOARD_POSE_PERIOD_S
        )
        if due:
            self._published = (est.stamp_s, est.pose_stamp_s)
            self.poses_published += 1
        return due

    def _odometry(self, est: Estimate) -> Odometry:
        c = est.covariance
        cov = [0.0] * 36
        for i, ri in enumerate((0, 1, 5)):
            for j, rj in enumerate((0, 1, 5)):
                cov[ri * 6 + rj] = c[i * 3 + j]
        return Odometry(
            header=Header(stamp=stamp(est.stamp_s), frame_id=self.map_frame),
            child_frame_id="base_link",
            pose=PoseWithCovariance(
                pose=Pose(
                    position=Point(x=est.x_m, y=est.y_m, z=0.0),
                    orientation=quaternion_from_yaw(math.radians(est.yaw_deg)),
                ),
                covariance=cov,
            ),
            twist=TwistWithCovariance(
                twist=Twist(linear=Vector3(x=est.v_mps), angular=Vector3(z=est.yaw_rate_rad_s))
            ),
        )

    # -- outputs -------------------------------------------------------------------------------
    def _act(self, actions: list[Action]) -> None:
        """Publish what the core decided (its STOPs come first)."""
        for action in actions:
            try:
                if isinstance(action, SendStop):
                    self._stop.publish(Bool(data=True))
                    self.published_stops += 1
                    logger.warning("STOP: %s", action.reason)
                elif isinstance(action, SendStep):
                    self._steps.publish(Int16MultiArray(data=list(action.step)))
                elif isinstance(action, SendAck):
                    self._ack.publish(String(data=action.ack.to_json()))
                elif isinstance(action, SayStatus):
                    self._status.publish(String(data=action.text))
                elif isinstance(action, SendReport):
                    report = action.report.shifted(self._offset())  # into ROS time
                    self._report.publish(String(data=report.to_json()))
            except Exception:
                # A port closed while the program ends; anything else is logged and the
                # program goes on (its next report tells the ground).
                logger.exception("could not publish %s", type(action).__name__)

    def stop_now(self, reason: str, answer_s: float = 1.0) -> bool:
        """End the plan armed or running (STOP when it runs): the program is ending.
        Waits at most ``answer_s`` for the bridge to answer its STOP (the timer thread
        sends copies meanwhile). ``False``: a STOP went unanswered."""
        self._feed("shutdown", reason)
        deadline = self._mono() + answer_s
        with self._lock:
            while self.core.stop_unanswered and not self._closed:
                left = deadline - self._mono()
                if left <= 0:
                    logger.error("the bridge did not answer the STOP of %s", reason)
                    return False
                self._wake.wait(min(left, TICK_MAX_S))
        return True

    # -- the timer -----------------------------------------------------------------------------
    def step(self) -> None:
        """Run the core's :meth:`~OnboardCore.tick` if it is due now: the timer thread's
        work at each wake, or a lockstep test's at each tick (instead of :meth:`start`)."""
        with self._lock:
            now = self._mono()
            if now - self._last_turn_s > LATE_TURN_S:
                # The program stalled: what queued up meanwhile is read before a deadline.
                self.late_turns += 1
                self._backlog_until = now + BACKLOG_GRACE_S
                logger.warning(
                    "onboard timer: %.3f s since its last turn; deadlines wait %.2f s for "
                    "the queued samples",
                    now - self._last_turn_s,
                    BACKLOG_GRACE_S,
                )
            self._last_turn_s = now
            actions: list[Action] = []
            if now >= self._backlog_until and now >= self.core.next_deadline(now):
                self.core.tick(now)
                actions = self.core.take_actions()
        self._act(actions)

    def _timer(self) -> None:
        """The timer thread: one turn after another until :meth:`close`. The stall
        monitor forgets its beat only then: a thread that died any other way is
        reported as stalled."""
        beat = stall.watch("onboard-timer")
        failures = 0
        while not self._closed:
            failures = self._timer_turn(beat, failures)
        stall.forget(beat)

    def _timer_turn(self, beat: stall.Beat, failures: int) -> int:
        """One wake of the timer: wait for the core's next deadline (at most
        :data:`TICK_MAX_S`), then :meth:`step`. An exception is logged and the thread
        goes on; :data:`TIMER_FAILURES_STOP` in a row and the rover is stopped (the
        timer is the guard's blind check and step timeouts). Returns the failures in a
        row."""
        try:
            with self._lock:
                now = self._mono()
                due = max(self.core.next_deadline(now), self._backlog_until)
                wait = min(TICK_MAX_S, max(0.0, due - now))
                if wait > 0:
                    self._timer_due = now + wait
                    try:
                        self._wake.wait(wait)
                    finally:
                        self._timer_due = -math.inf
                if self._closed:
                    return failures
            beat.tick()
            self.step()
            return 0
        except Exception:
            failures += 1
            if failures <= TIMER_FAILURES_STOP or failures % 1000 == 0:
                logger.exception("onboard timer: turn failed (%d in a row)", failures)
            if failures == TIMER_FAILURES_STOP:
                self._fail_safe(f"the onboard timer failed {failures} times in a row")
            with self._lock:
                if not self._closed:
                    self._wake.wait(TICK_MAX_S)  # no busy loop on a lasting fault
            return failures

    def _fail_safe(self, why: str) -> None:
        """STOP straight on the STOP topic (the core may be what fails), then end the
        plan through the core if it still can."""
        try:
            self._stop.publish(Bool(data=True))
            self.published_stops += 1
            logger.error("STOP: %s", why)
        except Exception:
            logger.exception("could not publish STOP (%s)", why)
        try:
            with self._lock:
                self.core.shutdown(why, self._mono())
                actions = self.core.take_actions()
            self._act(actions)
        except Exception:
            logger.exception("could not end the plan (%s)", why)

    def close(self) -> None:
        """Stop the timer and unsubscribe (idempotent). The port is the caller's."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._wake.notify_all()
        for sub in self._subs:
            sub.close()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout=5.0)

    def __enter__(self) -> OnboardNode:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
