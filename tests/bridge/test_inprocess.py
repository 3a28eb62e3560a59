"""In-process specifics: buses, keep-last queues, type matching."""

from __future__ import annotations

import threading

import pytest

from bridge.ros.rosport import HISTORY_DEPTH, MessageError
from bridge.ros.rosport.msgs import Int16MultiArray, String
from tests.bridge.conftest import Inbox, PortFactory


def test_ports_on_different_buses_do_not_see_each_other(make_port: PortFactory) -> None:
    here = make_port("inprocess", bus="lab")
    there = make_port("inprocess", bus="field")
    inbox = Inbox()
    there.subscribe("/chatter", String, inbox)
    pub = here.publisher("/chatter", String)
    assert pub.matched_count() == 0


def test_the_same_name_with_another_type_does_not_match(make_port: PortFactory) -> None:
    a = make_port("inprocess", node_name="a")
    b = make_port("inprocess", node_name="b")
    b.subscribe("/wheel_instructions", String, Inbox())
    assert a.publisher("/wheel_instructions", Int16MultiArray).matched_count() == 0


def test_a_slow_subscriber_keeps_the_last_ten(make_port: PortFactory) -> None:
    sender = make_port("inprocess", node_name="sender")
    receiver = make_port("inprocess", node_name="receiver")
    release = threading.Event()
    first_arrived = threading.Event()
    got: list[int] = []
    done = threading.Event()
    total = 30

    def slow(msg: Int16MultiArray) -> None:
        first_arrived.set()
        release.wait(10.0)
        got.append(msg.data[0])
        if msg.data[0] == total - 1:
            done.set()

    receiver.subscribe("/steps", Int16MultiArray, slow)
    pub = sender.publisher("/steps", Int16MultiArray)
    pub.publish(Int16MultiArray(data=(0,)))
    assert first_arrived.wait(10.0)
    for i in range(1, total):
        pub.publish(Int16MultiArray(data=(i,)))
    release.set()
    assert done.wait(10.0)
    # Message 0 was in the callback; of the 29 queued behind it, the last ten survive.
    assert got == [0, *range(total - HISTORY_DEPTH, total)]
    assert receiver.stats().dropped == total - 1 - HISTORY_DEPTH


def test_serialized_bytes_that_are_no_message_are_refused_and_nothing_is_delivered(
    make_port: PortFactory,
) -> None:
    port = make_port("inprocess")
    inbox = Inbox()
    port.subscribe("/chatter", String, inbox)
    pub = port.publisher("/chatter", String)
    with pytest.raises(MessageError, match="not a serialized std_msgs/msg/String"):
        pub.publish_serialized(b"\x00\x01\x00\x00\xff\xff\xff\x7f")  # a length past the end
    pub.publish(String(data="after"))
    assert inbox.wait_for(1) == [String(data="after")]
    assert port.stats().published == 1
