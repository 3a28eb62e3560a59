"""The transports on their own and under the link, on real parts.

Serial: pyserial URLs reach pyserial verbatim but for our ``baud`` (``loop://``,
``socket://`` to a real TCP server on 127.0.0.1, ``spy://`` around the emulator's pty);
a malformed URL is refused once, when the transport is built, and never retried.

CAN: a second python-can bus object on the same channel puts SocketCAN error frames
(linux/can/error.h) on the bus, as a CAN controller's driver does; the transport follows
the bus's fault-confinement state, ``/diagnostics`` warns while it is degraded, and
bus-off is a lost link that reconnects and shakes hands again. On python-can's
``virtual`` bus here, and on ``vcan0`` where the kernel has SocketCAN.
"""

from __future__ import annotations

import logging
import os
import select
import socket
import struct
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator
from typing import Any

import can
import pytest
import serial
from hypothesis import given
from hypothesis import strategies as st

from bridge.errors import TransportError, TransportUrlError
from bridge.link.can_transport import CanTransport
from bridge.link.controllerlink import ControllerLink, LinkConfig, StepRequest
from bridge.link.serial_transport import SerialTransport
from bridge.link.transport import open_transport
from bridge.ros.node import BridgeNode
from bridge.ros.params import load_params
from bridge.ros.rosport import RosPort
from bridge.ros.rosport.msgs import DiagnosticArray, DiagnosticStatus, String
from emulator.engine import Emulator
from emulator.serial_frontend import SerialFrontEnd
from firmware_proto.linkio.can_endpoint import (
    CAN_ERR_BUSOFF,
    CAN_ERR_CRTL,
    CAN_ERR_CRTL_ACTIVE,
    CAN_ERR_CRTL_RX_PASSIVE,
    CAN_ERR_CRTL_RX_WARNING,
    CAN_ERR_CRTL_TX_PASSIVE,
    CAN_ERR_CRTL_TX_WARNING,
    CAN_ERR_FLAG,
    CAN_ERR_RESTARTED,
    decode_error_frame,
)
from firmware_proto.linkio.urls import split_serial_url
from firmware_proto.wire.canmap import encode_can
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import (
    PROTOCOL_VERSION,
    SCHEMA_HASH,
    Command,
    ControllerState,
    Heartbeat,
    Hello,
    HostHeartbeat,
)

from .conftest import (
    CAN_MEDIA,
    Inbox,
    Links,
    Recorder,
    can_channel_for,
    link_url,
    serve,
    vm_slack,
)

Emus = Callable[..., Emulator]
FWD = Command.FWD
CAN_ERR_LOSTARB = 0x002
from bridge.ros.diagnostics import OK, WARN  # noqa: E402

RELAYED = {"ack_timeout_s": 0.2, "motion_retries": 5}
"""Link timing for a line with extra hops (a TCP relay thread, pyserial's spy dump): a
busy machine must not turn their latency into no-ack faults."""


# -- test plumbing: a TCP server on 127.0.0.1 -------------------------------------------


