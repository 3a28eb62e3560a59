"""The scripted protocol host and what it stands on (firmware_proto/linkio): the waitable
inbox, the wall and lockstep clocks, the in-memory serial line, ``read_ready`` on both
media, and :class:`ProtocolHost` in both ways to run. The controller here is played by
hand on the other end of a real endpoint; the host against the emulator is in
tests/emulator (served, real time) and tests/bridge (the conformance suite, lockstep)."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import can
import pytest

from firmware_proto.linkio.can_endpoint import CanEndpoint
from firmware_proto.linkio.clock import WALL, LockstepClock
from firmware_proto.linkio.endpoint import CONTROLLER, HOST, Endpoint
from firmware_proto.linkio.errors import (
    LinkError,
    LinkUrlError,
    NotReceivedError,
    UnexpectedMessageError,
)
from firmware_proto.linkio.host import ProtocolHost
from firmware_proto.linkio.inbox import Inbox
from firmware_proto.linkio.media import medium_of, open_endpoint
from firmware_proto.linkio.memory import memory_line
from firmware_proto.linkio.serial_endpoint import SerialEndpoint
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import (
    PROTOCOL_VERSION,
    SCHEMA_HASH,
    Heartbeat,
    Hello,
    HostHeartbeat,
    Ident,
    Stop,
    StopAck,
)

IDENT = Ident(PROTOCOL_VERSION, 1, 0, 0, SCHEMA_HASH, 0xBEEF)


def _serial_pair() -> tuple[SerialEndpoint, SerialEndpoint]:
    host_port, controller_port = memory_line("test")
    return (
        SerialEndpoint(HOST, lambda: host_port, name=host_port.name),
        SerialEndpoint(CONTROLLER, lambda: controller_port, name=controller_port.name),
    )


# -- the inbox ------------------------------------------------------------------------


def test_an_inbox_waits_from_a_mark_and_keeps_marks_when_trimmed() -> None:
    inbox: Inbox[int] = Inbox(keep=4)
    for n in range(6):
        inbox.append(n)
    mark = inbox.mark()
    assert mark == 6
    assert inbox.wait(lambda n: n % 2 == 1, since=2, timeout_s=0) == (3, 3)
    assert inbox.wait(lambda n: True, since=mark, timeout_s=0) is None
    for n in range(6, 12):
        inbox.append(n)
    # Twice ``keep`` reached: the oldest four went, positions did not move.
    assert inbox.items(0) == list(range(4, 12))
    assert inbox.indexed(10) == [(10, 10), (11, 11)]
    assert inbox.wait(lambda n: n == 7, since=mark, timeout_s=0) == (7, 7)


def test_an_inbox_wakes_a_waiter_and_raises_its_sources_failure() -> None:
    inbox: Inbox[str] = Inbox()
    threading.Timer(0.05, inbox.append, ("late",)).start()
    assert inbox.wait(lambda s: s == "late", since=0, timeout_s=5.0) == (0, "late")
    threading.Timer(0.05, inbox.fail, (OSError("unplugged"),)).start()
    with pytest.raises(LinkError, match="the link failed: unplugged"):
        inbox.wait(lambda s: False, since=0, timeout_s=5.0)


def test_an_inbox_waits_until_a_condition_on_everything_since_a_mark() -> None:
    clock = LockstepClock(0.001)
    inbox: Inbox[str] = Inbox(clock=clock)
    clock.add(lambda: inbox.append("beat") if clock.ticks % 10 == 0 else None)
    inbox.append("old")
    mark = inbox.mark()
    assert inbox.until(lambda xs: xs.count("beat") >= 3, since=mark, timeout_s=1.0)
    assert clock.ticks == 21 and inbox.items(mark) == ["beat"] * 3
    assert not inbox.until(lambda xs: "never" in xs, since=mark, timeout_s=0.1)
    inbox.fail(OSError("gone"))
    with pytest.raises(LinkError, match="gone"):
        inbox.until(lambda xs: False, since=0, timeout_s=1.0)


# -- clocks ---------------------------------------------------------------------------


def test_a_lockstep_wait_advances_the_world_until_the_condition_or_the_timeout() -> None:
    clock = LockstepClock(0.001)
    ticks: list[int] = []
    clock.add(lambda: ticks.append(clock.ticks))
    inbox: Inbox[int] = Inbox(clock=clock)
    clock.add(lambda: inbox.append(clock.ticks) if clock.ticks == 40 else None)
    assert inbox.wait(lambda n: True, since=0, timeout_s=1.0) == (0, 40)
    assert clock.ticks == 41 and ticks == list(range(41))
    assert inbox.wait(lambda n: n > 40, since=0, timeout_s=0.5) is None
    assert clock.ticks == 541  # exactly the timeout, in ticks
    clock.sleep(0.0104)
    assert clock.ticks == 551 and clock.now() == pytest.approx(0.551)
    with pytest.raises(ValueError, match="a tick must be > 0 s"):
        LockstepClock(0.0)


def test_the_wall_clock_sleeps_and_times_out_in_real_time() -> None:
    inbox: Inbox[int] = Inbox(clock=WALL)
    before = WALL.now()
    assert inbox.wait(lambda n: True, since=0, timeout_s=0.05) is None
    assert WALL.now() > before  # no lower bound asserted: a loaded machine is slow


# -- the in-memory line, read_ready -------------------------------------------------------


def test_a_memory_line_carries_frames_both_ways_through_the_codec() -> None:
    host, controller = _serial_pair()
    host.open()
    controller.open()
    host.write(Hello(PROTOCOL_VERSION, SCHEMA_HASH))
    host.write(HostHeartbeat(7))
    sent: list[tuple[Message, int | None]] = [
        (Hello(PROTOCOL_VERSION, SCHEMA_HASH), 0),
        (HostHeartbeat(7), 1),
    ]
    assert controller.read_ready() == sent
    assert controller.read_ready() == []
    controller.write(IDENT)
    host.write_wire(b"\x00\x03\x41\x42\x00", log=False)  # a run too short to be a frame
    assert host.read_numbered(0.0) == [(IDENT, 0)]
    assert controller.read_ready() == [] and controller.counters.framing == 1
    controller.close()
    assert not host.write(HostHeartbeat(8))  # the line's far end is gone: dropped
    host.close()
    with pytest.raises(OSError, match="closed"):
        host.read(0.0)


def test_read_ready_on_can_reads_past_frames_that_are_not_ours(can_channel: str) -> None:
    host = CanEndpoint(HOST, "virtual", can_channel, node=3)
    controller = CanEndpoint(CONTROLLER, "virtual", can_channel, node=3)
    other = CanEndpoint(CONTROLLER, "virtual", can_channel, node=5)
    for end in (host, controller, other):
        end.open()
    try:
        other.write(StopAck(1, 3, 1))  # node 5: foreign to a host of node 3
        controller.write(StopAck(2, 3, 1))
        other.write(StopAck(3, 3, 1))
        controller.write(StopAck(4, 3, 1))
        assert host.read_ready() == [(StopAck(2, 3, 1), None), (StopAck(4, 3, 1), None)]
        assert host.foreign == 2
    finally:
        for end in (host, controller, other):
            end.close()


@pytest.fixture
def can_channel() -> str:
    return f"host-test-{time.monotonic_ns()}"


# -- media ------------------------------------------------------------------------------


def test_a_url_names_its_medium_and_an_unknown_scheme_is_refused() -> None:
    assert medium_of("can://virtual/x?node=2") == "can"
    assert medium_of("/dev/rover-motor") == medium_of("socket://localhost:7") == "serial"
    with pytest.raises(LinkUrlError, match="unknown link scheme 'warp' in 'warp://x'; known: can"):
        open_endpoint("warp://x", HOST)
    endpoint = open_endpoint("can://virtual/x?node=4", HOST)
    assert isinstance(endpoint, CanEndpoint) and endpoint.node == 4
    assert isinstance(open_endpoint("loop://", CONTROLLER), SerialEndpoint)


# -- the protocol host ------------------------------------------------------------------


class _ScriptedController:
    """Plays a controller on a controller-side endpoint, one lockstep tick at a time:
    IDENT to every HELLO, STOP_ACK to every STOP, a HEARTBEAT every 100 ticks; counts
    the host's heartbeats."""

    def __init__(self, endpoint: Endpoint) -> None:
        self.endpoint = endpoint
        self.beats = 0
        self.ticks = 0

    def tick(self) -> None:
        for message, _ in self.endpoint.read_ready():
            if isinstance(message, Hello):
                self.endpoint.write(IDENT)
            elif isinstance(message, Stop):
                self.endpoint.write(StopAck(message.stop_id, 3, 1))
            elif isinstance(message, HostHeartbeat):
                self.beats += 1
        if self.ticks % 100 == 0:
            self.endpoint.write(Heartbeat(1, 0, 1, 0, 0, 0, 0, 0, 0xBEEF, 0, 0))
        self.ticks += 1


