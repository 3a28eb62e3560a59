"""The link relay in virtual time (a lockstep clock: its ports deliver and it releases
on the clock's ticks, no thread): each message arrives exactly its delay (plus its
jitter) after it was sent, never early, in order; loss follows the seed; a close drops
what is in flight. Its threads over real ROS 2 are tests/planner/test_relay_ros2.py's."""

from __future__ import annotations

import itertools
from collections.abc import Iterator

import pytest

from bridge.ros.rosport import RosPort, open_port
from bridge.ros.rosport.msgs import Int16MultiArray, String
from firmware_proto.linkio.clock import LockstepClock
from planner.ground.relay import LinkProfile, LinkRelay

TICK_S = 0.001
_buses = itertools.count()


@pytest.fixture
def clock() -> LockstepClock:
    return LockstepClock(TICK_S)


@pytest.fixture
def ports(clock: LockstepClock) -> Iterator[list[RosPort]]:
    """Operator, relay (ground side), relay (rover side), bridge: in-process, in lockstep."""
    bus = f"relay-{next(_buses)}"
    opened = [
        open_port("inprocess", namespace=namespace, node_name=name, bus=bus, clock=clock)
        for name, namespace in (
            ("op", "ground"),
            ("relay_g", "ground"),
            ("relay_r", ""),
            ("bridge", ""),
        )
    ]
    try:
        yield opened
    finally:
        for port in opened:
            port.close()


def test_uplink_and_downlink_are_delayed_by_their_delay_and_jitter_and_keep_order(
    clock: LockstepClock, ports: list[RosPort]
) -> None:
    op, rg, rr, br = ports
    up: list[tuple[float, int]] = []
    down: list[tuple[float, str]] = []
    br.subscribe(
        "wheel_instructions", Int16MultiArray, lambda m: up.append((clock.now(), m.data[2]))
    )
    op.subscribe("command_status", String, lambda m: down.append((clock.now(), m.data)))
    profile = LinkProfile(one_way_delay_s=0.2, jitter_s=0.05, seed=3)
    with LinkRelay(rg, rr, profile, clock=clock) as relay:
        assert not relay.serialized  # the in-process port carries messages
        steps = op.publisher("wheel_instructions", Int16MultiArray)
        status = br.publisher("command_status", String)
        sent: list[float] = []
        for i in range(20):
            sent.append(clock.now())
            steps.publish(Int16MultiArray(data=(1, 10, i)))
            status.publish(String(data=f"s{i}"))
            clock.sleep(0.013)  # a burst far shorter than the delay: all 20 in flight
        clock.sleep(0.3)
        assert relay.forwarded["up:wheel_instructions"] == 20
        assert relay.forwarded["down:command_status"] == 20
    assert [i for _, i in up] == list(range(20))
    assert [text for _, text in down] == [f"s{i}" for i in range(20)]
    # Each arrives its delay plus its jitter after it was sent, never early; the ports'
    # hops and the relay's release take at most a tick each.
    for (arrived, i), (came, _) in zip(up, down, strict=True):
        for t in (arrived, came):
            assert 0.2 <= t - sent[i] <= 0.25 + 3 * TICK_S, (i, t - sent[i])
    delays = [arrived - sent[i] for arrived, i in up]
    assert max(delays) - min(delays) > 0.01  # the jitter is there


def _survivors(seed: int, loss: float = 0.3) -> list[int]:
    clock = LockstepClock(TICK_S)
    bus = f"relay-loss-{next(_buses)}"
    opened = [
        open_port("inprocess", namespace=ns, node_name=name, bus=bus, clock=clock)
        for name, ns in (("op", "ground"), ("relay_g", "ground"), ("relay_r", ""), ("br", ""))
    ]
    op, rg, rr, br = opened
    try:
        got: list[int] = []
        br.subscribe("wheel_instructions", Int16MultiArray, lambda m: got.append(m.data[2]))
        with LinkRelay(
            rg, rr, LinkProfile(one_way_delay_s=0.0, loss=loss, seed=seed), clock=clock
        ) as relay:
            pub = op.publisher("wheel_instructions", Int16MultiArray)
            for i in range(200):
                pub.publish(Int16MultiArray(data=(1, 1, i)))
                clock.advance(2)
            clock.advance(5)
            assert relay.received == 200
            assert len(got) + sum(relay.dropped.values()) == 200
        return got
    finally:
        for port in opened:
            port.close()


def test_loss_is_seeded_and_reproducible() -> None:
    first, again, other = _survivors(7), _survivors(7), _survivors(8)
    assert first == again
    assert first != other
    assert 100 < len(first) < 180
    assert first == sorted(first)  # what survives keeps its order


def test_close_drops_messages_in_flight(clock: LockstepClock, ports: list[RosPort]) -> None:
    op, rg, rr, br = ports
    got: list[object] = []
    br.subscribe("wheel_instructions", Int16MultiArray, got.append)
    relay = LinkRelay(rg, rr, LinkProfile(one_way_delay_s=30.0), clock=clock)
    steps = op.publisher("wheel_instructions", Int16MultiArray)
    steps.publish(Int16MultiArray(data=(1, 1, 1)))
    clock.advance(2)
    assert relay.in_flight == 1
    relay.close()
    relay.close()  # idempotent
    clock.sleep(31.0)
    assert relay.in_flight == 0 and got == []


@pytest.mark.parametrize(
    ("profile", "complaint"),
    [
        ({"loss": 1.0}, "loss"),
        ({"one_way_delay_s": -1.0}, "delay"),
        ({"jitter_s": 1e9}, "delay"),
    ],
)
def test_bad_profiles_are_refused(profile: dict[str, float], complaint: str) -> None:
    with pytest.raises(ValueError, match=complaint):
        LinkProfile(**profile)  # type: ignore[arg-type]
