"""The public names of bridge.rosport, pinned."""

from __future__ import annotations

import bridge.rosport

EXPECTED = [
    "BACKENDS",
    "DEFAULT_NODE_NAME",
    "HISTORY_DEPTH",
    "MESSAGE_TYPES",
    "BackendUnavailableError",
    "Bool",
    "DiagnosticArray",
    "DiagnosticStatus",
    "Empty",
    "Header",
    "Int16MultiArray",
    "KeyValue",
    "Message",
    "MessageError",
    "MultiArrayDimension",
    "MultiArrayLayout",
    "Odometry",
    "Point",
    "PortClosedError",
    "PortStats",
    "Pose",
    "PoseWithCovariance",
    "Publisher",
    "Quaternion",
    "RosNameError",
    "RosPort",
    "RosPortError",
    "String",
    "Subscription",
    "Time",
    "TopicTypeError",
    "Twist",
    "TwistWithCovariance",
    "UnknownBackendError",
    "Vector3",
    "backend_class",
    "dds_topic_name",
    "dds_type_name",
    "loopback_config",
    "message_type",
    "network_config",
    "open_port",
    "resolve_topic",
]


def test_all_is_pinned() -> None:
    # ruff (RUF022) keeps __all__ sorted; this pins its content.
    assert bridge.rosport.__all__ == EXPECTED


def test_every_exported_name_exists() -> None:
    for name in bridge.rosport.__all__:
        assert getattr(bridge.rosport, name) is not None
