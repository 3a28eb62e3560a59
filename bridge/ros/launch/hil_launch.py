"""Launch the whole hardware-in-the-loop set on one machine (docs/ros2.md, "The HIL set").

    ros2 launch rover_hil hil_launch.py                          # rover side, gate, link
    ros2 launch rover_hil hil_launch.py goal:=2.0,3.0,90         # ... and run a mission

Starts ``rover_emulator`` on a pty, ``rover_bridge`` on that pty, ``rover_onboard``,
``rover_gate``, ``rover_link`` and, given a ``goal``, ``rover_executor``; the onboard
program and the executor take ``$ROVER_UPLINK_TOKEN`` from the environment.

Every node reads its section of one parameters YAML
(``share/rover_hil/config/hil.yaml`` by default; sections keyed ``/**/<node name>``).
The nodes that are not ROS nodes map their section to their command-line options
(firmware_proto.cli.rosargs). The launch arguments (``rtt``, the namespaces, ``goal``)
win over the file. The emulator's ``link`` and the bridge's ``device`` must name the
same path.
"""

from __future__ import annotations

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution, PythonExpression
from launch_ros.actions import Node
from launch_ros.substitutions import FindPackageShare

PACKAGE = "rover_hil"

NODES: tuple[str, ...] = (
    "rover_emulator",
    "rover_bridge",
    "rover_onboard",
    "rover_gate",
    "rover_link",
    "rover_executor",
)
"""The executables this file starts; each node is named after its executable."""


def _node(executable: str, **kwargs: object) -> Node:
    return Node(
        package=PACKAGE,
        executable=executable,
        name=executable,
        ros_arguments=["--log-level", LaunchConfiguration("log_level")],
        output="screen",
        emulate_tty=True,
        **kwargs,
    )


def generate_launch_description() -> LaunchDescription:
    """The HIL set with its launch arguments."""
    params = LaunchConfiguration("params_file")
    rover_ns = LaunchConfiguration("namespace")
    ground_ns = LaunchConfiguration("ground_namespace")
    rtt = LaunchConfiguration("rtt")
    goal = LaunchConfiguration("goal")
    arguments = [
        DeclareLaunchArgument(
            "params_file",
            default_value=PathJoinSubstitution([FindPackageShare(PACKAGE), "config", "hil.yaml"]),
            description="parameters YAML with the sections of rover_emulator, rover_bridge, "
            "rover_gate",
        ),
        DeclareLaunchArgument(
            "namespace", default_value="", description="ROS namespace of the rover's topics"
        ),
        DeclareLaunchArgument(
            "ground_namespace",
            default_value="ground",
            description="ROS namespace of the operator's topics (the far end of the link)",
        ),
        DeclareLaunchArgument(
            "rtt", default_value="3.0", description="round trip of the emulated link, s"
        ),
        DeclareLaunchArgument(
            "goal",
            default_value="",
            description="X,Y,YAW (m, m, deg): run one mission to this goal; empty: no executor",
        ),
        DeclareLaunchArgument(
            "with_gate", default_value="true", description="start the simulation gate"
        ),
        DeclareLaunchArgument(
            "with_link", default_value="true", description="start the link relay"
        ),
        DeclareLaunchArgument(
            "log_level", default_value="info", description="ROS log level (debug, info, warn)"
        ),
    ]
    nodes = [
        _node("rover_emulator", parameters=[params]),
        _node(
            "rover_bridge",
            namespace=rover_ns,
            arguments=["--ros-backend", "rclpy-process"],
            parameters=[params],
        ),
        _node(
            "rover_onboard",
            parameters=[params],
            arguments=["--ros-backend", "rclpy", "--namespace", rover_ns],
        ),
        _node(
            "rover_gate",
            parameters=[params],
            condition=IfCondition(LaunchConfiguration("with_gate")),
        ),
        _node(
            "rover_link",
            parameters=[params],
            arguments=[
                "--ros-backend",
                "rclpy",
                "--rtt",
                rtt,
                "--ground-namespace",
                ground_ns,
                "--rover-namespace",
                rover_ns,
            ],
            condition=IfCondition(LaunchConfiguration("with_link")),
        ),
        _node(
            "rover_executor",
            parameters=[params],
            arguments=[
                "--ros-backend",
                "rclpy",
                "--goal",
                goal,
                "--namespace",
                ground_ns,
                "--rtt",
                rtt,
            ],
            condition=IfCondition(PythonExpression(["'", goal, "' != ''"])),
        ),
    ]
    return LaunchDescription([*arguments, *nodes])
