"""The emulator is faithful when its own process is late (docs/realtime.md): a real
controller is never descheduled, so an emulator held up by its computer must not invent
a watchdog trip; a host that really falls silent still trips it."""

from __future__ import annotations

import os
import queue
import signal
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import pytest

from emulator.engine import MAX_BACKLOG_S, _Call
from firmware_proto.runtime.realtime import RealtimeConfig, apply_realtime
from firmware_proto.wire.messages import Fault, FaultCode, Heartbeat
from tests.child import Child
from tests.emulator.host import serial_host
from tests.emulator.test_served import ControlClient

FREEZE_S = 0.6
"""How long the emulator's process is stopped: more than twice the 250 ms watchdog."""


@contextmanager
def realtime_threads() -> Iterator[None]:
    """Threads started inside get real-time priority where permitted (the host's
    heartbeat must keep time, or the test would see a real host silence)."""
    apply_realtime(RealtimeConfig(25, lock_memory=False))
    try:
        yield
    finally:
        apply_realtime(RealtimeConfig(0))


def _status(control: ControlClient) -> dict[str, Any]:
    answer = control.ask("status")
    assert answer["ok"], answer
    status: dict[str, Any] = answer["status"]
    return status


def test_a_stopped_emulator_trips_no_watchdog_and_a_silent_host_still_does() -> None:
    args = ["emulate", "--serial", "--control-port", "0", "--seed", "5"]
    emulator = Child(args, dict(os.environ))
    try:
        device = emulator.wait_for("DEVICE ").split()[1]
        port = int(emulator.wait_for("CONTROL ").rsplit(":", 1)[1])
        control = ControlClient(port)
        with realtime_threads():
            host = serial_host(device, heartbeat_s=0.02)
        try:
            host.handshake()
            host.expect(
                Heartbeat, lambda hb: hb.handshake_ok == 1, since=host.mark(), timeout_s=10.0
            )
            before = _status(control)
            mark = host.mark()
            # The emulator's computer holds it up (every thread, as a busy machine can);
            # the host keeps sending its heartbeats meanwhile.
            os.kill(emulator.proc.pid, signal.SIGSTOP)
            time.sleep(FREEZE_S)
            os.kill(emulator.proc.pid, signal.SIGCONT)
            # The control loop counts the stall on its first turn after it: when it wakes
            # late, or, stopped in the middle of its ticks, when it finds the ticks owed
            # past its backlog. A status call may be served before that turn (it was, in a
            # CI run beside the other real-time tests): wait for the count, bounded.
            late = before["overruns"] + before["catchups"]
            deadline = time.monotonic() + 10.0
            after = _status(control)
            while after["overruns"] + after["catchups"] <= late:
                assert time.monotonic() < deadline, (before, after)
                after = _status(control)
            # Two heartbeats sent after it caught up: any trip would have come before them.
            resumed = host.mark()
            host.expect(Heartbeat, since=resumed, timeout_s=10.0)
            last = host.expect(Heartbeat, since=host.mark(), timeout_s=10.0)
            assert not [f for f in host.messages(Fault, mark) if f.code == FaultCode.WATCHDOG]
            assert last.latch_watchdog == 0 and last.stop_latched == 0
            gaps = _status(control)["host_heartbeat_gaps"]
            assert gaps["max_ms"] >= FREEZE_S * 1e3 * 0.8  # it saw the host's frames late

            # A host that really falls silent trips the watchdog as before.
            with host.silent():
                silent = host.mark()
                trip = host.expect(
                    Fault,
                    lambda f: f.code == FaultCode.WATCHDOG and f.active == 1,
                    since=silent,
                    timeout_s=10.0,
                )
            assert trip.active == 1
        finally:
            host.close()
            control.close()
    finally:
        if emulator.proc.poll() is None:
            os.kill(emulator.proc.pid, signal.SIGCONT)
        emulator.stop()


@pytest.mark.parametrize("freeze_s", [0.09])
def test_a_late_control_loop_is_counted_as_a_catch_up(freeze_s: float) -> None:
    """A control loop held up under the backlog limit runs the ticks it owes in a burst
    and counts it, with how late it was."""
    from emulator.controller import ControllerConfig, ControllerModel
    from emulator.engine import Emulator
    from emulator.serial_frontend import SerialFrontEnd
    from emulator.twin import Twin
    from firmware_proto.model.rover import load_rover

    rover = load_rover()
    model = ControllerModel(rover, Twin(rover), ControllerConfig(), seed=1)
    with Emulator(model, SerialFrontEnd(seed=1)) as emu:
        before = emu.call(lambda: model.now_s)
        emu.call(lambda: time.sleep(freeze_s))  # the control thread itself is held up
        deadline = time.monotonic() + 5.0
        status = emu.status()
        while status.time_s - before < freeze_s:  # the owed ticks are run, not skipped
            assert time.monotonic() < deadline, status
            status = emu.status()
        assert status.catchups >= 1
        assert status.late_max_ms >= freeze_s * 1e3 * 0.8