class TcpRelay:
    """A TCP server on 127.0.0.1 that relays one connection at a time to a serial device
    (the emulator's pty), or echoes it back when there is no device. Test plumbing, as a
    ser2net would be on a real bench: every byte goes through real sockets."""

    def __init__(self, device: str | None = None) -> None:
        self._server = socket.create_server(("127.0.0.1", 0))
        self.port: int = self._server.getsockname()[1]
        self._device = serial.Serial(device, timeout=0) if device else None
        self._client: socket.socket | None = None
        self._lock = threading.Lock()
        self.accepted = 0
        self.flaps = 0
        """Connections still to be closed as soon as they are accepted (a flapping line)."""
        self._stop = threading.Event()
        self._reset = threading.Event()
        self._thread = threading.Thread(target=self._run, name="tcp-relay", daemon=True)
        self._thread.start()

    @property
    def url(self) -> str:
        return f"socket://127.0.0.1:{self.port}"

    def drop(self) -> None:
        """End the current connection, as a network cable pulled would."""
        with self._lock:
            if self._client is not None:
                self._client.shutdown(socket.SHUT_RDWR)

    def reset(self) -> None:
        """End the current connection with a TCP reset, as a crashed server would."""
        self._reset.set()

    def _close_client(self) -> None:
        with self._lock:
            client, self._client = self._client, None
        if client is not None:
            client.close()

    def _run(self) -> None:
        while not self._stop.is_set():
            if self._reset.is_set() and self._client is not None:
                self._reset.clear()
                linger = struct.pack("ii", 1, 0)  # close with RST, not FIN
                self._client.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, linger)
                self._close_client()
            watched: list[Any] = [self._server]
            if self._client is not None:
                watched.append(self._client)
            if self._device is not None:
                watched.append(self._device)
            ready, _, _ = select.select(watched, [], [], 0.05)
            for source in ready:
                if source is self._server:
                    conn, _ = self._server.accept()
                    self.accepted += 1
                    if self.flaps > 0:
                        self.flaps -= 1
                        conn.close()
                        continue
                    self._close_client()
                    with self._lock:
                        self._client = conn
                elif source is self._device:
                    data = self._device.read(self._device.in_waiting or 1)
                    self._to_client(data)
                elif source is self._client:
                    try:
                        data = self._client.recv(4096)
                    except OSError:
                        data = b""
                    if not data:
                        self._close_client()
                    elif self._device is not None:
                        self._device.write(data)
                    else:
                        self._to_client(data)

    def _to_client(self, data: bytes) -> None:
        client = self._client
        if client is None or not data:
            return  # nobody connected: bytes are lost, as on a serial line
        try:
            client.sendall(data)
        except OSError:
            self._close_client()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
        self._close_client()
        self._server.close()
        if self._device is not None:
            self._device.close()


@pytest.fixture
def relays() -> Iterator[Callable[[str | None], TcpRelay]]:
    made: list[TcpRelay] = []

    def make(device: str | None = None) -> TcpRelay:
        relay = TcpRelay(device)
        made.append(relay)
        return relay

    yield make
    for relay in made:
        relay.close()


def _lost_then_ready(statuses: list[str]) -> bool:
    """The link was reported lost, then shook hands again."""
    return (
        "fault:link_lost" in statuses and "ready" in statuses[statuses.index("fault:link_lost") :]
    )


def _drive_after_outage(link: ControllerLink, rec: Recorder, step: StepRequest) -> None:
    """Run one step after the link came back. If the controller's watchdog stopped the
    rover during the outage, the step is refused until the link has cleared that latch
    (``cleared``); then it is sent again. Either way it completes exactly once."""
    mark = rec.mark()
    link.submit_step(step)
    got = rec.wait(lambda xs: "completed" in xs or any("rejected" in x for x in xs), since=mark)
    if "completed" in got:
        assert got == ["accepted", "completed"]
        return
    # The refusal, perhaps with the ``cleared`` that followed it in the same wake-up.
    refusals = [x for x in got if x.startswith("rejected:")]
    assert refusals in (["rejected:fault_active"], ["rejected:stop_latched"]), got
    rec.wait(lambda xs: "cleared" in xs, since=mark)
    mark = rec.mark()
    link.submit_step(step)
    assert rec.wait_count("completed", 1, since=mark) == ["accepted", "completed"]


def _pty(emu: Emulator) -> str:
    assert isinstance(emu.frontend, SerialFrontEnd)
    return emu.frontend.device


