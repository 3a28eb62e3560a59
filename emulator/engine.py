"""The emulator: a controller model served over a front end, in real time.

:class:`Emulator` owns one control thread, the only one that touches the model: one
:meth:`~emulator.controller.ControllerModel.tick` per twin step, twin time running
``speed_factor`` times the wall clock, waking at least :data:`WAKE_QUANTUM_S` apart
unless a message arrives. A STOP preempts the ticks owed (at most one wake quantum of
twin time early), as a receive interrupt does. Woken late, the loop runs the ticks it
owes in a burst, each message in the tick it arrived in, so timing rules see the host's
timing; beyond :data:`MAX_BACKLOG_S` behind, twin time slips. Catch-ups are counted in
:class:`EmulatorStatus` (docs/realtime.md, "The emulator is faithful when it is late").

Other threads go through :meth:`Emulator.call`, which runs a function on the control
thread. Faults are checked when given, never refused when they fire.
:meth:`Emulator.close` is idempotent and joins every thread it started.
"""

from __future__ import annotations

import logging
import math
import queue
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass
from types import TracebackType
from typing import Any, TypeVar

from emulator.controller import ControllerModel
from emulator.errors import InjectionError
from emulator.frontend import FrontEnd
from emulator.injection import (
    FaultSchedule,
    FaultSpec,
    InjectionListener,
    InjectionRecord,
    Injector,
    ScheduledFault,
    parse_fault,
)
from firmware_proto.runtime import stall
from firmware_proto.wire.gapstats import GapStats, GapSummary
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import (
    CONTROLLER_HEARTBEAT_PERIOD_MS,
    HOST_HEARTBEAT_PERIOD_MS,
    ControllerState,
    FaultCode,
    Heartbeat,
    HostHeartbeat,
    Stop,
)

__all__ = ["MAX_BACKLOG_S", "WAKE_QUANTUM_S", "Emulator", "EmulatorStatus"]

logger = logging.getLogger(__name__)

T = TypeVar("T")

MAX_BACKLOG_S = 0.1
"""Wall seconds the control loop may lag and still catch up in a burst; beyond, twin time slips."""
WAKE_QUANTUM_S = 0.002
"""Least wall time between the control thread's wakes unless a message arrives, s: waking
every tick, this real-time thread would starve the kernel's pty receive path (normal priority)."""


@dataclass(frozen=True)
class _Received:
    """A message from the host and its arrival time (``time.monotonic()``)."""

    message: Message
    arrived: float


@dataclass(frozen=True)
class _Call:
    """A function to run on the control thread and the future of its result."""

    fn: Callable[[], Any]
    future: Future[Any]


@dataclass(frozen=True)
class EmulatorStatus:
    """A snapshot of the emulator, taken on the control thread."""

    time_s: float
    state: str
    x_m: float
    y_m: float
    yaw_deg: float
    wheel_mps: tuple[float, float]
    setpoints_mps: tuple[float, float]
    queue_depth: int
    stop_latched: bool
    faults: tuple[str, ...]
    boot_nonce: int
    device: str
    rx_frames: int
    rx_errors: int
    tx_frames: int
    tx_dropped: int
    overruns: int
    collision: str | None
    injected: tuple[str, ...] = ()
    """Injected faults in force (:meth:`~emulator.injection.Injector.in_force`)."""
    latch: tuple[str, ...] = ()
    """What holds the latch (``stop``, ``watchdog``, ``fault``), sorted; empty: none."""
    catchups: int = 0
    """Times the control loop woke late and ran more than one tick at once."""
    late_max_ms: float = 0.0
    """How late the latest-running tick ran, ms (wall)."""
    late_p99_ms: float = 0.0
    """99th percentile of the lateness of the last 1,000 catch-ups, ms."""
    host_heartbeat_gaps: GapSummary | None = None
    """Gaps between the host's HOST_HEARTBEATs as they arrived (wall)."""
    heartbeat_gaps: GapSummary | None = None
    """Gaps between this controller's HEARTBEATs as they were sent (wall)."""

    def line(self) -> str:
        """One status line: controller faults (``faults=``) beside injected ones."""
        faults = ",".join(self.faults) or "none"
        injected = ",".join(self.injected) or "none"
        hit = f" HIT {self.collision}" if self.collision else ""
        left, right = self.wheel_mps
        return (
            f"t={self.time_s:8.2f}s {self.state:<12} x={self.x_m:+7.3f} y={self.y_m:+7.3f} "
            f"yaw={self.yaw_deg:+7.1f} wheels={left:+.2f}/{right:+.2f} m/s "
            f"q={self.queue_depth} faults={faults} injected={injected} "
            f"rx={self.rx_frames} err={self.rx_errors} late={self.late_max_ms:.0f}ms{hit}"
        )


