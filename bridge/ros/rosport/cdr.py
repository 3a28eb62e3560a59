"""``nav_msgs/Odometry`` as CDR bytes, packed and read in place: for a hot topic passed
serialized (:meth:`~bridge.ros.rosport.Publisher.publish_serialized`, ``subscribe(...,
serialized=True)``; docs/rosport.md, "Serialized messages"). Building the nested Python
message (a dozen objects, two covariance arrays) and converting it for rclpy cost about
34 us a message either way; packing or reading here takes about 2.

The layout is ``nav_msgs/msg/Odometry`` in plain CDR, little-endian when packed (XCDR1,
the encapsulation header ``00 01 00 00``; either byte order is read), alignment counted
from after that header: ``header.stamp`` (int32 s, uint32 ns), ``header.frame_id`` and
``child_frame_id`` (each a uint32 byte length with its NUL, the UTF-8 bytes, the NUL,
padded to 4), padding to 8, then 7 + 36 doubles of the pose with its covariance and
6 + 36 of the twist. The bytes are those ``rclpy.serialization.serialize_message``
makes of the same message but for the alignment padding: zero here, whatever happened to
be in Fast CDR's buffer there.
"""

from __future__ import annotations

import functools
import math
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from bridge.ros.rosport.errors import MessageError

__all__ = [
    "OdometryFields",
    "odometry_fields",
    "pack_odometry",
    "planar_yaw",
    "read_odometry",
    "stamp_parts",
    "stamp_seconds",
]

_ENCAPSULATION = b"\x00\x01\x00\x00"
"""CDR_LE: plain CDR, little-endian (what rmw_fastrtps_cpp writes)."""


@functools.lru_cache(maxsize=8)
def _layout(frame: str, child: str) -> tuple[struct.Struct, bytes, bytes]:
    """The struct of one Odometry with these frame names, and the names as packed."""
    names = []
    fmt = "<4siI"
    offset = 8  # the stamp, from the end of the encapsulation header
    for name in (frame, child):
        raw = name.encode()
        size = len(raw) + 1  # with the NUL ("s" pads with it)
        pad = -offset % 4
        fmt += f"{pad}xI{size}s"
        offset += pad + 4 + size
        names.append(raw)
    fmt += f"{-offset % 8}x7d36d6d36d"
    return struct.Struct(fmt), names[0], names[1]


def stamp_parts(t_s: float) -> tuple[int, int]:
    """Seconds as ``builtin_interfaces/Time``'s ``(sec, nanosec)`` (what
    :func:`bridge.ros.rosport.msgs.stamp` builds its message from)."""
    sec = math.floor(t_s)
    return sec, min(999_999_999, round((t_s - sec) * 1e9))


def stamp_seconds(sec: int, nanosec: int) -> float:
    """``builtin_interfaces/Time``'s ``(sec, nanosec)`` as seconds."""
    return float(sec) + float(nanosec) * 1e-9


def planar_yaw(x: float, y: float, z: float, w: float) -> float:
    """The rotation about +z of a planar quaternion ``(x, y, z, w)``, radians in (-pi, pi]."""
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def pack_odometry(
    stamp: tuple[int, int],
    frame: str,
    child: str,
    pose: tuple[float, float, float],
    pose_covariance: Sequence[float],
    twist: tuple[float, float] = (0.0, 0.0),
    twist_covariance: Sequence[float] = (0.0,) * 36,
) -> bytes:
    """One ``nav_msgs/Odometry`` in the plane as CDR bytes.

    Args:
        stamp: ``header.stamp`` as ``(sec, nanosec)`` (:func:`stamp_parts`).
        frame, child: ``header.frame_id`` and ``child_frame_id``.
        pose: ``(x_m, y_m, yaw_rad)``; z is 0 and the orientation the rotation by yaw
            about +z, as ``msgs.quaternion_from_yaw`` makes it.
        pose_covariance, twist_covariance: 36 values each, row-major.
        twist: ``(linear.x m/s, angular.z rad/s)``; the other components are 0.

    Raises:
        struct.error: a covariance of another length, or a stamp out of int32/uint32.
    """
    layout, f, c = _layout(frame, child)
    half = pose[2] / 2.0
    return layout.pack(
        _ENCAPSULATION, stamp[0], stamp[1], len(f) + 1, f, len(c) + 1, c,
        pose[0], pose[1], 0.0, 0.0, 0.0, math.sin(half), math.cos(half),
        *pose_covariance,
        twist[0], 0.0, 0.0, 0.0, 0.0, twist[1],
        *twist_covariance,
    )  # fmt: skip