# -- serial URLs ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("url", "device", "baud"),
    [
        ("loop://", "loop://", 115200),
        ("loop://?baud=9600", "loop://", 9600),
        ("loop://?logging=debug&baud=9600", "loop://?logging=debug", 9600),
        ("spy:///dev/pts/3", "spy:///dev/pts/3", 115200),
        ("spy:///dev/pts/3?baud=57600&raw", "spy:///dev/pts/3?raw", 57600),
        ("socket://127.0.0.1:7000", "socket://127.0.0.1:7000", 115200),
        ("socket://[::1]:7000?baud=1", "socket://[::1]:7000", 1),
        (
            "rfc2217://bench:2217?poll_modem&timeout=3",
            "rfc2217://bench:2217?poll_modem&timeout=3",
            115200,
        ),
        ("/dev/ttyACM0", "/dev/ttyACM0", 115200),
        ("/dev/serial/by-id/usb-rover?baud=460800", "/dev/serial/by-id/usb-rover", 460800),
    ],
)
def test_serial_urls_reach_pyserial_verbatim_but_for_baud(url: str, device: str, baud: int) -> None:
    assert split_serial_url(url)[:2] == (device, baud)
    transport = open_transport(url)
    assert isinstance(transport, SerialTransport)
    assert (transport.device, transport.baud) == (device, baud)
    assert SerialTransport(url, baud=19200).baud == 19200  # the argument wins


BAD_URLS = [
    ("socket://localhost", "socket:// needs HOST:PORT"),
    ("socket://127.0.0.1:99999", "socket:// needs HOST:PORT"),
    ("socket://:7000", "socket:// needs HOST:PORT"),
    ("rfc2217://bench", "rfc2217:// needs HOST:PORT"),
    ("loop://?speed=9", "loop:// takes no option 'speed'"),
    ("spy://", "no device path"),
    ("/dev/ttyACM0?baud=fast", "baud must be a positive integer"),
    ("/dev/ttyACM0?baud=0", "baud must be a positive integer"),
    ("/dev/ttyACM0?parity=E", "a device path takes no option 'parity'"),
    ("warp://x", "unknown link scheme 'warp'"),
    ("can://virtual", "CAN URL must be can://INTERFACE/CHANNEL"),
    ("can://virtual/bus?node=16", "CAN node id must be 1..15"),
    ("can://virtual/bus?node=two", "CAN node id must be 1..15"),
    ("can://nosuchbus/bus", "unknown python-can interface 'nosuchbus'"),
]


@pytest.mark.parametrize(("url", "words"), BAD_URLS)
def test_a_malformed_url_is_refused_once_not_retried(url: str, words: str) -> None:
    with pytest.raises(TransportUrlError, match=words) as info:
        open_transport(url)
    # Callers that catch the broad classes still catch it.
    assert isinstance(info.value, TransportError) and isinstance(info.value, ValueError)
    statuses: list[str] = []
    with pytest.raises(TransportUrlError, match=words):
        ControllerLink(LinkConfig(url), on_status=statuses.append)
    assert statuses == []


def test_rover_bridge_exits_at_once_on_a_malformed_url() -> None:
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "firmware_proto.cli",
            "bridge",
            "--device",
            "socket://localhost",
            "--ros-backend",
            "inprocess",
        ],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert proc.returncode == 2, proc.stderr  # a usage error, as any bad parameter
    assert "socket:// needs HOST:PORT" in proc.stderr
    assert "BRIDGE" not in proc.stdout


def test_loop_url_opens_and_round_trips_frames() -> None:
    got, errors = Inbox(), Inbox()
    sent: list[Message] = [Hello(PROTOCOL_VERSION, SCHEMA_HASH), HostHeartbeat(7), HostHeartbeat(8)]
    with open_transport("loop://?baud=9600") as transport:
        transport.open(lambda msg, _t: got(msg), errors)
        for msg in sent:
            transport.send(msg)
        assert got.wait_for(3) == sent
        assert transport.tx_frames == 3 and transport.counters.frames == 3
    assert errors.items == []


