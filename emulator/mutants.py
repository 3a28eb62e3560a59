"""Mutant controllers: the Python model with exactly one rule of docs/protocol.md broken.

They measure the conformance suite: each :class:`Mutant` names the rule it breaks and
the conformance rule that must catch it (``tests/bridge/test_mutants.py``; the score in
docs/protocol.md, "Conformance suite"). A mutant is a small subclass of
:class:`~emulator.controller.ControllerModel` overriding one method, with at most one
change to the link (:attr:`Mutant.link`). ``rover emulate --mutant NAME`` serves one: a
test aid, never a controller to drive a rover with.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from emulator.controller import STOPPING_FAULTS, ControllerConfig, ControllerModel, _PendingStop
from emulator.drive import StepProfile, travel_units
from emulator.errors import UnknownMutantError
from emulator.sensors import EncoderModel
from emulator.twin import Twin
from firmware_proto.linkio.endpoint import Endpoint
from firmware_proto.model.rover import RoverDescription
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import (
    Ack,
    AckField,
    AckResult,
    ClearResult,
    Command,
    ControllerState,
    Fault,
    FaultCode,
    Heartbeat,
    Hello,
    Motion,
    Param,
    ParamResult,
    ParamValue,
    Progress,
    SetParam,
    Status,
    StepState,
    StopAck,
)

__all__ = ["MUTANTS", "Mutant", "UnknownMutantError", "make_mutant", "mutant"]


@dataclass(frozen=True)
class Mutant:
    """One broken controller.

    Attributes:
        name: what ``--mutant`` takes.
        rule: the conformance rule (``rover conformance --list``) that must fail on it.
        breaks: the rule of docs/protocol.md it breaks, one sentence.
        model: the controller class.
        link: a change to the controller's end of the link, if the break is there.
    """

    name: str
    rule: str
    breaks: str
    model: type[ControllerModel]
    link: Callable[[Endpoint], None] | None = None


MUTANTS: dict[str, Mutant] = {}
"""Every mutant by name, in the order of the suite's rules."""


def _mutant(name: str, rule: str, breaks: str) -> Callable[[type[ControllerModel]], type]:
    def register(cls: type[ControllerModel]) -> type[ControllerModel]:
        MUTANTS[name] = Mutant(name, rule, breaks, cls)
        return cls

    return register


def mutant(name: str) -> Mutant:
    """The mutant called ``name``.

    Raises:
        UnknownMutantError: none is (the message lists the known ones).
    """
    try:
        return MUTANTS[name]
    except KeyError:
        raise UnknownMutantError(f"unknown mutant {name!r}; known: {', '.join(MUTANTS)}") from None


def make_mutant(
    name: str,
    rover: RoverDescription,
    twin: Twin,
    config: ControllerConfig | None = None,
    **kwargs: Any,
) -> ControllerModel:
    """The controller of mutant ``name``; ``kwargs`` as :class:`ControllerModel` takes.
    Apply :attr:`Mutant.link` to its endpoint too, where it has one.

    Raises:
        UnknownMutantError: no mutant has that name.
    """
    return mutant(name).model(rover, twin, config, **kwargs)


def _moved_after(out: list[Message], message: Message, kinds: tuple[type, ...]) -> None:
    """Move ``message`` in ``out`` to just after the last message of ``kinds``."""
    out.remove(message)
    last = max((i for i, m in enumerate(out) if isinstance(m, kinds)), default=-1)
    out.insert(last + 1, message)


# -- handshake and liveness ---------------------------------------------------------------


@_mutant(
    "hello-delays-heartbeat",
    "handshake",
    "A HELLO does not restart the heartbeat schedule: the first HEARTBEAT of a session "
    "comes at most one period after its IDENT.",
)
class _HelloDelaysHeartbeat(ControllerModel):
    def _hello(self, msg: Hello, out: list[Message]) -> None:
        super()._hello(msg, out)
        self._next_heartbeat = self.now_s + 2.5 / self.heartbeat_hz


@_mutant(
    "heartbeat-without-progress",
    "heartbeat",
    "The controller sends HEARTBEAT every period, each followed by PROGRESS.",
)
class _HeartbeatWithoutProgress(ControllerModel):
    def _telemetry(self, out: list[Message]) -> None:
        mine: list[Message] = []
        super()._telemetry(mine)
        out += [m for m in mine if not isinstance(m, Progress)]


