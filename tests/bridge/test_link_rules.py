"""The host's rules of docs/protocol.md that hang on one ordering of frames, played by a
scripted controller over a real pty (tests/bridge/scripted.py) against the bridge's
``ControllerLink``: an automatic clear that meets a new stopping fault, a FAULT frame
lost, a reboot that restarts the frame counter, sensor samples before a session."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest

from bridge.link.controllerlink import ControllerLink, LinkConfig, LinkDiagnostics, LinkState
from bridge.link.serial_transport import SerialTransport
from bridge.link.transport import Transport
from firmware_proto.wire.faults import fault_bit
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import (
    ClearAck,
    ClearResult,
    ClearStop,
    ControllerState,
    Encoders,
    Fault,
    FaultCode,
    Hello,
    HostHeartbeat,
    Stop,
    StopAck,
)

from .scripted import ScriptedController

FAULT = ControllerState.FAULT
ENCODER_BIT = fault_bit(FaultCode.ENCODER)


class Seen:
    """What the link hands out: statuses and telemetry, in order."""

    def __init__(self) -> None:
        self.statuses: list[str] = []
        self.telemetry: list[Message] = []

    def status(self, text: str) -> None:
        self.statuses.append(text)

    def sample(self, msg: Message, arrived: float) -> None:
        self.telemetry.append(msg)


def wait_until(what: str, pred: Callable[[], bool], timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not pred():
        if time.monotonic() > deadline:
            pytest.fail(f"{what}: not within {timeout_s} s")
        time.sleep(0.005)


@pytest.fixture
def scripted() -> Iterator[tuple[ScriptedController, ControllerLink, Seen]]:
    """A link handshaken with a scripted controller. Its heartbeat period is long (1 s),
    so a test that pauses between two frames never loses the link."""
    with ScriptedController() as ctl:
        seen = Seen()
        link = ControllerLink(
            LinkConfig(ctl.device, controller_heartbeat_s=1.0),
            on_status=seen.status,
            on_telemetry=seen.sample,
        )
        with link:
            ctl.handshake()
            wait_until("ready", lambda: link.state is LinkState.READY)
            yield ctl, link, seen


def settled(ctl: ScriptedController) -> None:
    """Two host heartbeats written after now: whatever the link decided on the frames
    sent before has been written by then (its timer and writer run in order)."""
    mark = ctl.mark()
    ctl.wait_for(HostHeartbeat, since=mark)
    ctl.wait_for(HostHeartbeat, since=ctl.mark())


def diag(link: ControllerLink, **expect: Any) -> Callable[[], bool]:
    def check() -> bool:
        d: LinkDiagnostics = link.diagnostics()
        return all(getattr(d, k) == v for k, v in expect.items())

    return check


def test_an_automatic_clear_never_outlives_a_new_stopping_fault(
    scripted: tuple[ScriptedController, ControllerLink, Seen],
) -> None:
    """docs/protocol.md, "Latch and faults": the watchdog alone holds the latch
    (generation 1), the bridge clears it by itself naming that generation, and a new
    encoder fault crosses that clear (generation 2: answered LATCH_CHANGED): once the
    fault's condition ends, the latch holds the watchdog and the fault, and only the
    operator may release it. An operator's clear answered FAULT_PERSISTS is over: it
    releases nothing later, by itself (issue #40, hole 2); a new one does."""
    ctl, link, seen = scripted
    mark = ctl.mark()
    ctl.send(*ctl.heartbeat(FAULT, watchdog=1, gen=1))  # a trip; frames arrive again
    auto = ctl.wait_for(ClearStop, since=mark)
    assert auto.latch_gen == 1
    ctl.send(
        ClearAck(auto.stop_id, ClearResult.LATCH_CHANGED, 2),
        *ctl.heartbeat(FAULT, watchdog=1, fault=1, fault_bits=ENCODER_BIT, gen=2),
    )
    wait_until("the fault seen", diag(link, faults=("ENCODER",)))
    after = ctl.mark()
    ctl.send(*ctl.heartbeat(FAULT, watchdog=1, fault=1, gen=2))  # the condition ends
    wait_until("the condition gone", diag(link, faults=(), latch=("fault", "watchdog")))
    # Heartbeats as a controller sends them, for three of the link's heartbeat periods
    # (it sends at most one clear request per period): no clear may go out.
    deadline = time.monotonic() + 3 * link.config.controller_heartbeat_s
    while time.monotonic() < deadline and not ctl.messages(ClearStop, after):
        ctl.send(*ctl.heartbeat(FAULT, watchdog=1, fault=1, gen=2))
        time.sleep(0.05)
    settled(ctl)
    assert ctl.messages(ClearStop, after) == []
    assert link.stop_latched
    assert "cleared" not in seen.statuses
    assert "fault:encoder" in seen.statuses  # reported before any clear names it

    # The operator's clear names generation 2; answered FAULT_PERSISTS it is over.
    mark = ctl.mark()
    ctl.send(*ctl.heartbeat(FAULT, watchdog=1, fault=1, fault_bits=ENCODER_BIT, gen=2))
    wait_until("the fault active again", diag(link, faults=("ENCODER",)))
    link.clear_stop()
    first = ctl.wait_for(ClearStop, since=mark)
    assert first.latch_gen == 2
    ctl.send(ClearAck(first.stop_id, ClearResult.FAULT_PERSISTS, 2))
    wait_until("fault_persists said", lambda: "fault:fault_persists" in seen.statuses)
    after = ctl.mark()
    deadline = time.monotonic() + 3 * link.config.controller_heartbeat_s
    while time.monotonic() < deadline and not ctl.messages(ClearStop, after):
        ctl.send(*ctl.heartbeat(FAULT, watchdog=1, fault=1, gen=2))  # condition gone
        time.sleep(0.05)
    settled(ctl)
    assert ctl.messages(ClearStop, after) == []  # no retry of a refused clear
    assert "cleared" not in seen.statuses
    mark = ctl.mark()
    link.clear_stop()
    again = ctl.wait_for(ClearStop, since=mark)
    assert again.stop_id != first.stop_id and again.latch_gen == 2
    ctl.send(ClearAck(again.stop_id, ClearResult.CLEARED, 2))
    wait_until("cleared", lambda: "cleared" in seen.statuses)


def test_an_automatic_clear_ends_when_a_heartbeat_shows_an_emergency_stop(
    scripted: tuple[ScriptedController, ControllerLink, Seen],
) -> None:
    ctl, link, _seen = scripted
    mark = ctl.mark()
    ctl.send(*ctl.heartbeat(FAULT, watchdog=1))
    ctl.wait_for(ClearStop, since=mark)
    # Its answer is lost; meanwhile another host stopped the rover.
    after = ctl.mark()
    ctl.send(*ctl.heartbeat(FAULT, watchdog=1, stop=1))
    wait_until("the latch seen", diag(link, latch=("stop", "watchdog")))
    settled(ctl)
    # The copy being repeated (same id) may still go out once; no new request does.
    assert {c.stop_id for c in ctl.messages(ClearStop, after)} <= {
        c.stop_id for c in ctl.messages(ClearStop, mark)[:1]
    }
    settled(ctl)
    late = ctl.mark()
    settled(ctl)
    assert ctl.messages(ClearStop, late) == []


def test_watchdog_trips_are_counted_from_the_heartbeat_when_the_fault_frame_is_lost(
    scripted: tuple[ScriptedController, ControllerLink, Seen],
) -> None:
    ctl, link, _seen = scripted
    ctl.send(*ctl.heartbeat(FAULT, watchdog=1))  # its FAULT WATCHDOG frame was lost
    wait_until("one trip", diag(link, watchdog_trips=1))
    ctl.send(*ctl.heartbeat(FAULT, watchdog=1))  # the same latch: no new trip
    ctl.send(*ctl.heartbeat(ControllerState.IDLE))  # cleared
    ctl.send(Fault(FaultCode.WATCHDOG, 1, 260, 2), *ctl.heartbeat(FAULT, watchdog=1, gen=2))
    wait_until("two trips", diag(link, watchdog_trips=2))
    ctl.send(*ctl.heartbeat(FAULT, watchdog=1))
    settled(ctl)
    assert link.diagnostics().watchdog_trips == 2  # the FAULT and its latch: one trip


def test_a_reboot_restarting_the_frame_counter_is_no_loss(
    scripted: tuple[ScriptedController, ControllerLink, Seen],
) -> None:
    ctl, link, _seen = scripted
    for _ in range(150):  # the old boot's counter runs on past 150
        ctl.send(Encoders(0, 0, 0))
    ctl.send(*ctl.heartbeat())
    settled(ctl)
    assert link.diagnostics().lost_frames == 0
    ctl.reboot(0x4321)  # its frame counter restarts at 0
    mark = ctl.mark()
    ctl.send(*ctl.heartbeat(ControllerState.BOOT, handshake_ok=0))
    ctl.wait_for(Hello, since=mark)
    ctl.send(ctl.ident(), *ctl.heartbeat())
    wait_until("ready again", lambda: link.state is LinkState.READY)
    ctl.send(*ctl.heartbeat())
    settled(ctl)
    d = link.diagnostics()
    assert (d.reboots, d.lost_frames) == (1, 0)
    # A real loss after the reboot is still counted.
    ctl.send(*ctl.heartbeat())
    ctl._encoder.encode(Encoders(0, 0, 0))  # one frame counted but never written: a loss
    ctl.send(*ctl.heartbeat())
    wait_until("the loss counted", diag(link, lost_frames=1))


def test_samples_outside_a_session_never_reach_odometry(
    scripted: tuple[ScriptedController, ControllerLink, Seen],
) -> None:
    """A reboot whose IDENT is lost: the new boot's first encoder counts (0) must never
    be taken for motion of the old boot. A conforming controller sends no sample before
    a HELLO; the bridge takes samples only in a session whose IDENT it has."""
    ctl, link, seen = scripted
    ctl.send(Encoders(1, 7000, 7000))
    wait_until("a sample", lambda: any(isinstance(m, Encoders) for m in seen.telemetry))
    ctl.reboot(0x7777)
    mark = ctl.mark()
    ctl.send(*ctl.heartbeat(ControllerState.BOOT, handshake_ok=0))  # the IDENT was lost
    ctl.wait_for(Hello, since=mark)
    ctl.send(Encoders(2, 0, 0))  # a controller that breaks the rule sends one anyway
    wait_until("it is counted", diag(link, samples_outside_session=1))
    ctl.send(ctl.ident(), *ctl.heartbeat(), Encoders(3, 10, 10))
    wait_until(
        "the new boot's sample",
        lambda: any(isinstance(m, Encoders) and m.t_ms == 3 for m in seen.telemetry),
    )
    counts = [(m.left, m.t_ms) for m in seen.telemetry if isinstance(m, Encoders)]
    assert counts == [(7000, 1), (10, 3)]


class _ClearSticks(SerialTransport):
    """The real serial transport, its documented write hook holding a CLEAR_STOP until
    released: the moment a clear is on its way out (tests/bridge/test_stop_write_path.py
    holds other frames the same way)."""

    def __init__(self, url: str) -> None:
        super().__init__(url)
        self.entered = threading.Event()
        self.release = threading.Event()

    def _write(self, message: Message) -> None:
        if isinstance(message, ClearStop):
            self.entered.set()
            self.release.wait(10.0)
        super()._write(message)


def test_no_clear_stop_reaches_the_wire_after_a_later_stop() -> None:
    """docs/protocol.md, "Latch and faults": the operator clears, and stops while that
    clear is being written. STOP waits for no other write, so it reaches the controller
    first; the clear follows and would release the new latch (firmware answers at once).
    The host sends STOP once more after the clear: its last word is STOP."""
    made: list[_ClearSticks] = []

    def factory(url: str) -> Transport:
        made.append(_ClearSticks(url))
        return made[-1]

    with ScriptedController() as ctl:
        seen = Seen()
        link = ControllerLink(
            LinkConfig(ctl.device, controller_heartbeat_s=1.0),
            on_status=seen.status,
            transport_factory=factory,
        )
        with link:
            ctl.handshake()
            wait_until("ready", lambda: link.state is LinkState.READY)
            ctl.send(*ctl.heartbeat(ControllerState.STOP_LATCHED, stop=1))
            mark = ctl.mark()
            link.clear_stop()
            transport = made[-1]
            assert transport.entered.wait(10.0)  # the clear is being written
            stop_id = link.emergency_stop()
            ctl.wait_for(Stop, lambda s: s.stop_id == stop_id, since=mark)
            ctl.send(StopAck(stop_id, ControllerState.STOP_LATCHED, 1))  # at once, as firmware
            wait_until("the STOP acknowledged", lambda: "stopped" in seen.statuses)
            transport.release.set()
            ctl.wait_for(ClearStop, since=mark)
            settled(ctl)
            order = [m for m in ctl.received[mark:] if isinstance(m, (Stop, ClearStop))]
            assert isinstance(order[-1], Stop), order
            assert order[-1].stop_id == stop_id
