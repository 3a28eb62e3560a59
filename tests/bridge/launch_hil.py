"""Launch test of the HIL set: the emulator and the bridge from launch/hil_launch.py, and
one step driven through ROS 2 until ``completed``.

Run by the ``ros2`` job of .github/workflows/ci.yml, in a Jazzy workspace where rover_hil
is built and sourced::

    launch_test tests/bridge/launch_hil.py

pytest does not collect this file (its name matches neither ``test_*.py`` nor
``*_test.py``): it needs ROS 2, which this machine lacks. tests/bridge/test_ros_package.py
checks that it compiles and that the executables it starts are declared.
"""

from __future__ import annotations

import os
import secrets
import time
import unittest
from typing import Any

import launch
import launch_testing.actions
import launch_testing.asserts
import rclpy
from launch.actions import IncludeLaunchDescription
from launch.launch_description_sources import PythonLaunchDescriptionSource
from launch.substitutions import PathJoinSubstitution
from launch_ros.substitutions import FindPackageShare
from std_msgs.msg import Int16MultiArray, String

LAUNCH_FILE = ("rover_hil", "launch", "hil_launch.py")
LAUNCH_ARGUMENTS = {"with_gate": "false", "with_link": "false"}
"""The emulator, the bridge and the onboard program only (no goal: no executor): the
smallest set that drives a step end to end."""
STEP = [1, 30, 2300]
"""FWD at speed 30 for 0.1 m of wheel travel."""


def generate_test_description() -> launch.LaunchDescription:
    # rover_onboard refuses to start without the uplink token: the launched processes
    # take it from this environment (as from an operator's shell).
    os.environ.setdefault("ROVER_UPLINK_TOKEN", secrets.token_hex(32))
    hil = IncludeLaunchDescription(
        PythonLaunchDescriptionSource(
            PathJoinSubstitution([FindPackageShare(LAUNCH_FILE[0]), *LAUNCH_FILE[1:]])
        ),
        launch_arguments=LAUNCH_ARGUMENTS.items(),
    )
    return launch.LaunchDescription([hil, launch_testing.actions.ReadyToTest()])


class TestHilLaunch(unittest.TestCase):
    def test_a_step_completes_through_ros(self, proc_output: Any) -> None:
        proc_output.assertWaitFor("BRIDGE ", timeout=60)
        proc_output.assertWaitFor("ONBOARD ", timeout=60)  # beside the bridge (review D2)
        rclpy.init()
        try:
            node = rclpy.create_node("hil_launch_test")
            statuses: list[str] = []

            def on_status(msg: Any) -> None:
                statuses.append(str(msg.data))

            node.create_subscription(String, "command_status", on_status, 10)
            publisher = node.create_publisher(Int16MultiArray, "wheel_instructions", 10)
            deadline = time.monotonic() + 60.0
            next_try = 0.0
            while time.monotonic() < deadline and "completed" not in statuses:
                accepted = "accepted" in statuses
                if (
                    not accepted
                    and time.monotonic() >= next_try
                    and publisher.get_subscription_count()
                ):
                    # Until the bridge has shaken hands with the emulator it answers
                    # rejected:link_down; try again every second until it accepts.
                    publisher.publish(Int16MultiArray(data=STEP))
                    next_try = time.monotonic() + 1.0
                rclpy.spin_once(node, timeout_sec=0.1)
            assert "completed" in statuses, f"statuses seen: {statuses}"
            node.destroy_node()
        finally:
            rclpy.shutdown()


@launch_testing.post_shutdown_test()
class TestShutdown(unittest.TestCase):
    def test_processes_exit_cleanly(self, proc_info: Any) -> None:
        launch_testing.asserts.assertExitCodes(proc_info, allowable_exit_codes=[0])
