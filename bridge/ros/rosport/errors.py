"""Exceptions raised by the ROS port.

All derive from :class:`bridge.errors.RosPortError` (itself a
:class:`bridge.errors.BridgeError`)::

    RosPortError
     +-- UnknownBackendError       no backend has that name (lists the known ones); also ValueError
     +-- BackendUnavailableError   the backend's dependency (rclpy) is not installed
     +-- RosNameError              a name breaks the ROS 2 naming rules; also ValueError
     +-- MessageError              a message does not fit its ROS type; also ValueError
     +-- TopicTypeError            a message of another type, or two types on one topic;
     |                             also TypeError
     +-- PortClosedError           the port (or the publisher) is closed

Backend failures that fit none of these (a DDS entity cannot be created, a config is
invalid) are raised as :class:`RosPortError` itself, chained to the backend's exception.
"""

from __future__ import annotations

from collections.abc import Iterable

from bridge.errors import RosPortError

__all__ = [
    "BackendUnavailableError",
    "MessageError",
    "PortClosedError",
    "RosNameError",
    "RosPortError",
    "TopicTypeError",
    "UnknownBackendError",
]


class UnknownBackendError(RosPortError, ValueError):
    """No ROS port backend is registered under that name.

    Attributes:
        known: the registered backend names, sorted.
    """

    def __init__(self, name: str, known: Iterable[str]) -> None:
        self.name = name
        self.known = tuple(sorted(known))
        super().__init__(
            f"unknown ROS port backend {name!r}; known backends: {', '.join(self.known)}"
        )


class BackendUnavailableError(RosPortError):
    """The backend exists but what it needs is not installed on this machine."""


class RosNameError(RosPortError, ValueError):
    """A topic name, namespace or node name is not valid under the ROS 2 naming rules.

    Attributes:
        name: the offending name as given.
        kind: ``"topic"``, ``"namespace"`` or ``"node"``.
    """

    def __init__(self, text: str, *, name: str, kind: str) -> None:
        super().__init__(text)
        self.name = name
        self.kind = kind


class MessageError(RosPortError, ValueError):
    """A message value does not fit the ROS field it is for (names the field)."""


class TopicTypeError(RosPortError, TypeError):
    """A message of the wrong type for a publisher, or two types on one topic in one port."""


class PortClosedError(RosPortError):
    """The port or publisher is closed."""
