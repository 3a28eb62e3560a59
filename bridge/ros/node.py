"""The rover-side ROS 2 node: ``/wheel_instructions`` in, frames out; telemetry back.

:class:`BridgeNode` joins a ROS port (:mod:`bridge.ros.rosport`: rclpy in production, or
in-process for fast unit tests) to a :class:`~bridge.link.controllerlink.ControllerLink`.

The topics, their types and meaning are docs/bridge.md, "Topics". Invalid
``wheel_instructions`` are answered ``rejected:<reason>`` and never sent
(:func:`validate_step`); ``emergency_stop`` ``true`` sends STOP on the STOP lane, ``false``
does nothing; ``/tf`` is published only where ``tf2_msgs`` is installed
(:attr:`BridgeNode.tf_note`); ``/diagnostics`` at ``diagnostics_hz`` and at once whenever
the link changes state (:mod:`bridge.ros.diagnostics`).

Threads: the ROS port's threads run the input callbacks; the transport's dispatcher
thread runs the telemetry and status outputs; one diagnostics thread publishes
``/diagnostics``. Given a lockstep clock (a whole mission in virtual time, docs/sim.md),
the node and its link start no thread: the link runs on the clock's ticks, and so does
the diagnostics schedule; every stamp is the clock's time of day.
"""

from __future__ import annotations

import importlib
import logging
import math
import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Mapping
from dataclasses import replace
from types import TracebackType
from typing import Any

from bridge.errors import ParameterError
from bridge.link.controllerlink import ControllerLink, LinkDiagnostics, LinkState, StepRequest
from bridge.link.odometry import OdometryEstimator, ground_pose
from bridge.link.transport import Transport, open_transport
from bridge.ros.diagnostics import RECENT_STATUSES, diagnostic_array
from bridge.ros.odommsg import ground_odometry_cdr, wheel_odometry_cdr
from bridge.ros.params import BridgeParams, check_params, parameter_specs
from bridge.ros.rosport import STOP_LANE, RosPort, Subscription, qos
from bridge.ros.rosport.cdr import stamp_parts
from bridge.ros.rosport.contract import rejected
from bridge.ros.rosport.msgs import (
    Bool,
    DiagnosticArray,
    Empty,
    Header,
    Int16MultiArray,
    Odometry,
    String,
    quaternion_from_yaw,
    stamp,
)
from firmware_proto.linkio.clock import WALL, Clock, LockstepClock
from firmware_proto.linkio.trafficio import LogWriter, open_recorder
from firmware_proto.model.pose import Pose as PlanarPose
from firmware_proto.model.pose import frame_in
from firmware_proto.model.rover import RoverDescription, load_rover
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import (
    Command,
    Encoders,
    Heartbeat,
    Ident,
    Imu,
    PoseMsg,
    StopSource,
    WheelSpeeds,
)

__all__ = ["BridgeNode", "validate_step"]

logger = logging.getLogger(__name__)


def validate_step(data: object, rover: RoverDescription) -> StepRequest | str:
    """A ``wheel_instructions`` payload as a step, or the rejection reason."""
    if not isinstance(data, (list, tuple)) or len(data) != 3:
        return "bad_length"
    command, speed, distance = data
    if not all(isinstance(v, int) and not isinstance(v, bool) for v in data):
        return "bad_type"
    if command not in Command._value2member_map_:
        return "unknown_command"
    if command == Command.STOP:
        return StepRequest(command, 0, 0)
    if not 0 <= speed <= rover.drive.max_speed:
        return "speed_out_of_range"
    if not 0 <= distance <= rover.drive.max_distance:
        return "distance_out_of_range"
    return StepRequest(command, speed, distance)


TF_TOPIC = "/tf"
"""tf2's topic (absolute: one tree per ROS domain, REP 105)."""
NO_TF2_MSGS = (
    "no /tf: tf2_msgs is not installed (the ROS 2 Jazzy wheels on PyPI have no "
    "tf2_msgs, and rclpy cannot publish a type without its generated support; a sourced "
    "ROS 2 has it). Recordings and rover go --foxglove carry /tf (docs/ros2.md)"
)
"""What :attr:`BridgeNode.tf_note` says where ``tf2_msgs`` cannot be imported."""