def test_socket_url_round_trips_frames_and_reports_a_dropped_connection(
    relays: Callable[[str | None], TcpRelay],
) -> None:
    relay = relays(None)  # an echo server
    got, errors = Inbox(), Inbox()
    sent: list[Message] = [Hello(PROTOCOL_VERSION, SCHEMA_HASH), HostHeartbeat(1)]
    with open_transport(relay.url) as transport:
        transport.open(lambda msg, _t: got(msg), errors)
        for msg in sent:
            transport.send(msg)
        assert got.wait_for(2) == sent
        relay.drop()
        (exc,) = errors.wait_for(1)
    assert isinstance(exc, OSError) and "disconnected" in str(exc)


def test_a_reset_connection_is_reported_and_its_socket_closed(
    relays: Callable[[str | None], TcpRelay],
) -> None:
    relay = relays(None)
    got, errors = Inbox(), Inbox()
    fds_before = set(os.listdir("/proc/self/fd"))
    transport = open_transport(relay.url)
    transport.open(lambda msg, _t: got(msg), errors)
    transport.send(HostHeartbeat(1))
    got.wait_for(1)
    relay.reset()
    (exc,) = errors.wait_for(1)
    assert "reset" in str(exc)
    transport.close()
    # pyserial leaves a reset socket open on close; the transport closes it itself.
    assert set(os.listdir("/proc/self/fd")) <= fds_before


def test_a_refused_connection_is_retryable(relays: Callable[[str | None], TcpRelay]) -> None:
    relay = relays(None)
    url = relay.url
    relay.close()  # nothing listens on that port any more
    transport = open_transport(url)  # well formed: built without complaint
    with pytest.raises(TransportError, match="refused") as info:
        transport.open(lambda _m, _t: None, lambda _e: None)
    assert not isinstance(info.value, TransportUrlError)


def test_link_drives_the_emulator_over_socket_url_and_reconnects(
    emulators: Emus, relays: Callable[[str | None], TcpRelay], links: Links
) -> None:
    emu = emulators()
    relay = relays(_pty(emu))
    link, rec = links(relay.url, reconnect_min_s=0.05, **RELAYED)
    rec.wait_count("ready", 1)
    link.submit_step(StepRequest(FWD, 60, 2300))
    assert rec.wait_count("completed", 1) == ["ready", "accepted", "completed"]
    link.submit_step(StepRequest(FWD, 60, 30000))
    rec.wait_count("accepted", 2)
    mark = rec.mark()
    relay.drop()
    got = rec.wait(_lost_then_ready, since=mark)
    assert "completed" not in got  # the step in flight was dropped, not replayed
    assert relay.accepted == 2
    diag = link.diagnostics()
    assert diag.reconnects == 1 and "disconnected" in diag.last_error
    _drive_after_outage(link, rec, StepRequest(FWD, 60, 2300))


def _reconnect_delays(caplog: pytest.LogCaptureFixture) -> list[float]:
    """The delays the link announced before each reconnect attempt, s, in order."""
    return [
        float(r.args[-1])  # type: ignore[index, arg-type]
        for r in caplog.records
        if r.name.startswith("bridge.link.") and ("retry in" in r.msg or "reconnecting in" in r.msg)
    ]


def test_reconnect_backoff_grows_while_the_line_flaps_and_a_handshake_resets_it(
    emulators: Emus,
    relays: Callable[[str | None], TcpRelay],
    links: Links,
    caplog: pytest.LogCaptureFixture,
) -> None:
    """A line that opens and fails at once (a flapping ser2net, a CAN bus going bus-off
    again and again) is retried with the same doubling backoff as one that cannot be
    opened, not every ``reconnect_min_s``; a completed handshake resets it."""
    caplog.set_level(logging.INFO, logger="bridge.link.linkcore")
    emu = emulators()
    relay = relays(_pty(emu))
    relay.flaps = 4
    link, rec = links(relay.url, reconnect_min_s=0.1, reconnect_max_s=0.4, **RELAYED)
    rec.wait_count("ready", 1)
    assert relay.accepted == 5
    assert _reconnect_delays(caplog) == [0.1, 0.2, 0.4, 0.4]
    caplog.clear()
    mark = rec.mark()
    relay.drop()
    rec.wait(_lost_then_ready, since=mark)
    assert _reconnect_delays(caplog) == [0.1]  # the handshake reset it
    link.submit_step(StepRequest(FWD, 60, 2300))
    rec.wait(lambda xs: "completed" in xs or any("rejected" in x for x in xs), since=mark)


