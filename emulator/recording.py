"""A recorded mission read back for calibration: the steps sent and what the rover said.

:func:`read_recording` reads the ground station's ROS 2 MCAP (``rover go --record``,
``rover demo``) with the mcap reader (no ROS installation needed) into a
:class:`Recording`. Statuses are matched to steps first in, first out, as the
controller's queue works; a STOP step is an emergency stop, not a step. Times are
seconds relative to :attr:`Recording.origin_ns`; topics are found by their last name
component (several namespaces need ``namespace``). docs/twin.md, "Calibration": What
is measured.
"""

from __future__ import annotations

import logging
import math
import statistics
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from emulator.errors import RecordingError

__all__ = ["TOPICS", "RecordedStep", "Recording", "read_recording"]

logger = logging.getLogger(__name__)

TOPICS = ("wheel_instructions", "command_status", "odom", "odom_ground", "emergency_stop")
"""The topics read, by last name component."""

FloatArray = npt.NDArray[np.float64]


@dataclass
class RecordedStep:
    """One step the ground station sent, and its fate.

    Attributes:
        index: position among the steps of the recording (0-based).
        command, speed, distance: the step (``[command, speed, distance]``).
        sent_s: log time of the ``wheel_instructions`` message (ground clock).
        accepted_s: log time of its ``accepted`` (ground clock), if any.
        ended_s: log time of its ``completed``, ``aborted:*`` or ``rejected:*``.
        outcome: ``completed``, ``aborted:<reason>``, ``rejected:<reason>``, or ``""``
            when the recording ends first.
        faults: ``fault:*`` statuses heard while it ran.
    """

    index: int
    command: int
    speed: int
    distance: int
    sent_s: float
    accepted_s: float | None = None
    ended_s: float | None = None
    outcome: str = ""
    faults: list[str] = field(default_factory=list)

    @property
    def completed(self) -> bool:
        """The controller finished it (its encoders counted the whole distance)."""
        return self.outcome == "completed"


@dataclass(frozen=True)
class Recording:
    """What :func:`read_recording` found (see the module docstring).

    Attributes:
        path: the file.
        namespace: the namespace of the topics read (``""`` for none).
        origin_ns: log time, ns, that every time here is relative to.
        steps: the steps in the order sent.
        pose_t_s, pose_xy_m, pose_yaw_rad, pose_sigma_m: POSE samples (measurement
            time on the rover's clock, position, yaw, 1-sigma position error).
        odom_t_s, odom_xy_m, odom_yaw_rad: odometry (publication time, position in the
            odometry frame, gyro-integrated yaw); ``odom_v_mps`` the mean wheel speed,
            ``odom_yaw_rate_rad_s`` the gyro.
        downlink_delay_s: median of log time minus header stamp over odometry (``nan``
            without odometry).
        stops_s: log times (ground clock) of every ``emergency_stop`` sent.
    """

    path: str
    namespace: str
    origin_ns: int
    steps: tuple[RecordedStep, ...]
    pose_t_s: FloatArray
    pose_xy_m: FloatArray
    pose_yaw_rad: FloatArray
    pose_sigma_m: FloatArray
    odom_t_s: FloatArray
    odom_xy_m: FloatArray
    odom_yaw_rad: FloatArray
    odom_v_mps: FloatArray
    odom_yaw_rate_rad_s: FloatArray
    downlink_delay_s: float
    stops_s: tuple[float, ...] = ()

    def to_rover_clock(self, log_s: float) -> float:
        """A log time (ground clock) as the rover's clock: minus the downlink delay."""
        return log_s - (0.0 if math.isnan(self.downlink_delay_s) else self.downlink_delay_s)


def _yaw(q: Any) -> float:
    return 2.0 * math.atan2(float(q.z), float(q.w))


def _stamp_ns(header: Any) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def _namespaces(topics: list[str]) -> dict[str, set[str]]:
    """Namespace -> the known topic names (last components) under it."""
    found: dict[str, set[str]] = {}
    for topic in topics:
        ns, _, last = topic.rpartition("/")
        if last in TOPICS:
            found.setdefault(ns, set()).add(last)
    return found


def read_recording(path: str | Path, namespace: str | None = None) -> Recording:
    """Read a mission recorded as ROS 2 MCAP.

    Args:
        path: the ``.mcap`` file.
        namespace: the namespace whose topics to read (``"/ground"``); ``None`` picks
            the only one that has odometry.

    Raises:
        RecordingError: the file cannot be read, is not MCAP, has no odometry or no
            ``wheel_instructions``, or several namespaces and none was chosen.
    """
    from mcap.exceptions import McapError  # noqa: PLC0415 - light, but only here
    from mcap.reader import make_reader  # noqa: PLC0415
    from mcap_ros2.decoder import DecoderFactory  # noqa: PLC0415

    source = str(path)
    try:
        with Path(path).open("rb") as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            summary = reader.get_summary()
            if summary is None:
                raise RecordingError(f"{source}: an MCAP file without a summary (unfinished?)")
            topics = sorted({c.topic for c in summary.channels.values()})
            spaces = _namespaces(topics)
            if namespace is not None:
                chosen = namespace.rstrip("/")
                if chosen not in spaces:
                    raise RecordingError(
                        f"{source}: no mission topics under namespace {namespace!r} "
                        f"(found: {', '.join(repr(n or '/') for n in spaces) or 'none'})"
                    )
            else:
                with_odom = sorted(ns for ns, names in spaces.items() if "odom" in names)
                if len(with_odom) != 1:
                    raise RecordingError(
                        f"{source}: "
                        + (
                            "no odom topic: not a mission recording"
                            if not with_odom
                            else "odometry under several namespaces ("
                            + ", ".join(repr(n or "/") for n in with_odom)
                            + "): choose one with --namespace"
                        )
                    )
                chosen = with_odom[0]
            wanted = [f"{chosen}/{t}" for t in TOPICS]
            messages = list(reader.iter_decoded_messages(topics=wanted, log_time_order=True))
    except OSError as exc:
        raise RecordingError(f"cannot read {source}: {exc}") from exc
    except McapError as exc:
        raise RecordingError(f"{source}: not a readable MCAP file: {exc}") from exc
    return _build(source, chosen, messages)