def tf_message_type() -> type[Any] | None:
    """``tf2_msgs/msg/TFMessage``'s generated class, or ``None`` where it is not installed."""
    try:
        found: type[Any] = importlib.import_module("tf2_msgs.msg").TFMessage
    except (ImportError, AttributeError):
        return None
    return found


def _transform(when: Any, parent: str, child: str, x: float, y: float, yaw: float) -> Any:
    """A planar ``geometry_msgs/TransformStamped``: ``child`` at (x, y, yaw rad) in ``parent``."""
    geometry = importlib.import_module("geometry_msgs.msg")
    return geometry.TransformStamped(
        header=Header(stamp=when, frame_id=parent),
        child_frame_id=child,
        transform=geometry.Transform(
            translation=geometry.Vector3(x=x, y=y, z=0.0), rotation=quaternion_from_yaw(yaw)
        ),
    )


class BridgeNode:
    """The bridge: a ROS port on one side, the controller link on the other."""

    def __init__(
        self,
        params: BridgeParams,
        port: RosPort,
        *,
        rover: RoverDescription | None = None,
        link: ControllerLink | None = None,
        clock: Clock = WALL,
        transport_factory: Callable[[str], Transport] | None = None,
    ) -> None:
        """Args:
        params: validated parameters (see :func:`bridge.ros.params.load_params`).
        port: an open ROS port; the node publishes and subscribes on it but does not
            close it.
        rover: the rover description (default: ``params.rover_description`` or the
            packaged one).
        link: a link to use instead of one built from ``params`` (it is started here).
        clock: the time (stamps, the diagnostics schedule) and, when it is a lockstep
            clock, what runs the node and its link instead of threads.
        transport_factory: builds the link's transport for ``params.url`` (default: the
            one the URL names, recording to the traffic log ``params.record``, if set,
            which the node closes with itself).

        Raises:
            TransportUrlError: ``params.url`` is malformed (checked before the traffic
                log is created).
        """
        self.params = params
        self.port = port
        self.rover = rover or load_rover(params.rover_description or None)
        self.rejected: Counter[str] = Counter()
        """``wheel_instructions`` this node refused, by reason (see :meth:`rejected_counts`)."""
        self._rejected_lock = threading.Lock()
        self._recent: deque[str] = deque(maxlen=RECENT_STATUSES)
        """The last ``command_status`` strings, for ``/diagnostics`` (append is atomic)."""
        self.odometry = OdometryEstimator(self.rover)
        self._status_pub = port.publisher(params.topic_command_status, String, qos.STATUS)
        self._odom_pub = port.publisher(params.topic_odom, Odometry, qos.TELEMETRY)
        self._ground_pub = port.publisher(params.topic_ground_pose, Odometry, qos.TELEMETRY)
        self._diag_pub = port.publisher(params.topic_diagnostics, DiagnosticArray, qos.DIAGNOSTICS)
        self._tf_type = tf_message_type() if params.publish_tf else None
        self._tf_pub = (
            port.publisher(TF_TOPIC, self._tf_type, qos.TELEMETRY)
            if self._tf_type is not None
            else None
        )
        self.tf_note = NO_TF2_MSGS if params.publish_tf and self._tf_type is None else ""
        """Why the node publishes no ``/tf`` (``""``: it does, or was told not to)."""
        if self.tf_note:
            logger.info("%s", self.tf_note)
        self._map_to_odom: PlanarPose | None = None
        """Where the odometry's frame lies in the map, from the last POSE (held)."""
        self._odom_now: PlanarPose | None = None
        self.recorder: LogWriter | None = None
        if link is None and params.record:
            open_transport(params.url)  # a malformed URL raises here, before the file exists
            self.recorder = open_recorder(
                params.record,
                "can" if params.can_interface else "serial",
                channel=params.can_channel,
                metadata={"role": "bridge", "url": params.url},
            )
        recorder = self.recorder

        def recording_transport(url: str) -> Transport:
            return open_transport(url, recorder=recorder)

        self.clock = clock
        self._stepping = clock if isinstance(clock, LockstepClock) else None
        self.link = link or ControllerLink(
            params.link_config(),
            on_status=self._publish_status,
            on_telemetry=self._on_telemetry,
            on_state=self._on_link_state,
            transport_factory=transport_factory or recording_transport,
            clock=clock,
        )
        self._odom_lock = threading.Lock()
        self._stop = threading.Event()
        self._diag_now = threading.Event()
        self._diag_thread = threading.Thread(
            target=self._diagnostics_loop, name="bridge-diag", daemon=True
        )
        self._diag_next = 0.0  # lockstep: when the next scheduled diagnostics are due
        self._subs: list[Subscription[Any]] = [
            port.subscribe(
                params.topic_wheel_instructions,
                Int16MultiArray,
                self._on_wheel_instructions,
                qos.COMMAND,
            ),
            # The STOP lane: its own executor thread, never behind another callback.
            port.subscribe(
                params.topic_emergency_stop, Bool, self._on_emergency_stop, qos.STOP, lane=STOP_LANE
            ),
            port.subscribe(
                params.topic_clear_stop, Empty, self._on_clear, qos.STOP, lane=STOP_LANE
            ),
        ]
        self._started = False
        self.last_estop_received: float | None = None
        """``time.monotonic()`` when the last true ``emergency_stop`` reached this node's STOP lane
        callback: where the ROS hop ends and the link's begins."""
        port.declare_parameters(parameter_specs(params), self._on_parameters, params.to_dict())

    # -- lifecycle ----------------------------------------------------------------------
    def start(self) -> BridgeNode:
        """Start the link and the diagnostics timer."""
        self._started = True
        self.link.start()
        if self._stepping is not None:
            self._diag_next = self.clock.now() + 1.0 / self.params.diagnostics_hz
            self._stepping.add(self._diagnostics_tick)
        else:
            self._diag_thread.start()
        return self

    def close(self) -> None:
        """Stop everything this node started (idempotent); the port stays open."""
        self._stop.set()
        self._diag_now.set()
        for sub in self._subs:
            sub.close()
        if self._started:
            self.link.close()
            if self._stepping is not None:
                self._stepping.remove(self._diagnostics_tick)
            else:
                self._diag_thread.join(timeout=5.0)
            self._started = False
        if self.recorder is not None:
            self.recorder.close()

    def __enter__(self) -> BridgeNode:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    # -- ROS parameters --------------------------------------------------------------------
    def _on_parameters(self, changes: Mapping[str, Any]) -> str | None:
        """Apply parameters set while running (only those the descriptors let through:
        see :func:`bridge.ros.params.parameter_specs`); the reason when they break a rule
        between parameters, e.g. ``reconnect_max_s`` below ``reconnect_min_s``."""
        try:
            new = replace(self.params, **changes)
            check_params(new)
        except (ParameterError, TypeError) as exc:
            return str(exc)
        self.params = new
        if new.link_config() != self.link.config:
            self.link.reconfigure(new.link_config())
        logger.info("parameters set: %s", ", ".join(f"{k}={v!r}" for k, v in changes.items()))
        self._diag_now.set()
        return None

    # -- ROS inputs --------------------------------------------------------------------------
    def _on_wheel_instructions(self, msg: Int16MultiArray) -> None:
        step = validate_step(tuple(msg.data), self.rover)
        if isinstance(step, str):
            with self._rejected_lock:
                self.rejected[step] += 1
            logger.warning("wheel_instructions %s rejected: %s", list(msg.data), step)
            self._publish_status(rejected(step))
            return
        self.link.submit_step(step)

    def _on_emergency_stop(self, msg: Bool) -> None:
        if msg.data:
            self.last_estop_received = self.clock.now()
            self.link.emergency_stop(StopSource.OPERATOR)

    def _on_clear(self, msg: Empty) -> None:
        self.link.clear_stop()

    # -- outputs -------------------------------------------------------------------------------
    def _publish_status(self, text: str) -> None:
        self._recent.append(text)
        self._status_pub.publish(String(data=text))

    def _on_telemetry(self, msg: Message, arrived: float) -> None:
        if isinstance(msg, Encoders):
            with self._odom_lock:
                est = self.odometry.update_encoders(msg)
                self._odom_now = PlanarPose(est.x_m, est.y_m, math.degrees(est.yaw_rad))
            t_s = self.clock.time()
            if self._tf_pub is not None:
                self._publish_tf(stamp(t_s), est.x_m, est.y_m, est.yaw_rad)
            # Packed directly (bridge/ros/odommsg.py): the message every encoder sample.
            self._odom_pub.publish_serialized(
                wheel_odometry_cdr(
                    est, stamp_parts(t_s), self.params.odom_frame, self.params.base_frame
                )
            )
        elif isinstance(msg, (Heartbeat, Ident)):
            with self._odom_lock:
                if self.odometry.observe_boot(self.link.reboots):
                    logger.info("controller rebooted: odometry re-based, pose kept")
        elif isinstance(msg, Imu):
            with self._odom_lock:
                self.odometry.update_imu(msg)
        elif isinstance(msg, WheelSpeeds):
            with self._odom_lock:
                self.odometry.update_speeds(msg)
        elif isinstance(msg, PoseMsg):
            pose = ground_pose(msg)
            if pose is None:
                return  # no fix: nothing to report
            with self._odom_lock:
                odom_now = self._odom_now
            if odom_now is not None:
                # map -> odom: the POSE against the odometry at (about) the same moment.
                self._map_to_odom = frame_in(
                    PlanarPose(pose.x_m, pose.y_m, math.degrees(pose.yaw_rad)), odom_now
                )
            self._ground_pub.publish_serialized(
                ground_odometry_cdr(
                    pose,
                    stamp_parts(self.clock.time() - pose.age_s),
                    self.params.map_frame,
                    self.params.base_frame,
                )
            )

    def _publish_tf(self, when: Any, x_m: float, y_m: float, yaw_rad: float) -> None:
        """``/tf`` for one odometry sample (dispatcher thread); nothing without tf2_msgs."""
        if self._tf_pub is None or self._tf_type is None:
            return
        p = self.params
        transforms = [_transform(when, p.odom_frame, p.base_frame, x_m, y_m, yaw_rad)]
        held = self._map_to_odom
        if held is not None:
            transforms.insert(
                0, _transform(when, p.map_frame, p.odom_frame, held.x, held.y, held.yaw_rad)
            )
        self._tf_pub.publish(self._tf_type(transforms=transforms))

    def diagnostics(self) -> LinkDiagnostics:
        """The link's diagnostics snapshot."""
        return self.link.diagnostics()

    def rejected_counts(self) -> dict[str, int]:
        """A copy of :attr:`rejected`, safe to read from any thread."""
        with self._rejected_lock:
            return dict(self.rejected)

    def _on_link_state(self, state: LinkState) -> None:
        """The link changed state: publish ``/diagnostics`` now, not at the next tick (on
        the diagnostics thread, so the link's threads never wait on the ROS port)."""
        self._diag_now.set()

    def _publish_diagnostics(self) -> None:
        try:
            self._diag_pub.publish(
                diagnostic_array(
                    self.link.diagnostics(),
                    stamp(self.clock.time()),
                    rejected=self.rejected_counts(),
                    statuses=tuple(self._recent),
                )
            )
        except Exception:
            logger.exception("publishing diagnostics failed")

    def _diagnostics_tick(self) -> None:
        """Lockstep: the diagnostics loop's work for one tick of the clock."""
        if self._stop.is_set():
            return
        now = self.clock.now()
        due = now >= self._diag_next
        if due:
            period = 1.0 / self.params.diagnostics_hz
            self._diag_next = max(self._diag_next + period, now + period / 2)
        if self._diag_now.is_set() or due:
            self._diag_now.clear()
            self._publish_diagnostics()

    def _diagnostics_loop(self) -> None:
        """Publish every ``1/diagnostics_hz`` s, on schedule, and at once on a link state
        change (which leaves the schedule alone)."""
        next_tick = time.monotonic() + 1.0 / self.params.diagnostics_hz
        while not self._stop.is_set():
            period = 1.0 / self.params.diagnostics_hz  # a ROS parameter: may change
            if self._diag_now.wait(max(0.0, next_tick - time.monotonic())):
                self._diag_now.clear()
            if self._stop.is_set():
                return
            now = time.monotonic()
            if now >= next_tick:
                next_tick = max(next_tick + period, now + period / 2)
            self._publish_diagnostics()
