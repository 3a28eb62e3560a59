"""The same behaviour on every backend: delivery, threads, names, errors, closing.

Each test runs on ``inprocess`` and on real ROS 2 (``rclpy``, inside the private network
namespace; see conftest.py).
"""

from __future__ import annotations

import logging
import threading
import time

import pytest

from bridge.errors import ParameterError
from bridge.ros.rosport import (
    STOP_LANE,
    PortClosedError,
    RosNameError,
    TopicTypeError,
    qos,
)
from bridge.ros.rosport.msgs import MESSAGE_TYPES, Bool, Int16MultiArray, Odometry, String
from bridge.ros.rosport.names import ros_type_name
from bridge.ros.rosport.parameters import ParameterSpec
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
        assert inbox.wait_for(count) == expected, ros_type_name(msg_type)
    assert sender.stats().published == count * len(MESSAGE_TYPES)
    assert receiver.stats().delivered == count * len(MESSAGE_TYPES)


def test_callbacks_run_on_the_backend_thread(make_port: PortFactory, backend: str) -> None:
    port = make_port(backend)
    inbox = Inbox()
    port.subscribe("/chatter", String, inbox)
    pub = port.publisher("/chatter", String)
    assert pub.wait_for_subscribers(1, timeout_s=10.0)
    pub.publish(String(data="hello"))
    assert inbox.wait_for(1) == [String(data="hello")]
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
    with caplog.at_level(logging.ERROR, logger="bridge.ros.rosport.port"):
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
        pub.publish(String(data=text))
    assert relative.wait_for(1) == [String(data="relative")]
    assert absolute.wait_for(1) == [String(data="absolute")]
    assert private.wait_for(1) == [String(data="private")]


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
        pub.publish(String(data="stop"))
    with pytest.raises(TopicTypeError, match="already used with std_msgs/msg/Bool"):
        port.subscribe("/emergency_stop", String, Inbox())
    with pytest.raises(TopicTypeError, match="not a generated ROS 2 message class"):
        port.publisher("/x", dict)
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
    pub.publish(String(data="one"))
    closing.wait_for(1)
    staying.wait_for(1)
    closing_sub.close()
    closing_sub.close()
    pub.publish(String(data="two"))
    assert staying.wait_for(2) == [String(data="one"), String(data="two")]
    assert closing.items == [String(data="one")]


def test_subscriptions_closed_while_the_lane_waits_leave_it_delivering(
    make_port: PortFactory, backend: str, caplog: pytest.LogCaptureFixture
) -> None:
    """Subscriptions made and closed on another thread while the lane's executor waits
    on them (as a ground station's executor closes its own at the end): on rclpy the
    executor may meet one being destroyed ("destruction was requested"); the lane goes
    on delivering and logs no failure."""
    sender = make_port(backend, node_name="sender")
    receiver = make_port(backend, node_name="receiver")
    staying = Inbox()
    receiver.subscribe("/chatter", String, staying)
    pub = sender.publisher("/chatter", String)
    assert pub.wait_for_subscribers(1, timeout_s=10.0)
    with caplog.at_level(logging.ERROR, logger="bridge.ros.rosport"):
        # A race: with 1,000 the old lane failed 2 runs of 2 beside the test command, none
        # of 5 on an idle machine; 100 keep the behaviour checked (1,000 through a child
        # process took 12 s of the host part).
        for i in range(100):
            receiver.subscribe(f"/churn_{i % 5}", Odometry, Inbox()).close()
        pub.publish(String(data="after"))
        assert staying.wait_for(1) == [String(data="after")]
    assert not [r for r in caplog.records if "failed" in r.getMessage()], caplog.text


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
    pub.publish(Bool(data=True))
    assert closed.wait(10.0)
    assert receiver.closed
    # The backend thread ends and frees the backend by itself; the leak guard checks.


def test_waiting_for_subscribers_times_out(make_port: PortFactory, backend: str) -> None:
    port = make_port(backend)
    pub = port.publisher("/nobody_listens", String)
    assert pub.matched_count() == 0
    assert not pub.wait_for_subscribers(1, timeout_s=0.05)


def test_a_subscription_counts_its_matched_publishers(make_port: PortFactory, backend: str) -> None:
    listener, talker = make_port(backend, node_name="listener"), make_port(backend)
    sub = listener.subscribe("/counted", String, lambda _m: None)
    assert sub.matched_count() == 0
    assert not sub.wait_for_publishers(1, timeout_s=0.05)
    pub = talker.publisher("/counted", String)
    talker.publisher("/counted_other", String)  # another topic does not count
    assert sub.wait_for_publishers(1, timeout_s=10.0)
    assert sub.matched_count() == 1
    pub.close()
    deadline = time.monotonic() + 10.0
    while sub.matched_count() and time.monotonic() < deadline:
        time.sleep(0.02)
    assert sub.matched_count() == 0
    sub.close()
    assert sub.matched_count() == 0


def test_a_reliable_subscription_ignores_a_best_effort_publisher(
    make_port: PortFactory, backend: str
) -> None:
    sender = make_port(backend, node_name="sender")
    receiver = make_port(backend, node_name="receiver")
    reliable, best_effort = Inbox(), Inbox()
    receiver.subscribe("/odom", Odometry, reliable, qos.TELEMETRY)
    receiver.subscribe("/odom", Odometry, best_effort, qos.SENSOR)
    telemetry = sender.publisher("/odom", Odometry, qos.TELEMETRY)  # reliable
    sensor = sender.publisher("/odom_raw", Odometry, qos.SENSOR)  # best effort
    assert telemetry.wait_for_subscribers(2, timeout_s=10.0)
    sensor_readers = Inbox()
    receiver.subscribe("/odom_raw", Odometry, sensor_readers, qos.TELEMETRY)
    assert not sensor.wait_for_subscribers(1, timeout_s=0.5)  # reliable asks, none offered
    msg = Odometry(child_frame_id="base_link")
    telemetry.publish(msg)
    assert reliable.wait_for(1) == [msg]
    assert best_effort.wait_for(1) == [msg]
    sensor.publish(msg)
    assert sensor_readers.items == []


