"""The bridge's two odometry messages, built in one place: ``/odom`` (wheel odometry in
the odom frame) and ``/odom_ground`` (the POSE sensor's fix in the map frame).

The bridge node publishes them, and the calibration's lockstep runs (sim/) record the
very same messages, so a twin calibrated from either sees one convention: covariances in
m^2 and rad^2, z, roll and pitch unobserved (1e6), the twist's covariance fixed at 1e-4,
a fix's yaw variance its position variance over 0.25 m^2 (docs/bridge.md, "Topics").
"""

from __future__ import annotations

from typing import Any

import numpy

from bridge.link.odometry import GroundPose, OdometryEstimate
from bridge.ros.rosport.cdr import pack_odometry
from bridge.ros.rosport.msgs import (
    Header,
    Odometry,
    Point,
    Pose,
    PoseWithCovariance,
    Twist,
    TwistWithCovariance,
    Vector3,
    quaternion_from_yaw,
)

__all__ = ["ground_odometry", "ground_odometry_cdr", "wheel_odometry", "wheel_odometry_cdr"]


def _covariance_values(var_xy: float, var_yaw: float) -> tuple[float, ...]:
    """A pose's 6x6 covariance, row-major: x and y ``var_xy``, yaw ``var_yaw``; z, roll and
    pitch 1e6, not observed in the plane."""
    return (
        var_xy, 0.0, 0.0, 0.0, 0.0, 0.0,
        0.0, var_xy, 0.0, 0.0, 0.0, 0.0,
        0.0, 0.0, 1e6, 0.0, 0.0, 0.0,
        0.0, 0.0, 0.0, 1e6, 0.0, 0.0,
        0.0, 0.0, 0.0, 0.0, 1e6, 0.0,
        0.0, 0.0, 0.0, 0.0, 0.0, var_yaw,
    )  # fmt: skip


def _covariance(var_xy: float, var_yaw: float) -> numpy.ndarray[Any, Any]:
    # A float64 array of 36: the generated setter takes it as it is (a list is checked
    # value by value).
    return numpy.array(_covariance_values(var_xy, var_yaw))


def wheel_odometry(est: OdometryEstimate, when: Any, frame: str, child: str) -> Odometry:
    """``/odom`` for one estimate, stamped ``when`` (a ROS time) in ``frame``."""
    return Odometry(
        header=Header(stamp=when, frame_id=frame),
        child_frame_id=child,
        pose=PoseWithCovariance(
            pose=Pose(
                position=Point(x=est.x_m, y=est.y_m, z=0.0),
                orientation=quaternion_from_yaw(est.yaw_rad),
            ),
            covariance=_covariance(est.var_xy_m2, est.var_yaw_rad2),
        ),
        twist=TwistWithCovariance(
            twist=Twist(linear=Vector3(x=est.v_mps), angular=Vector3(z=est.yaw_rate_rad_s)),
            covariance=_covariance(1e-4, 1e-4),
        ),
    )


def ground_odometry(pose: GroundPose, when: Any, frame: str, child: str) -> Odometry:
    """``/odom_ground`` for one POSE fix, stamped ``when`` (the fix's own time) in ``frame``."""
    var = pose.sigma_m**2
    return Odometry(
        header=Header(stamp=when, frame_id=frame),
        child_frame_id=child,
        pose=PoseWithCovariance(
            pose=Pose(
                position=Point(x=pose.x_m, y=pose.y_m, z=0.0),
                orientation=quaternion_from_yaw(pose.yaw_rad),
            ),
            covariance=_covariance(var, (var / 0.25) if var else 1e-4),
        ),
    )


# The same two messages packed straight into CDR bytes (bridge/ros/rosport/cdr.py), as the
# bridge publishes them (Publisher.publish_serialized): /odom goes out with every encoder
# sample (200 a second in a stack at --speed 4), and building the message above and
# converting it for rclpy took most of the bridge's CPU on an idle stack. What rclpy
# reads from these bytes is exactly the message the functions above build (tested).


_TWIST_COVARIANCE = _covariance_values(1e-4, 1e-4)


def wheel_odometry_cdr(
    est: OdometryEstimate, stamp: tuple[int, int], frame: str, child: str
) -> bytes:
    """:func:`wheel_odometry` serialized, stamped ``stamp`` (``cdr.stamp_parts``)."""
    return pack_odometry(
        stamp,
        frame,
        child,
        (est.x_m, est.y_m, est.yaw_rad),
        _covariance_values(est.var_xy_m2, est.var_yaw_rad2),
        (est.v_mps, est.yaw_rate_rad_s),
        _TWIST_COVARIANCE,
    )


def ground_odometry_cdr(pose: GroundPose, stamp: tuple[int, int], frame: str, child: str) -> bytes:
    """:func:`ground_odometry` serialized, stamped ``stamp`` (the fix's own time)."""
    var = pose.sigma_m**2
    return pack_odometry(
        stamp,
        frame,
        child,
        (pose.x_m, pose.y_m, pose.yaw_rad),
        _covariance_values(var, (var / 0.25) if var else 1e-4),
    )
