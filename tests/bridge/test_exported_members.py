"""The public names of bridge.ros.rosport, pinned."""

from __future__ import annotations

import bridge.ros.rosport

EXPECTED = [
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
    "qos",
    "resolve_topic",
]


def test_all_is_pinned() -> None:
    # ruff (RUF022) keeps __all__ sorted; this pins its content.
    assert bridge.ros.rosport.__all__ == EXPECTED


def test_every_exported_name_exists() -> None:
    for name in bridge.ros.rosport.__all__:
        assert getattr(bridge.ros.rosport, name) is not None
