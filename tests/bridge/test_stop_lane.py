"""The STOP lane's repeats on the wire (docs/protocol.md, "STOP semantics"): the first
copy goes out at once on the caller's thread, each repeat at least ``stop_repeat_s``
after the previous copy, and ``stop_repeats`` counts exactly the copies after the first.

The link runs against the real emulator over a real pty; its transport is the real
serial transport, subclassed only to note every STOP it writes (time and thread) and,
where a test needs it, to hold the caller's first write the way a slow serial write
would, so that the link's timer thread gets to run meanwhile.
"""

from __future__ import annotations

import itertools
import threading
import time
from collections.abc import Callable

from bridge.link.controllerlink import ControllerLink
from bridge.link.serial_transport import SerialTransport
from bridge.link.transport import Transport
from emulator.engine import Emulator
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import Stop

from .conftest import Recorder, link_url, start_link

Emus = Callable[..., Emulator]


class NotingTransport(SerialTransport):
    """The serial transport, noting each STOP written: ``(monotonic time, thread)``.

    With :attr:`hold_first` set, the first STOP written on a thread other than the link's
    timer is held until another STOP is written or ``hold_s`` passes (a slow write).
    """

    def __init__(self, url: str) -> None:
        super().__init__(url)
        self.stops: list[tuple[float, str, int]] = []
        self.hold_first = False
        self.hold_s = 0.3
        self._other_copy = threading.Event()
        self._held = False
        self._lock = threading.Lock()

    def _write(self, message: Message) -> None:
        if isinstance(message, Stop):
            thread = threading.current_thread().name
            with self._lock:
                hold = self.hold_first and not self._held and thread != "link-timer"
                self._held = self._held or hold
                if not hold:
                    self.stops.append((time.monotonic(), thread, message.stop_id))
                    self._other_copy.set()
            if hold:
                self._other_copy.wait(self.hold_s)
                with self._lock:
                    self.stops.append((time.monotonic(), thread, message.stop_id))
        super()._write(message)


def _link(emu: Emulator, **config: float) -> tuple[ControllerLink, Recorder, NotingTransport]:
    made: list[NotingTransport] = []

    def factory(url: str) -> Transport:
        transport = NotingTransport(url)
        made.append(transport)
        return transport

    link, rec = start_link(link_url(emu), transport_factory=factory, **config)
    rec.wait_count("ready", 1)
    return link, rec, made[-1]


def test_a_slow_first_write_is_not_doubled_by_the_timer(emulators: Emus) -> None:
    """The race of #16: the caller had registered the STOP but not yet written it when
    the timer thread found it 'never sent' and wrote it too, 0.2 ms apart, uncounted."""
    emu = emulators()
    link, rec, transport = _link(emu, stop_repeat_s=0.5)
    try:
        transport.hold_first = True
        stop_id = link.emergency_stop()
        rec.wait_count("stopped", 1)
        copies = [s for s in transport.stops if s[2] == stop_id]
        diag = link.diagnostics()
    finally:
        link.close()
    # One copy, from the caller; the ACK came before any repeat was due.
    assert [thread for _, thread, _ in copies] == ["MainThread"], copies
    assert diag.stop_repeats == 0


def test_repeats_follow_the_interval_and_are_counted(emulators: Emus) -> None:
    emu = emulators()
    link, rec, transport = _link(emu, stop_repeat_s=0.02)
    try:
        emu.inject("link-drop=1.0")  # no STOP_ACK: the link repeats
        stop_id = link.emergency_stop()
        deadline = time.monotonic() + 10.0
        while len([s for s in transport.stops if s[2] == stop_id]) < 6:
            assert time.monotonic() < deadline, transport.stops
            time.sleep(0.01)
        emu.inject("clear:link-drop")
        rec.wait_count("stopped", 1)
        copies = [t for t, _, sid in transport.stops if sid == stop_id]
        repeats = link.diagnostics().stop_repeats
    finally:
        link.close()
    gaps = [b - a for a, b in itertools.pairwise(copies)]
    # Never two copies back to back: each repeat waits the interval (a lower bound only;
    # the machine may make it later, never earlier).
    assert min(gaps) >= 0.02 - 1e-4, gaps
    assert repeats == len(copies) - 1