def test_a_call_taken_between_owed_ticks_that_holds_the_loop_up_is_counted() -> None:
    """A call the loop takes while it runs the ticks it owes (drained between two of
    them) and that holds it up is a catch-up too. It went uncounted: a CI run beside load
    saw the test above's freeze taken so, and the loop looked never late."""
    from concurrent.futures import Future

    from emulator.controller import ControllerConfig, ControllerModel
    from emulator.engine import Emulator
    from emulator.serial_frontend import SerialFrontEnd
    from emulator.twin import Twin
    from firmware_proto.model.rover import load_rover

    hold_s = 0.09
    rover = load_rover()
    model = ControllerModel(rover, Twin(rover), ControllerConfig(), seed=1)
    with Emulator(model, SerialFrontEnd(seed=1)) as emu:
        held: Future[None] = Future()

        def queue_the_hold_at_the_next_tick() -> None:
            # On the control thread. Its next tick queues the hold, and the loop then
            # owes ten ticks: the hold is drained before the second of them.
            tick = model.tick

            def first_tick() -> Any:
                del model.tick  # the class's own again
                emu._inbox.put(_Call(lambda: time.sleep(hold_s), held))
                return tick()

            model.tick = first_tick  # type: ignore[method-assign]
            time.sleep(0.01)

        emu.call(queue_the_hold_at_the_next_tick)
        held.result(timeout=5.0)
        deadline = time.monotonic() + 5.0
        status = emu.status()
        while status.late_max_ms < hold_s * 1e3 * 0.8 and time.monotonic() < deadline:
            status = emu.status()
        assert status.late_max_ms >= hold_s * 1e3 * 0.8, status
        assert status.catchups >= 2, status  # the turn after the 10 ms, and the hold


class _HeldUpInbox:
    """The control loop's inbox, whose wait for the next call returns ``hold_s`` late once:
    the loop's thread descheduled by its computer just as a call woke it."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.hold_s = 0.0

    def put(self, item: Any) -> None:
        self.inner.put(item)

    def get_nowait(self) -> Any:
        # While armed, the loop finds the inbox empty between its waits: the call it is
        # to be woken by reaches it in its wait (had the loop's ticks drained it, nothing
        # would be late: the test raced the loop's first ticks so, once).
        if self.hold_s:
            raise queue.Empty
        return self.inner.get_nowait()

    def get(self, timeout: float | None = None) -> Any:
        item = self.inner.get(timeout=timeout)
        if self.hold_s and isinstance(item, _Call):
            time.sleep(self.hold_s)
            self.hold_s = 0.0
        return item


def test_a_status_asked_for_as_the_loop_wakes_late_shows_it_was_late() -> None:
    """The loop's wait ends late, woken by the very call that asks for the status (what
    SIGCONT after SIGSTOP can do): the lateness is counted before the call runs, so the
    status shows it (this raced the call before)."""
    from emulator.controller import ControllerConfig, ControllerModel
    from emulator.engine import Emulator
    from emulator.serial_frontend import SerialFrontEnd
    from emulator.twin import Twin
    from firmware_proto.model.rover import load_rover

    rover = load_rover()
    model = ControllerModel(rover, Twin(rover), ControllerConfig(), seed=1)
    emu = Emulator(model, SerialFrontEnd(seed=1))
    inbox = _HeldUpInbox(emu._inbox)
    emu._inbox = inbox  # type: ignore[assignment]
    with emu:
        before = emu.status()
        inbox.hold_s = 0.09
        after = emu.status()
        assert after.catchups > before.catchups
        assert after.late_max_ms >= 0.09 * 1e3 * 0.8


@pytest.mark.parametrize(("max_backlog_s", "slips"), [(MAX_BACKLOG_S, True), (1.0, False)])
def test_a_loop_held_up_past_its_backlog_limit_slips_and_under_it_catches_up(
    max_backlog_s: float, slips: bool
) -> None:
    """Held up 0.3 s: a live emulator (its default limit, 0.1 s) lets twin time slip and counts an
    overrun; one allowed 1 s (a replay's) runs every tick it owes."""
    from emulator.controller import ControllerConfig, ControllerModel
    from emulator.engine import Emulator
    from emulator.serial_frontend import SerialFrontEnd
    from emulator.twin import Twin
    from firmware_proto.model.rover import load_rover

    rover = load_rover()
    model = ControllerModel(rover, Twin(rover), ControllerConfig(), seed=1)
    with Emulator(model, SerialFrontEnd(seed=1), max_backlog_s=max_backlog_s) as emu:
        wall0, twin0 = time.monotonic(), emu.call(lambda: model.now_s)
        emu.call(lambda: time.sleep(0.3))  # the control thread itself is held up
        emu.call(lambda: None)  # the loop ran again after it
        deadline = time.monotonic() + 5.0
        status = emu.status()
        while status.time_s - twin0 < 0.3 and not emu.overruns:
            assert time.monotonic() < deadline, status
            status = emu.status()
        wall = time.monotonic() - wall0
        twin = emu.call(lambda: model.now_s) - twin0
    assert (emu.overruns >= 1) is slips
    if slips:
        assert twin < wall - 0.1  # twin time fell behind the wall clock
