"""The motor controller's firmware behaviour, driving the physics twin.

:class:`ControllerModel` implements the controller side of docs/protocol.md (states,
MOTION queue, STOP and its latch, CLEAR_STOP, watchdog, stall, telemetry);
docs/emulator.md, "The controller model", summarises it. The latch
(:attr:`ControllerModel.latch_causes`) is kept apart from the fault conditions active
now (:attr:`ControllerModel.faults`).

Pure logic over the twin: no I/O, no threads, no wall clock; time is the twin's. A front
end calls :meth:`ControllerModel.handle` per received message and
:meth:`ControllerModel.tick` per control period, and sends what they return.
Time-outs (watchdog, stall) are twin seconds times ``timeout_scale`` (``k`` for a twin
``k`` times faster than the host). Wrapping counters are compared modulo their width,
as the C core does (:func:`emulator.sensors.count_delta`).
"""

from __future__ import annotations

import enum
import logging
import math
import random
from collections import deque
from dataclasses import dataclass, field

from emulator.drive import StepProfile, motor_omegas, ramp
from emulator.sensors import EncoderModel, ImuModel, PoseSensor, SensorConfig, count_delta
from emulator.twin import Twin
from firmware_proto.model.rover import RoverDescription
from firmware_proto.wire.faults import STOPPING_FAULTS
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import (
    CONTROLLER_HEARTBEAT_PERIOD_MS,
    ENCODERS_RATE_HZ,
    MOTION_QUEUE_DEPTH,
    POSE_RATE_HZ,
    PROTOCOL_VERSION,
    SCHEMA_HASH,
    STALL_TIMEOUT_MS,
    WATCHDOG_MS,
    AbortReason,
    Ack,
    AckField,
    AckResult,
    ClearAck,
    ClearResult,
    ClearStop,
    Command,
    ControllerState,
    Encoders,
    Fault,
    FaultCode,
    Heartbeat,
    Hello,
    HostHeartbeat,
    Ident,
    Imu,
    Motion,
    Param,
    ParamResult,
    ParamValue,
    PoseMsg,
    Progress,
    SetParam,
    Status,
    StepState,
    Stop,
    StopAck,
    Stopped,
    WheelSpeeds,
)

__all__ = [
    "DEDUP_WINDOW",
    "PARAM_RANGES",
    "STOPPING_FAULTS",
    "ControllerConfig",
    "ControllerModel",
    "LatchCause",
]

logger = logging.getLogger(__name__)

DEDUP_WINDOW = 64
"""Accepted MOTION seqs remembered per session (docs/protocol.md)."""


class LatchCause(enum.Enum):
    """What set the latch (HEARTBEAT ``latch_stop``, ``latch_watchdog``, ``latch_fault``)."""

    STOP = "stop"
    WATCHDOG = "watchdog"
    FAULT = "fault"


PARAM_RANGES: dict[int, tuple[int, int]] = {
    Param.WATCHDOG_MS: (50, 10_000),
    Param.TELEMETRY_HZ: (1, 200),
    Param.POSE_HZ: (1, 50),
    Param.HEARTBEAT_HZ: (1, 50),
}
"""Accepted SET_PARAM values, inclusive."""

_REST_MPS = 1e-4
"""Wheel speed below which a side counts as at rest, m/s."""
_STALL_MIN_PROGRESS_UNITS = 1.0
_TIME_EPS_S = 1e-9
"""Float tolerance on twin-time comparisons, s: twin time is ``steps * dt``, so a silence of
exactly a timeout can compute a hair longer and trip it a tick early."""


@dataclass(frozen=True)
class ControllerConfig:
    """Firmware settings; defaults are the protocol's (docs/protocol.md, Timing)."""

    firmware_version: tuple[int, int, int] = (1, 0, 0)
    watchdog_ms: int = WATCHDOG_MS
    telemetry_hz: int = ENCODERS_RATE_HZ
    pose_hz: int = POSE_RATE_HZ
    heartbeat_hz: int = 1000 // CONTROLLER_HEARTBEAT_PERIOD_MS
    queue_depth: int = MOTION_QUEUE_DEPTH
    stall_timeout_ms: int = STALL_TIMEOUT_MS
    timeout_scale: float = 1.0
    sensors: SensorConfig = field(default_factory=SensorConfig)


