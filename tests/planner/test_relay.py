"""Link relay over real ROS 2 (rclpy) and the in-process port: delay, order, loss, seed."""

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


#: The relay runs in the ground station's process: in-process and rclpy (the bridge's
#: child-process backend is the bridge's, tested in tests/bridge).
RELAY_BACKENDS = [param for param in BACKEND_PARAMS if param.id != "rclpy-process"]


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
    assert [m.data[2] for _, m in got_up] == list(range(20))  # type: ignore[attr-defined]
    assert [m.data for _, m in got_down] == [f"s{i}" for i in range(20)]  # type: ignore[attr-defined]
    assert min(t for t, _ in got_up + got_down) - sent >= 0.2  # never early


@pytest.mark.parametrize("backend", RELAY_BACKENDS)
def test_loss_is_seeded_and_reproducible(request: pytest.FixtureRequest, backend: str) -> None:
    def run(seed: int, tag: str) -> list[int]:
        opened = _ports(backend, f"loss-{tag}-{request.node.name}")
        op, rg, rr, br = opened
        try:
            sink = Sink()
            far_end = br.subscribe("wheel_instructions", Int16MultiArray, sink)
            with LinkRelay(rg, rr, LinkProfile(one_way_delay_s=0.0, loss=0.3, seed=seed)) as relay:
                pub = op.publisher("wheel_instructions", Int16MultiArray)
                assert pub.wait_for_subscribers(1, timeout_s=10.0)
                assert relay.wait_until_matched(10.0, {"wheel_instructions"})
                assert far_end.wait_for_publishers(1, timeout_s=10.0)
                for i in range(200):
                    pub.publish(Int16MultiArray(data=(1, 1, i)))
                    _wait_handled(relay, i + 1)
                    # Paced by the far end too: a burst over keep-last QoS drops, as in ROS.
                    sink.wait(i + 1 - sum(relay.dropped.values()))
                kept = 200 - sum(relay.dropped.values())
                return [m.data[2] for _, m in sink.wait(kept)]  # type: ignore[attr-defined]
        finally:
            for port in opened:
                port.close()

    first, again, other = run(7, "a"), run(7, "b"), run(8, "c")
    assert first == again
    assert first != other
    assert 100 < len(first) < 180


def _wait_handled(relay: LinkRelay, total: int, timeout: float = 10.0) -> None:
    """Until the relay has taken ``total`` messages (queued, forwarded or dropped)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if relay.received >= total:
            return
        time.sleep(0.0005)
    raise TimeoutError(f"relay took {relay.received}/{total} messages")


def test_close_drops_messages_in_flight(ports: list[RosPort]) -> None:
    op, rg, rr, br = ports
    sink = Sink()
    br.subscribe("wheel_instructions", Int16MultiArray, sink)
    relay = LinkRelay(rg, rr, LinkProfile(one_way_delay_s=30.0))
    steps = op.publisher("wheel_instructions", Int16MultiArray)
    _matched(relay, steps)
    steps.publish(Int16MultiArray(data=(1, 1, 1)))
    deadline = time.monotonic() + 5
    while relay.in_flight == 0 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert relay.in_flight == 1
    relay.close()
    relay.close()  # idempotent
    assert relay.in_flight == 0 and sink.items == []


@pytest.mark.parametrize(
    ("profile", "complaint"),
    [
        (LinkProfile.__init__, None),
        ({"loss": 1.0}, "loss"),
        ({"one_way_delay_s": -1.0}, "delay"),
        ({"jitter_s": 1e9}, "delay"),
    ][1:],
)
def test_bad_profiles_are_refused(profile: dict[str, float], complaint: str) -> None:
    with pytest.raises(ValueError, match=complaint):
        LinkProfile(**profile)  # type: ignore[arg-type]
