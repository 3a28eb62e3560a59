"""Launch the rover-side bridge alone, on the real rover (docs/ros2.md).

    ros2 launch rover_hil bridge_launch.py                          # USB-serial
    ros2 launch rover_hil bridge_launch.py can_interface:=socketcan can_channel:=rovercan0

The link to the controller comes from the launch arguments below (``device`` and
``baud``, or ``can_interface``, ``can_channel`` and ``node_id``); everything else (topic
names, frames, heartbeat and diagnostics rates, reconnect timing) from ``params_file``,
``share/rover_hil/config/bridge.yaml`` by default, under ``rover_bridge:
ros__parameters:``. The bridge runs on the rclpy backend.
"""

from __future__ import annotations

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue
from launch_ros.substitutions import FindPackageShare

PACKAGE = "rover_hil"

LINK_ARGUMENTS: tuple[tuple[str, str, type, str], ...] = (
    (
        "device",
        "/dev/rover-motor",
        str,
        "serial device of the motor controller (udev/ names it /dev/rover-motor); "
        "used when can_interface is empty",
    ),
    ("baud", "115200", int, "serial baud rate"),
    (
        "can_interface",
        "",
        str,
        "python-can interface for a CAN link (socketcan); empty: use the serial device",
    ),
    (
        "can_channel",
        "rovercan0",
        str,
        "CAN channel (udev/ and udev/80-rovercan0.network name it rovercan0)",
    ),
    ("node_id", "1", int, "CAN node id of the motor controller, 1..15"),
    (
        "record",
        "",
        str,
        "traffic log file of the link (docs/traffic-logs.md); empty: no log",
    ),
)
"""Launch arguments that become bridge parameters: name, default, type, description."""


def generate_launch_description() -> LaunchDescription:
    """The bridge node with its launch arguments."""
    arguments = [
        DeclareLaunchArgument(name, default_value=default, description=text)
        for name, default, _kind, text in LINK_ARGUMENTS
    ]
    arguments += [
        DeclareLaunchArgument(
            "params_file",
            default_value=PathJoinSubstitution(
                [FindPackageShare(PACKAGE), "config", "bridge.yaml"]
            ),
            description="ROS parameters file with a rover_bridge section (topics, rates, ...)",
        ),
        DeclareLaunchArgument(
            "namespace", default_value="", description="ROS namespace of the bridge and its topics"
        ),
        DeclareLaunchArgument(
            "log_level", default_value="info", description="ROS log level (debug, info, warn)"
        ),
    ]
    link_parameters = {
        name: ParameterValue(LaunchConfiguration(name), value_type=kind)
        for name, _default, kind, _text in LINK_ARGUMENTS
    }
    bridge = Node(
        package=PACKAGE,
        executable="rover_bridge",
        name="rover_bridge",
        namespace=LaunchConfiguration("namespace"),
        arguments=["--ros-backend", "rclpy-process"],
        parameters=[LaunchConfiguration("params_file"), link_parameters],
        ros_arguments=["--log-level", LaunchConfiguration("log_level")],
        output="screen",
        emulate_tty=True,
    )
    return LaunchDescription([*arguments, bridge])