@_mutant(
    "slow-telemetry",
    "telemetry",
    "ENCODERS come at the telemetry rate (ENCODERS_RATE_HZ by default).",
)
class _SlowTelemetry(ControllerModel):
    def _init_params(self) -> None:
        super()._init_params()
        self.telemetry_hz = 10


@_mutant(
    "samples-before-session",
    "samples-in-session",
    "Until a matching HELLO opens a session the controller must not send sensor samples.",
)
class _SamplesBeforeSession(ControllerModel):
    def _sends_samples(self) -> bool:
        return True


@_mutant(
    "mismatch-keeps-session",
    "hello-mismatch",
    "A mismatched HELLO is answered with IDENT and clears handshake_ok.",
)
class _MismatchKeepsSession(ControllerModel):
    def _hello(self, msg: Hello, out: list[Message]) -> None:
        super()._hello(Hello(self.protocol_version, self.schema_hash), out)


@_mutant(
    "mismatch-keeps-steps",
    "mismatch-session",
    "A mismatched HELLO after a session ends that session exactly as a matching one starts "
    "a new one (STATUS ABORTED reason SESSION, before the IDENT).",
)
class _MismatchKeepsSteps(ControllerModel):
    def _hello(self, msg: Hello, out: list[Message]) -> None:
        if (msg.protocol_version, msg.schema_hash) == (self.protocol_version, self.schema_hash):
            super()._hello(msg, out)
            return
        self.handshake_ok = False
        out.append(self._ident())


@_mutant(
    "boot-clear-to-idle",
    "boot-latch",
    "CLEARED without a session leaves the controller in BOOT, not IDLE.",
)
class _BootClearToIdle(ControllerModel):
    def _clear(self, stop_id: int, latch_gen: int) -> int:
        result = super()._clear(stop_id, latch_gen)
        if result == ClearResult.CLEARED and self.state == ControllerState.BOOT:
            self.state = ControllerState.IDLE
        return result


@_mutant(
    "watchdog-without-session",
    "watchdog-unarmed",
    "The watchdog is armed by a matching HELLO: a controller without a session never trips it.",
)
class _WatchdogWithoutSession(ControllerModel):
    def _check_watchdog(self, out: list[Message]) -> None:
        session = self.handshake_ok
        self.handshake_ok = True
        try:
            super()._check_watchdog(out)
        finally:
            self.handshake_ok = session


# -- motion ----------------------------------------------------------------------------


@_mutant(
    "travel-zero",
    "motion",
    "STATUS COMPLETED reports the step's travel, the mean encoder travel of both sides.",
)
class _TravelZero(ControllerModel):
    def _ended_status(self, seq: int, state: int, reason: int, travel: int) -> Status:
        if state == StepState.COMPLETED:
            travel = 0
        return super()._ended_status(seq, state, reason, travel)


@_mutant(
    "no-accel-ramp",
    "accel-ramp",
    "The controller must ramp each side's surface speed toward v at no more than a.",
)
class _NoAccelRamp(ControllerModel):
    def _profile(self, motion: Motion) -> StepProfile:
        drive = dataclasses.replace(self.rover.drive, wheel_accel_limit_mps2=1000.0)
        rover = dataclasses.replace(self.rover, drive=drive)
        return StepProfile(
            rover,
            motion.command,
            motion.speed,
            motion.distance,
            initial_left_mps=self._commanded[0],
            initial_right_mps=self._commanded[1],
        )

    def _ramp_commands(self, dt: float) -> None:
        self._commanded = self._setpoint


@_mutant(
    "zero-step-refused",
    "zero-step",
    "A step with speed 0 or distance 0 is valid: accepted, STARTED and COMPLETED with travel 0.",
)
class _ZeroStepRefused(ControllerModel):
    def _motion(self, msg: Motion) -> list[Message]:
        if (
            self.handshake_ok
            and msg.seq not in self._accepted_set
            and 0 < msg.command <= max(Command)
            and (msg.speed == 0 or msg.distance == 0)
        ):
            fld = AckField.SPEED if msg.speed == 0 else AckField.DISTANCE
            return [Ack(msg.seq, AckResult.OUT_OF_RANGE, fld, self.queue_depth)]
        return super()._motion(msg)


