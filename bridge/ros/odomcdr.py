"""The bridge's two odometry messages packed straight into CDR bytes, for
:meth:`bridge.ros.rosport.Publisher.publish_serialized`: what rclpy reads from them is
exactly the message :func:`bridge.ros.odommsg.wheel_odometry` or
:func:`bridge.ros.odommsg.ground_odometry` builds (the tests check every field). The bytes
are those ``rclpy.serialization.serialize_message`` makes of that message but for the
alignment padding, zero here, whatever happened to be in Fast CDR's buffer there.

``/odom`` goes out with every encoder sample (50 Hz at 1x, 200 Hz in a stack at
``--speed 4``): building its nested Python message (a dozen objects, two covariance
arrays) and converting that for rclpy took about half of the bridge's CPU on an idle
stack. Packed here it is one ``struct`` call (docs/rosport.md, "Serialized messages").

The layout is ``nav_msgs/msg/Odometry`` in plain CDR, little-endian (XCDR1, the
encapsulation header ``00 01 00 00``), alignment counted from after that header:
``header.stamp`` (int32 s, uint32 ns), ``header.frame_id`` and ``child_frame_id``
(each a uint32 byte length with its NUL, the UTF-8 bytes, the NUL, padded to 4), padding
to 8, then 7 + 36 doubles of the pose with its covariance and 6 + 36 of the twist.
"""

from __future__ import annotations

import functools
import math
import struct
from dataclasses import dataclass

from bridge.link.odometry import GroundPose, OdometryEstimate
from bridge.ros.rosport.errors import MessageError

__all__ = [
    "OdometryFields",
    "ground_odometry_cdr",
    "read_odometry",
    "stamp_parts",
    "wheel_odometry_cdr",
]

_ENCAPSULATION = b"\x00\x01\x00\x00"
"""CDR_LE: plain CDR, little-endian (what rmw_fastrtps_cpp writes)."""
_UNOBSERVED = 1e6
"""Variance of z, roll and pitch: not observed in the plane (as bridge.ros.odommsg)."""
_TWIST_VARIANCE = 1e-4
"""The wheel odometry's fixed twist variance (as bridge.ros.odommsg)."""


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
    """Seconds as ``builtin_interfaces/Time``'s ``(sec, nanosec)``, rounded as
    :func:`bridge.ros.rosport.msgs.stamp` rounds them."""
    sec = math.floor(t_s)
    return sec, min(999_999_999, round((t_s - sec) * 1e9))


def _pose_covariance(var_xy: float, var_yaw: float) -> tuple[float, ...]:
    return (
        var_xy, 0.0, 0.0, 0.0, 0.0, 0.0,
        0.0, var_xy, 0.0, 0.0, 0.0, 0.0,
        0.0, 0.0, _UNOBSERVED, 0.0, 0.0, 0.0,
        0.0, 0.0, 0.0, _UNOBSERVED, 0.0, 0.0,
        0.0, 0.0, 0.0, 0.0, _UNOBSERVED, 0.0,
        0.0, 0.0, 0.0, 0.0, 0.0, var_yaw,
    )  # fmt: skip


_TWIST_COVARIANCE = _pose_covariance(_TWIST_VARIANCE, _TWIST_VARIANCE)
_NO_TWIST = (0.0,) * 42  # a fix carries no twist: zeros and a zero covariance


def wheel_odometry_cdr(
    est: OdometryEstimate, stamp: tuple[int, int], frame: str, child: str
) -> bytes:
    """``/odom`` for one estimate, stamped ``stamp`` (:func:`stamp_parts`) in ``frame``:
    ``wheel_odometry(est, stamp, frame, child)`` serialized."""
    layout, f, c = _layout(frame, child)
    half = est.yaw_rad / 2.0
    return layout.pack(
        _ENCAPSULATION, stamp[0], stamp[1], len(f) + 1, f, len(c) + 1, c,
        est.x_m, est.y_m, 0.0, 0.0, 0.0, math.sin(half), math.cos(half),
        *_pose_covariance(est.var_xy_m2, est.var_yaw_rad2),
        est.v_mps, 0.0, 0.0, 0.0, 0.0, est.yaw_rate_rad_s,
        *_TWIST_COVARIANCE,
    )  # fmt: skip


def ground_odometry_cdr(pose: GroundPose, stamp: tuple[int, int], frame: str, child: str) -> bytes:
    """``/odom_ground`` for one POSE fix, stamped ``stamp`` (the fix's own time) in
    ``frame``: ``ground_odometry(pose, stamp, frame, child)`` serialized."""
    layout, f, c = _layout(frame, child)
    var = pose.sigma_m**2
    half = pose.yaw_rad / 2.0
    return layout.pack(
        _ENCAPSULATION, stamp[0], stamp[1], len(f) + 1, f, len(c) + 1, c,
        pose.x_m, pose.y_m, 0.0, 0.0, 0.0, math.sin(half), math.cos(half),
        *_pose_covariance(var, (var / 0.25) if var else 1e-4),
        *_NO_TWIST,
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
    qx, qy, qz, qw = v[3:7]
    return OdometryFields(
        stamp_s=float(sec) + float(nanosec) * 1e-9,
        x_m=v[0],
        y_m=v[1],
        yaw_rad=math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz)),
        v_mps=v[43],
        yaw_rate_rad_s=v[48],
        covariance=v[7:43],
    )