def _build(source: str, namespace: str, messages: list[Any]) -> Recording:
    if not messages:
        raise RecordingError(f"{source}: no mission messages")
    origin = messages[0][2].log_time
    steps: list[RecordedStep] = []
    unanswered: deque[RecordedStep] = deque()
    running: deque[RecordedStep] = deque()
    pose: list[tuple[float, float, float, float, float]] = []
    odom: list[tuple[float, float, float, float, float, float]] = []
    delays: list[float] = []
    stops: list[float] = []
    for _schema, channel, message, decoded in messages:
        last = channel.topic.rpartition("/")[2]
        log_s = (message.log_time - origin) / 1e9
        if last == "wheel_instructions":
            data = [int(v) for v in decoded.data]
            if len(data) != 3 or data[0] == 0:
                continue  # malformed (the bridge rejects it too) or an emergency stop
            step = RecordedStep(len(steps), data[0], data[1], data[2], log_s)
            steps.append(step)
            unanswered.append(step)
        elif last == "command_status":
            _status(str(decoded.data), log_s, unanswered, running)
        elif last == "emergency_stop":
            if bool(decoded.data):
                stops.append(log_s)
        elif last == "odom":
            t_ns = _stamp_ns(decoded.header)
            p = decoded.pose.pose
            odom.append(
                (
                    (t_ns - origin) / 1e9,
                    float(p.position.x),
                    float(p.position.y),
                    _yaw(p.orientation),
                    float(decoded.twist.twist.linear.x),
                    float(decoded.twist.twist.angular.z),
                )
            )
            delays.append((message.log_time - t_ns) / 1e9)
        else:  # odom_ground
            p = decoded.pose.pose
            var = float(decoded.pose.covariance[0])
            pose.append(
                (
                    (_stamp_ns(decoded.header) - origin) / 1e9,
                    float(p.position.x),
                    float(p.position.y),
                    _yaw(p.orientation),
                    math.sqrt(var) if var > 0.0 else 0.01,
                )
            )
    if not odom:
        raise RecordingError(f"{source}: no odom messages: not a mission recording")
    if not steps:
        raise RecordingError(f"{source}: no step was sent on wheel_instructions")
    pose.sort()
    odom.sort()
    p_arr = np.array(pose, dtype=np.float64).reshape(-1, 5)
    o_arr = np.array(odom, dtype=np.float64).reshape(-1, 6)
    recording = Recording(
        path=source,
        namespace=namespace,
        origin_ns=origin,
        steps=tuple(steps),
        pose_t_s=p_arr[:, 0].copy(),
        pose_xy_m=p_arr[:, 1:3].copy(),
        pose_yaw_rad=p_arr[:, 3].copy(),
        pose_sigma_m=p_arr[:, 4].copy(),
        odom_t_s=o_arr[:, 0].copy(),
        odom_xy_m=o_arr[:, 1:3].copy(),
        odom_yaw_rad=o_arr[:, 3].copy(),
        odom_v_mps=o_arr[:, 4].copy(),
        odom_yaw_rate_rad_s=o_arr[:, 5].copy(),
        downlink_delay_s=statistics.median(delays),
        stops_s=tuple(stops),
    )
    logger.info(
        "%s: %d steps (%d completed), %d POSE, %d odom, downlink %.3f s",
        source,
        len(steps),
        sum(s.completed for s in steps),
        len(pose),
        len(odom),
        recording.downlink_delay_s,
    )
    return recording


def _status(
    text: str, log_s: float, unanswered: deque[RecordedStep], running: deque[RecordedStep]
) -> None:
    """Give one ``command_status`` to the step it answers (module docstring)."""
    kind, _, _reason = text.partition(":")
    if kind == "accepted":
        if unanswered:
            step = unanswered.popleft()
            step.accepted_s = log_s
            running.append(step)
    elif kind == "rejected":
        if unanswered:
            step = unanswered.popleft()
            step.ended_s = log_s
            step.outcome = text
    elif kind in ("completed", "aborted"):
        if running:
            step = running.popleft()
            step.ended_s = log_s
            step.outcome = text
        elif kind == "aborted" and unanswered:
            # Purged from the queue before its acknowledgement was heard.
            step = unanswered.popleft()
            step.ended_s = log_s
            step.outcome = text
    elif kind == "fault" and running:
        running[0].faults.append(text)
