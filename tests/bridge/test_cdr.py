"""bridge/ros/rosport/cdr.py and bridge/ros/odommsg.py's packed messages: odometry
packed into CDR and read from it in place, against rclpy's own serialization of the
messages bridge/ros/odommsg.py builds."""

from __future__ import annotations

import math
import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st

from bridge.link.odometry import GroundPose, OdometryEstimate
from bridge.ros.odommsg import (
    ground_odometry,
    ground_odometry_cdr,
    wheel_odometry,
    wheel_odometry_cdr,
)
from bridge.ros.rosport import MessageError
from bridge.ros.rosport.cdr import odometry_fields, read_odometry, stamp_parts
from bridge.ros.rosport.msgs import Odometry, stamp, stamp_s, yaw_rad
from tests.bridge.samples import sample

serialization = pytest.importorskip("rclpy.serialization")

finite = st.floats(allow_nan=False, allow_infinity=False, min_value=-1e9, max_value=1e9)
positive = st.floats(min_value=0.0, max_value=1e3)
frames = st.text(st.characters(exclude_categories=["Cs"], exclude_characters="\0"), max_size=12)
times = st.floats(min_value=0.0, max_value=2.0e9)


@st.composite
def estimates(draw: st.DrawFn) -> OdometryEstimate:
    return OdometryEstimate(
        x_m=draw(finite),
        y_m=draw(finite),
        yaw_rad=draw(st.floats(min_value=-4.0, max_value=4.0)),
        v_mps=draw(finite),
        yaw_rate_rad_s=draw(finite),
        distance_m=draw(positive),
        var_xy_m2=draw(positive),
        var_yaw_rad2=draw(positive),
        heading_source="imu",
    )


@given(estimates(), times, frames, frames)
def test_packed_wheel_odometry_reads_back_as_the_built_message(
    est: OdometryEstimate, t_s: float, frame: str, child: str
) -> None:
    cdr = wheel_odometry_cdr(est, stamp_parts(t_s), frame, child)
    built = wheel_odometry(est, stamp(t_s), frame, child)
    assert serialization.deserialize_message(cdr, Odometry) == built
    assert len(cdr) == len(serialization.serialize_message(built))


@given(
    st.builds(GroundPose, finite, finite, finite, st.one_of(st.just(0.0), positive), positive),
    times,
    frames,
    frames,
)
def test_packed_ground_odometry_reads_back_as_the_built_message(
    pose: GroundPose, t_s: float, frame: str, child: str
) -> None:
    cdr = ground_odometry_cdr(pose, stamp_parts(t_s), frame, child)
    assert serialization.deserialize_message(cdr, Odometry) == ground_odometry(
        pose, stamp(t_s), frame, child
    )


@given(times)
def test_stamp_parts_round_as_the_message_stamp_does(t_s: float) -> None:
    when = stamp(t_s)
    assert stamp_parts(t_s) == (when.sec, when.nanosec)


def _same(a: object, b: object) -> bool:
    """Equal, NaN equal to NaN (the samples draw NaN and infinities too)."""
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return a == b


@pytest.mark.parametrize("seed", range(30))
def test_reading_in_place_gives_the_fields_of_any_odometry(seed: int) -> None:
    msg = sample(Odometry, seed)  # every field drawn, frame names of any length
    fields = read_odometry(serialization.serialize_message(msg))
    from_message = odometry_fields(msg)  # what a subscription of messages takes the same way
    pose = msg.pose.pose
    expected = [
        stamp_s(msg.header.stamp),
        pose.position.x,
        pose.position.y,
        yaw_rad(pose.orientation),
        msg.twist.twist.linear.x,
        msg.twist.twist.angular.z,
        *msg.pose.covariance,
    ]
    got = [
        fields.stamp_s,
        fields.x_m,
        fields.y_m,
        fields.yaw_rad,
        fields.v_mps,
        fields.yaw_rate_rad_s,
        *fields.covariance,
    ]
    assert len(got) == len(expected) == 42
    assert all(_same(a, float(b)) for a, b in zip(got, expected, strict=True)), (got, expected)
    again = [
        from_message.stamp_s,
        from_message.x_m,
        from_message.y_m,
        from_message.yaw_rad,
        from_message.v_mps,
        from_message.yaw_rate_rad_s,
        *from_message.covariance,
    ]
    assert all(_same(a, b) for a, b in zip(again, got, strict=True)), (again, got)


def test_big_endian_cdr_is_read_too() -> None:
    frame, child = b"map\0", b"base_link\0"
    body = [float(i) for i in range(7 + 36 + 6 + 36)]
    # Past the encapsulation header: stamp 8, a length and "map" 8 (aligned to 4 as it
    # is), a length and "base_link" 14: 30 bytes, then 2 of padding to align the doubles.
    cdr = (
        b"\x00\x00\x00\x00"
        + struct.pack(">iII4sI10s", 12, 500_000_000, len(frame), frame, len(child), child)
        + b"\0" * 2
        + struct.pack(">85d", *body)
    )
    fields = read_odometry(cdr)
    assert fields.stamp_s == 12.5 and (fields.x_m, fields.y_m) == (0.0, 1.0)
    assert (fields.v_mps, fields.yaw_rate_rad_s) == (43.0, 48.0)
    assert fields.covariance == tuple(body[7:43])


def test_bytes_that_are_no_odometry_are_a_message_error() -> None:
    good = serialization.serialize_message(sample(Odometry, 1))
    for cut in range(len(good) - 288):  # short of the pose's covariance, at every length
        with pytest.raises(MessageError):
            read_odometry(good[:cut])
    with pytest.raises(MessageError, match="not plain CDR"):
        read_odometry(b"\x00\x07\x00\x00" + good[4:])  # XCDR2's parameter list
    huge = good[:12] + struct.pack("<I", 1 << 30) + good[16:]  # a frame id past the end
    with pytest.raises(MessageError):
        read_odometry(huge)
