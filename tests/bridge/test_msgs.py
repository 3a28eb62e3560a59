"""The message dataclasses match ROS 2 Jazzy field for field, and refuse bad values."""

from __future__ import annotations

import dataclasses
import math
import re
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st
from rosbags.typesys import Stores, get_typestore

from bridge.rosport import msgs
from bridge.rosport.errors import MessageError, RosPortError
from bridge.rosport.msgs import (
    MESSAGE_TYPES,
    DiagnosticStatus,
    Empty,
    Int16MultiArray,
    MultiArrayDimension,
    Odometry,
    Point,
    PoseWithCovariance,
    Quaternion,
    String,
    Time,
    message_type,
)

JAZZY = get_typestore(Stores.ROS2_JAZZY)

#: The interfaces the project uses (DESIGN.md contract 3 and what they contain).
EXPECTED_TYPES = {
    "builtin_interfaces/msg/Time",
    "std_msgs/msg/Header",
    "std_msgs/msg/String",
    "std_msgs/msg/Bool",
    "std_msgs/msg/Empty",
    "std_msgs/msg/MultiArrayDimension",
    "std_msgs/msg/MultiArrayLayout",
    "std_msgs/msg/Int16MultiArray",
    "geometry_msgs/msg/Point",
    "geometry_msgs/msg/Quaternion",
    "geometry_msgs/msg/Pose",
    "geometry_msgs/msg/PoseWithCovariance",
    "geometry_msgs/msg/Vector3",
    "geometry_msgs/msg/Twist",
    "geometry_msgs/msg/TwistWithCovariance",
    "nav_msgs/msg/Odometry",
    "diagnostic_msgs/msg/KeyValue",
    "diagnostic_msgs/msg/DiagnosticStatus",
    "diagnostic_msgs/msg/DiagnosticArray",
}


def _rosbags_spelling(desc: Any) -> str:
    """rosbags' field description in .msg spelling (``int16[]``, ``float64[36]``)."""
    kind, rest = desc
    if kind.name == "BASE":
        return str(rest[0])
    if kind.name == "NAME":
        return str(rest)
    element = _rosbags_spelling(rest[0])
    return f"{element}[{rest[1] or ''}]" if kind.name in ("ARRAY", "SEQUENCE") else "?"


def test_every_type_we_use_is_defined() -> None:
    assert set(MESSAGE_TYPES) == EXPECTED_TYPES


@pytest.mark.parametrize("ros_type", sorted(EXPECTED_TYPES))
def test_fields_match_ros2_jazzy(ros_type: str) -> None:
    cls = MESSAGE_TYPES[ros_type]
    _, jazzy_fields = JAZZY.fielddefs[ros_type]
    jazzy = [(name, _rosbags_spelling(desc)) for name, desc in jazzy_fields]
    if ros_type == "std_msgs/msg/Empty":
        # rosidl adds this member to empty structures; it is not a field of the .msg.
        assert jazzy == [("structure_needs_at_least_one_member", "uint8")]
        jazzy = []
    assert list(cls.ROS_FIELDS) == jazzy
    assert [f.name for f in dataclasses.fields(cls)] == [name for name, _ in jazzy]  # type: ignore[arg-type]


def test_diagnostic_levels_are_the_ros_constants() -> None:
    constants, _ = JAZZY.fielddefs["diagnostic_msgs/msg/DiagnosticStatus"]
    assert {name: value for name, _, value in constants} == {
        "OK": DiagnosticStatus.OK,
        "WARN": DiagnosticStatus.WARN,
        "ERROR": DiagnosticStatus.ERROR,
        "STALE": DiagnosticStatus.STALE,
    }
    assert [type_ for _, type_, _ in constants] == ["byte"] * 4


def test_defaults_are_the_ros_defaults() -> None:
    odom = Odometry()
    assert odom.pose.pose.orientation == Quaternion(0.0, 0.0, 0.0, 1.0)
    assert odom.pose.covariance == (0.0,) * 36
    assert odom.twist.covariance == (0.0,) * 36
    assert odom.header.stamp == Time(0, 0)
    assert Int16MultiArray().data == ()
    assert Empty() == Empty()


