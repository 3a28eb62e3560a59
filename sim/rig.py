"""One scenario played in virtual time: the host's :class:`~bridge.link.linkcore.LinkCore`, a
controller (the Python model or the C core) over its twin, and the two directions of a
serial line or a CAN bus between them, with the scenario's faults (docs/sim.md, "What
is simulated").

:class:`Rig` is an event loop over virtual time: the next event is the earliest of the
controller's next tick, the next frame arriving at either end, the host core's next
deadline, a fault starting or ending and the operator's next action; time jumps to it.
Ties are broken in one fixed order (operator and faults, frames to the controller, its
tick, frames to the host, the host's tick), so a seed plays the same way every time.

Each side is driven as the product drives it: the host as
:class:`bridge.link.controllerlink.ControllerLink` drives the core (STOP copies first and
at once, ordinary frames in order, real codecs both ways, odometry fed as the bridge node
feeds it); the controller as the emulator's front ends drive the model (every message on
arrival, a tick every ``tick_s``). What the rig sees goes to a
:class:`~sim.checks.Ledger`; the invariants (:mod:`sim.checks`) are checked as events
happen and once more at the end.
"""

from __future__ import annotations

import bisect
import functools
import hashlib
import heapq
import logging
import math
import random
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import partial
from typing import NamedTuple

from bridge.link.linkcore import LinkCore
from bridge.link.linktypes import (
    SAMPLE_MESSAGES,
    LinkConfig,
    LinkDiagnostics,
    LinkState,
    MediumStats,
    StatusEvent,
    StepRequest,
)
from bridge.link.odometry import OdometryEstimator
from emulator.controller import STOPPING_FAULTS, LatchCause
from emulator.sensors import count_delta
from firmware_proto.model.rover import RoverDescription, load_rover
from firmware_proto.runtime.stall import DEFAULT_STALL_THRESHOLD_S
from firmware_proto.wire.canmap import CanDecoder, encode_can
from firmware_proto.wire.framing import Frame, FrameDecoder, FrameEncoder
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import (
    Ack,
    AckResult,
    ClearAck,
    ClearResult,
    ClearStop,
    Command,
    Encoders,
    Fault,
    FaultCode,
    Heartbeat,
    Hello,
    Ident,
    Imu,
    Motion,
    Status,
    Stop,
    StopAck,
    StopSource,
    WheelSpeeds,
)
from sim.checks import Ledger, Violation, final_checks
from sim.controllers import SampleLeak, build_controller
from sim.linkmutants import DecoderTotalReader, make_link_core
from sim.pipe import Delivery, Pipe, Window
from sim.scenario import Scenario, ScenarioFault

__all__ = ["RECOVERY_S", "Rig", "ScenarioOutcome", "run_scenario"]

logger = logging.getLogger(__name__)

RECOVERY_S = 8.0
"""After the last fault ends, a new step must complete within this, virtual s: the longest
reconnect backoff (2 s), loss detection, a handshake, a clear and a short step, with room."""
STEP_OVERHEAD_S = 0.1
"""Added to each step's nominal duration in the recovery bound, s: its ticks, STATUS, round trip."""
RECOVERY_START_S = 0.15
"""The operator starts recovering this long after the last fault ended, s (a latch the
watchdog alone holds is the host's to clear first)."""
POLL_S = 0.05
"""How often the operator looks at the link while recovering, s."""
PROBE = StepRequest(int(Command.FWD), 60, 100)
"""The step that shows the link recovered (4 mm)."""
CAN_NODE = 1
MAX_EVENTS_AT_ONCE = 10_000
"""More events than this at one virtual instant: something reschedules itself forever."""
ODOM_TOLERANCE_M = 0.003
"""Odometry may move this much more than the encoders between two samples (rounding)."""

_ACTION, _TO_CTL, _TICK, _TO_HOST, _HOST = range(5)


class _FrameInfo(NamedTuple):
    """What the simulator knew of a controller frame as it was sent: the boot that sent
    it (counted from 0) and what the checks need of its kind (``inner``). A named tuple:
    one is made for every frame the controller sends."""

    boot: int
    inner: object


@dataclass(frozen=True)
class _Gen:
    """What the simulator knew of a controller frame that names a latch generation: the
    generation then, counted over every boot (the wire's wraps at 256 and restarts)."""

    absolute: int


@dataclass
class ScenarioOutcome:
    """What one scenario did and whether every invariant held.

    Attributes:
        scenario: what was played.
        violations: the invariants broken (empty: the scenario passed).
        sim_s: virtual time simulated, s.
        digest: a hash of everything both sides did, in order (two runs of one scenario
            give the same digest).
        counts: what happened, by name (frames, steps, faults, excused odometry jumps...).
        trace: every event in words (only when asked for).
    """

    scenario: Scenario
    violations: list[Violation]
    sim_s: float
    digest: str
    counts: dict[str, int] = field(default_factory=dict)
    trace: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """Every invariant held."""
        return not self.violations


def _windows(faults: tuple[ScenarioFault, ...], direction: str, medium: str) -> tuple[Window, ...]:
    out = []
    for f in faults:
        if f.kind not in ("cut", "drop", "corrupt", "delay", "kind-loss", "dup"):
            continue
        if f.direction not in ("both", direction):
            continue
        level = f.level
        out.append(Window(f.kind, f.start_s, f.end_s, level, f.kinds))
    return tuple(out)


