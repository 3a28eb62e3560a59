"""Link events seen from outside the bridge, end to end over a real pty: every dropped
step's own fate, ``/diagnostics`` published at once on a link state change, refusals
counted on ``/diagnostics``, and the transport's reader/dispatcher split."""

from __future__ import annotations

import functools
import os
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from bridge.link.serial_transport import SerialTransport
from bridge.ros.node import BridgeNode
from bridge.ros.params import load_params
from bridge.ros.rosport import RosPort
from bridge.ros.rosport.msgs import Bool, DiagnosticArray
from emulator.engine import Emulator
from emulator.serial_frontend import SerialFrontEnd
from firmware_proto.linkio.inbox import Inbox
from firmware_proto.linkio.ptypair import PtyPair
from firmware_proto.wire.framing import FrameEncoder
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import Ack, Encoders, Status

from .test_node import Client

Emus = Callable[..., Emulator]

from bridge.ros.diagnostics import ERROR, OK  # noqa: E402


class Diagnostics:
    """``/diagnostics`` as it arrives; waits on a condition, with timeouts."""

    def __init__(self, port: RosPort) -> None:
        self.log: Inbox[DiagnosticArray] = Inbox()
        port.subscribe("/diagnostics", DiagnosticArray, self.log.append)

    def mark(self) -> int:
        return self.log.mark()

    def wait(
        self, pred: Callable[[DiagnosticArray], bool], *, since: int = 0, timeout: float = 15.0
    ) -> DiagnosticArray:
        """The first array at or after ``since`` for which ``pred`` holds."""
        found = self.log.wait(pred, since=since, timeout_s=timeout)
        if found is None:
            pytest.fail(f"no matching /diagnostics in {timeout} s ({self.log.mark()} seen)")
        return found[1]


def values(msg: DiagnosticArray, name: str) -> dict[str, str]:
    """The key/values of the status called ``rover_bridge: <name>``."""
    for status in msg.status:
        if status.name == f"rover_bridge: {name}":
            return {kv.key: kv.value for kv in status.values}
    raise AssertionError(f"no status {name!r} in {[s.name for s in msg.status]}")


def level(msg: DiagnosticArray, name: str) -> bytes:
    return bytes(next(s.level for s in msg.status if s.name == f"rover_bridge: {name}"))


Bridged = tuple[Emulator, BridgeNode, Client, Diagnostics]


@pytest.fixture
def bridge(
    emulators: Emus, make_port: Callable[..., RosPort], tmp_path: Path
) -> Iterator[Callable[..., Bridged]]:
    """``bridge(**params)``: an emulator on a pty (symlinked, so it can be unplugged), a
    bridge node on it (in-process port) and a client that subscribed first."""
    nodes: list[BridgeNode] = []

    def make(**params: Any) -> Bridged:
        emu = emulators(link=tmp_path / "rover-motor")
        assert isinstance(emu.frontend, SerialFrontEnd)
        values = {"device": str(tmp_path / "rover-motor"), "ros_backend": "inprocess", **params}
        client = Client(make_port("inprocess", node_name="executor"))
        diags = Diagnostics(make_port("inprocess", node_name="monitor"))
        node = BridgeNode(load_params(values, env={}), make_port("inprocess", node_name="bridge"))
        nodes.append(node.start())
        client.status.wait_count("ready", 1)
        return emu, node, client, diags

    yield make
    for node in nodes:
        node.close()


# -- 1. every dropped step gets its own fate ----------------------------------------------

STEPS = 9
"""More than the controller holds (8), so one waits in the lane; with the link event that
makes 10 statuses at once, what a keep-last 10 subscription keeps."""


@pytest.mark.parametrize(
    ("cause", "fate", "event"),
    [
        ("silence", "aborted:link_lost", "fault:link_lost"),
        ("unplug", "aborted:link_lost", "fault:link_lost"),
        ("reboot", "aborted:controller_reboot", "fault:controller_reboot"),
    ],
)
def test_every_dropped_step_gets_one_fate_in_order(
    bridge: Callable[..., Bridged], cause: str, fate: str, event: str
) -> None:
    emu, node, client, _ = bridge(reconnect_min_s=0.05, reconnect_max_s=0.2)
    client_port = client.steps.port
    mark = client.status.mark()
    base = node.port.stats().delivered
    for n in range(STEPS):
        # One at a time: a burst could overflow the subscription's keep-last 10.
        client.step(1, 60, 30000)  # ~1.3 m each: none ends during the test
        _wait_until(functools.partial(_delivered, node.port, base + n + 1))
        if n < 8:
            client.status.wait_count("accepted", n + 1, since=mark)
    before = client.status.since(mark)
    assert before == ["accepted"] * 8
    held = node.link.diagnostics()
    assert held.steps_sent == 8 and held.steps_aborted == 0, held
    if cause == "silence":
        emu.inject("link-drop=1.0")
    elif cause == "unplug":
        assert isinstance(emu.frontend, SerialFrontEnd)
        emu.frontend.unplug()
    else:
        emu.inject("reboot")
    got = client.status.wait(lambda xs: event in xs, since=mark)
    after = client.status.since(mark + len(got))
    settled = got[len(before) :]
    # One fate per step, in order (in the controller, in flight, the lane), then the event.
    assert settled == [fate] * STEPS + [event], settled
    assert "completed" not in got
    assert client_port.stats().dropped == 0, (client_port.stats(), client.status.since(mark))
    diag = node.link.diagnostics()
    assert diag.steps_aborted == STEPS
    assert diag.steps_sent == 8  # the lane's step was never sent, and never will be
    # None twice: whatever follows is the link coming back, not a second fate.
    assert fate not in after and "accepted" not in after, after