class _OpensAfterItsReaderFailed(SerialTransport):
    """A real serial transport whose ``open`` returns only once its reader has reported
    a failure: the moment a line that dies at once gives the link, made certain."""

    def open(
        self, on_message: Callable[[Message, float], None], on_error: Any, *, threads: bool = True
    ) -> None:
        reported = threading.Event()

        def report(exc: Exception) -> None:
            on_error(exc)
            reported.set()

        super().open(on_message, report, threads=threads)
        assert reported.wait(10.0), "the reader did not fail"


def test_a_failure_reported_while_the_transport_opens_is_not_lost(
    emulators: Emus,
    relays: Callable[[str | None], TcpRelay],
    caplog: pytest.LogCaptureFixture,
) -> None:
    """The reader may fail before ``open`` returns; the link handles that failure (and
    reconnects) instead of keeping a dead transport until a write fails."""
    caplog.set_level(logging.INFO, logger="bridge.link.linkcore")
    emu = emulators()
    relay = relays(_pty(emu))
    relay.flaps = 1
    rec = Recorder()
    made: list[str] = []

    def factory(url: str) -> SerialTransport:
        made.append(url)
        return _OpensAfterItsReaderFailed(url) if len(made) <= 2 else SerialTransport(url)

    link = ControllerLink(
        LinkConfig(relay.url, reconnect_min_s=0.05, **RELAYED),  # type: ignore[arg-type]
        on_status=rec,
        transport_factory=factory,
    )
    with link:
        rec.wait_count("ready", 1)
    failures = [
        r.getMessage()
        for r in caplog.records
        if r.name.startswith("bridge.link.") and "reconnecting in" in r.msg
    ]
    assert len(failures) == 1 and "disconnected" in failures[0], failures


def test_spy_url_wraps_the_emulator_pty(
    capfd: pytest.CaptureFixture[str], emulators: Emus, links: Links
) -> None:
    emu = emulators()
    url = f"spy://{_pty(emu)}"
    assert url.startswith("spy:///dev/")
    link, rec = links(url, **RELAYED)
    rec.wait_count("ready", 1)
    link.submit_step(StepRequest(FWD, 60, 2300))
    rec.wait_count("completed", 1)
    link.close()
    dump = capfd.readouterr().err  # pyserial's spy writes a hexdump of the traffic
    assert " TX " in dump and " RX " in dump


# -- CAN error frames ----------------------------------------------------------------------


@pytest.mark.parametrize(
    ("classes", "data", "state"),
    [
        (CAN_ERR_CRTL, [0, CAN_ERR_CRTL_RX_WARNING], "error_warning"),
        (CAN_ERR_FLAG | CAN_ERR_CRTL, [0, CAN_ERR_CRTL_TX_WARNING], "error_warning"),
        (CAN_ERR_CRTL, [0, CAN_ERR_CRTL_RX_PASSIVE], "error_passive"),
        (CAN_ERR_CRTL, [0, CAN_ERR_CRTL_TX_PASSIVE | CAN_ERR_CRTL_RX_WARNING], "error_passive"),
        (CAN_ERR_CRTL, [0, CAN_ERR_CRTL_ACTIVE], "error_active"),
        (CAN_ERR_CRTL, [0, 0x01], None),  # RX overflow: no state
        (CAN_ERR_CRTL, [], None),  # too short to say
        (CAN_ERR_BUSOFF, [], "bus_off"),
        (CAN_ERR_BUSOFF | CAN_ERR_RESTARTED, [], "bus_off"),
        (CAN_ERR_RESTARTED, [], "error_active"),
        (CAN_ERR_LOSTARB, [3], None),
        (0x080, [0] * 8, None),  # bus error
    ],
)
def test_decode_error_frame(classes: int, data: list[int], state: str | None) -> None:
    report = decode_error_frame(classes, bytes(data))
    assert report.state == state
    assert report.classes == classes & ~CAN_ERR_FLAG