class Rig:
    """One scenario, ready to :meth:`run`; see the module docstring."""

    def __init__(
        self, scenario: Scenario, rover: RoverDescription | None = None, *, trace: bool = False
    ) -> None:
        """Args:
        rover: default: the packaged description.
        trace: keep every event in words (:attr:`ScenarioOutcome.trace`).

        Raises:
            FirmwareBuildError: the C core is asked for and cannot be built here.
        """
        self.sc = scenario
        self.rover = rover or _packaged_rover()
        self.rng = random.Random(scenario.seed * 1_000_003 + 17)
        self.now = 0.0
        self._heap: list[tuple[float, int, int, Callable[[], None]]] = []
        self._n = 0
        self._trace: list[str] | None = [] if trace else None
        self._digest = hashlib.blake2b(digest_size=12)
        self.ledger = Ledger()
        self.violations: list[Violation] = []
        # -- the controller
        self.ctl = build_controller(
            scenario.controller,
            self.rover,
            scenario.tick_s,
            scenario.queue_depth,
            scenario.seed,
            scenario.controller_mutant,
        )
        self.leak = SampleLeak(self.ctl) if scenario.leak_samples else None
        self._ctl_frozen = False
        self._ctl_backlog: list[tuple[Message, float]] = []
        self._ctl_encoder = FrameEncoder()
        self._ctl_seq = 0
        """The controller's serial frame counter (its encoder's, from 0 at each boot)."""
        self._meta_by_seq: list[deque[tuple[int, Message, object]] | None] = [None] * 256
        """What the simulator knew of each serial frame the controller sent, by its frame
        counter (the last 256), each with its place in the order sent (a counter's deque
        made when it is first used: most scenarios use few)."""
        self._frames_sent = 0
        """Serial frames the controller sent, all boots."""
        self._frame_read = -1
        """The place of the last serial frame the host read (the wire keeps the order)."""
        self._ctl_decoder = FrameDecoder()
        self._ctl_can = CanDecoder()
        self._ctl_rejected = 0
        self._units_per_m = float(self.rover.drive.distance_units_per_m)
        self._travel_ref = self.ctl.encoders.travel()
        self.true_path_m = 0.0
        """Both sides' mean absolute encoder travel over ticks and boots, m: odometry's bound."""
        # -- the medium
        medium = scenario.medium
        self.to_ctl = Pipe(
            medium,
            random.Random(self.rng.random()),
            _windows(scenario.faults, "to_controller", medium),
        )
        self.to_host = Pipe(
            medium, random.Random(self.rng.random()), _windows(scenario.faults, "to_host", medium)
        )
        # -- the host
        self._ids = random.Random(scenario.seed * 1_000_003 + 40)
        """Draws each bridge's first request id, as ControllerLink does (other draws unchanged)."""
        self._epoch = 0
        """The bridge process now running: 0, then one more at every restart."""
        self._epoch_starts: list[float] = []
        """When each bridge after the first was started (its frames are sent after)."""
        self._first_ids: list[int] = []
        """The first request id each bridge drew."""
        self._ctl_epoch = 0
        """The bridge whose HELLO opened the controller's session (its MOTION seqs)."""
        self._requests: dict[tuple[int, int], set[int]] = {}
        """The request ids (STOP, CLEAR_STOP) the controller received, by (boot, bridge)."""
        self._host_dead = False
        """The bridge process has ended and the next has not started."""
        self._numbers_base = 0
        """Step numbers of the bridges before this one (the ledger numbers on)."""
        self._numbers = 0
        """The last step number this bridge gave."""
        self._hello_reboot = False
        """The controller reboots right after answering its next HELLO."""
        self.core = self._new_core()
        self._device_present = True
        self._writer_stalled = False
        """The host's writer is held (a write stuck in the OS): frames wait, STOP still goes."""
        self._clear_copies: dict[int, float] = {}
        """When the last copy of each CLEAR_STOP id went on the wire."""
        self._stop_waits: int | None = None
        """The operator's emergency stop whose STOP_ACK has not reached the host yet."""
        self.stopped_owed = 0
        """Operator stops whose STOP_ACK reached the host (each owes ``stopped``)."""
        self._clear_answers: dict[int, int] = {}
        """CLEAR_ACK results that reached the host, by request id."""
        self._steps_after_clear: dict[int, int] = {}
        """Steps submitted while an operator's clear was open: the clear's id, by step."""
        self._host_frozen = False
        self._frozen_at = 0.0
        self.host_stalls = 0
        """Host freezes the bridge's stall monitor would have recorded."""
        self._host_backlog: list[tuple[Message, object, int | None, float]] = []
        """Frames read while the host was frozen, with when their connection opened."""
        self._deferred: list[Callable[[], None]] = []
        self._connected_at = -math.inf
        self._host_encoder = FrameEncoder()
        self._host_decoder = FrameDecoder()
        self._host_can = CanDecoder()
        self._host_at = math.inf
        self.odometry = OdometryEstimator(self.rover)
        self.status_listeners: list[Callable[[StatusEvent], None]] = []
        """Called with each status the host core says, as on ``/command_status``."""
        self.sample_listeners: list[Callable[[Message], None]] = []
        """Called with every sensor sample the host core forwards, after odometry took it."""
        self._odom_prev: tuple[float, float, float] | None = None
        """(x, y, true path at the sample's making) of the last ENCODERS applied."""
        # -- the operator
        self._probe: int | None = None
        self._probe_done = False
        self._last_clear = -math.inf
        self._last_clear_id = 0
        self._auto_clears: set[tuple[int, int]] = set()
        """The hosts' automatic clear requests, by (bridge, request id)."""
        self._operator_clears: dict[tuple[int, int], int] = {}
        """The operator's clear requests: the latch generation the host had heard of when
        each was asked for (:class:`_Gen` numbering), by (bridge, request id)."""
        self._gen_wire = self.ctl.latch_gen
        self._gen_abs = 0
        """The controller's latch generation counted over every boot."""
        self._gen_cause: dict[int, str] = {}
        """What raised each generation: ``stop``, ``watchdog`` or ``fault``."""
        self._latch_base = 0
        """Generation when the latch was last empty (released, rebooted): it holds later causes."""
        self._heard_gen = 0
        """The newest generation a frame that reached the host named."""
        # The steps queued before the probe run first: their nominal time counts too.
        work_s = sum(
            self.rover.step_duration_s(speed, distance) + STEP_OVERHEAD_S
            for action in scenario.actions
            for _, speed, distance in action.steps
        )
        self.end_s = scenario.quiet_s + RECOVERY_START_S + RECOVERY_S + work_s

    def _new_core(self) -> LinkCore:
        """A bridge's core, as ``rover bridge`` starts one: its first request id drawn at
        random (docs/protocol.md, "Latch and faults")."""
        first = self._ids.randrange(1, 0x10000)
        self._first_ids.append(first)
        core = make_link_core(
            LinkConfig(f"sim://{self.sc.medium}"), self.sc.mutants, first_request_id=first
        )
        if isinstance(core, DecoderTotalReader):
            core.decoder_lost = lambda: self._host_decoder.counters.lost
        return core

    def diagnostics(self) -> LinkDiagnostics:
        """The bridge's ``/diagnostics`` now, as ``ControllerLink`` makes them: the core's
        with what the transport knows (on serial, the host decoder's counts) and the
        stalls of the bridge process (each host-freeze longer than the stall monitor's
        threshold)."""
        c = self._host_decoder.counters
        medium = MediumStats(
            connected=self.core.connected,
            rx_frames=c.frames,
            crc_errors=c.crc,
            resyncs=c.framing + c.oversize,
            rx_dropped=c.rejected,
            rx_lost=c.lost,
        )
        return self.core.diagnostics(self.now, medium, stalls=self.host_stalls)

    def every(self, period_s: float, fn: Callable[[], None]) -> None:
        """Call ``fn`` every ``period_s`` of virtual time from now, as the operator's
        actions are called (a bridge's periodic work outside its link: its narrator)."""

        def again() -> None:
            fn()
            self._at(self.now + period_s, _ACTION, again)

        self._at(self.now + period_s, _ACTION, again)

    # -- bookkeeping -----------------------------------------------------------------------
    def _at(self, t: float, prio: int, fn: Callable[[], None]) -> None:
        self._n += 1
        heapq.heappush(self._heap, (t, prio, self._n, fn))

    def _note(self, text: str) -> None:
        """Something both runs of a seed must do alike: into the digest (and the trace)."""
        line = f"{self.now:.6f} {text}"
        self._digest.update(line.encode())
        if self._trace is not None:
            self._trace.append(line)

    def violate(self, rule: str, text: str) -> None:
        """An invariant broke now."""
        self.violations.append(Violation(rule, self.now, text))
        self._note(f"VIOLATION {rule}: {text}")

    # -- the run ---------------------------------------------------------------------------
    def run(self) -> ScenarioOutcome:
        """Play the scenario to its end; the outcome with every violation found."""
        sc = self.sc
        for action in sc.actions:
            self._at(action.at_s, _ACTION, partial(self._operator, action.kind, action.steps))
        for f in sc.faults:
            self._schedule_fault(f)
        self._at(sc.quiet_s + RECOVERY_START_S, _ACTION, self._recover)
        self._at(0.0, _TICK, self._tick)
        self._reschedule_host()
        heap = self._heap
        to_ctl, to_host = self.to_ctl, self.to_host
        # Pipe.due inlined (the loop's hottest call): the pipes keep their queues.
        queue_a, queue_b = to_ctl._queue, to_host._queue
        inf = math.inf
        end = self.end_s
        last_t, same = -1.0, 0
        while not self._probe_done:
            t_heap, p_heap = (heap[0][0], heap[0][1]) if heap else (inf, 9)
            t_a = queue_a[0].at_s if queue_a else inf
            t_b = queue_b[0].at_s if queue_b else inf
            if t_a < t_heap or (t_a == t_heap and p_heap > _TO_CTL):
                if t_b < t_a:
                    t, which = t_b, _TO_HOST
                else:
                    t, which = t_a, _TO_CTL
            elif t_b < t_heap or (t_b == t_heap and p_heap > _TO_HOST):
                t, which = t_b, _TO_HOST
            else:
                t, which = t_heap, -1
            if t > end:
                break
            if t == last_t:
                same += 1
                if same > MAX_EVENTS_AT_ONCE:
                    self.violate("crash", f"time stands still: {same} events at t={t}")
                    break
            else:
                last_t, same = t, 0
            self.now = t
            if which == _TO_CTL:
                self._deliver_to_ctl(to_ctl.pop())
            elif which == _TO_HOST:
                self._deliver_to_host(to_host.pop())
            else:
                heapq.heappop(heap)[3]()
        if not self._probe_done:
            self.now = end
            self.violate(
                "never-stuck",
                f"no step completed within {RECOVERY_S:g} s of the last fault's end and the "
                "nominal time of the steps before it "
                f"(link {self.core.state.value}, latch {self.core.latch})",
            )
        self.violations += final_checks(self.ledger, self.diagnostics(), self.now)
        self._final_issue_40()
        counts = self.ledger.counts()
        counts["frames_to_controller"] = self.to_ctl.sent
        counts["frames_to_host"] = self.to_host.sent
        counts["leaked_samples"] = self.leak.sent if self.leak is not None else 0
        close = getattr(self.ctl, "close", None)
        if close is not None:
            close()
        return ScenarioOutcome(
            sc,
            self.violations,
            self.now,
            self._digest.hexdigest(),
            counts,
            self._trace or [],
        )

    def _final_issue_40(self) -> None:
        """The ``stopped`` and ``order`` invariants (:mod:`sim.checks`)."""
        said = self.ledger.statuses["stopped"]
        if said < self.stopped_owed:
            self.violate(
                "stopped",
                f"{self.stopped_owed} operator STOP(s) acknowledged to the host, 'stopped' "
                f"said {said} time(s)",
            )
        for number, clear_id in sorted(self._steps_after_clear.items()):
            fates = self.ledger.fates.get(number, [])
            if (
                self._clear_answers.get(clear_id) == ClearResult.CLEARED
                and "rejected:stop_latched" in fates
            ):
                self.violate(
                    "order",
                    f"step {number}, submitted after the operator's clear {clear_id}, was "
                    "refused stop_latched although that clear released the latch",
                )

    # -- faults ---------------------------------------------------------------------------------
    def _schedule_fault(self, f: ScenarioFault) -> None:
        kind = f.kind
        if kind == "reboot":
            self._at(f.start_s, _ACTION, self._reboot)
        elif kind == "host-freeze":
            self._at(f.start_s, _ACTION, self._freeze_host)
            self._at(f.end_s, _ACTION, self._thaw_host)
        elif kind == "controller-freeze":
            self._at(f.start_s, _ACTION, self._freeze_ctl)
            self._at(f.end_s, _ACTION, self._thaw_ctl)
        elif kind == "encoder":
            side = 0 if f.side == "left" else 1
            self._at(f.start_s, _ACTION, lambda: self._encoder_fault(side, True))
            self._at(f.end_s, _ACTION, lambda: self._encoder_fault(side, False))
        elif kind == "stall":
            self._at(f.start_s, _ACTION, lambda: self._stall(f.side, True))
            self._at(f.end_s, _ACTION, lambda: self._stall(f.side, False))
        elif kind == "unplug":
            self._at(f.start_s, _ACTION, self._unplug)
            self._at(f.end_s, _ACTION, self._replug)
        elif kind == "writer-stall":
            self._at(f.start_s, _ACTION, lambda: self._writer_stall(f.end_s))
            self._at(f.end_s, _ACTION, self._writer_resume)
        elif kind == "hello-reboot":
            self._at(f.start_s, _ACTION, self._arm_hello_reboot)
        elif kind == "host-restart":
            self._at(f.start_s, _ACTION, self._bridge_ends)
            self._at(f.end_s, _ACTION, self._bridge_starts)

    def _arm_hello_reboot(self) -> None:
        self._note("fault hello-reboot armed")
        self._hello_reboot = True

    def _bridge_ends(self) -> None:
        """The bridge process ends: its device closed, nothing of it runs any more; what it
        owed its operator is checked now, and its steps that have no fate are lost."""
        if self._host_dead:
            return
        self._note("fault bridge ends")
        self._final_issue_40()
        self.ledger.new_host(self._numbers_base + self._numbers)
        self._host_dead = self._host_frozen = True
        if self.core.connected:
            self.core.failed(self.now, "sim: the bridge ended")
        self._host_backlog.clear()

    def _bridge_starts(self) -> None:
        """A new bridge process starts on the same controller boot: a new core with a first
        request id of its own, odometry and every host-side record anew."""
        self._note("fault bridge starts")
        self._host_dead = self._host_frozen = False
        self._epoch += 1
        self._epoch_starts.append(self.now)
        self._numbers_base += self._numbers
        self._numbers = 0
        self.core = self._new_core()
        self.odometry = OdometryEstimator(self.rover)
        self._odom_prev = None
        self._host_at = math.inf
        self._clear_copies.clear()
        self._stop_waits = None
        self.stopped_owed = 0
        self._clear_answers.clear()
        self._steps_after_clear.clear()
        self._probe = None
        self._heard_gen = 0
        self._reschedule_host()
        deferred, self._deferred = self._deferred, []
        for fn in deferred:
            fn()

    def _reboot(self, answered: list[Message] | None = None) -> None:
        """The controller resets now; ``answered``: what it had just sent in answer to a
        HELLO (the old boot's IDENT), sent with the new boot's first frames in one batch,
        so that the host reads both in one read."""
        self._note("fault reboot")
        first = self._ctl_encode(answered) if answered else ([], 0)
        self._account_travel()
        self.ledger.controller_reboots += 1
        self._ctl_backlog.clear()
        out = self.ctl.reboot()
        self._gen_wire = self.ctl.latch_gen  # a new boot counts from 0; the latch is gone
        self._latch_base = self._gen_abs
        self._travel_ref = self.ctl.encoders.travel()
        self._ctl_encoder = FrameEncoder()  # its frame counter restarts with it
        self._ctl_seq = 0
        self._ctl_decoder = FrameDecoder()
        self._ctl_rejected = 0
        batch, lost = self._ctl_encode(out)
        self._ctl_ship(first[0] + batch, first[1] + lost)

    def _freeze_host(self) -> None:
        self._note("fault host-freeze")
        self._host_frozen = True
        self._frozen_at = self.now

    def _thaw_host(self) -> None:
        if self._host_dead:
            return  # the process ended meanwhile
        self._note("fault host-thaw")
        self._host_frozen = False
        if self.now - self._frozen_at > DEFAULT_STALL_THRESHOLD_S:
            self.host_stalls += 1
        backlog, self._host_backlog = self._host_backlog, []
        deferred, self._deferred = self._deferred, []
        # A process resumed: its reader reads what waited, its timer runs; which comes
        # first is a race, played both ways.
        tick_first = self.rng.random() < 0.5
        if tick_first:
            self._host_tick()
        for msg, meta, seq, opened in backlog:
            # A frame of a connection that failed meanwhile went with its transport.
            if self.core.connected and opened == self._connected_at:
                self._host_frame(msg, meta, seq)
        for fn in deferred:
            fn()
        if not tick_first:
            self._host_tick()

    def _writer_stall(self, until_s: float) -> None:
        self._note("fault writer-stall")
        self._writer_stalled = True

    def _writer_resume(self) -> None:
        self._note("fault writer-resume")
        self._writer_stalled = False
        self._host_after()

    def _freeze_ctl(self) -> None:
        self._note("fault controller-freeze")
        self._ctl_frozen = True

    def _thaw_ctl(self) -> None:
        self._note("fault controller-thaw")
        self._ctl_frozen = False
        backlog, self._ctl_backlog = self._ctl_backlog, []
        for msg, sent_s in backlog:
            self._ctl_handle(msg, sent_s)

    def _encoder_fault(self, side: int, on: bool) -> None:
        self._note(f"fault encoder {side} {on}")
        ctl = self.ctl
        if on:
            ctl.encoders.dropout[side] = True
            out = ctl.raise_fault(FaultCode.ENCODER, condition=True)
            self._track_gen(out)
            self._ctl_send(out)
        else:
            ctl.encoders.dropout[side] = False
            if not any(ctl.encoders.dropout):
                self._ctl_send(ctl.clear_fault_condition(FaultCode.ENCODER))

    def _stall(self, side: str, on: bool) -> None:
        self._note(f"fault stall {side} {on}")
        self.ctl.twin.set_wheel_locked(side, on)

    def _unplug(self) -> None:
        self._note("fault unplug")
        self._device_present = False
        if self.core.connected:
            self.ledger.transport_failures += 1
            self.core.failed(self.now, "sim: device unplugged")
            self.to_host.clear()
            self._host_after()

    def _replug(self) -> None:
        self._note("fault replug")
        self._device_present = True
        self._reschedule_host()

    # -- the controller ---------------------------------------------------------------------------
    def _tick(self) -> None:
        self._at(self.now + self.sc.tick_s, _TICK, self._tick)
        if self._ctl_frozen:
            return
        out = self.ctl.tick()
        self._track_gen(out)
        self._account_travel()
        if self.leak is not None:
            self.leak.after_tick(out)
        if out:
            self._ctl_send(out)

    def _account_travel(self) -> None:
        left, right = self.ctl.encoders.travel()
        l0, r0 = self._travel_ref
        if left != l0 or right != r0:
            self.true_path_m += (
                abs(count_delta(left, l0) + count_delta(right, r0)) / 2.0 / self._units_per_m
            )
            self._travel_ref = (left, right)

    def _track_gen(self, out: list[Message]) -> None:
        """Note every latch generation the controller raised in the call that sent
        ``out``, with its cause (a stopping FAULT among them names it, else a stop)."""
        g = self.ctl.latch_gen
        if g == self._gen_wire:
            return
        cause = "stop"
        for msg in out:
            if isinstance(msg, Fault) and msg.active and msg.code in STOPPING_FAULTS:
                cause = "watchdog" if msg.code == FaultCode.WATCHDOG else "fault"
        while self._gen_wire != g:
            self._gen_wire = (self._gen_wire + 1) & 0xFF
            self._gen_abs += 1
            self._gen_cause[self._gen_abs] = cause

    def _ctl_send(self, out: list[Message]) -> None:
        """Send what the controller said in one call (one batch on serial)."""
        self._ctl_ship(*self._ctl_encode(out))

    def _ctl_encode(self, out: list[Message]) -> tuple[list[tuple[bytes, Message]], int]:
        """Encode ``out`` with the controller's frame counter, noting what the checks need
        of each frame: the serial batch, and how many CAN frames were lost on the way."""
        ledger = self.ledger
        ctl = self.ctl
        serial = self.sc.medium == "serial"
        batch: list[tuple[bytes, Message]] = []
        lost = 0
        for msg in out:
            meta: object = None
            if isinstance(msg, Status):
                ledger.controller_status(msg, self._ctl_epoch << 16 | msg.seq, self)
            elif isinstance(msg, Encoders):
                meta = (self.true_path_m, ctl.handshake_ok)
            if isinstance(msg, Fault) and msg.active and msg.code == FaultCode.WATCHDOG:
                ledger.watchdog_trips += 1
            if isinstance(msg, (Heartbeat, StopAck, Fault, ClearAck)):
                meta = _Gen(self._gen_abs)
            meta = _FrameInfo(ledger.controller_reboots, meta)
            if serial:
                sent = self._meta_by_seq[self._ctl_seq & 0xFF]
                if sent is None:
                    sent = self._meta_by_seq[self._ctl_seq & 0xFF] = deque(maxlen=8)
                sent.append((self._frames_sent, msg, meta))
                self._frames_sent += 1
                self._ctl_seq += 1
                batch.append((self._ctl_encoder.encode(msg), msg))
            else:
                can_id, data = encode_can(msg, CAN_NODE)
                if not self.to_host.send(self.now, data, msg, can_id=can_id, meta=meta):
                    lost += 1
        return batch, lost

    def _ctl_ship(self, batch: list[tuple[bytes, Message]], lost: int) -> None:
        """Hand a serial batch to the line; count what was lost on the way."""
        if batch:
            lost += self.to_host.send_batch(self.now, batch).count(False)
        if lost and self.core.connected:
            self.ledger.frames_lost_to_host += lost

    def _deliver_to_ctl(self, d: Delivery) -> None:
        if self.sc.medium == "serial":
            decoder = self._ctl_decoder
            messages = [f.message for f in decoder.feed(d.data)]
            rejected = decoder.counters.rejected
            if rejected != self._ctl_rejected:
                self.ctl.rx_error(rejected - self._ctl_rejected)
                self._ctl_rejected = rejected
        else:
            assert d.can_id is not None
            frame = self._ctl_can.decode(d.can_id, d.data)
            messages = [frame.message] if frame is not None and frame.node in (0, CAN_NODE) else []
        for msg in messages:
            if self._ctl_frozen:
                self._ctl_backlog.append((msg, d.sent_s))
            else:
                self._ctl_handle(msg, d.sent_s)

    def _ctl_handle(self, msg: Message, sent_s: float = math.inf) -> None:
        ctl = self.ctl
        # The bridge that sent it: every one before had ended when a later one started.
        epoch = bisect.bisect_right(self._epoch_starts, sent_s)
        if isinstance(msg, (Stop, ClearStop)):
            self._request(msg.stop_id, epoch)
        if isinstance(msg, ClearStop):
            before = set(ctl.latch_causes)
            out = ctl.handle(msg)
            if before and not ctl.latch_causes:
                self._released((epoch, msg.stop_id), before)
                self._latch_base = self._gen_abs
        elif isinstance(msg, Hello):
            out = ctl.handle(msg)
            self._ctl_epoch = epoch
            if self._hello_reboot:
                self._hello_reboot = False
                self._track_gen(out)
                self._reboot(answered=out)  # both IDENTs in one batch: one read
                return
        elif isinstance(msg, Stop):
            out = ctl.handle(msg)
            if ctl.wheel_setpoints_mps != (0.0, 0.0):
                self.violate(
                    "stop-zeroes",
                    f"STOP {msg.stop_id} handled and the wheel targets are "
                    f"{ctl.wheel_setpoints_mps}, not zero",
                )
        elif isinstance(msg, Motion):
            self.ledger.motions_handled += 1
            out = ctl.handle(msg)
        else:
            out = ctl.handle(msg)
        self._track_gen(out)
        if out:
            self._ctl_send(out)

    def _request(self, request_id: int, epoch: int) -> None:
        """The controller received a STOP or CLEAR_STOP ``request_id`` from bridge
        ``epoch``: ``request-id`` holds if no bridge before it on this boot used that id,
        unless both drew their first ids at random and the draws met (counted)."""
        boot = self.ledger.controller_reboots
        self._requests.setdefault((boot, epoch), set()).add(request_id)
        for earlier in range(epoch):
            if request_id not in self._requests.get((boot, earlier), ()):
                continue
            if _drawn(request_id, self._first_ids[epoch]) and _drawn(
                request_id, self._first_ids[earlier]
            ):
                self.ledger.id_collisions += 1
                self._note(f"request id {request_id} met by chance")
                continue
            self.violate(
                "request-id",
                f"bridge {epoch} (started again) sent request id {request_id}, which "
                f"bridge {earlier} used on this controller boot",
            )

    def _released(self, clear_id: tuple[int, int], causes: set[LatchCause]) -> None:
        """CLEAR_STOP ``clear_id`` (bridge, id) released a latch held by ``causes``: by the rules of
        docs/protocol.md ("Latch and faults")? An automatic clear only a latch the
        watchdog alone holds; an operator's only one whose stopping faults (and watchdog
        trips) the host had heard of when the operator asked; nothing else at all."""
        names = ",".join(sorted(c.value for c in causes))
        if clear_id in self._auto_clears:
            if causes - {LatchCause.WATCHDOG}:
                self.violate(
                    "auto-clear",
                    f"the host's automatic CLEAR_STOP {clear_id[1]} released a latch held by "
                    f"{names} (only a watchdog-only latch is the host's to clear)",
                )
            return
        heard = self._operator_clears.get(clear_id)
        if heard is None:
            self.violate(
                "release",
                f"CLEAR_STOP {clear_id[1]}, which no operator asked for, released a latch held "
                f"by {names}",
            )
            return
        unheard = [
            f"{g} ({self._gen_cause.get(g)})"
            for g in range(max(heard, self._latch_base) + 1, self._gen_abs + 1)
            if self._gen_cause.get(g) in ("watchdog", "fault")
        ]
        if unheard:
            self.violate(
                "release",
                f"the operator's CLEAR_STOP {clear_id[1]}, asked for when the host had heard of "
                f"latch generation {heard}, released a latch held by {names} whose "
                f"generation(s) {', '.join(unheard)} it had not heard of then",
            )

    # -- the host -------------------------------------------------------------------------------
    def _reschedule_host(self) -> None:
        core = self.core
        if core.connected:
            due = core.next_deadline(self.now)
        else:
            due = max(self.now, core.next_deadline(self.now))
        if due < self._host_at:
            self._host_at = due
            self._at(due, _HOST, self._host_tick_event)

    def _host_tick_event(self) -> None:
        if self.now != self._host_at:
            return  # superseded by an earlier one
        self._host_at = math.inf
        if self._host_frozen:
            return  # it runs at the thaw
        self._host_tick()

    def _host_tick(self) -> None:
        if self._host_dead:
            return
        core = self.core
        now = self.now
        if not core.connected and core.connect_due(now):
            if self._device_present:
                core.on_connected(now)
                self._connected_at = now
                self.ledger.connected()
                self._host_encoder = FrameEncoder()
                self._host_decoder = FrameDecoder()
                self._host_can = CanDecoder()
                self._note("host connected")
            else:
                core.connect_failed(now, "cannot open sim: no such device")
        core.tick(now)
        self._host_after()

    def _host_after(self) -> None:
        """Write what the core decided (STOP first), take its events, plan its next tick."""
        if self._host_dead:
            return
        core = self.core
        while True:
            stops = core.take_stops()
            for stop in stops:
                self._host_send(stop)
            if self._writer_stalled:
                break
            entry = core.take_write()
            if entry is None:
                break
            msg = entry.msg
            if isinstance(msg, ClearStop) and entry.auto_clear:
                self._auto_clears.add((self._epoch, msg.stop_id))
            elif isinstance(msg, Motion):
                number = entry.step_number
                self.ledger.motion_written(
                    self._epoch << 16 | msg.seq,
                    None if number is None else self._numbers_base + number,
                )
            self._host_send(msg)
            core.written(entry, self.now, True)
        for event in core.take_events():
            if isinstance(event, StatusEvent):
                self._note(f"status {event.text} {event.step}")
                if event.step is not None and self._numbers_base:
                    self.ledger.status(replace(event, step=self._numbers_base + event.step), self)
                else:
                    self.ledger.status(event, self)
                for listener in self.status_listeners:
                    listener(event)
                if event.step is not None and event.step == self._probe:
                    if event.text == "completed":
                        self._probe_done = True
                    elif event.text != "accepted":
                        self._probe = None
            else:
                self._note(f"state {event.value}")
        self._reschedule_host()

    def _host_send(self, msg: Message) -> None:
        if isinstance(msg, Stop):
            self.ledger.stops_written.append(msg.stop_id)
        elif isinstance(msg, ClearStop):
            last = self._clear_copies.get(msg.stop_id)
            repeat_s = self.core.config.stop_repeat_s
            if last is not None and self.now - last < repeat_s - 1e-9:
                self.violate(
                    "repeat",
                    f"CLEAR_STOP {msg.stop_id} copies {1000 * (self.now - last):.1f} ms apart "
                    f"(at least {1000 * repeat_s:g} ms after the previous copy)",
                )
            self._clear_copies[msg.stop_id] = self.now
        if self.sc.medium == "serial":
            self.to_ctl.send(self.now, self._host_encoder.encode(msg), msg)
        else:
            can_id, data = encode_can(msg, CAN_NODE)
            self.to_ctl.send(self.now, data, msg, can_id=can_id)

    def _deliver_to_host(self, d: Delivery) -> None:
        if not self.core.connected or d.sent_s < self._connected_at:
            return  # nobody reads, or flushed when the device was opened
        got: list[tuple[Message, object, int | None]]
        if self.sc.medium == "serial":
            # A frame whose closing delimiter was cut is completed by the next delivery's
            # leading one: its frame counter, not the delivery, says which frame it is.
            find = self._frame_info
            got = [(f.message, find(f), f.seq) for f in self._host_decoder.feed(d.data)]
        else:
            assert d.can_id is not None
            frame = self._host_can.decode(d.can_id, d.data)
            got = (
                [(frame.message, d.meta, None)]
                if frame is not None and frame.node == CAN_NODE
                else []
            )
        for msg, info, seq in got:
            if msg.DIRECTION != "controller_to_host":
                continue
            if self._host_frozen:
                self._host_backlog.append((msg, info, seq, self._connected_at))
            else:
                self._host_frame(msg, info, seq)

    def _frame_info(self, frame: Frame) -> object:
        """What the simulator knew of a serial frame the controller sent, found by its frame
        counter and its content (frames of one counter value arrive in the order sent: a
        reboot restarts the counter, so two boots' frames may share one, even their
        content: a controller that repeats its nonce repeats its boot IDENT). A frame sent
        before the last one read was lost: never the one read now."""
        sent = self._meta_by_seq[frame.seq]
        while sent:  # None: no frame of this counter was sent
            place, msg, info = sent.popleft()
            if place > self._frame_read and msg == frame.message:
                self._frame_read = place
                return info
        return None

    def _host_frame(self, msg: Message, info: object, seq: int | None = None) -> None:
        core = self.core
        ledger = self.ledger
        state = core.state
        meta: object = None
        boot = ledger.controller_reboots
        if isinstance(info, _FrameInfo):
            meta, boot = info.inner, info.boot
        ledger.frame_delivered(msg, boot, seq)
        if isinstance(msg, Fault) and msg.code == FaultCode.WATCHDOG and msg.active:
            ledger.watchdog_fault_frames += 1
        elif isinstance(msg, Ack) and msg.result == AckResult.QUEUE_FULL:
            ledger.queue_full += 1
        if isinstance(meta, _Gen) and meta.absolute > self._heard_gen:
            self._heard_gen = meta.absolute
        if isinstance(msg, StopAck) and msg.stop_id == self._stop_waits:
            self._stop_waits = None
            self.stopped_owed += 1
        elif isinstance(msg, ClearAck):
            self._clear_answers.setdefault(msg.stop_id, msg.result)
        forward = core.on_frame(msg, self.now, rx_seq=seq)
        if forward:
            self._odometry(msg, meta, state)
            for listener in self.sample_listeners:
                listener(msg)
        if not isinstance(msg, SAMPLE_MESSAGES):  # a sample changes nothing in the core
            self._host_after()

    def _odometry(self, msg: Message, meta: object, state: LinkState) -> None:
        """Feed odometry as the bridge node does; check that it never moves more than the
        encoders did between the samples it used (continuity across reboots)."""
        odo = self.odometry
        if isinstance(msg, Encoders):
            est = odo.update_encoders(msg)
            path, in_session = meta if isinstance(meta, tuple) else (self.true_path_m, True)
            prev = self._odom_prev
            self._odom_prev = (est.x_m, est.y_m, path)
            if prev is None:
                return
            moved = math.hypot(est.x_m - prev[0], est.y_m - prev[1])
            allowed = max(0.0, path - prev[2]) + ODOM_TOLERANCE_M
            if moved <= allowed:
                return
            if not in_session and state is LinkState.READY:
                # A v2 controller's sample of a boot the host could not know of yet (no
                # IDENT or HEARTBEAT of it had arrived): protocol v3 forbids it.
                self.ledger.excused_jumps += 1
                self._note(f"excused odometry jump {moved:.3f} m")
                return
            self.violate(
                "odometry",
                f"odometry moved {moved:.3f} m between two ENCODERS while the encoders "
                f"travelled {path - prev[2]:.3f} m (link {state.value} when it arrived)",
            )
        elif isinstance(msg, (Heartbeat, Ident)):
            odo.observe_boot(self.core.reboots)  # as the bridge node does
        elif isinstance(msg, Imu):
            odo.update_imu(msg)
        elif isinstance(msg, WheelSpeeds):
            odo.update_speeds(msg)

    # -- the operator ---------------------------------------------------------------------------
    def _operator(self, kind: str, steps: tuple[tuple[int, int, int], ...]) -> None:
        if self._host_frozen:
            self._deferred.append(lambda: self._operator(kind, steps))
            return
        self._note(f"operator {kind} {len(steps)}")
        core = self.core
        now = self.now
        if kind == "steps":
            clear_open = core.clear_open
            for step in steps:
                self.ledger.submitted += 1
                number = core.submit_step(StepRequest(*step), now)
                self._numbers = max(self._numbers, number)
                if clear_open:
                    self._steps_after_clear[self._numbers_base + number] = self._last_clear_id
        elif kind in ("stop", "stop-step"):
            source = StopSource.OPERATOR if kind == "stop" else StopSource.PLAN_STEP
            self._stop_waits = core.emergency_stop(source, now)
            for stop in core.take_stops():
                self._host_send(stop)
                core.stop_written(stop.stop_id, now, True)
        elif kind == "clear":
            self._last_clear_id = self.operator_clear()
            self._last_clear = now
        self._host_after()

    def operator_clear(self) -> int:
        """The operator (or the ground) asks the host to clear now: the request id. The
        ``release`` invariant holds every release to what the host had heard of then."""
        clear_id = self.core.clear_stop(self.now)
        self._operator_clears[self._epoch, clear_id] = self._heard_gen
        return clear_id

    def _recover(self) -> None:
        """After the faults: wait for the link, release a latch that is the operator's
        (an emergency stop, a fault), send a short step until one completes."""
        if self._probe_done:
            return
        self._at(self.now + POLL_S, _ACTION, self._recover)
        if self._host_frozen or self._probe is not None:
            return
        core = self.core
        if core.state is not LinkState.READY:
            return
        latch = core.latch
        if core.estop_requested or "stop" in latch or "fault" in latch:
            if self.now - self._last_clear >= 0.5:
                self._note("operator clear (recovery)")
                self.operator_clear()
                self._last_clear = self.now
                self._host_after()
            return
        if core.stop_latched:
            return  # the watchdog's latch: the host clears it itself
        self.ledger.submitted += 1
        self._probe = core.submit_step(PROBE, self.now)
        self._numbers = max(self._numbers, self._probe)
        self._note(f"operator probe {self._probe}")
        self._host_after()


DRAWN_IDS = 256
"""A bridge's requests in one scenario stay within this many ids of its first."""


def _drawn(request_id: int, first: int) -> bool:
    """Whether a bridge whose first request id was ``first`` gives ``request_id`` (ids wrap)."""
    return (request_id - first) % 0xFFFF < DRAWN_IDS


@functools.cache
def _packaged_rover() -> RoverDescription:
    """The packaged rover description, read once per process (it is immutable)."""
    return load_rover(None)


def run_scenario(scenario: Scenario, *, trace: bool = False) -> ScenarioOutcome:
    """Play ``scenario`` once; see :class:`Rig`."""
    return Rig(scenario, trace=trace).run()