def test_values_are_normalised_and_frozen() -> None:
    msg = Int16MultiArray(data=[1, -2, 3])
    assert msg.data == (1, -2, 3)
    point = Point(1, 2, 3)
    assert (point.x, point.y, point.z) == (1.0, 2.0, 3.0)
    assert all(type(v) is float for v in (point.x, point.y, point.z))
    cov = PoseWithCovariance(covariance=list(range(36)))
    assert cov.covariance == tuple(float(i) for i in range(36))
    with pytest.raises(dataclasses.FrozenInstanceError):
        msg.data = ()  # type: ignore[misc]
    assert hash(msg) == hash(Int16MultiArray(data=(1, -2, 3)))


@pytest.mark.parametrize(
    ("make", "complaint"),
    [
        (lambda: Int16MultiArray(data=[40000]), "Int16MultiArray.data[0]: 40000 is out of range"),
        (lambda: Int16MultiArray(data=[1.5]), "Int16MultiArray.data[0]: expected int16"),  # type: ignore[list-item]
        (lambda: Int16MultiArray(data="123"), "expected a sequence of int16"),  # type: ignore[arg-type]
        (lambda: Int16MultiArray(data=[True]), "got a bool"),
        (lambda: PoseWithCovariance(covariance=(0.0,) * 35), "expected exactly 36 values"),
        (lambda: String("a\x00b"), "String.data: a ROS string cannot contain NUL"),
        (lambda: String(b"bytes"), "String.data: expected str"),  # type: ignore[arg-type]
        (lambda: Point("1", 0, 0), "Point.x: expected float64, got str"),  # type: ignore[arg-type]
        (lambda: DiagnosticStatus(level=-1), "DiagnosticStatus.level: -1 is out of range for byte"),
        (lambda: Time(sec=2**31), "Time.sec"),
        (lambda: Time(nanosec=-1), "Time.nanosec"),
        (lambda: MultiArrayDimension(size=2**32), "MultiArrayDimension.size"),
        (lambda: Odometry(header=Time()), "Odometry.header: expected Header, got Time"),  # type: ignore[arg-type]
    ],
)
def test_bad_values_are_refused_naming_the_field(make: Any, complaint: str) -> None:
    with pytest.raises(MessageError, match=re.escape(complaint)):
        make()


def test_message_error_is_a_value_error_and_a_port_error() -> None:
    with pytest.raises(ValueError, match=r"Bool\.data"):
        msgs.Bool(1)  # type: ignore[arg-type]
    assert issubclass(MessageError, RosPortError)


def test_message_type_lookup() -> None:
    assert message_type("std_msgs/msg/String") is String
    with pytest.raises(KeyError, match="no message type 'std_msgs/msg/Nope'"):
        message_type("std_msgs/msg/Nope")


@given(st.integers(min_value=-(2**31) * 10**9, max_value=(2**31 - 1) * 10**9))
def test_time_from_ns_round_trips(ns: int) -> None:
    stamp = Time.from_ns(ns)
    assert 0 <= stamp.nanosec < 10**9
    assert stamp.to_ns() == ns


@given(st.floats(min_value=-math.pi + 1e-9, max_value=math.pi))
def test_quaternion_from_yaw_round_trips(yaw: float) -> None:
    q = Quaternion.from_yaw(yaw)
    assert math.isclose(q.x**2 + q.y**2 + q.z**2 + q.w**2, 1.0)
    assert math.isclose(q.yaw_rad(), yaw, abs_tol=1e-9)


@pytest.mark.parametrize("bad", ["int16[<=3]", "int16[0]", "int16[x]"])
def test_parse_field_type_refuses_unsupported_shapes(bad: str) -> None:
    with pytest.raises(ValueError, match="unsupported ROS field type"):
        msgs.parse_field_type(bad)
