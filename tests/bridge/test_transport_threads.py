"""The transport's and the link's threads over a real pty, in real time: the reader reads,
the dispatcher dispatches, the receive queue is bounded and drops only sensor samples;
the link's callbacks run on the dispatcher and a STOP is written on the caller's thread.

Only threads show these, so they run in real time; nothing here is timed (every wait is
on an event, with a generous timeout). What the link does on its events (each dropped
step's fate, ``/diagnostics`` on a state change, refusals counted) is checked in virtual
time: tests/bridge/test_link_events.py.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable, Iterator

import pytest

from bridge.link.serial_transport import SerialTransport
from bridge.ros.node import BridgeNode
from bridge.ros.params import load_params
from bridge.ros.rosport import RosPort
from emulator.engine import Emulator
from emulator.serial_frontend import SerialFrontEnd
from firmware_proto.linkio.ptypair import PtyPair
from firmware_proto.runtime.realtime import BRIDGE_PRIORITY
from firmware_proto.wire.framing import FrameEncoder
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import Ack, Encoders, Status
from tests.scheduling import threads_at

from .test_node import Client


def _wait_until(pred: Callable[[], bool], timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not pred():
        if time.monotonic() > deadline:
            pytest.fail(f"condition not met in {timeout} s")
        time.sleep(0.005)


class Received:
    """on_message/on_error of a transport: blocks on the first message until released."""

    def __init__(self) -> None:
        self.messages: list[Message] = []
        self.threads: set[str] = set()
        self.errors: list[tuple[Exception, int]] = []
        self.entered = threading.Event()
        self.release = threading.Event()
        self.failed = threading.Event()

    def on_message(self, message: Message, arrived: float) -> None:
        self.threads.add(threading.current_thread().name)
        self.messages.append(message)
        self.entered.set()
        assert self.release.wait(10.0), "the test never released the dispatcher"

    def on_error(self, exc: Exception) -> None:
        self.threads.add(threading.current_thread().name)
        self.errors.append((exc, len(self.messages)))
        self.failed.set()


def test_reader_queues_dispatcher_delivers_and_only_samples_are_dropped() -> None:
    encoder = FrameEncoder()
    depth, extra = 64, 44
    with PtyPair() as pty:
        transport = SerialTransport(pty.device)
        transport.rx_queue_depth = depth
        got = Received()
        transport.open(got.on_message, got.on_error)
        try:
            os.write(pty.master_fd, encoder.encode(Encoders(0, 0, 0)))
            assert got.entered.wait(10.0)  # the dispatcher holds that one: the queue is empty
            burst = b"".join(encoder.encode(Encoders(i, i, i)) for i in range(1, depth + extra + 1))
            os.write(pty.master_fd, burst)
            _wait_until(lambda: transport.rx_overflow == extra)
            # Not samples: never dropped, even with the queue full (the reader waits).
            os.write(pty.master_fd, encoder.encode(Ack(7, 0, 0, 1)))
            os.write(pty.master_fd, encoder.encode(Status(7, 2, 0, 100)))
            got.release.set()
            _wait_until(lambda: len(got.messages) == 1 + depth + 2)
            pty.close()  # the device goes away: reported after every message before it
            assert got.failed.wait(10.0)
        finally:
            got.release.set()
            transport.close()
    names = [m.NAME for m in got.messages]
    assert names == ["ENCODERS"] * (1 + depth) + ["ACK", "STATUS"]
    # In order: the first `depth` samples of the burst were kept, the rest dropped.
    assert [m.t_ms for m in got.messages[1 : 1 + depth]] == list(  # type: ignore[attr-defined]
        range(1, depth + 1)
    )
    assert transport.rx_overflow == extra
    assert len(got.errors) == 1 and got.errors[0][1] == len(got.messages)
    assert got.threads == {"serial-dispatch"}  # never the reader thread ("serial-rx")


@pytest.fixture
def bridged(
    emulators: Callable[..., Emulator], make_port: Callable[..., RosPort]
) -> Iterator[tuple[BridgeNode, Client]]:
    """An emulator on a pty, the bridge node on it (in-process port, its threads at the
    bridge's real-time priority where permitted, as ``rover bridge``) and a client that
    subscribed first; the link ready."""
    emu = emulators()
    assert isinstance(emu.frontend, SerialFrontEnd)
    client = Client(make_port("inprocess", node_name="executor"))
    params = load_params({"device": emu.frontend.device, "ros_backend": "inprocess"}, env={})
    node = BridgeNode(params, make_port("inprocess", node_name="bridge"))
    try:
        with threads_at(BRIDGE_PRIORITY):
            node.start()
        client.status.wait_count("ready", 1)
        yield node, client
    finally:
        node.close()


def test_link_callbacks_run_on_the_dispatcher_and_writes_on_the_caller(
    bridged: tuple[BridgeNode, Client],
) -> None:
    node, client = bridged
    seen: set[str] = set()
    original = node.link._on_telemetry
    assert original is not None

    def spy(msg: Message, arrived: float) -> None:
        seen.add(threading.current_thread().name)
        original(msg, arrived)

    node.link._on_telemetry = spy
    _wait_until(lambda: bool(seen))
    assert seen == {"serial-dispatch"}
    # STOP goes out on the caller's thread: written before emergency_stop returns.
    before = node.link.last_stop_written
    node.link.emergency_stop()
    assert node.link.last_stop_written is not None and node.link.last_stop_written != before
    client.status.wait_count("stopped", 1)
