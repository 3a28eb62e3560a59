"""The same behaviour on every backend: delivery, threads, names, errors, closing.

Each test runs on ``inprocess`` here, on ``dds`` inside the private network namespace,
and on ``rclpy`` where ROS 2 is installed (see conftest.py).
"""

from __future__ import annotations

import logging
import threading

import pytest

from bridge.rosport import (
    MESSAGE_TYPES,
    Bool,
    Int16MultiArray,
    Odometry,
    PortClosedError,
    RosNameError,
    String,
    TopicTypeError,
)
from tests.bridge.conftest import BACKEND_PARAMS, Inbox, PortFactory
from tests.bridge.samples import sample, topic_for

pytestmark = pytest.mark.parametrize("backend", BACKEND_PARAMS)


def test_every_message_type_round_trips_in_order(make_port: PortFactory, backend: str) -> None:
    sender = make_port(backend, node_name="sender")
    receiver = make_port(backend, node_name="receiver")
    count = 5
    inboxes = {}
    for msg_type in MESSAGE_TYPES.values():
        inboxes[msg_type] = Inbox()
        receiver.subscribe(topic_for(msg_type), msg_type, inboxes[msg_type])
    for msg_type in MESSAGE_TYPES.values():
        pub = sender.publisher(topic_for(msg_type), msg_type)
        assert pub.wait_for_subscribers(1, timeout_s=10.0)
        for seed in range(count):
            pub.publish(sample(msg_type, seed))
    for msg_type, inbox in inboxes.items():
        expected = [sample(msg_type, seed) for seed in range(count)]
        assert inbox.wait_for(count) == expected, msg_type.ROS_TYPE
    assert sender.stats().published == count * len(MESSAGE_TYPES)
    assert receiver.stats().delivered == count * len(MESSAGE_TYPES)


def test_callbacks_run_on_the_backend_thread(make_port: PortFactory, backend: str) -> None:
    port = make_port(backend)
    inbox = Inbox()
    port.subscribe("/chatter", String, inbox)
    pub = port.publisher("/chatter", String)
    assert pub.wait_for_subscribers(1, timeout_s=10.0)
    pub.publish(String("hello"))
    assert inbox.wait_for(1) == [String("hello")]
    assert threading.current_thread().name not in inbox.threads
    assert len(inbox.threads) == 1


def test_a_raising_callback_is_logged_counted_and_survived(
    make_port: PortFactory, backend: str, caplog: pytest.LogCaptureFixture
) -> None:
    port = make_port(backend)
    good = Inbox()
    failures = 0

    def bad(msg: Int16MultiArray) -> None:
        nonlocal failures
        if msg.data[0] % 2 == 0:
            failures += 1
            raise RuntimeError(f"cannot handle {msg.data[0]}")

    bad_sub = port.subscribe("/wheel_instructions", Int16MultiArray, bad)
    good_sub = port.subscribe("/wheel_instructions", Int16MultiArray, good)
    pub = port.publisher("/wheel_instructions", Int16MultiArray)
    assert pub.wait_for_subscribers(2, timeout_s=10.0)
    with caplog.at_level(logging.ERROR, logger="bridge.rosport.port"):
        for i in range(8):
            pub.publish(Int16MultiArray(data=(i, 30, 1000)))
        received = good.wait_for(8)
    assert [m.data[0] for m in received] == list(range(8))
    assert (bad_sub.errors, bad_sub.delivered) == (4, 4)
    assert (good_sub.errors, good_sub.delivered) == (0, 8)
    assert port.stats().callback_errors == 4
    # Logged at failures 1, 2 and 4 (powers of two), the first with its traceback.
    records = [r for r in caplog.records if "callback on /wheel_instructions raised" in r.message]
    assert [bool(r.exc_info) for r in records] == [True, False, False]
    assert "cannot handle 0" in caplog.text


