"""The rclpy backend imports anywhere and says clearly when ROS 2 is missing."""

from __future__ import annotations

import importlib
import sys
import threading
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


@pytest.mark.rclpy
def test_the_nodes_own_timers_and_services_run_on_the_default_lane_thread() -> None:
    """The default lane waits on the node's timers and services besides its subscriptions
    and runs their callbacks on its own thread, between messages, never beside them."""
    from bridge.ros.rosport.msgs import String

    rcl_interfaces = importlib.import_module("rcl_interfaces.srv")
    with open_port("rclpy", namespace="lanes", node_name="bridge") as port:
        threads: dict[str, threading.Thread] = {}
        heard = {name: threading.Event() for name in ("message", "timer", "service")}

        def mark(name: str) -> None:
            threads[name] = threading.current_thread()
            heard[name].set()

        port.subscribe("chatter", String, lambda _msg: mark("message"))
        publisher = port.publisher("chatter", String)
        node = port.node  # type: ignore[attr-defined]
        timer = node.create_timer(0.05, lambda: mark("timer"))

        def on_list(request: object, response: object) -> object:
            mark("service")
            return response

        node.create_service(rcl_interfaces.ListParameters, "probe", on_list)
        client = node.create_client(rcl_interfaces.ListParameters, "probe")
        assert client.wait_for_service(timeout_sec=10.0)
        future = client.call_async(rcl_interfaces.ListParameters.Request())
        deadline = time.monotonic() + 10.0
        while not heard["message"].is_set() and time.monotonic() < deadline:
            publisher.publish(String(data="hello"))
            heard["message"].wait(0.05)
        assert heard["timer"].wait(10.0) and heard["service"].wait(10.0)
        assert heard["message"].is_set()
        done = threading.Event()
        future.add_done_callback(lambda _f: done.set())
        assert done.wait(10.0)  # the client's response, taken by the same lane
        timer.cancel()
        assert threads["timer"] is threads["message"] is threads["service"]
        assert threads["message"] is not threading.current_thread()


@pytest.mark.rclpy
def test_a_serialized_message_is_published_as_it_is() -> None:
    """``publish_serialized`` (the process child's publish) delivers the very message
    whose CDR it was given, counts it, and refuses another port's publisher or a closed one."""
    from rclpy.serialization import serialize_message

    from bridge.ros.rosport import PortClosedError, RosPortError
    from bridge.ros.rosport.msgs import Odometry
    from bridge.ros.rosport.rclpy_backend import RclpyPort

    sent = Odometry()
    sent.header.frame_id = "odom"
    sent.pose.pose.position.x = 1.25
    sent.pose.covariance[35] = 0.5
    got: list[Odometry] = []
    arrived = threading.Event()
    with (
        RclpyPort(namespace="raw", node_name="pub") as pub_port,
        RclpyPort(namespace="raw", node_name="sub") as sub_port,
        RclpyPort(namespace="other", node_name="other") as other,
    ):

        def take(msg: Odometry) -> None:
            got.append(msg)
            arrived.set()

        sub_port.subscribe("odom", Odometry, take)
        pub = pub_port.publisher("odom", Odometry)
        assert pub.wait_for_subscribers(1, timeout_s=10.0)
        before = pub_port.stats().published
        pub_port.publish_serialized(pub, serialize_message(sent))
        assert arrived.wait(10.0)
        assert got[0] == sent
        assert pub_port.stats().published == before + 1
        with pytest.raises(RosPortError):
            other.publish_serialized(pub, serialize_message(sent))
        pub.close()
        with pytest.raises(PortClosedError):
            pub_port.publish_serialized(pub, serialize_message(sent))
