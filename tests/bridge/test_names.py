"""Topic names resolve and validate as rcl/rmw do."""

from __future__ import annotations

import pytest

from bridge.ros.rosport.errors import RosNameError
from bridge.ros.rosport.names import (
    TOPIC_NAME_MAX_LENGTH,
    is_message_type,
    normalize_namespace,
    resolve_topic,
    ros_type_name,
    validate_node_name,
)


@pytest.mark.parametrize(
    ("name", "namespace", "expected"),
    [
        ("odom", "", "/odom"),
        ("odom", "/", "/odom"),
        ("odom", "/rover1", "/rover1/odom"),
        ("odom", "rover1", "/rover1/odom"),
        ("odom", "/lab/rover1", "/lab/rover1/odom"),
        ("pose/ground", "/rover1", "/rover1/pose/ground"),
        ("/odom", "/rover1", "/odom"),
        ("/wheel_instructions", "/rover1", "/wheel_instructions"),
        ("~", "/rover1", "/rover1/bridge"),
        ("~/status", "/rover1", "/rover1/bridge/status"),
        ("~/status", "/", "/bridge/status"),
        ("{node}/status", "/rover1", "/rover1/bridge/status"),
        ("{ns}/odom", "/rover1", "/rover1/odom"),
        ("{namespace}/odom", "/", "/odom"),
        ("Camera_2/image", "/", "/Camera_2/image"),
        ("_private", "/", "/_private"),
    ],
)
def test_resolution(name: str, namespace: str, expected: str) -> None:
    assert resolve_topic(name, namespace=namespace, node_name="bridge") == expected


@pytest.mark.parametrize(
    ("name", "complaint"),
    [
        ("", "must not be empty"),
        ("odom/", "must not end with '/'"),
        ("/", "must not end with '/'"),
        ("wheel instructions", r"not allowed in ROS names: \[' '\]"),
        ("wheel-instructions", r"not allowed in ROS names: \['-'\]"),
        ("odom.v2", r"not allowed in ROS names: \['.'\]"),
        ("/a//b", "contains '//'"),
        ("2odom", "the token '2odom' starts with a digit"),
        ("/rover/1odom", "the token '1odom' starts with a digit"),
        ("a~b", "'~' may only start a name"),
        ("~odom", "'~' may only start a name"),
        ("{robot}/odom", r"unknown substitution \{robot\}"),
        ("{node/odom", "unbalanced braces"),
        ("/" + "a" * TOPIC_NAME_MAX_LENGTH, "longer than 247 characters"),
        ("ödom", "not allowed in ROS names"),
    ],
)
def test_invalid_topic_names_are_refused(name: str, complaint: str) -> None:
    with pytest.raises(RosNameError, match=complaint) as info:
        resolve_topic(name, namespace="/rover1", node_name="bridge")
    assert info.value.kind == "topic"
    assert info.value.name == name
    assert isinstance(info.value, ValueError)


@pytest.mark.parametrize(
    ("namespace", "expected"),
    [("", "/"), ("/", "/"), ("rover1", "/rover1"), ("/lab/rover_1", "/lab/rover_1")],
)
def test_namespace_normalisation(namespace: str, expected: str) -> None:
    assert normalize_namespace(namespace) == expected


@pytest.mark.parametrize(
    ("namespace", "complaint"),
    [
        ("/rover1/", "must not end with '/'"),
        ("/lab//rover", "contains '//'"),
        ("/9lab", "starts with a digit"),
        ("/lab rover", "not allowed"),
        ("~", "not allowed"),
    ],
)
def test_invalid_namespaces_are_refused(namespace: str, complaint: str) -> None:
    with pytest.raises(RosNameError, match=complaint) as info:
        normalize_namespace(namespace)
    assert info.value.kind == "namespace"


@pytest.mark.parametrize(
    ("node", "complaint"),
    [
        ("", "must not be empty"),
        ("2bridge", "must not start with a digit"),
        ("rover/bridge", "may use only A-Z a-z 0-9 _"),
        ("bridge-1", "may use only"),
        ("n" * 256, "longer than 255"),
    ],
)
def test_invalid_node_names_are_refused(node: str, complaint: str) -> None:
    with pytest.raises(RosNameError, match=complaint) as info:
        validate_node_name(node)
    assert info.value.kind == "node"


def test_interface_names_of_generated_classes() -> None:
    from bridge.ros.rosport.msgs import Int16MultiArray, Odometry, Time

    assert ros_type_name(Int16MultiArray) == "std_msgs/msg/Int16MultiArray"
    assert ros_type_name(Odometry) == "nav_msgs/msg/Odometry"
    assert ros_type_name(Time) == "builtin_interfaces/msg/Time"
    assert is_message_type(Odometry)
    assert not is_message_type(Odometry())
    assert not is_message_type(dict)