@given(st.integers(0, 0x3FFFFFFF), st.binary(max_size=8))
def test_decode_error_frame_never_raises(arbitration_id: int, data: bytes) -> None:
    decode_error_frame(arbitration_id, data)


def _error_frame(classes: int, *data: int) -> can.Message:
    return can.Message(
        arbitration_id=classes,
        data=bytes(data).ljust(8, b"\0"),
        is_error_frame=True,
        is_extended_id=False,
    )


def _heartbeat_frame(node: int) -> can.Message:
    arbitration_id, data = encode_can(
        Heartbeat(
            state=ControllerState.IDLE,
            stop_latched=0,
            handshake_ok=1,
            latch_stop=0,
            latch_watchdog=0,
            latch_fault=0,
            fault_bits=0,
            queue_depth=0,
            boot_nonce=0x1234,
            rx_errors=0,
            latch_gen=0,
        ),
        node,
    )
    return can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=False)


@pytest.mark.parametrize("kind", CAN_MEDIA)
def test_can_transport_follows_the_bus_state_and_bus_off_is_a_transport_error(
    kind: str, can_channel: str, caplog: pytest.LogCaptureFixture
) -> None:
    channel = can_channel_for(kind, can_channel)
    got, errors = Inbox(), Inbox()
    transport = CanTransport(f"can://{kind}/{channel}?node=2")
    caplog.set_level(logging.INFO, logger="firmware_proto.linkio.can_endpoint")
    with can.Bus(interface=kind, channel=channel) as peer, transport:
        transport.open(lambda msg, _t: got(msg), errors)

        def report(classes: int, *data: int) -> None:
            """One error frame, then a heartbeat behind it: once the heartbeat is in, the
            error frame was handled (a bus delivers in order)."""
            mark = got.mark()
            peer.send(_error_frame(classes, *data))
            peer.send(_heartbeat_frame(2))
            got.wait_for(mark + 1)

        assert transport.medium_state == "error_active"
        report(CAN_ERR_CRTL, 0, CAN_ERR_CRTL_RX_WARNING)
        assert transport.medium_state == "error_warning"
        report(CAN_ERR_CRTL, 0, CAN_ERR_CRTL_TX_WARNING)  # still warning: no new transition
        report(CAN_ERR_CRTL, 0, CAN_ERR_CRTL_TX_PASSIVE)
        assert transport.medium_state == "error_passive"
        report(CAN_ERR_LOSTARB, 5)  # counted, says nothing of the state
        assert transport.medium_state == "error_passive"
        report(CAN_ERR_CRTL, 0, CAN_ERR_CRTL_ACTIVE)
        assert transport.medium_state == "error_active"
        assert transport.error_frames == transport.medium_errors == 5
        assert transport.state_changes == {
            "error_active": 1,
            "error_warning": 1,
            "error_passive": 1,
            "bus_off": 0,
        }
        assert errors.items == []
        peer.send(_error_frame(CAN_ERR_BUSOFF))
        (exc,) = errors.wait_for(1)
        assert isinstance(exc, OSError) and "bus off" in str(exc)
        assert transport.medium_state == "bus_off"
    transitions = [
        (r.levelname, r.getMessage().split(": ", 1)[1])
        for r in caplog.records
        if r.name == "firmware_proto.linkio.can_endpoint" and "->" in r.getMessage()
    ]
    assert [(level, text.split(" (")[0]) for level, text in transitions] == [
        ("WARNING", "error_active -> error_warning"),
        ("WARNING", "error_warning -> error_passive"),
        ("INFO", "error_passive -> error_active"),
        ("ERROR", "error_active -> bus_off"),
    ]


