"""STOP never waits behind another write of ours (#15; bridge/link/controllerlink.py, Threads;
bridge/link/transport.py, Writes).

A write can stick in the OS for the serial write timeout (1 s): a full output buffer, a
stalled USB-serial adapter, hardware flow control. Before, the link wrote HELLO, host
heartbeats and MOTION with its state lock held and STOP needed that lock, so a STOP
requested meanwhile reached the device behind them (875 ms after the call in the
issue's trial). Here the link runs against the real emulator over a real pty, a
python-can ``virtual`` bus and SocketCAN; its transport is the real one, subclassed only
so that a HELLO or HOST_HEARTBEAT write sticks until the test lets it go, as a write to
a full buffer would, and so that every write's start and end is noted in order.

Every check is on events, none on time: STOP's write ended, and the controller
acknowledged it, while the stuck write was still in progress.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from functools import partial

import pytest

from bridge.link.can_transport import CanTransport
from bridge.link.controllerlink import ControllerLink, LinkState, StepRequest
from bridge.link.serial_transport import SerialTransport
from bridge.link.transport import Transport
from emulator.engine import Emulator
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import Command, Hello, HostHeartbeat, Motion, Stop

from .conftest import MEDIA, Recorder, link_url, serve, start_link, vm_slack, wait_emulator

STUCK_LIMIT_S = 20.0
"""A stuck write lets go by itself after this long, so that a failing test ends."""


class _Sticky:
    """Notes every write; with :attr:`stick` set, a HELLO or HOST_HEARTBEAT write
    sticks (``entered`` set) until :attr:`release` is set (then ``left`` is set)."""

    def __init__(self, url: str) -> None:
        super().__init__(url)  # type: ignore[call-arg]
        self.stick = threading.Event()
        self.release = threading.Event()
        self.entered = threading.Event()
        self.left = threading.Event()
        """Set when a stuck write has ended."""
        self.writes: list[tuple[str, Message, str]] = []
        """(``begin``/``end``, message, thread name), in order."""
        self._note_lock = threading.Lock()

    def _note(self, what: str, message: Message) -> None:
        with self._note_lock:
            self.writes.append((what, message, threading.current_thread().name))

    def _write(self, message: Message) -> None:
        self._note("begin", message)
        stuck = self.stick.is_set() and isinstance(message, (Hello, HostHeartbeat))
        if stuck:
            self.entered.set()
            self.release.wait(STUCK_LIMIT_S)
        super()._write(message)  # type: ignore[misc]
        self._note("end", message)
        if stuck:
            self.left.set()

    def ended(self, name: str) -> bool:
        with self._note_lock:
            return ("end", name) in [(w, m.NAME) for w, m, _ in self.writes]


class StickySerial(_Sticky, SerialTransport):
    pass


class StickyCan(_Sticky, CanTransport):
    pass


Sticky = StickySerial | StickyCan


def _link(
    emu: Emulator, *, stick_from_start: bool, **config: float
) -> tuple[ControllerLink, Recorder, list[Sticky]]:
    made: list[Sticky] = []

    def factory(url: str) -> Transport:
        transport: Sticky = StickyCan(url) if url.startswith("can://") else StickySerial(url)
        if stick_from_start:
            transport.stick.set()
        made.append(transport)
        return transport

    link, rec = start_link(link_url(emu), transport_factory=factory, **vm_slack(config))
    return link, rec, made


def _stuck(made: list[Sticky]) -> Sticky:
    """The transport whose write is stuck (the link builds one to check its URL, then
    one per connection), waiting for it at most 10 s."""
    for _ in range(1000):
        for transport in made:
            if transport.entered.is_set():
                return transport
        threading.Event().wait(0.01)
    pytest.fail(f"no write stuck in 10 s; writes: {[t.writes for t in made]}")


def _motion_seqs(transport: Sticky) -> set[int]:
    """The sequence numbers of the MOTION frames whose write began."""
    with transport._note_lock:
        return {m.seq for w, m, _ in transport.writes if w == "begin" and isinstance(m, Motion)}


@pytest.mark.parametrize("kind", MEDIA)
def test_stop_passes_a_heartbeat_write_stuck_in_the_os(
    emulators: Callable[..., Emulator], can_channel: str, kind: str
) -> None:
    emu = serve(emulators, kind, can_channel)
    link, rec, made = _link(emu, stick_from_start=False)
    try:
        rec.wait_count("ready", 1)
        transport = made[-1]
        link.submit_step(StepRequest(Command.FWD, 60, 30000))
        rec.wait_count("accepted", 1)
        transport.stick.set()
        assert transport.entered.wait(10.0), "no heartbeat write within 10 s"
        # The writer thread is now inside a stuck HOST_HEARTBEAT write; a second step
        # queues behind it.
        link.submit_step(StepRequest(Command.FWD, 60, 30000))
        link.emergency_stop()
        stop_written = transport.ended("STOP")
        # The controller acknowledges the STOP (a real STOP_ACK back through the medium)
        # while the heartbeat write is still stuck.
        rec.wait_count("stopped", 1)
        still_stuck = not transport.left.is_set()
        status = wait_emulator(emu, lambda s: s.stop_latched, "STOP latched")
        transport.release.set()
        # Both steps end by the STOP: the one in the controller (its STATUS) and the one
        # that was queued (purged by the link).
        rec.wait_count("aborted:stop", 2)
        # The link carries on: the latch clears and a new step runs.
        transport.stick.clear()
        link.clear_stop()
        rec.wait_count("cleared", 1)
        mark = rec.mark()
        link.submit_step(StepRequest(Command.FWD, 60, 500))
        rec.wait_count("completed", 1, since=mark)
        motions = _motion_seqs(transport)
        stops = [(w, thread) for w, m, thread in transport.writes if isinstance(m, Stop)]
    finally:
        for made_one in made:
            made_one.release.set()
        link.close()
    assert stop_written, "emergency_stop() returned before its STOP was written"
    assert still_stuck, "the STOP was acknowledged only after the stuck write ended"
    assert status.stop_latched and "stop" in status.latch
    # STOP went out on the caller's thread while the writer thread was stuck.
    assert stops[0] == ("begin", "MainThread"), stops
    # The second step (seq 2) never reached the wire: queued behind the stuck write, its
    # MOTION was dropped with it when STOP purged the lane. Seq 1 before, seq 3 after.
    assert motions == {1, 3}, transport.writes


@pytest.mark.parametrize("kind", MEDIA)
def test_stop_passes_a_hello_stuck_in_the_handshake(
    emulators: Callable[..., Emulator], can_channel: str, kind: str
) -> None:
    emu = serve(emulators, kind, can_channel)
    link, rec, made = _link(emu, stick_from_start=True)
    try:
        # Connected, handshaking: the first HELLO is stuck in the writer thread.
        transport = _stuck(made)
        assert link.state is LinkState.HANDSHAKE
        link.emergency_stop()
        rec.wait_count("stopped", 1)
        before_release = not transport.left.is_set()
        status = wait_emulator(emu, lambda s: s.stop_latched, "STOP latched")
        transport.stick.clear()
        transport.release.set()
        rec.wait_count("ready", 1)
        latched = link.stop_latched
    finally:
        for made_one in made:
            made_one.release.set()
        link.close()
    assert before_release, "the STOP was acknowledged only after the stuck HELLO ended"
    assert "stop" in status.latch
    assert latched


@pytest.mark.parametrize("kind", MEDIA[:2])
def test_a_motion_behind_a_stuck_write_keeps_its_retries(
    emulators: Callable[..., Emulator], can_channel: str, kind: str
) -> None:
    """A MOTION's ACK timeout runs from when it was written: queued behind a stuck write
    for many times its timeout and retries, it is not declared unacknowledged
    (``fault:no_ack``, link lost); once the line moves it runs."""
    emu = serve(emulators, kind, can_channel)
    # Our frames stop while the write is stuck: the controller's watchdog must outlast it.
    emu.call(partial(setattr, emu.model, "watchdog_ms", 10000))
    link, rec, made = _link(emu, stick_from_start=False, ack_timeout_s=0.02, motion_retries=1)
    try:
        rec.wait_count("ready", 1)
        transport = made[-1]
        transport.stick.set()
        assert transport.entered.wait(10.0), "no heartbeat write within 10 s"
        mark = rec.mark()
        link.submit_step(StepRequest(Command.FWD, 60, 500))
        # Stuck for 15 times what the MOTION's two tries would take (a bounded wait: a
        # slower machine only makes this test weaker, never failing).
        transport.release.wait(0.6)
        transport.stick.clear()
        transport.release.set()
        got = rec.wait(lambda xs: "completed" in xs or "fault:no_ack" in xs, since=mark)
    finally:
        for made_one in made:
            made_one.release.set()
        link.close()
    assert got == ["accepted", "completed"], got