@_mutant(
    "no-dedup",
    "duplicate",
    "A retransmitted MOTION (an accepted seq) is acknowledged DUPLICATE and never executed twice.",
)
class _NoDedup(ControllerModel):
    def _remember(self, seq: int) -> None:
        pass


@_mutant(
    "latch-before-range",
    "ack-order",
    "The order of checks: speed and distance limits (5, 6) before the latch (8).",
)
class _LatchBeforeRange(ControllerModel):
    def _motion(self, msg: Motion) -> list[Message]:
        if (
            self.handshake_ok
            and self.stop_latched
            and msg.seq not in self._accepted_set
            and 0 < msg.command <= max(Command)
        ):
            return [Ack(msg.seq, AckResult.STOP_LATCHED, AckField.NONE, self.queue_depth)]
        return super()._motion(msg)


@_mutant(
    "queue-one-deeper",
    "queue-full",
    "The queue holds MOTION_QUEUE_DEPTH steps, the running one included.",
)
class _QueueOneDeeper(ControllerModel):
    def __init__(
        self, rover: RoverDescription, twin: Twin, config: ControllerConfig | None = None, **kw: Any
    ) -> None:
        config = config or ControllerConfig()
        super().__init__(
            rover, twin, dataclasses.replace(config, queue_depth=config.queue_depth + 1), **kw
        )


# -- STOP --------------------------------------------------------------------------------


@_mutant(
    "stop-ack-after-status",
    "stop",
    "The controller answers STOP_ACK at once: it goes ahead of the aborted STATUS.",
)
class _StopAckAfterStatus(ControllerModel):
    def handle(self, msg: Message) -> list[Message]:
        out = super().handle(msg)
        ack = next((m for m in out if isinstance(m, StopAck)), None)
        if ack is not None:
            _moved_after(out, ack, (Status,))
        return out


@_mutant(
    "repeat-gets-stopped",
    "stop",
    "A repeat of a stop_id already seen since the latch was last cleared gets its STOP_ACK "
    "and no other STOPPED.",
)
class _RepeatGetsStopped(ControllerModel):
    def _stop(self, stop_id: int, reason: int, out: list[Message], cause: Any) -> None:
        self._reported_stops.clear()
        super()._stop(stop_id, reason, out, cause)


@_mutant(
    "new-id-ignored-while-latched",
    "stop-new-id",
    "Every STOP with a new stop_id gets its own STOPPED, also when the controller is "
    "already latched and at rest.",
)
class _NewIdIgnoredWhileLatched(ControllerModel):
    def _stop(self, stop_id: int, reason: int, out: list[Message], cause: Any) -> None:
        latched, owed = self.stop_latched, len(self._pending_stops)
        super()._stop(stop_id, reason, out, cause)
        if latched and stop_id != 0:
            del self._pending_stops[owed:]


@_mutant(
    "stopped-at-once",
    "stopped-at-rest",
    "The controller brakes, then reports STOPPED with the stopping distance and time, "
    "once the wheels are at rest (not when the STOP arrives: 0 mm, 0 ms).",
)
class _StoppedAtOnce(ControllerModel):
    def _stop(self, stop_id: int, reason: int, out: list[Message], cause: Any) -> None:
        super()._stop(stop_id, reason, out, cause)
        self._report_stopped(self.encoders.travel(), out)


@_mutant(
    "no-brake-ramp",
    "braking",
    "The controller brakes at the acceleration limit a (the motor commands follow the "
    "targets at a, also to zero).",
)
class _NoBrakeRamp(ControllerModel):
    def _ramp_commands(self, dt: float) -> None:
        self._commanded = self._setpoint


@_mutant(
    "signed-stop-distance",
    "stopped-distance",
    "STOPPED distance_mm is unsigned: the mean of each side's absolute travel (a spin "
    "reports a positive distance).",
)
class _SignedStopDistance(ControllerModel):
    @staticmethod
    def _stopped_distance_units(
        travel: tuple[float, float], at_arrival: tuple[float, float]
    ) -> float:
        return abs((travel[0] - at_arrival[0]) + (travel[1] - at_arrival[1])) / 2.0