@dataclass(frozen=True)
class OdometryFields:
    """What a reader of ``nav_msgs/Odometry`` in the plane takes of it (:func:`read_odometry`).

    Attributes:
        stamp_s: ``header.stamp`` in seconds.
        x_m, y_m: the pose's position.
        yaw_rad: the rotation about +z of its orientation, in (-pi, pi].
        v_mps, yaw_rate_rad_s: ``twist.linear.x`` and ``twist.angular.z``.
        covariance: the pose's 6x6 covariance, row-major (36 values).
    """

    stamp_s: float
    x_m: float
    y_m: float
    yaw_rad: float
    v_mps: float
    yaw_rate_rad_s: float
    covariance: tuple[float, ...]


_STAMP = {b"\x00\x01": struct.Struct("<iII"), b"\x00\x00": struct.Struct(">iII")}
_LENGTH = {b"\x00\x01": struct.Struct("<I"), b"\x00\x00": struct.Struct(">I")}
_BODY = {b"\x00\x01": struct.Struct("<7d36d6d"), b"\x00\x00": struct.Struct(">7d36d6d")}


def read_odometry(cdr: bytes) -> OdometryFields:
    """The fields of one serialized ``nav_msgs/Odometry`` (as a subscription with
    ``serialized=True`` delivers it; plain CDR of either byte order), read in place
    instead of building the nested message.

    Raises:
        MessageError: the bytes are not such a message (too short, another encoding, a
            name's length past the end).
    """
    kind = cdr[:2]
    stamp, length, body = _STAMP.get(kind), _LENGTH.get(kind), _BODY.get(kind)
    if stamp is None or length is None or body is None:
        raise MessageError(f"not plain CDR (encapsulation {cdr[:4].hex() or 'missing'})")
    try:
        sec, nanosec, n = stamp.unpack_from(cdr, 4)
        offset = 4 + 12 + n  # past the frame id, counted from the buffer's start
        offset += -(offset - 4) % 4
        (n,) = length.unpack_from(cdr, offset)
        offset += 4 + n
        offset += -(offset - 4) % 8
        v = body.unpack_from(cdr, offset)
    except struct.error as exc:
        raise MessageError(
            f"{len(cdr)} bytes are not a serialized nav_msgs/Odometry: {exc}"
        ) from exc
    return OdometryFields(
        stamp_s=stamp_seconds(sec, nanosec),
        x_m=v[0],
        y_m=v[1],
        yaw_rad=planar_yaw(v[3], v[4], v[5], v[6]),
        v_mps=v[43],
        yaw_rate_rad_s=v[48],
        covariance=v[7:43],
    )


def odometry_fields(msg: Any) -> OdometryFields:
    """:class:`OdometryFields` of an ``Odometry`` as a subscription delivers it: its bytes
    (``serialized=True``, read in place) or the message.

    Raises:
        MessageError: bytes that are not such a message.
    """
    if isinstance(msg, bytes):
        return read_odometry(msg)
    p = msg.pose.pose
    q = p.orientation
    t = msg.twist.twist
    return OdometryFields(
        stamp_s=stamp_seconds(msg.header.stamp.sec, msg.header.stamp.nanosec),
        x_m=p.position.x,
        y_m=p.position.y,
        yaw_rad=planar_yaw(q.x, q.y, q.z, q.w),
        v_mps=t.linear.x,
        yaw_rate_rad_s=t.angular.z,
        covariance=tuple(float(c) for c in msg.pose.covariance),
    )
