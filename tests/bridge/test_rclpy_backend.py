"""The rclpy backend imports anywhere and says clearly when ROS 2 is missing."""

from __future__ import annotations

import importlib
import sys

import pytest

from bridge.rosport import BackendUnavailableError, open_port


def test_module_imports_without_rclpy(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "rclpy", None)  # as if not installed
    monkeypatch.delitem(sys.modules, "bridge.rosport.rclpy_backend", raising=False)
    module = importlib.import_module("bridge.rosport.rclpy_backend")
    assert module.rclpy_available() is False


def test_opening_without_rclpy_raises_a_clear_error(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "rclpy", None)
    with pytest.raises(BackendUnavailableError) as info:
        open_port("rclpy", node_name="bridge")
    text = str(info.value)
    assert "needs ROS 2 (rclpy), which is not installed here" in text
    assert "source a ROS 2 Jazzy setup" in text
    assert "'dds' backend" in text
    assert isinstance(info.value.__cause__, ImportError)


@pytest.mark.rclpy
def test_rclpy_port_is_a_ros_node() -> None:
    with open_port("rclpy", namespace="rover1", node_name="bridge") as port:
        node = port.node  # type: ignore[attr-defined]
        assert node.get_name() == "bridge"
        assert node.get_namespace() == "/rover1"
