"""Fixtures of the ROS port tests: backends, loopback DDS, collecting callbacks.

DDS tests (marker ``dds``) run only inside the private network namespace that
``.ci/test`` sets up (``ROVER_PRIVATE_NETNS=1``): Cyclone DDS sends a multicast probe
when it starts, and nothing may leave this machine. Elsewhere they skip, saying why.
rclpy tests (marker ``rclpy``) skip where ROS 2 is not installed.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Iterator
from typing import Any

import pytest

from bridge.rosport import RosPort, loopback_config, open_port
from bridge.rosport.rclpy_backend import rclpy_available

IN_PRIVATE_NETNS = os.environ.get("ROVER_PRIVATE_NETNS") == "1"
SKIP_DDS_REASON = (
    "DDS tests run only in the private network namespace of .ci/test "
    "(ROVER_PRIVATE_NETNS=1 not set): Cyclone DDS multicasts at start"
)
SKIP_RCLPY_REASON = "rclpy (ROS 2 Jazzy) is not installed here; source a ROS 2 setup to run"

#: Every backend, with the marks it needs.
BACKEND_PARAMS = [
    pytest.param("inprocess", id="inprocess"),
    pytest.param("dds", id="dds", marks=pytest.mark.dds),
    pytest.param("rclpy", id="rclpy", marks=pytest.mark.rclpy),
]


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if item.get_closest_marker("dds") and not IN_PRIVATE_NETNS:
            item.add_marker(pytest.mark.skip(reason=SKIP_DDS_REASON))
        if item.get_closest_marker("rclpy") and not rclpy_available():
            item.add_marker(pytest.mark.skip(reason=SKIP_RCLPY_REASON))


@pytest.fixture(scope="session")
def dds_config() -> str:
    """Cyclone DDS config that keeps every packet on 127.0.0.1."""
    return loopback_config()


PortFactory = Callable[..., RosPort]


@pytest.fixture
def make_port(request: pytest.FixtureRequest, dds_config: str) -> Iterator[PortFactory]:
    """``make_port(backend, namespace=..., node_name=...)``; every port closes at teardown.

    In-process ports of one test share a bus private to that test.
    """
    ports: list[RosPort] = []
    bus = f"test-{request.node.nodeid}"

    def make(backend: str, **kwargs: Any) -> RosPort:
        if backend == "dds":
            kwargs.setdefault("config", dds_config)
        elif backend == "inprocess":
            kwargs.setdefault("bus", bus)
        port = open_port(backend, **kwargs)
        ports.append(port)
        return port

    yield make
    for port in reversed(ports):
        port.close()


class Inbox:
    """A callback that keeps what it receives, and lets a test wait for it."""

    def __init__(self) -> None:
        self.items: list[Any] = []
        self.threads: set[str] = set()
        self._cond = threading.Condition()

    def __call__(self, msg: Any) -> None:
        with self._cond:
            self.items.append(msg)
            self.threads.add(threading.current_thread().name)
            self._cond.notify_all()

    def wait_for(self, count: int, timeout_s: float = 10.0) -> list[Any]:
        """Wait until ``count`` items arrived; fail the test on timeout."""
        with self._cond:
            if not self._cond.wait_for(lambda: len(self.items) >= count, timeout_s):
                pytest.fail(f"received {len(self.items)} of {count} messages in {timeout_s} s")
            return list(self.items)
