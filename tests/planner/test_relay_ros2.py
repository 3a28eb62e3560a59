"""The link relay over real ROS 2 (rclpy), in real time: the smoke of its threads and DDS;
what it does (delay, order, loss, its seed, what a close drops) is checked in virtual
time in tests/planner/test_relay.py."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from typing import Any

import pytest

from bridge.ros.rosport import Publisher, RosPort, open_port
from bridge.ros.rosport.msgs import Int16MultiArray, String
from planner.ground.relay import LinkProfile, LinkRelay
from tests.bridge.conftest import BACKEND_PARAMS


class Sink:
    def __init__(self) -> None:
        self.items: list[tuple[float, object]] = []
        self.cond = threading.Condition()

    def __call__(self, msg: object) -> None:
        with self.cond:
            self.items.append((time.monotonic(), msg))
            self.cond.notify_all()

    def wait(self, n: int, timeout: float = 10.0) -> list[tuple[float, object]]:
        deadline = time.monotonic() + timeout
        with self.cond:
            while len(self.items) < n:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise TimeoutError(f"{len(self.items)}/{n} messages")
                self.cond.wait(left)
            return list(self.items)


def _ports(backend: str, tag: str) -> list[RosPort]:
    """Operator, relay (ground side), relay (rover side), bridge."""
    options = {"bus": f"relay-{tag}"} if backend == "inprocess" else {}
    return [
        open_port(backend, namespace=namespace, node_name=name, **options)
        for name, namespace in (
            ("op", "ground"),
            ("relay_g", "ground"),
            ("relay_r", ""),
            ("bridge", ""),
        )
    ]


def _matched(relay: LinkRelay, *publishers: Publisher[Any]) -> None:
    """Over DDS, wait until every hop of these publishers' topics discovered the next."""
    for pub in publishers:
        assert pub.wait_for_subscribers(1, timeout_s=10.0), pub.topic
    assert relay.wait_until_matched(10.0, {pub.topic.rsplit("/", 1)[-1] for pub in publishers})


#: The relay runs in the ground station's process over rclpy (the in-process port is
#: tests/planner/test_relay.py's, in virtual time; the bridge's child-process backend is
#: the bridge's, tested in tests/bridge).
RELAY_BACKENDS = [param for param in BACKEND_PARAMS if param.id == "rclpy"]


@pytest.fixture(params=RELAY_BACKENDS)
def ports(request: pytest.FixtureRequest) -> Iterator[list[RosPort]]:
    opened = _ports(request.param, request.node.name)
    try:
        yield opened
    finally:
        for port in opened:
            port.close()


def test_uplink_and_downlink_are_delayed_and_keep_order(ports: list[RosPort]) -> None:
    op, rg, rr, br = ports
    up, down = Sink(), Sink()
    far_ends = [
        br.subscribe("wheel_instructions", Int16MultiArray, up),
        op.subscribe("command_status", String, down),
    ]
    with LinkRelay(rg, rr, LinkProfile(one_way_delay_s=0.2, jitter_s=0.05, seed=3)) as relay:
        steps = op.publisher("wheel_instructions", Int16MultiArray)
        status = br.publisher("command_status", String)
        _matched(relay, steps, status)
        for far_end in far_ends:
            assert far_end.wait_for_publishers(1, timeout_s=10.0), far_end.topic
        sent = time.monotonic()
        for i in range(20):
            steps.publish(Int16MultiArray(data=(1, 10, i)))
            status.publish(String(data=f"s{i}"))
            # Paced by the far ends: the relay releases what it holds after the delay, and
            # a burst of them over keep-last-10 QoS to a reader slowed by a loaded
            # machine would drop, as in ROS (it lost 6 of 20 so under two test workers).
            up.wait(i + 1)
            down.wait(i + 1)
        got_up = up.wait(20)
        got_down = down.wait(20)
        assert relay.forwarded["up:wheel_instructions"] == 20
        assert relay.serialized  # over DDS the bytes pass as they came
    assert [m.data[2] for _, m in got_up] == list(range(20))  # type: ignore[attr-defined]
    assert [m.data for _, m in got_down] == [f"s{i}" for i in range(20)]  # type: ignore[attr-defined]
    assert min(t for t, _ in got_up + got_down) - sent >= 0.2  # never early