@_mutant(
    "steps-skip-owed-stopped",
    "stopped-owed",
    "Queued steps must not start while a STOPPED is owed (they wait for rest).",
)
class _StepsSkipOwedStopped(ControllerModel):
    def _may_start_next(self) -> bool:
        return not self.stop_latched


@_mutant(
    "predated-id-remembered",
    "stopped-owed",
    "An id reported after the CLEARED that it predates is not remembered as seen.",
)
class _PredatedIdRemembered(ControllerModel):
    def _report_stopped(self, travel: tuple[float, float], out: list[Message]) -> None:
        for pending in self._pending_stops:
            pending.clears = self._clears
        super()._report_stopped(travel, out)


@_mutant(
    "relatch-keeps-generation",
    "stop-after-clear",
    "A copy of a STOP that arrives after the CLEARED that released its latch, while its "
    "STOPPED is owed, latches again with a new latch generation (the issue #40 clean-room "
    "check: both controllers latched again with the released one).",
)
class _RelatchKeepsGeneration(ControllerModel):
    def _stop_is_repeat(self, stop_id: int) -> bool:
        return stop_id != 0 and (
            stop_id in self._reported_stops
            or any(p.stop_id == stop_id for p in self._pending_stops)
        )


@_mutant(
    "own-stops-as-repeats",
    "own-stops",
    "The controller's own stops (stop_id 0) are never taken for repeats: each gets a "
    "STOPPED 0 at the next rest.",
)
class _OwnStopsAsRepeats(ControllerModel):
    def _stop(self, stop_id: int, reason: int, out: list[Message], cause: Any) -> None:
        owed = len(self._pending_stops)
        super()._stop(stop_id, reason, out, cause)
        if stop_id == 0 and 0 in self._reported_stops:
            del self._pending_stops[owed:]

    def _report_stopped(self, travel: tuple[float, float], out: list[Message]) -> None:
        own = any(p.stop_id == 0 for p in self._pending_stops)
        super()._report_stopped(travel, out)
        if own:
            self._reported_stops.add(0)


@_mutant(
    "own-stops-each-stopped",
    "own-stops-share",
    "Own stops that come while a STOPPED 0 is still owed share it (issue #40, 10: each "
    "owing its own passed the suite).",
)
class _OwnStopsEachStopped(ControllerModel):
    def _stop(self, stop_id: int, reason: int, out: list[Message], cause: Any) -> None:
        owed = any(p.stop_id == 0 for p in self._pending_stops)
        super()._stop(stop_id, reason, out, cause)
        if stop_id == 0 and owed:
            self._pending_stops.append(
                _PendingStop(0, self.now_s, self.encoders.travel(), self._clears)
            )


@_mutant(
    "motion-stop-forgotten",
    "motion-stop",
    "MOTION STOP is a plan step: its seq is remembered, and a repeat is DUPLICATE.",
)
class _MotionStopForgotten(ControllerModel):
    def _motion(self, msg: Motion) -> list[Message]:
        fresh = msg.seq not in self._accepted_set
        out = super()._motion(msg)
        if fresh and msg.command == Command.STOP and msg.seq in self._accepted_set:
            self._accepted.remove(msg.seq)
            self._accepted_set.discard(msg.seq)
        return out


@_mutant(
    "motion-stop-ack-last",
    "motion-stop-order",
    "MOTION STOP's ACK comes first, then the STATUS ABORTED of the steps it purges.",
)
class _MotionStopAckLast(ControllerModel):
    def _motion(self, msg: Motion) -> list[Message]:
        out = super()._motion(msg)
        if msg.command == Command.STOP and out and isinstance(out[0], Ack):
            _moved_after(out, out[0], (Status,))
        return out


@_mutant(
    "motion-stop-depth-before-purge",
    "motion-stop-order",
    "MOTION STOP's ACK has queue_depth 0, the queue after the purge.",
)
class _MotionStopDepthBeforePurge(ControllerModel):
    def _motion(self, msg: Motion) -> list[Message]:
        depth = self.queue_depth
        out = super()._motion(msg)
        first = out[0] if out else None
        if msg.command == Command.STOP and isinstance(first, Ack):
            out[0] = first._replace(queue_depth=depth)
        return out


