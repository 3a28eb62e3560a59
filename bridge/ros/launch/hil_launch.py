"""Launch the whole hardware-in-the-loop set on one machine (docs/ros2.md).

    ros2 launch rover_hil hil_launch.py
    ros2 launch rover_hil hil_launch.py params_file:=/path/to/my_hil.yaml
    ros2 launch rover_hil hil_launch.py with_executor:=false     # drive it yourself

Starts the controller emulator on a pty (``rover_emulator``), the rover-side bridge on
that pty (``rover_bridge``, rclpy backend), the simulation gate (``rover_gate``), the
emulated Earth-Moon link (``rover_link``) and the plan executor (``rover_executor``).
Every node reads its section of one parameters YAML (``share/rover_hil/config/hil.yaml``
by default; sections are keyed ``/**/<node name>`` so that a namespace does not hide
them). The programs that are not ROS nodes (emulator, gate, link relay) map their
section to their command-line options (firmware_proto.rosargs): ``speed_factor: 2.0``
is ``--speed-factor 2.0``.

The emulator's ``link`` and the bridge's ``device`` must name the same path; the bridge
reconnects until the emulator has created it, so start order does not matter.
"""

from __future__ import annotations

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare

PACKAGE = "rover_hil"

NODES: tuple[tuple[str, str, str | None, tuple[str, ...]], ...] = (
    ("rover_emulator", "rover_emulator", None, ()),
    ("rover_bridge", "rover_bridge", None, ("--ros-backend", "rclpy")),
    ("rover_gate", "rover_gate", "with_gate", ()),
    ("rover_link", "rover_link", "with_link", ()),
    ("rover_executor", "rover_executor", "with_executor", ()),
)
"""Node name, executable, the launch argument that switches it (None: always on), and
fixed command-line arguments."""


def generate_launch_description() -> LaunchDescription:
    """The HIL set with its launch arguments."""
    arguments = [
        DeclareLaunchArgument(
            "params_file",
            default_value=PathJoinSubstitution([FindPackageShare(PACKAGE), "config", "hil.yaml"]),
            description="parameters YAML with a /**/<node> section per node",
        ),
        DeclareLaunchArgument(
            "namespace", default_value="", description="ROS namespace of every node and topic"
        ),
        DeclareLaunchArgument(
            "log_level", default_value="info", description="ROS log level (debug, info, warn)"
        ),
        DeclareLaunchArgument(
            "with_gate", default_value="true", description="start the simulation gate"
        ),
        DeclareLaunchArgument(
            "with_link",
            default_value="true",
            description="start the link relay (emulated 3 s round trip)",
        ),
        DeclareLaunchArgument(
            "with_executor", default_value="true", description="start the plan executor"
        ),
    ]
    nodes = [
        Node(
            package=PACKAGE,
            executable=executable,
            name=name,
            namespace=LaunchConfiguration("namespace"),
            arguments=list(fixed),
            parameters=[LaunchConfiguration("params_file")],
            ros_arguments=["--log-level", LaunchConfiguration("log_level")],
            condition=IfCondition(LaunchConfiguration(switch)) if switch else None,
            output="screen",
            emulate_tty=True,
        )
        for name, executable, switch, fixed in NODES
    ]
    return LaunchDescription([*arguments, *nodes])