class Emulator:
    """A :class:`ControllerModel` served in real time over a :class:`FrontEnd`."""

    def __init__(
        self,
        model: ControllerModel,
        frontend: FrontEnd,
        *,
        speed_factor: float = 1.0,
        faults: list[FaultSpec] | None = None,
        on_injection: InjectionListener | None = None,
        fault_source: str = "api",
        max_backlog_s: float = MAX_BACKLOG_S,
    ) -> None:
        """Args:
        model: the controller over its twin (the engine steps it).
        frontend: the pty or CAN front end (the engine starts and closes it).
        speed_factor: twin seconds per wall second (> 0); the model's ``timeout_scale``
            should match.
        faults: faults to schedule (no trigger: at the first tick).
        on_injection: told of every injection applied, on the control thread; it
            must be quick and must not call back into the emulator.
        fault_source: who asked for ``faults`` (``cli``), recorded with each injection.
        max_backlog_s: wall seconds the loop may fall behind and still catch up in a
            burst; further behind, twin time slips (a replay allows more).

        Raises:
            ValueError: speed factor not positive and finite.
            InjectionError: one of ``faults`` cannot apply here.
        """
        if not (math.isfinite(speed_factor) and speed_factor > 0):
            raise ValueError(f"speed factor must be > 0, got {speed_factor}")
        self.model = model
        self.frontend = frontend
        self.speed_factor = speed_factor
        self.max_backlog_s = max_backlog_s
        self.injector = Injector(model, frontend)
        if on_injection is not None:
            self.injector.listeners.append(on_injection)
        self.schedule = FaultSchedule(self.injector, faults, fault_source)
        self.refused_injections = 0
        """Faults refused by :meth:`inject` (malformed or inapplicable)."""
        self._refused_lock = threading.Lock()
        self.stop_reactions: list[float] = []
        """Seconds from each STOP frame's arrival to its targets being zero."""
        self.stop_handled: list[float] = []
        """``time.monotonic()`` when each STOP had zeroed the targets."""
        self.overruns = 0
        """Times the loop fell more than ``max_backlog_s`` behind and let twin time slip."""
        self.catchups = 0
        self._late_max_s = 0.0
        self._late: deque[float] = deque(maxlen=1000)
        self.host_heartbeat_gaps = GapStats(HOST_HEARTBEAT_PERIOD_MS / 1000.0)
        """Gaps between the host's heartbeats as they arrived (control thread only)."""
        self.heartbeat_gaps = GapStats(CONTROLLER_HEARTBEAT_PERIOD_MS / 1000.0 / speed_factor)
        """Gaps between the controller's heartbeats as they were sent (control thread)."""
        self._held: deque[_Received] = deque()
        """Messages taken from the inbox that wait for the tick they arrived in."""
        self._inbox: queue.SimpleQueue[_Received | _Call] = queue.SimpleQueue()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._rx_errors_seen = 0
        self._status: EmulatorStatus | None = None
        self._closed = False

    # -- lifecycle ----------------------------------------------------------------------
    def start(self) -> None:
        """Open the front end, boot the controller and start the control thread."""
        if self._thread is not None:
            raise RuntimeError("emulator already started")
        self.frontend.start(self._on_message)
        self._thread = threading.Thread(target=self._run, name="emulator-control", daemon=True)
        self._thread.start()

    def close(self) -> None:
        """Stop the control thread and close the front end (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            if self._thread.is_alive():
                logger.error("control thread did not stop within 5 s")
        self.frontend.close()

    def __enter__(self) -> Emulator:
        self.start()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    # -- cross-thread calls ---------------------------------------------------------------
    def call(self, fn: Callable[[], T], timeout_s: float = 5.0) -> T:
        """Run ``fn`` on the control thread and return its result (or raise its error).

        Raises:
            TimeoutError: the control thread did not run it within ``timeout_s``.
        """
        if self._thread is None or not self._thread.is_alive():
            raise RuntimeError("emulator is not running")
        future: Future[T] = Future()
        self._inbox.put(_Call(fn, future))
        return future.result(timeout=timeout_s)

    def inject(
        self, fault: str | FaultSpec, source: str = "api"
    ) -> InjectionRecord | ScheduledFault:
        """Apply a fault now, or schedule it if it has a trigger; checked first either way.

        Returns:
            the injection applied, or, for a triggered fault, when it will fire.

        Raises:
            InjectionError: the fault is malformed or cannot be applied here; counted in
                :attr:`refused_injections` and logged.
        """
        try:
            spec = parse_fault(fault) if isinstance(fault, str) else fault
            # Reads configuration only (map, front end), so it is safe on this thread.
            self.injector.check(spec)
        except InjectionError as exc:
            with self._refused_lock:
                self.refused_injections += 1
            logger.warning("fault %s refused (%s): %s", fault, source, exc)
            raise
        if spec.trigger.immediate:
            return self.call(lambda: self._apply_now(spec, source))
        return self.call(lambda: self.schedule.add(spec, source))

    def _apply_now(self, spec: FaultSpec, source: str) -> InjectionRecord:
        self._send(self.injector.apply(spec, source))
        return self.injector.log[-1]

    @property
    def injections(self) -> list[InjectionRecord]:
        """Every injection applied so far."""
        return list(self.injector.log)

    def status(self) -> EmulatorStatus:
        """A fresh snapshot (taken on the control thread)."""
        return self.call(self._snapshot)

    # -- control loop ---------------------------------------------------------------------
    def _on_message(self, msg: Message, arrived: float) -> None:
        self._inbox.put(_Received(msg, arrived))

    def _send(self, messages: list[Message]) -> None:
        if messages:
            if any(isinstance(m, Heartbeat) for m in messages):
                self.heartbeat_gaps.event(time.monotonic())
            self.frontend.send(messages)

    def _drain(self, first: _Received | _Call | None, until: float = math.inf) -> float:
        """Empty the inbox: run each call at once; handle messages that arrived by
        ``until`` (``time.monotonic()``) in order, hold later ones for their ticks.

        Returns:
            The wall time the calls took, s (what they held the loop up).
        """
        item = first
        in_calls = 0.0
        while True:
            if item is None:
                try:
                    item = self._inbox.get_nowait()
                except queue.Empty:
                    break
            if isinstance(item, _Call):
                if item.future.set_running_or_notify_cancel():
                    started = time.monotonic()
                    try:
                        item.future.set_result(item.fn())
                    except BaseException as exc:
                        item.future.set_exception(exc)
                    in_calls += time.monotonic() - started
            else:
                self._held.append(item)
            item = None
        held = self._held
        while held and held[0].arrived <= until:
            self._handle(held.popleft())
        return in_calls

    def _handle(self, item: _Received) -> None:
        if isinstance(item.message, HostHeartbeat):
            self.host_heartbeat_gaps.event(item.arrived)
        out = self.model.handle(item.message)
        if isinstance(item.message, Stop):
            handled = time.monotonic()
            self.stop_reactions.append(handled - item.arrived)
            self.stop_handled.append(handled)
        self._send(out)

    def _run(self) -> None:
        beat = stall.watch("emulator-control")
        try:
            self._loop(beat)
        finally:
            stall.forget(beat)

    def _catch_up(self, late_s: float) -> None:
        """The loop woke ``late_s`` after it planned to (more than a tick late)."""
        self.catchups += 1
        self._late.append(late_s)
        self._late_max_s = max(self._late_max_s, late_s)

    def _loop(self, beat: stall.Beat) -> None:
        model = self.model
        tick_wall = model.twin.dt_s / self.speed_factor
        self._send(model.boot())
        t0 = time.monotonic()
        ticks = 0
        next_status = 0
        planned: float | None = None  # when the loop meant to wake (None: by a message)
        try:
            while not self._stop.is_set():
                beat.tick()
                now = time.monotonic()
                if planned is not None and now - planned > tick_wall:
                    self._catch_up(now - planned)
                due = int((now - t0) / tick_wall) - ticks
                if due * tick_wall > self.max_backlog_s:
                    self.overruns += 1
                    if self.overruns == 1 or self.overruns % 100 == 0:
                        logger.warning(
                            "control loop %.0f ms behind; twin time slips", due * tick_wall * 1e3
                        )
                    t0 += (due - 1) * tick_wall
                    due = 1
                for _ in range(due):
                    # What arrived by the tick's end (wall) is handled first, in order.
                    held_up = self._drain(None, until=t0 + (ticks + 1) * tick_wall)
                    if held_up > tick_wall:
                        # A call taken between owed ticks held the loop up: late too.
                        self._catch_up(held_up)
                    out = model.tick()
                    out += self.schedule.poll()
                    ticks += 1
                    errors = self.frontend.rx_errors
                    if errors != self._rx_errors_seen:
                        model.rx_error(errors - self._rx_errors_seen)
                        self._rx_errors_seen = errors
                    self._send(out)
                if self._held:  # arrived during the last owed tick: now is their time
                    held_up = self._drain(None)
                    if held_up > tick_wall:
                        self._catch_up(held_up)
                if ticks >= next_status:
                    self._status = self._snapshot()
                    next_status = ticks + max(1, round(0.05 / model.twin.dt_s))
                self.frontend.flush_due()
                after = time.monotonic()
                planned = max(t0 + (ticks + 1) * tick_wall, after + WAKE_QUANTUM_S)
                try:
                    item = self._inbox.get(timeout=planned - after)
                except queue.Empty:
                    item = None
                woke: float = time.monotonic()
                if woke - planned > tick_wall:
                    # Counted before what woke it runs, so a status call shows it.
                    self._catch_up(woke - planned)
                    planned = None
                if isinstance(item, _Call):
                    # Runs now; should it hold the loop up, the next turn counts that.
                    self._drain(item, until=-math.inf)  # messages wait for their tick
                elif item is not None:
                    planned = None
                    if isinstance(item.message, Stop) and not self._held:
                        # STOP preempts the ticks owed, as a receive interrupt does.
                        self._handle(item)
                    else:
                        # Handled in its own tick, after the ticks owed.
                        self._held.append(item)
        except Exception:
            logger.exception("control loop crashed; the controller stops")
            raise
        finally:
            self._fail_pending_calls()

    def _fail_pending_calls(self) -> None:
        while True:
            try:
                item = self._inbox.get_nowait()
            except queue.Empty:
                return
            if isinstance(item, _Call) and item.future.set_running_or_notify_cancel():
                item.future.set_exception(RuntimeError("emulator stopped"))

    def _snapshot(self) -> EmulatorStatus:
        m = self.model
        late = sorted(self._late)
        pose = m.twin.pose
        hit = m.twin.first_collision
        stats = self.frontend.stats
        return EmulatorStatus(
            time_s=m.now_s,
            state=ControllerState(m.state).name,
            x_m=pose.x_m,
            y_m=pose.y_m,
            yaw_deg=pose.yaw_deg,
            wheel_mps=m.twin.wheel_surface_speeds_mps,
            setpoints_mps=m.wheel_setpoints_mps,
            queue_depth=m.queue_depth,
            stop_latched=m.stop_latched,
            faults=tuple(sorted(FaultCode(c).name for c in m.faults)),
            boot_nonce=m.boot_nonce,
            device=getattr(self.frontend, "device", ""),
            rx_frames=stats.rx_messages,
            rx_errors=self.frontend.rx_errors,
            tx_frames=stats.tx_messages,
            tx_dropped=stats.tx_dropped,
            overruns=self.overruns,
            collision=hit.obstacle_id if hit else None,
            injected=self.injector.in_force(),
            latch=tuple(sorted(cause.value for cause in m.latch_causes)),
            catchups=self.catchups,
            late_max_ms=self._late_max_s * 1e3,
            late_p99_ms=late[max(0, math.ceil(0.99 * len(late)) - 1)] * 1e3 if late else 0.0,
            host_heartbeat_gaps=self.host_heartbeat_gaps.summary(),
            heartbeat_gaps=self.heartbeat_gaps.summary(),
        )

    @property
    def last_status(self) -> EmulatorStatus | None:
        """The control loop's latest snapshot (every ~50 ms twin time), without a call."""
        return self._status