def test_a_lockstep_host_runs_a_script_in_virtual_time() -> None:
    host_end, controller_end = _serial_pair()
    controller_end.open()
    clock = LockstepClock(0.001)
    controller = _ScriptedController(controller_end)
    clock.add(controller.tick)
    with ProtocolHost(host_end, clock=clock) as host:
        assert host.lockstep and host.kind == "serial"
        assert host.handshake() == IDENT
        assert clock.now() == pytest.approx(0.001)  # sent, answered and read in one tick
        mark = host.send(Stop(9, 0))
        assert host.expect(StopAck, lambda a: a.stop_id == 9, since=mark) == StopAck(9, 3, 1)
        with pytest.raises(UnexpectedMessageError, match="unexpected STOP_ACK"):
            host.absent(StopAck, since=mark, window_s=0.1)
        with pytest.raises(NotReceivedError, match=r"expected IDENT again within 0\.5 s"):
            host.expect(Ident, since=host.mark(), timeout_s=0.5, what="IDENT again")
        host.settle(1.0)
        beats = controller.beats
        with host.silent():
            host.settle(1.0)
        assert controller.beats == beats  # quiet for a second
        assert 9 <= beats <= 30  # about one every 100 ms of virtual time
        received = host.inbox.items(0)
        assert [r.seq for r in received[:3]] == [0, 1, 2]  # the controller's frame counter
        assert all(isinstance(r.arrived, float) for r in received)
    assert host.messages(Heartbeat)[0].boot_nonce == 0xBEEF


