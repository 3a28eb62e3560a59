"""The ROS port: one small publish/subscribe seam over real ROS 2 (rclpy), used by the
rover-side bridge and the ground-side executor and link relay (docs/rosport.md).

Messages are the generated ROS 2 classes (:mod:`bridge.ros.rosport.msgs`, which needs ROS 2
installed). Importing this package does not: backends are imported when opened (see
:mod:`bridge.ros.rosport.registry`).
"""

from bridge.ros.rosport import qos
from bridge.ros.rosport.errors import (
    BackendUnavailableError,
    MessageError,
    PortClosedError,
    RosNameError,
    RosPortError,
    TopicTypeError,
    UnknownBackendError,
)
from bridge.ros.rosport.names import resolve_topic
from bridge.ros.rosport.port import (
    DEFAULT_LANE,
    DEFAULT_NODE_NAME,
    HISTORY_DEPTH,
    LANES,
    STOP_LANE,
    TAP_RECEIVED,
    TAP_SENT,
    PortStats,
    Publisher,
    RosPort,
    Subscription,
    Tap,
)
from bridge.ros.rosport.qos import Qos
from bridge.ros.rosport.registry import (
    BACKENDS,
    DEFAULT_BACKEND,
    backend_class,
    open_port,
    preload,
)

__all__ = [
    "BACKENDS",
    "DEFAULT_BACKEND",
    "DEFAULT_LANE",
    "DEFAULT_NODE_NAME",
    "HISTORY_DEPTH",
    "LANES",
    "STOP_LANE",
    "TAP_RECEIVED",
    "TAP_SENT",
    "BackendUnavailableError",
    "MessageError",
    "PortClosedError",
    "PortStats",
    "Publisher",
    "Qos",
    "RosNameError",
    "RosPort",
    "RosPortError",
    "Subscription",
    "Tap",
    "TopicTypeError",
    "UnknownBackendError",
    "backend_class",
    "open_port",
    "preload",
    "qos",
    "resolve_topic",
]