def test_relative_names_get_the_namespace_absolute_ones_do_not(
    make_port: PortFactory, backend: str
) -> None:
    rover = make_port(backend, namespace="rover1", node_name="bridge")
    ground = make_port(backend, node_name="executor")
    relative, absolute, private = Inbox(), Inbox(), Inbox()
    ground.subscribe("/rover1/command_status", String, relative)
    ground.subscribe("/command_status", String, absolute)
    ground.subscribe("/rover1/bridge/state", String, private)
    pubs = [
        rover.publisher("command_status", String),
        rover.publisher("/command_status", String),
        rover.publisher("~/state", String),
    ]
    assert [p.topic for p in pubs] == [
        "/rover1/command_status",
        "/command_status",
        "/rover1/bridge/state",
    ]
    for pub, text in zip(pubs, ("relative", "absolute", "private"), strict=True):
        assert pub.wait_for_subscribers(1, timeout_s=10.0)
        pub.publish(String(text))
    assert relative.wait_for(1) == [String("relative")]
    assert absolute.wait_for(1) == [String("absolute")]
    assert private.wait_for(1) == [String("private")]


def test_invalid_names_are_refused(make_port: PortFactory, backend: str) -> None:
    port = make_port(backend)
    with pytest.raises(RosNameError, match="starts with a digit"):
        port.publisher("2fast", String)
    with pytest.raises(RosNameError, match="not allowed in ROS names"):
        port.subscribe("wheel-instructions", Int16MultiArray, Inbox())
    with pytest.raises(RosNameError, match="node name"):
        make_port(backend, node_name="my-node")
    with pytest.raises(RosNameError, match="namespace"):
        make_port(backend, namespace="/rover1/")


def test_wrong_types_are_refused(make_port: PortFactory, backend: str) -> None:
    port = make_port(backend)
    pub = port.publisher("/emergency_stop", Bool)
    with pytest.raises(TopicTypeError, match="sends Bool, got String"):
        pub.publish(String("stop"))  # type: ignore[arg-type]
    with pytest.raises(TopicTypeError, match="already used with std_msgs/msg/Bool"):
        port.subscribe("/emergency_stop", String, Inbox())
    with pytest.raises(TopicTypeError, match="not a message type"):
        port.publisher("/x", dict)  # type: ignore[type-var]
    with pytest.raises(TypeError, match="callback must be callable"):
        port.subscribe("/y", String, "not callable")  # type: ignore[arg-type]


def test_closed_things_refuse_work_and_close_is_idempotent(
    make_port: PortFactory, backend: str
) -> None:
    port = make_port(backend)
    pub = port.publisher("/odom", Odometry)
    pub.close()
    pub.close()
    assert pub.closed
    with pytest.raises(PortClosedError):
        pub.publish(Odometry())
    other = port.publisher("/odom_pose", Odometry)
    with port:
        pass
    assert port.closed
    assert other.closed
    port.close()
    with pytest.raises(PortClosedError):
        other.publish(Odometry())
    with pytest.raises(PortClosedError):
        port.publisher("/odom", Odometry)
    with pytest.raises(PortClosedError):
        port.subscribe("/odom", Odometry, Inbox())


def test_a_closed_subscription_receives_nothing_more(make_port: PortFactory, backend: str) -> None:
    sender = make_port(backend, node_name="sender")
    receiver = make_port(backend, node_name="receiver")
    closing, staying = Inbox(), Inbox()
    closing_sub = receiver.subscribe("/chatter", String, closing)
    receiver.subscribe("/chatter", String, staying)
    pub = sender.publisher("/chatter", String)
    assert pub.wait_for_subscribers(2, timeout_s=10.0)
    pub.publish(String("one"))
    closing.wait_for(1)
    staying.wait_for(1)
    closing_sub.close()
    closing_sub.close()
    pub.publish(String("two"))
    assert staying.wait_for(2) == [String("one"), String("two")]
    assert closing.items == [String("one")]


def test_a_callback_may_close_its_own_port(make_port: PortFactory, backend: str) -> None:
    sender = make_port(backend, node_name="sender")
    receiver = make_port(backend, node_name="receiver")
    closed = threading.Event()

    def close_on_message(msg: Bool) -> None:
        receiver.close()
        closed.set()

    receiver.subscribe("/emergency_stop", Bool, close_on_message)
    pub = sender.publisher("/emergency_stop", Bool)
    assert pub.wait_for_subscribers(1, timeout_s=10.0)
    pub.publish(Bool(True))
    assert closed.wait(10.0)
    assert receiver.closed
    # The backend thread ends and frees the backend by itself; the leak guard checks.


def test_waiting_for_subscribers_times_out(make_port: PortFactory, backend: str) -> None:
    port = make_port(backend)
    pub = port.publisher("/nobody_listens", String)
    assert pub.matched_count() == 0
    assert not pub.wait_for_subscribers(1, timeout_s=0.05)
