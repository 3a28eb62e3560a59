"""The rclpy backend imports anywhere and says clearly when ROS 2 is missing."""

from __future__ import annotations

import importlib
import sys
import time

import pytest

from bridge.ros.rosport import BackendUnavailableError, open_port


def test_module_imports_without_rclpy(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "rclpy", None)  # as if not installed
    monkeypatch.delitem(sys.modules, "bridge.ros.rosport.rclpy_backend", raising=False)
    module = importlib.import_module("bridge.ros.rosport.rclpy_backend")
    assert module.rclpy_available() is False


def test_opening_without_rclpy_raises_a_clear_error(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "rclpy", None)
    with pytest.raises(BackendUnavailableError) as info:
        open_port("rclpy", node_name="bridge")
    text = str(info.value)
    assert "needs ROS 2 Jazzy (rclpy), which is not installed here" in text
    assert "pip install 'rover-hil[ros]'" in text
    assert "source /opt/ros/jazzy/setup.bash" in text
    assert isinstance(info.value.__cause__, ImportError)


@pytest.mark.rclpy
def test_rclpy_port_is_a_ros_node() -> None:
    with open_port("rclpy", namespace="rover1", node_name="bridge") as port:
        node = port.node  # type: ignore[attr-defined]
        assert node.get_name() == "bridge"
        assert node.get_namespace() == "/rover1"


@pytest.mark.rclpy
def test_the_stop_lane_is_a_node_of_its_own_in_the_same_context() -> None:
    from bridge.ros.rosport import STOP_LANE
    from bridge.ros.rosport.msgs import Bool

    with open_port("rclpy", namespace="rover1", node_name="bridge") as port:
        port.subscribe("emergency_stop", Bool, lambda _msg: None, lane=STOP_LANE)
        node = port.node  # type: ignore[attr-defined]
        deadline = time.monotonic() + 10.0
        names: list[tuple[str, str]] = []
        while ("bridge_stop", "/rover1") not in names and time.monotonic() < deadline:
            names = node.get_node_names_and_namespaces()
            time.sleep(0.05)
        assert ("bridge_stop", "/rover1") in names
        assert ("bridge", "/rover1") in names


@pytest.mark.rclpy
def test_middleware_names_the_rmw_and_rclpy() -> None:
    from bridge.ros.rosport.rclpy_backend import middleware

    assert middleware().startswith("rmw_fastrtps_cpp (rclpy 7.")
