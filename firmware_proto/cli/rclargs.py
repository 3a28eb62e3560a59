"""The ROS 2 tail of a command line read by rclpy itself, for the programs that load rclpy
anyway (docs/ros2.md).

:mod:`firmware_proto.cli.rosargs` reads ``--ros-args`` by hand for programs that never
load rclpy. Where rclpy is there, rcl's own parser decides, as for any ROS 2 node:
:func:`rclpy_node_parameters` initialises a private rclpy context with the arguments
(a malformed one is refused with rcl's words), creates the node they name and reads the
parameter overrides rcl resolved for it.

It costs one node's start, before the program opens its own ports; the node discovers
nothing (``ROS_AUTOMATIC_DISCOVERY_RANGE=OFF`` for its context alone) and is gone before
the program's own nodes start. Call it before the program starts threads (it sets that
variable while the context starts).
"""

from __future__ import annotations

import importlib
import os
from collections.abc import Sequence
from typing import Any

__all__ = ["RclArgs", "rclpy_available", "rclpy_node_parameters"]

_NODE_DEFAULTS = {"use_sim_time": False, "start_type_description_service": True}
"""Parameters rclpy declares on every node, with defaults: left out unless set to another value."""
_RANGE_ENV = "ROS_AUTOMATIC_DISCOVERY_RANGE"


class RclArgs:
    """What rcl made of the ROS arguments for one node.

    Attributes:
        node_name: the node's name (``-r __node:=`` applied).
        namespace: its namespace (``-r __ns:=`` applied; ``/`` for the root).
        params: the parameter overrides for it, by name, typed as rcl read them.
    """

    def __init__(self, node_name: str, namespace: str, params: dict[str, Any]) -> None:
        self.node_name = node_name
        self.namespace = namespace
        self.params = params


def rclpy_available() -> bool:
    """Whether rclpy can be imported here (the ROS 2 wheels, or a sourced ROS 2)."""
    try:
        importlib.import_module("rclpy")
    except ImportError:
        return False
    return True


def rclpy_node_parameters(ros_args: Sequence[str], default_node: str) -> RclArgs:
    """rcl's reading of ``ros_args`` (without the ``--ros-args`` marker) for the node
    ``default_node`` (see the module docstring).

    Raises:
        ValueError: rcl refused the arguments (an unknown or malformed ROS argument, a
            parameters file it cannot read or parse), with rcl's message.
    """
    rclpy = importlib.import_module("rclpy")
    context_module = importlib.import_module("rclpy.context")
    context = context_module.Context()
    before = os.environ.get(_RANGE_ENV)
    os.environ[_RANGE_ENV] = "OFF"  # this node only reads its arguments: no discovery
    try:
        context.init(["rover", "--ros-args", *ros_args])
    except Exception as exc:  # rclpy raises its own RCLError kinds
        raise ValueError(f"ROS arguments refused by rcl: {_first_line(exc)}") from exc
    finally:
        if before is None:
            os.environ.pop(_RANGE_ENV, None)
        else:
            os.environ[_RANGE_ENV] = before
    try:
        try:
            node = rclpy.create_node(
                default_node,
                context=context,
                start_parameter_services=False,
                enable_rosout=False,
                automatically_declare_parameters_from_overrides=True,
            )
        except Exception as exc:
            raise ValueError(f"ROS arguments refused by rcl: {_first_line(exc)}") from exc
        try:
            given = node.get_parameters_by_prefix("")
            params = {
                name: parameter.value
                for name, parameter in given.items()
                if name not in _NODE_DEFAULTS or parameter.value != _NODE_DEFAULTS[name]
            }
            return RclArgs(node.get_name(), node.get_namespace(), params)
        finally:
            node.destroy_node()
    finally:
        context.try_shutdown()


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip() or type(exc).__name__
    return text.splitlines()[0]
