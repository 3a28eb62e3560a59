"""The ROS 2 message types the product uses: the real generated classes of ROS 2 Jazzy.

The classes are re-exported from one place so that a missing ROS 2 installation fails
here, once, with a message that says how to get it. The generated classes check each
field on assignment; :func:`checked` turns their errors into
:class:`~bridge.ros.rosport.errors.MessageError`. Also the conversions every node here
repeats (stamps, planar quaternions, interface names).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from typing import Any, Final, TypeVar

from bridge.ros.rosport.cdr import planar_yaw, stamp_parts, stamp_seconds
from bridge.ros.rosport.errors import BackendUnavailableError, MessageError
from bridge.ros.rosport.names import is_message_type, ros_type_name

try:
    from builtin_interfaces.msg import Time
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from geometry_msgs.msg import (
        Point,
        Pose,
        PoseStamped,
        PoseWithCovariance,
        Quaternion,
        Twist,
        TwistWithCovariance,
        Vector3,
    )
    from nav_msgs.msg import Odometry, Path
    from std_msgs.msg import (
        Bool,
        Empty,
        Header,
        Int16MultiArray,
        MultiArrayDimension,
        MultiArrayLayout,
        String,
    )
except ImportError as exc:  # pragma: no cover - exercised where ROS 2 is absent
    raise BackendUnavailableError(
        "the ROS 2 message packages (std_msgs, nav_msgs, diagnostic_msgs, geometry_msgs) "
        "are not installed: install this project with its 'ros' extra "
        "(pip install 'rover-hil[ros]') or source a ROS 2 Jazzy setup "
        f"(/opt/ros/jazzy/setup.bash) before starting ({exc})"
    ) from exc

__all__ = [
    "MESSAGE_TYPES",
    "Bool",
    "DiagnosticArray",
    "DiagnosticStatus",
    "Empty",
    "Header",
    "Int16MultiArray",
    "KeyValue",
    "MultiArrayDimension",
    "MultiArrayLayout",
    "Odometry",
    "Path",
    "Point",
    "Pose",
    "PoseStamped",
    "PoseWithCovariance",
    "Quaternion",
    "String",
    "Time",
    "Twist",
    "TwistWithCovariance",
    "Vector3",
    "checked",
    "is_message_type",
    "quaternion_from_yaw",
    "ros_type_name",
    "stamp",
    "stamp_s",
    "yaw_rad",
]

T = TypeVar("T")

MESSAGE_TYPES: Final[Mapping[str, type[Any]]] = {
    "builtin_interfaces/msg/Time": Time,
    "diagnostic_msgs/msg/DiagnosticArray": DiagnosticArray,
    "diagnostic_msgs/msg/DiagnosticStatus": DiagnosticStatus,
    "diagnostic_msgs/msg/KeyValue": KeyValue,
    "geometry_msgs/msg/Point": Point,
    "geometry_msgs/msg/Pose": Pose,
    "geometry_msgs/msg/PoseStamped": PoseStamped,
    "geometry_msgs/msg/PoseWithCovariance": PoseWithCovariance,
    "geometry_msgs/msg/Quaternion": Quaternion,
    "geometry_msgs/msg/Twist": Twist,
    "geometry_msgs/msg/TwistWithCovariance": TwistWithCovariance,
    "geometry_msgs/msg/Vector3": Vector3,
    "nav_msgs/msg/Odometry": Odometry,
    "nav_msgs/msg/Path": Path,
    "std_msgs/msg/Bool": Bool,
    "std_msgs/msg/Empty": Empty,
    "std_msgs/msg/Header": Header,
    "std_msgs/msg/Int16MultiArray": Int16MultiArray,
    "std_msgs/msg/MultiArrayDimension": MultiArrayDimension,
    "std_msgs/msg/MultiArrayLayout": MultiArrayLayout,
    "std_msgs/msg/String": String,
}
"""Every interface the product publishes or subscribes (or nests), by ROS type name."""


def checked(build: Callable[[], T], what: str) -> T:
    """Run ``build`` (which makes a message) and turn the generated classes' field checks
    into :class:`MessageError`.

    Raises:
        MessageError: a field value does not fit its ROS type; names ``what`` and the field.
    """
    try:
        return build()
    except (AssertionError, TypeError, ValueError, OverflowError) as exc:
        raise MessageError(f"{what}: {exc}") from exc


def stamp(t_s: float | None = None) -> Time:
    """Wall-clock seconds (default: now) as a ``builtin_interfaces/Time``."""
    sec, nanosec = stamp_parts(time.time() if t_s is None else t_s)
    return Time(sec=sec, nanosec=nanosec)


def stamp_s(t: Time) -> float:
    """A ``builtin_interfaces/Time`` as seconds."""
    return stamp_seconds(t.sec, t.nanosec)


def quaternion_from_yaw(yaw: float) -> Quaternion:
    """The rotation by ``yaw`` radians about +z."""
    return Quaternion(x=0.0, y=0.0, z=math.sin(yaw / 2.0), w=math.cos(yaw / 2.0))


def yaw_rad(q: Quaternion) -> float:
    """The rotation about +z of a planar quaternion, radians in (-pi, pi]."""
    return planar_yaw(q.x, q.y, q.z, q.w)