@dataclass
class _Running:
    motion: Motion
    profile: StepProfile
    start_travel: tuple[float, float]


@dataclass
class _PendingStop:
    stop_id: int
    arrived_s: float
    travel_at_arrival: tuple[float, float]
    clears: int
    """The controller's count of CLEARED answers when the STOP arrived."""


class ControllerModel:
    """Firmware behaviour of the motor controller over a :class:`Twin`.

    Not thread-safe: one thread calls :meth:`handle` and :meth:`tick`. Some rules sit in
    methods of their own (:meth:`_sends_samples`, :meth:`_profile`,
    :meth:`_ramp_commands`, :meth:`_may_start_next`, :meth:`_stopped_distance_units`,
    :attr:`stall_min_command_mps`) so that a mutant (:mod:`emulator.mutants`) can break
    exactly one.
    """

    stall_min_command_mps = 0.0025
    """Stall detection watches a side whose ramped motor command is at least this, m/s:
    half of speed 1, so that every step is watched (docs/protocol.md, MOTION)."""

    def __init__(
        self,
        rover: RoverDescription,
        twin: Twin,
        config: ControllerConfig | None = None,
        *,
        seed: int = 0,
        protocol_version: int = PROTOCOL_VERSION,
        schema_hash: int = SCHEMA_HASH,
    ) -> None:
        """Args:
        rover: the rover description (speed scale, units, limits).
        twin: the plant; the model steps it once per :meth:`tick`.
        config: firmware settings.
        seed: seeds the boot nonces and every sensor's noise.
        protocol_version, schema_hash: what this firmware claims (to impersonate another).
        """
        self.rover = rover
        self.twin = twin
        self.config = config or ControllerConfig()
        self.protocol_version = protocol_version
        self.schema_hash = schema_hash
        self._rng = random.Random(seed)
        sensors = self.config.sensors
        self.encoders = EncoderModel(
            rover, twin, random.Random(self._rng.random()), sensors.encoder_noise_units
        )
        self.imu = ImuModel(twin, random.Random(self._rng.random()), sensors)
        self.pose_sensor = PoseSensor(twin, random.Random(self._rng.random()), sensors)
        self._init_params()
        self.rx_errors = 0
        self.boots = 0
        self._init_state()

    # -- state ------------------------------------------------------------------------
    def _init_params(self) -> None:
        """Run-time parameters at their firmware defaults (at power-on and every reboot:
        SET_PARAM values live in RAM, docs/protocol.md Parameters)."""
        self.watchdog_ms = self.config.watchdog_ms
        self.telemetry_hz = self.config.telemetry_hz
        self.pose_hz = self.config.pose_hz
        self.heartbeat_hz = self.config.heartbeat_hz

    def _init_state(self) -> None:
        self.state: int = ControllerState.BOOT
        """The :class:`ControllerState` code."""
        previous: int | None = getattr(self, "boot_nonce", None)
        nonce = self._rng.randrange(1 << 16)
        if nonce == previous:
            # Differs from the last boot's: the host tells a reboot by it (as the C core).
            nonce = (nonce + 1) & 0xFFFF
        self.boot_nonce = nonce
        self.boot_s = self.twin.time_s
        self.handshake_ok = False
        self.latch_causes: set[LatchCause] = set()
        """What set the latch since the last CLEARED (empty: not latched)."""
        self.faults: set[int] = set()
        """Fault codes whose condition is active now (HEARTBEAT ``fault_bits``)."""
        self._momentary: set[int] = set()
        """Active faults that are events (stall): their condition ends at rest."""
        self._queue: deque[Motion] = deque()
        self._running: _Running | None = None
        self._accepted: deque[int] = deque(maxlen=DEDUP_WINDOW)
        self._accepted_set: set[int] = set()
        self._setpoint = (0.0, 0.0)
        self._commanded = (0.0, 0.0)
        self._pending_stops: list[_PendingStop] = []
        self._reported_stops: set[int] = set()
        """Host stop_ids already answered with STOPPED since the latch was last cleared."""
        self._clears = 0
        """CLEAR_STOPs answered CLEARED since boot."""
        self.latch_gen = 0
        """The latch generation (HEARTBEAT ``latch_gen``): raised, wrapping at 256, by
        every new latch cause (docs/protocol.md, "Latch and faults")."""
        self._last_clear: tuple[int, int, int] | None = None
        """(stop_id, latch_gen, result) of the last CLEAR_STOP answered: a repeat of it
        gets the same answer and changes nothing. Survives sessions; a reboot forgets it."""
        self._ended = Progress(0, StepState.STARTED, AbortReason.NONE, 0, 0)
        self._last_rx_s: float | None = None
        self._watchdog_tripped = False
        self._stall_since: list[float | None] = [None, None]
        self._stall_ref = [0.0, 0.0]
        now = self.twin.time_s
        self._next_telemetry = now
        self._next_pose = now
        self._next_heartbeat = now

    @property
    def stop_latched(self) -> bool:
        """Motion is inhibited until CLEAR_STOP (a STOP, the watchdog or a fault set it)."""
        return bool(self.latch_causes)

    @property
    def now_s(self) -> float:
        """Twin time, s."""
        return self.twin.time_s

    @property
    def queue_depth(self) -> int:
        """Steps queued, the running one included."""
        return len(self._queue) + (self._running is not None)

    @property
    def wheel_setpoints_mps(self) -> tuple[float, float]:
        """Wheel speed targets (rover frame): zero from the moment a STOP is handled."""
        return self._setpoint

    @property
    def wheel_commands_mps(self) -> tuple[float, float]:
        """Speeds commanded to the motors: the setpoints, ramped at the accel limit."""
        return self._commanded

    @property
    def running_seq(self) -> int | None:
        """Sequence number of the step being executed, if any."""
        return self._running.motion.seq if self._running else None

    @property
    def at_rest(self) -> bool:
        """Both sides commanded to zero and measured at rest."""
        left, right = self.twin.wheel_surface_speeds_mps
        return self._commanded == (0.0, 0.0) and abs(left) < _REST_MPS and abs(right) < _REST_MPS

    def _clock_ms(self) -> int:
        return int((self.now_s - self.boot_s) * 1000.0 + 1e-6) & 0xFFFF

    def _scaled_s(self, ms: float) -> float:
        return ms / 1000.0 * self.config.timeout_scale

    # -- boot ---------------------------------------------------------------------------
    def boot(self) -> list[Message]:
        """Power-on: the IDENT the firmware sends unsolicited."""
        self.boots += 1
        logger.info("controller boot %d, nonce 0x%04X", self.boots, self.boot_nonce)
        return [self._ident()]

    def reboot(self) -> list[Message]:
        """A reset: state, queue, latch, session, counts and SET_PARAM values are lost;
        the motors stop at once (no braking ramp); a new boot nonce; IDENT again."""
        self._init_state()
        self._init_params()
        self.encoders.reset()
        self.pose_sensor.clear()
        return self.boot()

    def _ident(self) -> Ident:
        major, minor, patch = self.config.firmware_version
        return Ident(self.protocol_version, major, minor, patch, self.schema_hash, self.boot_nonce)

    # -- receive ------------------------------------------------------------------------
    def rx_error(self, count: int = 1) -> None:
        """The front end dropped ``count`` bad frames (reported in HEARTBEAT)."""
        self.rx_errors += count

    def handle(self, msg: Message) -> list[Message]:
        """Process one message from the host; returns the immediate answers.

        A STOP has zeroed the wheel targets and purged the queue when this returns. A
        controller-to-host message (an echo) is counted in ``rx_errors`` and ignored; it
        does not feed the watchdog.
        """
        if msg.DIRECTION != "host_to_controller":
            self.rx_errors += 1
            logger.debug("dropped %s: wrong direction (not for the controller)", msg.NAME)
            return []
        out: list[Message] = []
        if isinstance(msg, Stop) and not self._stop_is_repeat(msg.stop_id):
            # Raised first: every frame after the STOP names the generation it made.
            self._raise_latch_gen()
        self._feed_watchdog(out)
        if isinstance(msg, Stop):
            aborted: list[Message] = []
            self._stop(msg.stop_id, AbortReason.STOP, aborted, LatchCause.STOP)
            # The acknowledgement goes first: it is what the host is timing.
            out.insert(0, StopAck(msg.stop_id, self.state, self.latch_gen))
            out += aborted
        elif isinstance(msg, Motion):
            out += self._motion(msg)
        elif isinstance(msg, ClearStop):
            result = self._clear(msg.stop_id, msg.latch_gen)
            out.append(ClearAck(msg.stop_id, result, self.latch_gen))
        elif isinstance(msg, Hello):
            self._hello(msg, out)
        elif isinstance(msg, SetParam):
            out.append(self._set_param(msg))
        else:
            assert isinstance(msg, HostHeartbeat), msg.NAME
        return out

    def _feed_watchdog(self, out: list[Message]) -> None:
        self._last_rx_s = self.now_s
        if self._watchdog_tripped:
            self._watchdog_tripped = False
            out += self.clear_fault_condition(FaultCode.WATCHDOG)

    def _hello(self, msg: Hello, out: list[Message]) -> None:
        match = (
            msg.protocol_version == self.protocol_version and msg.schema_hash == self.schema_hash
        )
        # A new session: the previous host's steps and seqs are gone.
        self._abort_all(AbortReason.SESSION, out)
        self._setpoint = (0.0, 0.0)
        self._accepted.clear()
        self._accepted_set.clear()
        self._ended = Progress(0, StepState.STARTED, AbortReason.NONE, 0, 0)
        self.handshake_ok = match
        if match and self.state == ControllerState.BOOT:
            self.state = ControllerState.IDLE
        elif not match and self.state in (ControllerState.IDLE, ControllerState.EXECUTING):
            self.state = ControllerState.BOOT
        if not match:
            logger.warning(
                "HELLO mismatch: host v%d/0x%04X, firmware v%d/0x%04X",
                msg.protocol_version,
                msg.schema_hash,
                self.protocol_version,
                self.schema_hash,
            )
        out.append(self._ident())

    def _motion(self, msg: Motion) -> list[Message]:
        def ack(result: int, fld: int = AckField.NONE) -> list[Message]:
            return [Ack(msg.seq, result, fld, self.queue_depth)]

        # The order of the checks is normative (docs/protocol.md, MOTION).
        if not self.handshake_ok:
            return ack(AckResult.NOT_READY)
        if msg.seq in self._accepted_set:
            return ack(AckResult.DUPLICATE)
        limits = self.rover.drive
        if msg.command > max(Command):
            return ack(AckResult.OUT_OF_RANGE, AckField.COMMAND)
        if msg.command == Command.STOP:
            # An emergency stop whatever its speed and distance: they are ignored.
            self._remember(msg.seq)
            out: list[Message] = []
            self._stop(0, AbortReason.STOP, out, LatchCause.STOP)
            return ack(AckResult.ACCEPTED) + out
        if msg.speed > limits.max_speed:
            return ack(AckResult.OUT_OF_RANGE, AckField.SPEED)
        if msg.distance > limits.max_distance:
            return ack(AckResult.OUT_OF_RANGE, AckField.DISTANCE)
        if self.state == ControllerState.FAULT:
            return ack(AckResult.FAULT_ACTIVE)
        if self.stop_latched:
            return ack(AckResult.STOP_LATCHED)
        if self.queue_depth >= self.config.queue_depth:
            return ack(AckResult.QUEUE_FULL)
        self._remember(msg.seq)
        self._queue.append(msg)
        return ack(AckResult.ACCEPTED)

    def _remember(self, seq: int) -> None:
        if len(self._accepted) == self._accepted.maxlen:
            self._accepted_set.discard(self._accepted[0])
        self._accepted.append(seq)
        self._accepted_set.add(seq)

    def _stop(self, stop_id: int, reason: int, out: list[Message], cause: LatchCause) -> None:
        """Zero the targets now, purge, latch for ``cause``; STOPPED follows when at rest."""
        self._setpoint = (0.0, 0.0)
        self._abort_all(reason, out)
        self.latch_causes.add(cause)
        if stop_id == 0:
            self._raise_latch_gen()  # the controller's own stops are always new causes
        if cause is not LatchCause.STOP:
            self.state = ControllerState.FAULT
        elif self.state != ControllerState.FAULT:
            self.state = ControllerState.STOP_LATCHED
        # One STOPPED per host stop_id per latch (a repeat shares it); own stops (0) get one each.
        if stop_id != 0 and stop_id in self._reported_stops:
            return
        for pending in self._pending_stops:
            if pending.stop_id == stop_id:
                # Owed from a latch a CLEARED released: this latch shares it.
                pending.clears = self._clears
                return
        self._pending_stops.append(
            _PendingStop(stop_id, self.now_s, self.encoders.travel(), self._clears)
        )

    def _ended_status(self, seq: int, state: int, reason: int, travel: int) -> Status:
        """STATUS for a step that ended, remembered for PROGRESS."""
        count = (self._ended.ended_count + 1) & 0xFFFF
        self._ended = Progress(seq, state, reason, count, travel)
        return Status(seq, state, reason, travel)

    def _abort_all(self, reason: int, out: list[Message]) -> None:
        if self._running is not None:
            out.append(
                self._ended_status(
                    self._running.motion.seq, StepState.ABORTED, reason, self._step_travel()
                )
            )
            self._running = None
        while self._queue:
            out.append(self._ended_status(self._queue.popleft().seq, StepState.ABORTED, reason, 0))
        if self.state == ControllerState.EXECUTING:
            self.state = ControllerState.IDLE

    def _step_travel(self) -> int:
        if self._running is None:
            return 0
        left, right = self.encoders.travel()
        l0, r0 = self._running.start_travel
        return min(0xFFFF, round((abs(count_delta(left, l0)) + abs(count_delta(right, r0))) / 2.0))

    def _stop_is_repeat(self, stop_id: int) -> bool:
        """A host STOP with this id was seen in this latch (STOPPED owed or sent): a repeat,
        which raises no latch generation and gets no STOPPED of its own."""
        return stop_id != 0 and (
            stop_id in self._reported_stops
            or any(p.stop_id == stop_id and p.clears == self._clears for p in self._pending_stops)
        )

    def _raise_latch_gen(self) -> None:
        """A new latch cause: the generation moves on, wrapping at 256."""
        self.latch_gen = (self.latch_gen + 1) & 0xFF

    def _clear(self, stop_id: int, latch_gen: int) -> int:
        """Answer a CLEAR_STOP (docs/protocol.md, "Latch and faults"): a repeat of the last
        request answered gets its answer again; else the first that holds of
        NOT_LATCHED, LATCH_CHANGED, FAULT_PERSISTS, CLEARED."""
        last = self._last_clear
        if last is not None and last[:2] == (stop_id, latch_gen):
            return last[2]  # a repeat that crossed its answer: nothing changes
        result = self._judge_clear(latch_gen)
        self._last_clear = (stop_id, latch_gen, result)
        if result == ClearResult.CLEARED:
            self.latch_causes.clear()
            self._reported_stops.clear()
            self._clears += 1
            self.state = ControllerState.IDLE if self.handshake_ok else ControllerState.BOOT
        return result

    def _judge_clear(self, latch_gen: int) -> int:
        """The answer to a new CLEAR_STOP request naming generation ``latch_gen``."""
        if not self.latch_causes:
            return ClearResult.NOT_LATCHED
        if latch_gen != self.latch_gen:
            return ClearResult.LATCH_CHANGED
        if self.faults & STOPPING_FAULTS:
            return ClearResult.FAULT_PERSISTS
        return ClearResult.CLEARED

    def _set_param(self, msg: SetParam) -> ParamValue:
        rng = PARAM_RANGES.get(msg.param)
        if rng is None:
            return ParamValue(msg.param, ParamResult.UNKNOWN_PARAM, 0)
        attr = {
            Param.WATCHDOG_MS: "watchdog_ms",
            Param.TELEMETRY_HZ: "telemetry_hz",
            Param.POSE_HZ: "pose_hz",
            Param.HEARTBEAT_HZ: "heartbeat_hz",
        }[Param(msg.param)]
        if not rng[0] <= msg.value <= rng[1]:
            return ParamValue(msg.param, ParamResult.OUT_OF_RANGE, getattr(self, attr))
        setattr(self, attr, msg.value)
        return ParamValue(msg.param, ParamResult.OK, msg.value)

    # -- faults -------------------------------------------------------------------------
    def raise_fault(self, code: int, detail: int = 0, *, condition: bool = False) -> list[Message]:
        """A fault's condition became active: FAULT active = 1; a stopping fault also
        stops the rover, latches (``latch_watchdog`` or ``latch_fault``) and enters FAULT.

        Args:
            code: a :class:`FaultCode`.
            detail: code-specific detail for the FAULT message.
            condition: the condition persists until :meth:`clear_fault_condition`;
                without it the fault is an event (a stall) that ends at rest, with
                FAULT active = 0 after STOPPED.
        """
        out: list[Message] = []
        if code in self.faults:
            return out
        self.faults.add(code)
        if not condition:
            self._momentary.add(code)
        stopped: list[Message] = []
        if code in STOPPING_FAULTS:
            if code == FaultCode.WATCHDOG:
                reason, cause = AbortReason.WATCHDOG, LatchCause.WATCHDOG
            elif code in (FaultCode.STALL_LEFT, FaultCode.STALL_RIGHT):
                reason, cause = AbortReason.STALL, LatchCause.FAULT
            else:
                reason, cause = AbortReason.FAULT, LatchCause.FAULT
            self._stop(0, reason, stopped, cause)
        # FAULT first (it names the generation the stop raised), then the aborts.
        out.append(Fault(code, 1, min(detail, 0xFFFF), self.latch_gen))
        out += stopped
        logger.info("fault %s raised (detail %d)", FaultCode(code).name, detail)
        return out

    def clear_fault_condition(self, code: int) -> list[Message]:
        """The condition of a fault went away: FAULT active = 0 and its bit clears. The
        latch a stopping fault set holds until CLEAR_STOP."""
        if code not in self.faults:
            return []
        self.faults.discard(code)
        self._momentary.discard(code)
        logger.info("fault %s condition cleared", FaultCode(code).name)
        return [Fault(code, 0, 0, self.latch_gen)]

    # -- tick ---------------------------------------------------------------------------
    def tick(self) -> list[Message]:
        """One control period: watchdog, step logic, one physics step, telemetry due."""
        out: list[Message] = []
        dt = self.twin.dt_s
        self._check_watchdog(out)
        travel = self.encoders.travel()
        if self._running is None and self._queue and self._may_start_next():
            self._start_next(travel, out)
        if self._running is not None:
            run = self._running
            self._setpoint = run.profile.update(
                count_delta(travel[0], run.start_travel[0]),
                count_delta(travel[1], run.start_travel[1]),
                dt,
            )
            if run.profile.done:
                out.append(
                    self._ended_status(
                        run.motion.seq, StepState.COMPLETED, AbortReason.NONE, self._step_travel()
                    )
                )
                self._running = None
                if self._queue:
                    self._start_next(travel, out)
                else:
                    self.state = ControllerState.IDLE
        self._ramp_commands(dt)
        self.twin.set_motor_omegas(*motor_omegas(self.rover, *self._commanded))
        self.twin.step()
        travel_after = self.encoders.travel()
        self._check_stall(travel_after, out)
        self._check_stopped(travel_after, out)
        self._telemetry(out)
        return out

    def _may_start_next(self) -> bool:
        """Whether a queued step may start now: not while latched, nor while a STOPPED is
        owed (so every STOPPED measures a real stop, and the next step starts from rest)."""
        return not self.stop_latched and not self._pending_stops

    def _ramp_commands(self, dt: float) -> None:
        """The motor commands follow the setpoints at the acceleration limit."""
        dv = self.rover.drive.wheel_accel_limit_mps2 * dt
        self._commanded = (
            ramp(self._commanded[0], self._setpoint[0], dv),
            ramp(self._commanded[1], self._setpoint[1], dv),
        )

    def _profile(self, motion: Motion) -> StepProfile:
        """The speed profile of a step starting now, from the current commands."""
        return StepProfile(
            self.rover,
            motion.command,
            motion.speed,
            motion.distance,
            initial_left_mps=self._commanded[0],
            initial_right_mps=self._commanded[1],
        )

    def _start_next(self, travel: tuple[float, float], out: list[Message]) -> None:
        motion = self._queue.popleft()
        profile = self._profile(motion)
        self._running = _Running(motion, profile, travel)
        self._stall_since = [None, None]
        self._stall_ref = list(travel)
        self.state = ControllerState.EXECUTING
        out.append(Status(motion.seq, StepState.STARTED, AbortReason.NONE, 0))

    def _check_watchdog(self, out: list[Message]) -> None:
        # Armed by a matching HELLO only: without a session there is nothing to stop.
        if not self.handshake_ok or self._last_rx_s is None or self._watchdog_tripped:
            return
        silent_s = self.now_s - self._last_rx_s
        if silent_s > self._scaled_s(self.watchdog_ms) + _TIME_EPS_S:
            self._watchdog_tripped = True
            detail = round(silent_s / self.config.timeout_scale * 1000.0)
            logger.warning("watchdog: no valid frame for %.0f ms", detail)
            out += self.raise_fault(FaultCode.WATCHDOG, detail, condition=True)

    def _check_stall(self, travel: tuple[float, float], out: list[Message]) -> None:
        if self._running is None:
            self._stall_since = [None, None]
            return
        now = self.now_s
        for side, code in ((0, FaultCode.STALL_LEFT), (1, FaultCode.STALL_RIGHT)):
            if abs(self._commanded[side]) < self.stall_min_command_mps or (
                abs(count_delta(travel[side], self._stall_ref[side])) >= _STALL_MIN_PROGRESS_UNITS
            ):
                self._stall_since[side] = None
                self._stall_ref[side] = travel[side]
                continue
            since = self._stall_since[side]
            if since is None:
                self._stall_since[side] = now
            elif now - since > self._scaled_s(self.config.stall_timeout_ms) + _TIME_EPS_S:
                expected = self._running.profile.remaining_units(
                    count_delta(travel[0], self._running.start_travel[0]),
                    count_delta(travel[1], self._running.start_travel[1]),
                )[side]
                out += self.raise_fault(code, max(0, round(expected)))
                return

    def _check_stopped(self, travel: tuple[float, float], out: list[Message]) -> None:
        if not self.at_rest:
            return
        self._report_stopped(travel, out)
        # Events (a stall) are over once the wheels are at rest: after STOPPED.
        for code in sorted(self._momentary):
            out += self.clear_fault_condition(code)

    def _report_stopped(self, travel: tuple[float, float], out: list[Message]) -> None:
        if not self._pending_stops:
            return
        for pending in self._pending_stops:
            moved_m = (
                self._stopped_distance_units(travel, pending.travel_at_arrival)
                / self.rover.drive.distance_units_per_m
            )
            duration_ms = (self.now_s - pending.arrived_s) / self.config.timeout_scale * 1000.0
            out.append(
                Stopped(
                    pending.stop_id,
                    min(0xFFFF, round(moved_m * 1000.0)),
                    min(0xFFFF, round(duration_ms)),
                )
            )
            if pending.stop_id != 0 and pending.clears == self._clears:
                # Remembered only within its latch (after a CLEARED the id is new again).
                self._reported_stops.add(pending.stop_id)
        self._pending_stops.clear()

    @staticmethod
    def _stopped_distance_units(
        travel: tuple[float, float], at_arrival: tuple[float, float]
    ) -> float:
        """STOPPED's distance in distance units: the mean of both sides' absolute travel
        since the STOP arrived (unsigned: a spin reports a positive distance)."""
        return (
            abs(count_delta(travel[0], at_arrival[0])) + abs(count_delta(travel[1], at_arrival[1]))
        ) / 2.0

    # -- telemetry ----------------------------------------------------------------------
    def _telemetry(self, out: list[Message]) -> None:
        """Telemetry due now. Sensor samples only in a session (docs/protocol.md,
        Handshake): a new boot's first counts reach a host only after its HELLO."""
        now = self.now_s
        eps = 1e-9
        if now + eps >= self._next_telemetry:
            self._next_telemetry = max(self._next_telemetry + 1.0 / self.telemetry_hz, now)
            samples = self._fast_telemetry()  # read on schedule, sent or not
            if self._sends_samples():
                out += samples
        if now + eps >= self._next_pose:
            self._next_pose = max(self._next_pose + 1.0 / self.pose_hz, now)
            self.pose_sensor.sample()
        for m in self.pose_sensor.due():
            if not self._sends_samples():
                continue
            # The age is in host time, like the timeouts: the host stamps with it.
            age_s = (now - m.taken_s) / self.config.timeout_scale
            out.append(self._pose_message(m.pose.x_m, m.pose.y_m, m.pose.yaw_rad, m.sigma_m, age_s))
        if now + eps >= self._next_heartbeat:
            self._next_heartbeat = max(self._next_heartbeat + 1.0 / self.heartbeat_hz, now)
            out.append(self.heartbeat())
            out.append(self._ended)

    def _sends_samples(self) -> bool:
        """Whether sensor samples go out now: only in a session."""
        return self.handshake_ok

    def _fast_telemetry(self) -> list[Message]:
        t_ms = self._clock_ms()
        left, right = self.encoders.counts()
        ml, mr = self.twin.wheel_surface_speeds_mps
        sl, sr = self._setpoint
        out: list[Message] = [
            Encoders(t_ms, _wrap24(left), _wrap24(right)),
            WheelSpeeds(t_ms, _mm12(ml), _mm12(mr), _mm12(sl), _mm12(sr)),
        ]
        reading = self.imu.read()
        if reading is not None:
            out.append(
                Imu(
                    t_ms,
                    _clamp16(reading.yaw_rate_rad_s * 1000.0),
                    _clamp16(reading.accel_x_mps2 * 1000.0),
                    _clamp16(reading.accel_y_mps2 * 1000.0),
                )
            )
        return out

    @staticmethod
    def _pose_message(
        x_m: float, y_m: float, yaw_rad: float, sigma_m: float, age_s: float
    ) -> PoseMsg:
        limit = (1 << 19) - 1
        x_mm = max(-limit - 1, min(limit, round(x_m * 1000.0)))
        y_mm = max(-limit - 1, min(limit, round(y_m * 1000.0)))
        yaw = round(math.degrees(yaw_rad) * 10.0)
        yaw = (yaw + 1800) % 3600 - 1800
        sigma_cm = 0 if sigma_m <= 0.0 else max(1, min(15, round(sigma_m * 100.0)))
        return PoseMsg(x_mm, y_mm, yaw, sigma_cm, max(0, min(255, round(age_s * 1000.0 / 4.0))))

    def heartbeat(self) -> Heartbeat:
        """The HEARTBEAT for the current state."""
        bits = 0
        for code in self.faults:
            bits |= 1 << (code - 1)
        causes = self.latch_causes
        return Heartbeat(
            self.state,
            int(self.stop_latched),
            int(self.handshake_ok),
            int(LatchCause.STOP in causes),
            int(LatchCause.WATCHDOG in causes),
            int(LatchCause.FAULT in causes),
            bits,
            min(255, self.queue_depth),
            self.boot_nonce,
            self.rx_errors & 0xFFFF,
            self.latch_gen,
        )


def _wrap24(value: int) -> int:
    return ((value + (1 << 23)) & 0xFFFFFF) - (1 << 23)


def _mm12(speed_mps: float) -> int:
    return max(-2048, min(2047, round(speed_mps * 1000.0)))


def _clamp16(value: float) -> int:
    return max(-32768, min(32767, round(value)))