@_mutant(
    "session-ident-first",
    "session",
    "A new session aborts the steps (STATUS ABORTED reason SESSION) before the IDENT.",
)
class _SessionIdentFirst(ControllerModel):
    def _hello(self, msg: Hello, out: list[Message]) -> None:
        before = len(out)
        super()._hello(msg, out)
        out.insert(before, out.pop())


@_mutant(
    "progress-kept-at-hello",
    "session",
    "A new session starts PROGRESS again at ended_count 0.",
)
class _ProgressKeptAtHello(ControllerModel):
    def _hello(self, msg: Hello, out: list[Message]) -> None:
        ended = self._ended
        super()._hello(msg, out)
        self._ended = ended


# -- the latch ------------------------------------------------------------------------


@_mutant(
    "clear-repeat-not-latched",
    "clear-repeat",
    "A CLEAR_STOP repeating the last request answered CLEARED (its stop_id and "
    "latch_gen) is answered CLEARED again (protocol v2 answered a repeat with nothing "
    "latched NOT_LATCHED).",
)
class _ClearRepeatNotLatched(ControllerModel):
    def _clear(self, stop_id: int, latch_gen: int) -> int:
        last = self._last_clear
        if last is not None and last[:2] == (stop_id, latch_gen) and not self.latch_causes:
            return ClearResult.NOT_LATCHED
        return super()._clear(stop_id, latch_gen)


@_mutant(
    "clear-repeat-releases",
    "clear-repeat",
    "A repeated CLEAR_STOP id must not release a latch set since its CLEARED.",
)
class _ClearRepeatReleases(ControllerModel):
    def _clear(self, stop_id: int, latch_gen: int) -> int:
        last = self._last_clear
        if last is not None and last[:2] == (stop_id, latch_gen):
            # Judged again as new, and for the latch as it is now.
            self._last_clear = None
            if not self.latch_causes:
                return ClearResult.CLEARED
            return super()._clear(stop_id, self.latch_gen)
        return super()._clear(stop_id, latch_gen)


@_mutant(
    "clear-ignores-generation",
    "clear-generation",
    "A CLEAR_STOP naming a generation older than the latch's is answered LATCH_CHANGED and "
    "releases nothing (protocol v3 had no generation: a clear sent before a fault released "
    "it, issue #40 hole 1).",
)
class _ClearIgnoresGeneration(ControllerModel):
    def _judge_clear(self, latch_gen: int) -> int:
        return super()._judge_clear(self.latch_gen)


@_mutant(
    "stop-repeat-raises-generation",
    "clear-generation",
    "A repeated STOP (a stop_id seen in this latch) raises no latch generation.",
)
class _StopRepeatRaisesGeneration(ControllerModel):
    def _stop_is_repeat(self, stop_id: int) -> bool:
        return False


@_mutant(
    "stop-ack-names-old-generation",
    "clear-generation",
    "STOP_ACK names the latch generation after the STOP.",
)
class _StopAckNamesOldGeneration(ControllerModel):
    def handle(self, msg: Message) -> list[Message]:
        return [
            m._replace(latch_gen=(m.latch_gen - 1) & 0xFF) if isinstance(m, StopAck) else m
            for m in super().handle(msg)
        ]


# -- receive errors, parameters ---------------------------------------------------------


@_mutant(
    "rx-errors-ignored",
    "wire-range",
    "A frame outside its wire range is dropped and counted in rx_errors.",
)
class _RxErrorsIgnored(ControllerModel):
    def rx_error(self, count: int = 1) -> None:
        pass


@_mutant(
    "wrong-direction-uncounted",
    "rx-errors",
    "A controller-to-host frame received by the controller (an echo) is dropped and "
    "counted in rx_errors.",
)
class _WrongDirectionUncounted(ControllerModel):
    def handle(self, msg: Message) -> list[Message]:
        if msg.DIRECTION != "host_to_controller":
            return []
        return super().handle(msg)


