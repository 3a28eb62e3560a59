"""Backends of the ROS port by name (``rclpy``, ``rclpy-process``, ``inprocess``;
docs/rosport.md, "Backends"), imported only when opened. :data:`DEFAULT_BACKEND` is
what every entry point uses unless told otherwise.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping
from typing import Any, Final

from bridge.ros.rosport.errors import BackendUnavailableError, UnknownBackendError
from bridge.ros.rosport.port import DEFAULT_NODE_NAME, RosPort

__all__ = ["BACKENDS", "DEFAULT_BACKEND", "backend_class", "open_port", "preload"]

#: Backend name -> (module, class). Modules are imported on first use only.
BACKENDS: Final[Mapping[str, tuple[str, str]]] = {
    "inprocess": ("bridge.ros.rosport.inprocess", "InProcessPort"),
    "rclpy": ("bridge.ros.rosport.rclpy_backend", "RclpyPort"),
    "rclpy-process": ("bridge.ros.rosport.process_backend", "ProcessPort"),
}
#: The production backend: a real ROS 2 node.
DEFAULT_BACKEND: Final = "rclpy"
#: What each backend imports only once it opens (inside its methods): :func:`preload`.
_OPENED_MODULES: Final[Mapping[str, tuple[str, ...]]] = {
    "inprocess": (),
    "rclpy": (
        "rclpy",
        "rclpy.context",
        "rclpy.exceptions",
        "rclpy.executors",
        "rclpy.node",
        "rclpy.parameter",
        "rclpy.qos",
        "rclpy.serialization",
        "rclpy.signals",
        "rcl_interfaces.msg",
    ),
    "rclpy-process": ("rclpy.serialization", "rclpy.parameter", "rcl_interfaces.msg"),
}


def backend_class(backend: str) -> type[RosPort]:
    """The port class registered as ``backend``, importing its module.

    Raises:
        UnknownBackendError: no backend has that name (the error lists the known ones).
        BackendUnavailableError: the backend's module cannot be imported here (ROS 2 is
            not installed).
    """
    try:
        module_name, class_name = BACKENDS[backend]
    except KeyError:
        raise UnknownBackendError(backend, BACKENDS) from None
    try:
        module = importlib.import_module(module_name)
    except BackendUnavailableError:
        raise
    except ImportError as exc:
        raise BackendUnavailableError(
            f"the {backend!r} ROS port backend cannot be imported: {exc}"
        ) from exc
    cls: type[RosPort] = getattr(module, class_name)
    return cls


def open_port(
    backend: str, *, namespace: str = "", node_name: str = DEFAULT_NODE_NAME, **options: Any
) -> RosPort:
    """Open a ROS port on the named backend.

    Args:
        backend: ``"rclpy"``, ``"rclpy-process"`` or ``"inprocess"`` (see :data:`BACKENDS`).
        namespace, node_name: see :class:`~bridge.ros.rosport.port.RosPort`.
        **options: backend options: ``rclpy`` and ``rclpy-process``: ``domain_id``,
            ``args``; ``inprocess``: ``bus``.

    Raises:
        UnknownBackendError: unknown ``backend`` (the message lists the known ones).
        BackendUnavailableError: the backend's dependency is not installed.
        RosNameError: invalid namespace or node name.
        TypeError: an option the backend does not take.
        RosPortError: the backend failed to start.
    """
    return backend_class(backend)(namespace=namespace, node_name=node_name, **options)


def preload(backend: str) -> type[RosPort]:
    """:func:`backend_class`, and the modules the backend imports only once it opens
    (rclpy and its messages: 100-300 ms of CPU): a real-time program calls it before it
    takes real time, so that these imports do not hold a core from everything else
    (docs/realtime.md).

    Raises:
        UnknownBackendError, BackendUnavailableError: as :func:`backend_class`.
    """
    cls = backend_class(backend)
    for name in _OPENED_MODULES.get(backend, ()):
        try:
            importlib.import_module(name)
        except ImportError as exc:
            raise BackendUnavailableError(
                f"the {backend!r} ROS port backend cannot import {name}: {exc}"
            ) from exc
    return cls
