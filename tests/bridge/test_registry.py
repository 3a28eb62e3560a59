"""Backends by name, imported lazily; one precise error for an unknown name."""

from __future__ import annotations

import subprocess
import sys

import pytest

from bridge.ros.rosport import (
    BACKENDS,
    BackendUnavailableError,
    RosPortError,
    UnknownBackendError,
    open_port,
)
from bridge.ros.rosport.inprocess import InProcessPort
from bridge.ros.rosport.registry import backend_class


def test_unknown_backend_lists_the_known_ones() -> None:
    with pytest.raises(UnknownBackendError) as info:
        open_port("zenoh")
    assert str(info.value) == (
        "unknown ROS port backend 'zenoh'; known backends: inprocess, rclpy, rclpy-process"
    )
    assert info.value.known == ("inprocess", "rclpy", "rclpy-process")
    assert isinstance(info.value, ValueError)
    assert isinstance(info.value, RosPortError)


def test_open_port_passes_names_and_options() -> None:
    with open_port("inprocess", namespace="rover1", node_name="bridge", bus="registry") as port:
        assert isinstance(port, InProcessPort)
        assert (port.namespace, port.node_name, port.bus_name) == ("/rover1", "bridge", "registry")
    with pytest.raises(TypeError, match="unexpected keyword argument 'baud'"):
        open_port("inprocess", baud=115200)


def test_a_backend_that_cannot_import_says_so(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(BACKENDS, "broken", ("bridge.ros.rosport._no_such_module", "Port"))
    with pytest.raises(
        BackendUnavailableError, match="the 'broken' ROS port backend cannot be imported"
    ):
        backend_class("broken")


def test_importing_the_package_imports_no_backend() -> None:
    code = (
        "import sys, bridge.ros.rosport\n"
        "print(sorted(m for m in ('rclpy', 'std_msgs', 'bridge.ros.rosport.msgs',"
        " 'bridge.ros.rosport.rclpy_backend', 'bridge.ros.rosport.inprocess') if m in sys.modules))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60
    )
    assert out.stdout.strip() == "[]"