# -- 2. heartbeat loss: fault:link_lost and /diagnostics ERROR within 3 missed beats -------


def test_heartbeat_loss_publishes_error_diagnostics_at_once(bridge: Callable[..., Bridged]) -> None:
    # 0.1 Hz: the periodic sample is 10 s away, i.e. some 100 heartbeat periods; every
    # sample below comes from a state change.
    emu, node, client, diags = bridge(diagnostics_hz=0.1)
    diags.wait(lambda m: level(m, "link") == OK)  # READY, published on that change
    period_s = node.link.config.controller_heartbeat_s
    assert node.link.config.link_lost_beats == 3
    mark, dmark = client.status.mark(), diags.mark()
    emu.inject("link-drop=1.0")  # the controller runs on; none of its frames arrive
    client.status.wait_count("fault:link_lost", 1, since=mark)
    lost = diags.wait(lambda m: level(m, "link") == ERROR, since=dmark)
    link = values(lost, "link")
    assert link["state"] == "lost"
    # Counted in beats by the link itself, not timed here: declared lost once the third
    # beat was overdue, published before a fifth was due.
    assert 3 <= int(link["lost_after_beats"]) <= 4, link
    assert 3 <= int(link["missed_beats"]) <= 4, link
    assert float(link["heartbeat_age_s"]) >= 3 * period_s
    assert link["heartbeat_losses"] == "1"
    assert level(lost, "controller") == ERROR
    # Back: published as it happens too (changes in quick succession may share a sample).
    dmark = diags.mark()
    emu.inject("clear:link-drop")
    client.status.wait_count("ready", 1, since=mark)
    ready = diags.wait(lambda m: values(m, "link")["state"] == "ready", since=dmark)
    assert level(ready, "link") == OK


# -- 3. refusals counted on /diagnostics ----------------------------------------------------


def test_rejected_steps_are_counted_on_diagnostics(bridge: Callable[..., Bridged]) -> None:
    _emu, node, client, diags = bridge(diagnostics_hz=5.0)
    first = diags.wait(lambda m: True)
    assert values(first, "input")["rejected_total"] == "0"
    assert "rejected_bad_length" not in values(first, "input")
    mark = client.status.mark()
    client.step(1, 30)  # malformed: two values
    client.step(1, 30, 100, 4)  # malformed: four values
    client.status.wait_count("rejected:bad_length", 2, since=mark)
    dmark = diags.mark()
    counted = diags.wait(lambda m: "rejected_bad_length" in values(m, "input"), since=dmark)
    assert values(counted, "input")["rejected_bad_length"] == "2"
    # A refusal by the link (STOP latched) is counted beside the node's own.
    client.estop.publish(Bool(data=True))
    client.status.wait_count("stopped", 1, since=mark)
    client.step(1, 30, 100)
    client.status.wait_count("rejected:stop_latched", 1, since=mark)
    dmark = diags.mark()
    both = values(
        diags.wait(lambda m: "rejected_stop_latched" in values(m, "input"), since=dmark), "input"
    )
    assert (both["rejected_bad_length"], both["rejected_stop_latched"]) == ("2", "1")
    assert both["rejected_total"] == "3"
    assert node.rejected_counts() == {"bad_length": 2}


# -- 4. the reader reads; the dispatcher dispatches; the queue is bounded -------------------


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


def _delivered(port: RosPort, count: int) -> bool:
    return port.stats().delivered >= count


def _wait_until(pred: Callable[[], bool], timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not pred():
        if time.monotonic() > deadline:
            pytest.fail(f"condition not met in {timeout} s")
        time.sleep(0.005)


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


def test_link_callbacks_run_on_the_dispatcher_and_writes_on_the_caller(
    bridge: Callable[..., Bridged],
) -> None:
    _emu, node, client, _ = bridge()
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