def test_a_stop_lane_callback_runs_while_the_default_lane_is_blocked(
    make_port: PortFactory, backend: str
) -> None:
    sender = make_port(backend, node_name="sender")
    receiver = make_port(backend, node_name="receiver")
    entered, release, stopped = threading.Event(), threading.Event(), threading.Event()
    stops = Inbox()

    def on_stop(msg: Bool) -> None:
        stops(msg)
        stopped.set()

    def slow(msg: Odometry) -> None:
        entered.set()
        release.wait(10.0)

    receiver.subscribe("/odom", Odometry, slow, qos.SENSOR)
    receiver.subscribe("/emergency_stop", Bool, on_stop, qos.STOP, lane=STOP_LANE)
    odom = sender.publisher("/odom", Odometry, qos.TELEMETRY)
    stop = sender.publisher("/emergency_stop", Bool, qos.STOP)
    assert odom.wait_for_subscribers(1, timeout_s=10.0)
    assert stop.wait_for_subscribers(1, timeout_s=10.0)
    try:
        # Over DDS the reader may match a moment after the writer: send until it lands.
        for _ in range(100):
            odom.publish(Odometry())
            if entered.wait(0.1):
                break
        assert entered.is_set()
        for _ in range(100):
            stop.publish(Bool(data=True))
            if stopped.wait(0.1):
                break
        assert stops.items[0] == Bool(data=True)  # while `slow` still holds its lane
        assert not release.is_set()
        assert stops.threads.isdisjoint({threading.current_thread().name})
    finally:
        release.set()


def test_parameters_are_declared_checked_and_set(make_port: PortFactory, backend: str) -> None:
    port = make_port(backend, node_name="params")
    applied: list[dict[str, object]] = []

    def on_set(changes: object) -> str | None:
        values = dict(changes)  # type: ignore[call-overload]
        if values.get("rate_hz") == 13.0:
            return "13 Hz is unlucky"
        applied.append(values)
        return None

    specs = [
        ParameterSpec("rate_hz", 10.0, "a rate, Hz", range=(1.0, 100.0)),
        ParameterSpec("retries", 3, "retries", range=(0, 20)),
        ParameterSpec("device", "/dev/x", "a device", read_only=True),
    ]
    values = port.declare_parameters(specs, on_set, {"retries": 5})
    assert values == {"rate_hz": 10.0, "retries": 5, "device": "/dev/x"}
    assert port.set_parameters({"rate_hz": 20.0}) is None
    assert applied == [{"rate_hz": 20.0}]
    assert port.parameters()["rate_hz"] == 20.0
    for bad, why in (
        ({"rate_hz": 500.0}, "rate_hz"),
        ({"rate_hz": float("nan")}, "rate_hz"),
        ({"rate_hz": 5}, "rate_hz"),  # an integer for a double
        ({"device": "/dev/y"}, "device"),  # read-only
        ({"rate_hz": 13.0}, "unlucky"),  # the node's own reason
        ({"nope": 1}, "nope"),
    ):
        reason = port.set_parameters(bad)
        assert reason is not None and why in reason, (bad, reason)
    assert port.parameters() == {"rate_hz": 20.0, "retries": 5, "device": "/dev/x"}
    assert applied == [{"rate_hz": 20.0}]
    other = make_port(backend, node_name="params2")
    with pytest.raises(ParameterError, match="retries"):
        other.declare_parameters(specs, on_set, {"retries": 99})


def test_serialized_messages_pass_both_ways_and_taps_see_messages(
    make_port: PortFactory, backend: str
) -> None:
    """``publish_serialized`` and ``subscribe(..., serialized=True)`` (docs/rosport.md,
    "Serialized messages"): a serialized subscription gets the bytes of every message,
    published either way; a plain one gets messages; taps are shown messages."""
    serialization = pytest.importorskip("rclpy.serialization")
    sender = make_port(backend, node_name="sender")
    receiver = make_port(backend, node_name="receiver")
    assert sender.carries_serialized == (backend != "inprocess")
    sent: list[object] = []
    received: list[object] = []
    sender.add_tap(lambda _d, _t, msg: sent.append(msg))
    receiver.add_tap(lambda _d, _t, msg: received.append(msg))
    as_bytes, as_messages = Inbox(), Inbox()
    receiver.subscribe("/odom", Odometry, as_bytes, serialized=True)
    receiver.subscribe("/odom", Odometry, as_messages)
    pub = sender.publisher("/odom", Odometry)
    assert pub.wait_for_subscribers(2, timeout_s=10.0)
    messages = [sample(Odometry, seed) for seed in range(4)]
    for i, msg in enumerate(messages):
        if i % 2:
            pub.publish(msg)
        else:
            pub.publish_serialized(serialization.serialize_message(msg))
    assert as_messages.wait_for(4) == messages
    got = as_bytes.wait_for(4)
    assert all(type(cdr) is bytes for cdr in got)
    assert [serialization.deserialize_message(cdr, Odometry) for cdr in got] == messages
    assert sent == messages and sender.stats().published == 4
    assert len(received) == 8 and all(msg in messages for msg in received)
    with pytest.raises(TypeError, match="must be bytes"):
        pub.publish_serialized(bytearray(serialization.serialize_message(messages[0])))  # type: ignore[arg-type]
