"""Recovery from the controller's latch (#16 bug 1; docs/protocol.md, "Latch and faults").

The bridge clears a latch on its own only when the controller says the watchdog alone
set it and the watchdog's condition is gone, never one with an operator's STOP or a
fault in it; an operator's clear refused FAULT_PERSISTS is over, and releases nothing
when the fault's condition goes away (protocol v4; issue #40, hole 2).
Every interleaving the issue lists, against the real emulator:

- the host's frames cut for longer than the watchdog but the controller's heartbeats
  still arriving (an outage the host never sees as a lost link);
- both directions cut for longer than the link-lost threshold (lost, re-handshake);
- the bridge frozen in-process (its state lock held: timer, dispatcher and API all
  stop while the reader keeps reading), then released, so the timer and the dispatcher
  with its backlog of stale heartbeats race for the lock; eight times over;
- the bridge frozen as a process (``rover bridge``, SIGSTOP/SIGCONT);
- FAULT_PERSISTS followed by the fault clearing: the latch holds until a new clear.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from bridge.link.can_transport import CanTransport
from bridge.link.controllerlink import ControllerLink, LinkConfig, LinkState, StepRequest
from bridge.link.serial_transport import SerialTransport
from bridge.link.transport import Transport
from emulator.engine import Emulator, EmulatorStatus
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import Command, Heartbeat

from .conftest import Recorder, link_url, serve

Emus = Callable[..., Emulator]
FWD = Command.FWD
TX_CUT_MEDIA = [pytest.param("pty", id="pty"), pytest.param("virtual", id="virtual")]


class _TxCut:
    """Mixin for a real transport: writes are lost (the host's TX wire cut) while
    :attr:`cut` is set; reading is untouched."""

    cut: threading.Event

    def _write(self, message: Message) -> None:
        if self.cut.is_set():
            return
        super()._write(message)  # type: ignore[misc]


class _SerialTxCut(_TxCut, SerialTransport):
    pass


class _CanTxCut(_TxCut, CanTransport):
    pass


class Watched:
    """A started link on an emulator, with its statuses and controller heartbeats."""

    def __init__(self, emu: Emulator, **config: Any) -> None:
        self.emu = emu
        self.rec = Recorder()
        self.cut = threading.Event()
        self.beats: list[Heartbeat] = []
        self._cond = threading.Condition()

        def factory(url: str) -> Transport:
            transport: Transport
            if url.startswith("can://"):
                transport = _CanTxCut(url)
            else:
                transport = _SerialTxCut(url)
            transport.cut = self.cut
            return transport

        self.link = ControllerLink(
            LinkConfig(link_url(emu), **config),
            on_status=self.rec,
            on_telemetry=self._on_telemetry,
            transport_factory=factory,
        )
        self.link.start()
        self.rec.wait_count("ready", 1)

    def _on_telemetry(self, msg: Message, arrived: float) -> None:
        if isinstance(msg, Heartbeat):
            with self._cond:
                self.beats.append(msg)
                self._cond.notify_all()

    def heartbeats_after(self, n: int, *, timeout: float = 10.0) -> list[Heartbeat]:
        """Wait for ``n`` more controller heartbeats; returns them."""
        with self._cond:
            start = len(self.beats)
            assert self._cond.wait_for(lambda: len(self.beats) >= start + n, timeout)
            return self.beats[start:]

    def emulator_until(self, pred: Callable[[EmulatorStatus], bool], timeout: float = 10.0) -> None:
        deadline = time.monotonic() + timeout
        while not pred(self.emu.status()):
            assert time.monotonic() < deadline, self.emu.status()
            time.sleep(0.01)

    def step_completes(self) -> None:
        mark = self.rec.mark()
        self.link.submit_step(StepRequest(FWD, 30, 1000))
        assert self.rec.wait_count("completed", 1, since=mark) == ["accepted", "completed"]

    def close(self) -> None:
        self.link.close()


@pytest.fixture
def watched(emulators: Emus, can_channel: str) -> Iterator[Callable[..., Watched]]:
    made: list[Watched] = []

    def make(kind: str = "pty", **config: Any) -> Watched:
        w = Watched(serve(emulators, kind, can_channel), **config)
        made.append(w)
        return w

    yield make
    for w in made:
        w.close()


@pytest.mark.parametrize("kind", TX_CUT_MEDIA)
def test_outage_the_host_never_sees_is_cleared_by_the_bridge(
    watched: Callable[..., Watched], kind: str
) -> None:
    w = watched(kind)
    w.link.submit_step(StepRequest(FWD, 60, 30000))
    w.rec.wait_count("accepted", 1)
    mark = w.rec.mark()
    w.cut.set()  # the controller hears nothing; its heartbeats still reach us
    w.rec.wait(lambda xs: "fault:watchdog" in xs and "aborted:watchdog" in xs, since=mark)
    w.cut.clear()
    got = w.rec.wait(lambda xs: "cleared" in xs, since=mark)
    assert "fault:link_lost" not in got and w.link.state is LinkState.READY
    w.emulator_until(lambda s: not s.stop_latched and s.state == "IDLE")
    diag = w.link.diagnostics()
    assert (diag.faults, diag.latch, diag.watchdog_trips) == ((), (), 1)
    w.step_completes()


@pytest.mark.parametrize("kind", TX_CUT_MEDIA)
def test_outage_longer_than_link_lost_is_cleared_after_the_handshake(
    watched: Callable[..., Watched], kind: str
) -> None:
    w = watched(kind)
    w.link.submit_step(StepRequest(FWD, 60, 30000))
    w.rec.wait_count("accepted", 1)
    mark = w.rec.mark()
    w.emu.inject("link-drop=1.0")
    w.rec.wait_count("fault:link_lost", 1, since=mark)
    w.emulator_until(lambda s: s.latch == ("watchdog",))
    w.emu.inject("clear:link-drop")
    w.rec.wait(lambda xs: "ready" in xs and "cleared" in xs, since=mark)
    w.emulator_until(lambda s: not s.stop_latched)
    w.step_completes()


def test_bridge_frozen_in_process_recovers_every_time(watched: Callable[..., Watched]) -> None:
    w = watched("pty")
    for attempt in range(8):
        mark = w.rec.mark()
        with w.link._lock:  # frozen: no heartbeat out, nothing handled, reader reads on
            w.emulator_until(lambda s: s.latch == ("watchdog",))
            # Hold past the link-lost threshold (3.5 heartbeat periods) too.
            time.sleep(0.4)
        w.rec.wait(lambda xs: "cleared" in xs, since=mark)
        w.emulator_until(lambda s: not s.stop_latched and s.state == "IDLE")
        assert w.link.diagnostics().latch == (), attempt
    w.step_completes()
    assert w.link.diagnostics().watchdog_trips == 8


def test_an_operator_stop_is_never_cleared_by_the_bridge(watched: Callable[..., Watched]) -> None:
    w = watched("pty")
    w.link.emergency_stop()
    w.rec.wait_count("stopped", 1)
    mark = w.rec.mark()
    w.cut.set()
    w.rec.wait(lambda xs: "fault:watchdog" in xs, since=mark)
    w.cut.clear()
    w.emulator_until(lambda s: s.latch == ("stop", "watchdog") and s.faults == ())
    w.heartbeats_after(5)  # time for an automatic clear, were there one
    assert "cleared" not in w.rec.since(mark)
    assert w.emu.status().stop_latched
    assert w.link.diagnostics().latch == ("stop", "watchdog")
    w.link.clear_stop()
    w.rec.wait(lambda xs: "cleared" in xs, since=mark)
    w.step_completes()


def test_a_fault_latch_is_left_to_the_operator(watched: Callable[..., Watched]) -> None:
    w = watched("pty")
    w.emu.inject("stall:right")
    mark = w.rec.mark()
    w.link.submit_step(StepRequest(FWD, 30, 23000))
    w.rec.wait(lambda xs: "aborted:stall" in xs and "fault:stall_right" in xs, since=mark)
    w.emu.inject("clear:stall")
    # The stall's condition ends at rest; its latch stays, and the bridge leaves it.
    w.emulator_until(lambda s: s.faults == () and s.latch == ("fault",))
    beats = w.heartbeats_after(5)
    assert beats[-1].latch_fault == 1 and beats[-1].fault_bits == 0
    assert "cleared" not in w.rec.since(mark) and w.emu.status().stop_latched
    diag = w.link.diagnostics()
    assert (diag.faults, diag.latch) == ((), ("fault",))
    w.link.clear_stop()
    w.rec.wait(lambda xs: "cleared" in xs, since=mark)
    w.step_completes()


def test_fault_persists_is_over_and_only_a_new_clear_releases(
    watched: Callable[..., Watched],
) -> None:
    w = watched("pty")
    mark = w.rec.mark()
    w.emu.inject("encoder-dropout:left")
    w.rec.wait_count("fault:encoder", 1, since=mark)
    w.link.clear_stop()
    w.rec.wait_count("fault:fault_persists", 1, since=mark)
    w.heartbeats_after(3)
    assert "cleared" not in w.rec.since(mark)
    assert w.link.diagnostics().faults == ("ENCODER",)
    w.emu.inject("clear:encoder-dropout")
    w.emulator_until(lambda s: s.faults == () and s.latch == ("fault",))
    w.heartbeats_after(5)  # the condition is gone: the refused clear stays refused
    assert "cleared" not in w.rec.since(mark) and w.emu.status().stop_latched
    w.link.clear_stop()
    got = w.rec.wait(lambda xs: "cleared" in xs, since=mark)
    assert got.count("fault:fault_persists") == 1, got  # told once
    w.emulator_until(lambda s: not s.stop_latched)
    assert (w.link.diagnostics().faults, w.link.diagnostics().latch) == ((), ())
    w.step_completes()


# -- the bridge as a process, frozen with SIGSTOP ---------------------------------------


def test_bridge_process_frozen_and_resumed_clears_the_watchdog_latch(
    emulators: Emus, tmp_path: Path
) -> None:
    device = tmp_path / "rover-motor"
    emu = emulators(link=device)
    cmd = [sys.executable, "-m", "firmware_proto.cli", "bridge", "--device", str(device)]
    bridge = subprocess.Popen(
        [*cmd, "--ros-backend", "inprocess"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        w = _Poll(emu)
        w.until(lambda s: s.state == "IDLE", timeout=30.0)  # the bridge's handshake
        for _ in range(3):
            os.kill(bridge.pid, signal.SIGSTOP)
            try:
                w.until(lambda s: s.latch == ("watchdog",))
                time.sleep(0.4)  # frozen past the link-lost threshold as well
            finally:
                os.kill(bridge.pid, signal.SIGCONT)
            w.until(lambda s: not s.stop_latched and s.state == "IDLE")
        assert bridge.poll() is None
    finally:
        bridge.terminate()
        try:
            _, err = bridge.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            bridge.kill()
            _, err = bridge.communicate()
    assert bridge.returncode == 0, err


class _Poll:
    def __init__(self, emu: Emulator) -> None:
        self.emu = emu

    def until(self, pred: Callable[[EmulatorStatus], bool], timeout: float = 10.0) -> None:
        deadline = time.monotonic() + timeout
        while not pred(self.emu.status()):
            assert time.monotonic() < deadline, self.emu.status()
            time.sleep(0.01)
