"""The ROS port: one small publish/subscribe interface with rclpy, Cyclone DDS and
in-process backends, used by the rover-side bridge and the ground-side executor.

    from bridge.rosport import Int16MultiArray, String, open_port

    with open_port("dds", namespace="rover1", node_name="executor") as port:
        port.subscribe("command_status", String, on_status)
        steps = port.publisher("wheel_instructions", Int16MultiArray)
        steps.publish(Int16MultiArray(data=(1, 30, 23000)))

Backends are imported when opened (see :mod:`bridge.rosport.registry`). See docs/rosport.md.
"""

from bridge.rosport.ddsconfig import loopback_config, network_config
from bridge.rosport.errors import (
    BackendUnavailableError,
    MessageError,
    PortClosedError,
    RosNameError,
    RosPortError,
    TopicTypeError,
    UnknownBackendError,
)
from bridge.rosport.msgs import (
    MESSAGE_TYPES,
    Bool,
    DiagnosticArray,
    DiagnosticStatus,
    Empty,
    Header,
    Int16MultiArray,
    KeyValue,
    Message,
    MultiArrayDimension,
    MultiArrayLayout,
    Odometry,
    Point,
    Pose,
    PoseWithCovariance,
    Quaternion,
    String,
    Time,
    Twist,
    TwistWithCovariance,
    Vector3,
    message_type,
)
from bridge.rosport.names import dds_topic_name, dds_type_name, resolve_topic
from bridge.rosport.port import (
    DEFAULT_NODE_NAME,
    HISTORY_DEPTH,
    PortStats,
    Publisher,
    RosPort,
    Subscription,
)
from bridge.rosport.registry import BACKENDS, backend_class, open_port

__all__ = [
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