@_mutant(
    "param-refusal-without-value",
    "param",
    "SET_PARAM out of range is answered OUT_OF_RANGE with the value still in force.",
)
class _ParamRefusalWithoutValue(ControllerModel):
    def _set_param(self, msg: SetParam) -> ParamValue:
        answer = super()._set_param(msg)
        if answer.result == ParamResult.OUT_OF_RANGE and msg.param != Param.WATCHDOG_MS:
            return answer._replace(value=0)
        return answer


# -- the watchdog and faults --------------------------------------------------------------


@_mutant(
    "watchdog-bit-until-clear",
    "watchdog",
    "fault_bits follow the conditions, not the latch: the WATCHDOG bit clears with FAULT "
    "active 0 (protocol v1 kept it until CLEAR_STOP).",
)
class _WatchdogBitUntilClear(ControllerModel):
    def heartbeat(self) -> Heartbeat:
        hb = super().heartbeat()
        if any(c.value == "watchdog" for c in self.latch_causes):
            return hb._replace(fault_bits=hb.fault_bits | 1 << (FaultCode.WATCHDOG - 1))
        return hb


@_mutant(
    "watchdog-judged-before",
    "watchdog-end",
    "The next valid frame ends the watchdog condition before it is handled: it is judged "
    "with the condition gone.",
)
class _WatchdogJudgedBefore(ControllerModel):
    def _feed_watchdog(self, out: list[Message]) -> None:
        self._last_rx_s = self.now_s

    def handle(self, msg: Message) -> list[Message]:
        out = super().handle(msg)
        if self._watchdog_tripped and msg.DIRECTION == "host_to_controller":
            self._watchdog_tripped = False
            out += self.clear_fault_condition(FaultCode.WATCHDOG)
        return out


@_mutant(
    "fault-detail-kept",
    "fault-detail",
    "FAULT detail is 0 with active = 0, for every code.",
)
class _FaultDetailKept(ControllerModel):
    _details: dict[int, int]

    def raise_fault(self, code: int, detail: int = 0, *, condition: bool = False) -> list[Message]:
        out = super().raise_fault(code, detail, condition=condition)
        if out:
            self.__dict__.setdefault("_details", {})[code] = min(detail, 0xFFFF)
        return out

    def clear_fault_condition(self, code: int) -> list[Message]:
        detail = self.__dict__.get("_details", {}).get(code, 0)
        return [
            Fault(m.code, 0, detail, m.latch_gen) if isinstance(m, Fault) else m
            for m in super().clear_fault_condition(code)
        ]


@_mutant(
    "clear-despite-fault",
    "fault-persists",
    "CLEAR_STOP answers FAULT_PERSISTS while a stopping fault's condition is active (the "
    "latch holds).",
)
class _ClearDespiteFault(ControllerModel):
    def _clear(self, stop_id: int, latch_gen: int) -> int:
        faults, self.faults = self.faults, set()
        try:
            return super()._clear(stop_id, latch_gen)
        finally:
            self.faults = faults


@_mutant(
    "refused-clear-repeat-releases",
    "clear-refused-repeat",
    "A repeat of a CLEAR_STOP answered FAULT_PERSISTS gets FAULT_PERSISTS again, also once "
    "the condition has gone: a refused clear never releases later (issue #40 hole 2).",
)
class _RefusedClearRepeatReleases(ControllerModel):
    def _clear(self, stop_id: int, latch_gen: int) -> int:
        last = self._last_clear
        if last is not None and last[:2] == (stop_id, latch_gen) and last[2] != 0:
            self._last_clear = None  # only CLEARED remembered, as protocol v3 did
        return super()._clear(stop_id, latch_gen)


@_mutant(
    "fault-names-old-generation",
    "clear-refused-repeat",
    "A stopping FAULT active = 1 names the latch generation it raised.",
)
class _FaultNamesOldGeneration(ControllerModel):
    def raise_fault(self, code: int, detail: int = 0, *, condition: bool = False) -> list[Message]:
        return [
            m._replace(latch_gen=(m.latch_gen - 1) & 0xFF)
            if isinstance(m, Fault) and m.active and code in STOPPING_FAULTS
            else m
            for m in super().raise_fault(code, detail, condition=condition)
        ]


