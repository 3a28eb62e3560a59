"""The ROS 2 tail of a program's command line, read: the I/O edge of
:mod:`firmware_proto.cli.rosargs` for the programs that ``ros2 run`` starts but that are
not ROS nodes themselves (docs/ros2.md).
"""

from __future__ import annotations

import argparse
import importlib
from collections.abc import Sequence
from typing import Any

from firmware_proto.cli.rclargs import rclpy_available, rclpy_node_parameters
from firmware_proto.cli.rosargs import argv_from_ros_args, parameters_to_argv, split_ros_args

__all__ = ["load_parameters_file", "parse_args_with_ros_args"]


def load_parameters_file(path: str) -> Any:
    """A ROS parameters file (YAML; PyYAML comes with every ROS 2 installation).

    Raises:
        ValueError: PyYAML is missing.
        OSError: the file cannot be read.
    """
    try:
        yaml = importlib.import_module("yaml")
    except ImportError as exc:
        raise ValueError(
            f"reading --params-file {path} needs PyYAML (python3-yaml), which ROS 2 installs"
        ) from exc
    with open(path, encoding="utf-8") as f:
        return yaml.safe_load(f)


def parse_args_with_ros_args(
    parser: argparse.ArgumentParser,
    argv: Sequence[str],
    node_name: str,
    *,
    with_rclpy: bool = False,
) -> argparse.Namespace:
    """Parse a command line that may end in ``--ros-args``: the node's parameters become long
    options placed before the program's own, which therefore win. A bad ROS argument or an
    unreadable file is a usage error (``parser.error``: exit status 2). ``with_rclpy``: where
    rclpy is installed, rcl's own parser reads the arguments (:mod:`~.rclargs`)."""
    own, ros_args = split_ros_args(argv)
    try:
        if not ros_args:
            from_ros: list[str] = []
        elif with_rclpy and rclpy_available():
            from_ros = parameters_to_argv(rclpy_node_parameters(ros_args, node_name).params)
        else:
            from_ros = argv_from_ros_args(ros_args, node_name, load_parameters_file)
    except (OSError, ValueError) as exc:
        parser.error(str(exc))
    return parser.parse_args(from_ros + own)