def test_a_wall_clock_host_reads_and_beats_on_threads_and_stops_them() -> None:
    host_end, controller_end = _serial_pair()
    controller_end.open()
    before = {t.name for t in threading.enumerate()}
    with ProtocolHost(host_end, heartbeat_s=0.01) as host:
        assert {"host-rx", "host-hb"} <= {t.name for t in threading.enumerate()} - before
        mark = host.mark()
        controller_end.write(IDENT)
        assert host.expect(Ident, since=mark, timeout_s=5.0) == IDENT
        got: list[object] = []
        deadline = time.monotonic() + 5.0
        while len(got) < 2 and time.monotonic() < deadline:
            got += controller_end.read(0.05)
        assert got[:2] == [HostHeartbeat(1), HostHeartbeat(2)]
    assert not {t.name for t in threading.enumerate()} - before
    with pytest.raises(LinkError, match="is not open"):
        host.send(HostHeartbeat(1))


def test_a_host_refuses_a_controller_side_endpoint() -> None:
    _, controller_end = _serial_pair()
    with pytest.raises(ValueError, match="host-side endpoint"):
        ProtocolHost(controller_end)


def test_a_host_on_can_sends_no_raw_bytes(can_channel: str) -> None:
    bus = can.Bus(interface="virtual", channel=can_channel)
    try:
        with ProtocolHost(
            CanEndpoint(HOST, "virtual", can_channel, bus=bus), clock=LockstepClock()
        ) as host:
            with pytest.raises(LinkError, match="raw bytes need a serial link"):
                host.write_bytes(b"\x00")
            with pytest.raises(LinkError, match="cannot send RAW id=2 payload=01 bad-crc"):
                host.send_raw(2, b"\x01", bad_crc=True)
    finally:
        bus.shutdown()


def test_a_device_that_is_not_there_says_why_once(tmp_path: Path) -> None:
    """Issue #41: ``cannot open X: [Errno 2] [Errno 2] could not open port X: [Errno 2]
    ...``: pyserial's text already holds the errno, and wrapping it added another."""
    import errno as errno_codes

    from firmware_proto.linkio.serial_endpoint import PyserialPort

    missing = tmp_path / "rover-motor"
    with pytest.raises(OSError, match="No such file") as caught:
        PyserialPort(str(missing), 115200)
    assert caught.value.errno == errno_codes.ENOENT
    assert str(caught.value) == f"[Errno 2] No such file or directory: '{missing}'"