def _value(status: DiagnosticStatus, key: str) -> str:
    return str(next(kv.value for kv in status.values if kv.key == key))


@pytest.mark.parametrize("kind", CAN_MEDIA)
def test_error_passive_warns_in_diagnostics_and_the_link_stays_up(
    emulators: Emus, make_port: Callable[..., RosPort], kind: str, can_channel: str
) -> None:
    emu = serve(emulators, kind, can_channel, node=2)
    channel = can_channel_for(kind, can_channel)
    params = load_params(
        vm_slack(
            {
                "can_interface": kind,
                "can_channel": channel,
                "node_id": 2,
                "ros_backend": "inprocess",
                "diagnostics_hz": 20.0,
            }
        ),
        env={},
    )
    status, diagnostics = Recorder(), Inbox()
    client = make_port("inprocess", node_name="executor")
    client.subscribe("command_status", String, lambda m: status(m.data))
    client.subscribe("/diagnostics", DiagnosticArray, diagnostics)

    def link_status(since: int, state: str) -> DiagnosticStatus:
        # A diagnostics array sampled while the link was still handshaking can arrive
        # after "ready" (the timer's snapshot races the status): wait for a ready one.
        array = diagnostics.wait_until(
            lambda a: (
                _value(a.status[0], "medium_state") == state
                and a.status[0].message.startswith("ready")
            ),
            since=since,
        )
        link: DiagnosticStatus = array.status[0]
        return link

    with (
        can.Bus(interface=kind, channel=channel) as peer,
        BridgeNode(params, make_port("inprocess", node_name="rover_bridge")),
    ):
        status.wait_count("ready", 1)
        assert link_status(diagnostics.mark(), "error_active").level == OK
        peer.send(_error_frame(CAN_ERR_CRTL, 0, CAN_ERR_CRTL_RX_PASSIVE))
        link = link_status(diagnostics.mark(), "error_passive")
        assert (link.level, link.message) == (WARN, "ready; bus error_passive")
        assert _value(link, "medium_errors") == "1"
        peer.send(_error_frame(CAN_ERR_CRTL, 0, CAN_ERR_CRTL_ACTIVE))
        link = link_status(diagnostics.mark(), "error_active")
        assert (link.level, _value(link, "medium_errors")) == (OK, "2")
        assert status.items == ["ready"]  # degraded, never lost
    assert emu.status().x_m == 0.0


@pytest.mark.parametrize("kind", CAN_MEDIA)
def test_bus_off_is_a_lost_link_then_a_new_handshake(
    emulators: Emus, links: Links, kind: str, can_channel: str
) -> None:
    emu = serve(emulators, kind, can_channel)
    link, rec = links(link_url(emu), reconnect_min_s=0.05)
    rec.wait_count("ready", 1)
    link.submit_step(StepRequest(FWD, 60, 30000))
    rec.wait_count("accepted", 1)
    mark = rec.mark()
    with can.Bus(interface=kind, channel=can_channel_for(kind, can_channel)) as peer:
        peer.send(_error_frame(CAN_ERR_BUSOFF))
    got = rec.wait(_lost_then_ready, since=mark)
    assert "completed" not in got  # the step in flight was dropped, not replayed
    diag = link.diagnostics()
    assert diag.reconnects == 1 and "bus off" in diag.last_error
    assert diag.medium_state == "error_active"  # a new connection, a new bus
    x_before = emu.status().x_m
    _drive_after_outage(link, rec, StepRequest(FWD, 60, 2300))
    # Only the new step ran: a replay of the old one would add more than a metre.
    assert emu.status().x_m == pytest.approx(x_before + 0.1, abs=0.05)