class _FrozenResumeEncoders(EncoderModel):
    """An encoder that, after a dropout, counts on from the value it held."""

    _was_out = (False, False)

    def travel(self) -> tuple[float, float]:
        was = self._was_out
        self._was_out = (self.dropout[0], self.dropout[1])
        for side in (0, 1):
            if was[side] and not self.dropout[side]:
                true = travel_units(self._rover, *self._twin.motor_angles_rad)[side]
                offset = list(self._offset)
                offset[side] = true - self._held[side]
                self._offset = (offset[0], offset[1])
        return super().travel()


@_mutant(
    "encoder-resumes-frozen",
    "encoder-resume",
    "When an ENCODER fault's condition ends the failed side reports its true count since "
    "boot again (issue #40, 10: one that went on from its frozen value passed the suite).",
)
class _EncoderResumesFrozen(ControllerModel):
    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.encoders.__class__ = _FrozenResumeEncoders


@_mutant(
    "fault-status-first",
    "fault-order",
    "A stopping fault: FAULT active = 1 first, then STATUS ABORTED for the running step and "
    "each queued one.",
)
class _FaultStatusFirst(ControllerModel):
    def raise_fault(self, code: int, detail: int = 0, *, condition: bool = False) -> list[Message]:
        out = super().raise_fault(code, detail, condition=condition)
        if code in STOPPING_FAULTS and out and isinstance(out[0], Fault):
            _moved_after(out, out[0], (Status,))
        return out


@_mutant(
    "stall-over-before-stopped",
    "stall",
    "A stall is an event: FAULT active = 0 follows the STOPPED once the wheels are at rest.",
)
class _StallOverBeforeStopped(ControllerModel):
    def _check_stopped(self, travel: tuple[float, float], out: list[Message]) -> None:
        if self.at_rest:
            for code in sorted(self._momentary):
                out += self.clear_fault_condition(code)
        super()._check_stopped(travel, out)


@_mutant(
    "stall-detail-zero",
    "stall",
    "STALL_* detail is that side's distance still to go along its direction.",
)
class _StallDetailZero(ControllerModel):
    def raise_fault(self, code: int, detail: int = 0, *, condition: bool = False) -> list[Message]:
        stall = code in (FaultCode.STALL_LEFT, FaultCode.STALL_RIGHT)
        return super().raise_fault(code, 0 if stall else detail, condition=condition)


@_mutant(
    "stall-watch-10mm",
    "stall-speed-1",
    "Stall detection watches a side whose ramped motor command is at least 2.5 mm/s, so "
    "every step is watched (protocol v2 watched from 10 mm/s: speed 1 went unwatched).",
)
class _StallWatch10mm(ControllerModel):
    stall_min_command_mps = 0.01


# -- reboots ----------------------------------------------------------------------------


@_mutant(
    "reboot-keeps-nonce",
    "reboot",
    "At boot the controller picks a new random boot nonce.",
)
class _RebootKeepsNonce(ControllerModel):
    def _init_state(self) -> None:
        nonce = self.__dict__.get("boot_nonce")
        super()._init_state()
        if nonce is not None:
            self.boot_nonce = nonce


@_mutant(
    "reboot-keeps-clock",
    "reboot",
    "t_ms is ms since boot: it restarts at 0 at every boot.",
)
class _RebootKeepsClock(ControllerModel):
    def reboot(self) -> list[Message]:
        boot_s = self.boot_s
        out = super().reboot()
        self.boot_s = boot_s
        return out


@_mutant(
    "late-first-heartbeat",
    "reboot",
    "The first HEARTBEAT after boot follows the IDENT within one heartbeat period.",
)
class _LateFirstHeartbeat(ControllerModel):
    def reboot(self) -> list[Message]:
        out = super().reboot()
        self._next_heartbeat = self.now_s + 3.0 / self.heartbeat_hz
        return out


def _keep_frame_counter(endpoint: Endpoint) -> None:
    def keep() -> None:
        pass

    endpoint.restart_counter = keep  # type: ignore[method-assign]


MUTANTS["reboot-keeps-frame-counter"] = Mutant(
    "reboot-keeps-frame-counter",
    "seq-restart",
    "A controller's serial frame counter must restart at 0 at every boot: the boot IDENT "
    "has seq 0.",
    ControllerModel,
    _keep_frame_counter,
)
