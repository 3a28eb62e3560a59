"""Protocol messages, GENERATED from ``firmware_proto/wire/protocol.toml``. Do not edit.

Regenerate with ``rover frame generate``. Every class is an immutable named tuple of
raw integer fields (see :mod:`firmware_proto.wire.message` for why); ``pack()``
checks each field and ``unpack()`` is the strict decoder.
The stream decoders use :data:`DECODERS`, which return ``None`` for out-of-range data.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from enum import IntEnum
from typing import ClassVar, NamedTuple

from firmware_proto.errors import DecodeError
from firmware_proto.wire.message import Message, field_error

__all__ = [
    "ACK_TIMEOUT_MS",
    "BROADCAST_NODE",
    "BY_NAME",
    "CAN_NODE_BITS",
    "CONTROLLER_HEARTBEAT_PERIOD_MS",
    "DECODERS",
    "DEFAULT_NODE",
    "ENCODERS_RATE_HZ",
    "HOST_HEARTBEAT_PERIOD_MS",
    "IMU_RATE_HZ",
    "LENGTHS",
    "LINK_LOST_HEARTBEATS",
    "MAX_PAYLOAD_BYTES",
    "MESSAGE_TYPES",
    "MOTION_QUEUE_DEPTH",
    "MOTION_RETRIES",
    "POSE_RATE_HZ",
    "PROTOCOL_VERSION",
    "SCHEMA_HASH",
    "STALL_TIMEOUT_MS",
    "STOP_REPEAT_MS",
    "WATCHDOG_MS",
    "WHEEL_SPEEDS_RATE_HZ",
    "AbortReason",
    "Ack",
    "AckField",
    "AckResult",
    "ClearAck",
    "ClearResult",
    "ClearStop",
    "Command",
    "ControllerState",
    "Encoders",
    "Fault",
    "FaultCode",
    "Heartbeat",
    "Hello",
    "HostHeartbeat",
    "Ident",
    "Imu",
    "Motion",
    "Param",
    "ParamResult",
    "ParamValue",
    "PoseMsg",
    "Progress",
    "SetParam",
    "Status",
    "StepState",
    "Stop",
    "StopAck",
    "StopSource",
    "Stopped",
    "WheelSpeeds",
]

PROTOCOL_VERSION = 4
SCHEMA_HASH = 0x75E0
MAX_PAYLOAD_BYTES = 8
CAN_NODE_BITS = 4
BROADCAST_NODE = 0
DEFAULT_NODE = 1

_new = tuple.__new__

HOST_HEARTBEAT_PERIOD_MS = 100
CONTROLLER_HEARTBEAT_PERIOD_MS = 100
WATCHDOG_MS = 250
LINK_LOST_HEARTBEATS = 3
ACK_TIMEOUT_MS = 50
MOTION_RETRIES = 3
STOP_REPEAT_MS = 10
MOTION_QUEUE_DEPTH = 8
STALL_TIMEOUT_MS = 1000
ENCODERS_RATE_HZ = 50
WHEEL_SPEEDS_RATE_HZ = 50
IMU_RATE_HZ = 50
POSE_RATE_HZ = 10


class Command(IntEnum):
    """Motion command codes (docs/architecture.md, contract 2)."""

    STOP = 0
    FWD = 1
    REV = 2
    LEFT = 3
    RIGHT = 4


class StopSource(IntEnum):
    """Who asked for an emergency stop."""

    OPERATOR = 0
    PLAN_STEP = 1
    DRIFT = 2
    HOST_FAULT = 3
    BENCH = 4


class AckResult(IntEnum):
    """Answer to a MOTION request. ACCEPTED and DUPLICATE both mean: stop retransmitting."""

    ACCEPTED = 0
    OUT_OF_RANGE = 1
    QUEUE_FULL = 2
    STOP_LATCHED = 3
    DUPLICATE = 4
    NOT_READY = 5
    FAULT_ACTIVE = 6


class AckField(IntEnum):
    """Which MOTION field was out of range (NONE for other results)."""

    NONE = 0
    COMMAND = 1
    SPEED = 2
    DISTANCE = 3


class StepState(IntEnum):
    """Progress of one MOTION step."""

    STARTED = 0
    COMPLETED = 1
    ABORTED = 2


class AbortReason(IntEnum):
    """Why a step ended early (NONE unless STATUS state is ABORTED): STOP for a STOP frame or a MOTION with command STOP, WATCHDOG for the watchdog, STALL for a stall fault, FAULT for any other stopping fault, SESSION for a new session (HELLO)."""

    NONE = 0
    STOP = 1
    WATCHDOG = 2
    STALL = 3
    FAULT = 4
    SESSION = 5


class ControllerState(IntEnum):
    """Controller state machine (docs/protocol.md, 'State machine')."""

    BOOT = 0
    IDLE = 1
    EXECUTING = 2
    STOP_LATCHED = 3
    FAULT = 4


class ClearResult(IntEnum):
    """Answer to CLEAR_STOP: CLEARED (the latch is released), NOT_LATCHED (there was no latch; nothing changes), FAULT_PERSISTS (a stopping fault's condition is still active; the latch holds), LATCH_CHANGED (the latch gained a cause since the generation the request names; the latch holds). A repeat of the last request answered gets the same answer and changes nothing."""

    CLEARED = 0
    NOT_LATCHED = 1
    FAULT_PERSISTS = 2
    LATCH_CHANGED = 3


class FaultCode(IntEnum):
    """Fault codes; bit (code - 1) of HEARTBEAT.fault_bits is set while the fault's condition is active (from FAULT active = 1 to FAULT active = 0). WATCHDOG, STALL_*, ENCODER, DRIVER and INTERNAL stop the rover and latch; IMU and POSE only report."""

    WATCHDOG = 1
    STALL_LEFT = 2
    STALL_RIGHT = 3
    ENCODER = 4
    IMU = 5
    POSE = 6
    DRIVER = 7
    INTERNAL = 8


class Param(IntEnum):
    """Run-time parameters settable with SET_PARAM."""

    WATCHDOG_MS = 1
    TELEMETRY_HZ = 2
    POSE_HZ = 3
    HEARTBEAT_HZ = 4


class ParamResult(IntEnum):
    """Answer to SET_PARAM. OK: the value is in force; UNKNOWN_PARAM: no such parameter (value 0); OUT_OF_RANGE: refused, value is the one still in force."""

    OK = 0
    UNKNOWN_PARAM = 1
    OUT_OF_RANGE = 2


_S_STOP = struct.Struct("<HB")


class _StopFields(NamedTuple):
    stop_id: int
    source: int


class Stop(Message, _StopFields):
    """STOP (id 0, host to controller, emergency). Emergency stop: preempts everything, purges
    the queue, latches until CLEAR_STOP. Idempotent.

    Sent: on demand; repeated every stop_repeat_ms until STOP_ACK.

    Attributes:
        stop_id: u16 range 1..65535. host's request id, echoed in STOP_ACK and STOPPED; 0 is
            reserved for stops the controller starts itself (a STOP frame with 0 is outside the
            wire range: dropped and counted, not obeyed).
        source: u8 (StopSource) range 0..4. who asked.
    """

    __slots__ = ()
    MSG_ID: ClassVar[int] = 0
    NAME: ClassVar[str] = "STOP"
    LENGTH: ClassVar[int] = 3
    DIRECTION: ClassVar[str] = "host_to_controller"
    PRIORITY: ClassVar[str] = "emergency"
    FIELDS: ClassVar[tuple[str, ...]] = ("stop_id", "source")
    ENUMS: ClassVar[dict[str, type[IntEnum]]] = {"source": StopSource}

    def pack(self, strict: bool = True) -> bytes:
        """Encode the payload; see :meth:`Message.pack`."""
        stop_id = self.stop_id
        source = self.source
        if not (isinstance(stop_id, int) and 1 <= stop_id <= 65535):
            raise field_error("STOP", "stop_id", stop_id, 1, 65535)
        if not (isinstance(source, int) and 0 <= source <= 4):
            raise field_error("STOP", "source", source, 0, 4)
        return _S_STOP.pack(stop_id, source)

    @classmethod
    def unpack(cls, payload: bytes) -> Stop:
        """Strict decode of one payload.

        Raises:
            DecodeError: wrong length, or a value outside the wire range.
        """
        if len(payload) != 3:
            raise DecodeError(f"STOP payload is {len(payload)} bytes, expected 3")
        decoded = _decode_stop(bytes(payload))
        if decoded is None:
            raise DecodeError("STOP payload has a value outside its range")
        return decoded


def _decode_stop(payload: bytes) -> Stop | None:
    values = _S_STOP.unpack(payload)
    stop_id = values[0]
    source = values[1]
    if not (1 <= stop_id <= 65535 and 0 <= source <= 4):
        return None
    return _new(Stop, values)


_S_STOP_ACK = struct.Struct("<HBB")


class _StopAckFields(NamedTuple):
    stop_id: int
    state: int
    latch_gen: int


class StopAck(Message, _StopAckFields):
    """STOP_ACK (id 1, controller to host, emergency). STOP received; wheel targets are already
    zero and the queue purged. Sent for every STOP frame, repeats included.

    Sent: once per STOP received.

    Attributes:
        stop_id: u16. echo of STOP.stop_id.
        state: u8 (ControllerState) range 0..4. state after the STOP (STOP_LATCHED, or FAULT).
        latch_gen: u8. the latch generation after the STOP (docs/protocol.md, 'Latch and
            faults').
    """

    __slots__ = ()
    MSG_ID: ClassVar[int] = 1
    NAME: ClassVar[str] = "STOP_ACK"
    LENGTH: ClassVar[int] = 4
    DIRECTION: ClassVar[str] = "controller_to_host"
    PRIORITY: ClassVar[str] = "emergency"
    FIELDS: ClassVar[tuple[str, ...]] = ("stop_id", "state", "latch_gen")
    ENUMS: ClassVar[dict[str, type[IntEnum]]] = {"state": ControllerState}

    def pack(self, strict: bool = True) -> bytes:
        """Encode the payload; see :meth:`Message.pack`."""
        stop_id = self.stop_id
        state = self.state
        latch_gen = self.latch_gen
        if not (isinstance(stop_id, int) and 0 <= stop_id <= 65535):
            raise field_error("STOP_ACK", "stop_id", stop_id, 0, 65535)
        if not (isinstance(state, int) and 0 <= state <= 4):
            raise field_error("STOP_ACK", "state", state, 0, 4)
        if not (isinstance(latch_gen, int) and 0 <= latch_gen <= 255):
            raise field_error("STOP_ACK", "latch_gen", latch_gen, 0, 255)
        return _S_STOP_ACK.pack(stop_id, state, latch_gen)

    @classmethod
    def unpack(cls, payload: bytes) -> StopAck:
        """Strict decode of one payload.

        Raises:
            DecodeError: wrong length, or a value outside the wire range.
        """
        if len(payload) != 4:
            raise DecodeError(f"STOP_ACK payload is {len(payload)} bytes, expected 4")
        decoded = _decode_stop_ack(bytes(payload))
        if decoded is None:
            raise DecodeError("STOP_ACK payload has a value outside its range")
        return decoded


def _decode_stop_ack(payload: bytes) -> StopAck | None:
    values = _S_STOP_ACK.unpack(payload)
    state = values[1]
    if not (0 <= state <= 4):
        return None
    return _new(StopAck, values)


_S_CLEAR_STOP = struct.Struct("<HB")


class _ClearStopFields(NamedTuple):
    stop_id: int
    latch_gen: int


class ClearStop(Message, _ClearStopFields):
    """CLEAR_STOP (id 2, host to controller, emergency). Explicit unlatch: releases the latch
    (whatever set it: STOP, watchdog, fault) if it is still the latch of the generation named
    and no stopping fault's condition is active.

    Sent: on demand; repeated every stop_repeat_ms until CLEAR_ACK.

    Attributes:
        stop_id: u16 range 1..65535. host's request id, echoed in CLEAR_ACK.
        latch_gen: u8. the latch generation the request releases: the last one the host reported
            to whoever asked for the clear (its operator, or its own automatic clear).
    """

    __slots__ = ()
    MSG_ID: ClassVar[int] = 2
    NAME: ClassVar[str] = "CLEAR_STOP"
    LENGTH: ClassVar[int] = 3
    DIRECTION: ClassVar[str] = "host_to_controller"
    PRIORITY: ClassVar[str] = "emergency"
    FIELDS: ClassVar[tuple[str, ...]] = ("stop_id", "latch_gen")
    ENUMS: ClassVar[dict[str, type[IntEnum]]] = {}

    def pack(self, strict: bool = True) -> bytes:
        """Encode the payload; see :meth:`Message.pack`."""
        stop_id = self.stop_id
        latch_gen = self.latch_gen
        if not (isinstance(stop_id, int) and 1 <= stop_id <= 65535):
            raise field_error("CLEAR_STOP", "stop_id", stop_id, 1, 65535)
        if not (isinstance(latch_gen, int) and 0 <= latch_gen <= 255):
            raise field_error("CLEAR_STOP", "latch_gen", latch_gen, 0, 255)
        return _S_CLEAR_STOP.pack(stop_id, latch_gen)

    @classmethod
    def unpack(cls, payload: bytes) -> ClearStop:
        """Strict decode of one payload.

        Raises:
            DecodeError: wrong length, or a value outside the wire range.
        """
        if len(payload) != 3:
            raise DecodeError(f"CLEAR_STOP payload is {len(payload)} bytes, expected 3")
        decoded = _decode_clear_stop(bytes(payload))
        if decoded is None:
            raise DecodeError("CLEAR_STOP payload has a value outside its range")
        return decoded


def _decode_clear_stop(payload: bytes) -> ClearStop | None:
    values = _S_CLEAR_STOP.unpack(payload)
    stop_id = values[0]
    if not (1 <= stop_id <= 65535):
        return None
    return _new(ClearStop, values)


_S_CLEAR_ACK = struct.Struct("<HBB")


class _ClearAckFields(NamedTuple):
    stop_id: int
    result: int
    latch_gen: int


class ClearAck(Message, _ClearAckFields):
    """CLEAR_ACK (id 3, controller to host, emergency). Answer to CLEAR_STOP.

    Sent: once per CLEAR_STOP received.

    Attributes:
        stop_id: u16. echo of CLEAR_STOP.stop_id.
        result: u8 (ClearResult) range 0..3.
        latch_gen: u8. the latch generation after the answer.
    """

    __slots__ = ()
    MSG_ID: ClassVar[int] = 3
    NAME: ClassVar[str] = "CLEAR_ACK"
    LENGTH: ClassVar[int] = 4
    DIRECTION: ClassVar[str] = "controller_to_host"
    PRIORITY: ClassVar[str] = "emergency"
    FIELDS: ClassVar[tuple[str, ...]] = ("stop_id", "result", "latch_gen")
    ENUMS: ClassVar[dict[str, type[IntEnum]]] = {"result": ClearResult}

    def pack(self, strict: bool = True) -> bytes:
        """Encode the payload; see :meth:`Message.pack`."""
        stop_id = self.stop_id
        result = self.result
        latch_gen = self.latch_gen
        if not (isinstance(stop_id, int) and 0 <= stop_id <= 65535):
            raise field_error("CLEAR_ACK", "stop_id", stop_id, 0, 65535)
        if not (isinstance(result, int) and 0 <= result <= 3):
            raise field_error("CLEAR_ACK", "result", result, 0, 3)
        if not (isinstance(latch_gen, int) and 0 <= latch_gen <= 255):
            raise field_error("CLEAR_ACK", "latch_gen", latch_gen, 0, 255)
        return _S_CLEAR_ACK.pack(stop_id, result, latch_gen)

    @classmethod
    def unpack(cls, payload: bytes) -> ClearAck:
        """Strict decode of one payload.

        Raises:
            DecodeError: wrong length, or a value outside the wire range.
        """
        if len(payload) != 4:
            raise DecodeError(f"CLEAR_ACK payload is {len(payload)} bytes, expected 4")
        decoded = _decode_clear_ack(bytes(payload))
        if decoded is None:
            raise DecodeError("CLEAR_ACK payload has a value outside its range")
        return decoded


def _decode_clear_ack(payload: bytes) -> ClearAck | None:
    values = _S_CLEAR_ACK.unpack(payload)
    result = values[1]
    if not (0 <= result <= 3):
        return None
    return _new(ClearAck, values)


_S_MOTION = struct.Struct("<HBBH")


class _MotionFields(NamedTuple):
    seq: int
    command: int
    speed: int
    distance: int


class Motion(Message, _MotionFields):
    """MOTION (id 8, host to controller, motion). Queue one motion step. The controller answers
    ACK; a repeated seq is acknowledged DUPLICATE and never executed twice. Checks in this
    order: session, duplicate, command, (command STOP: emergency stop), speed, distance,
    fault, latch, queue.

    Sent: one per plan step; retransmitted after ack_timeout_ms, at most motion_retries times.

    Attributes:
        seq: u16. host step sequence number, wraps; new per step, kept across retransmissions.
        command: u8 (Command) limit 0..4. STOP/FWD/REV/LEFT/RIGHT; STOP here acts as an
            emergency stop (speed and distance ignored).
        speed: u8 limit 0..60. speed units; wheel angular speed = speed * k rad/s, surface speed
            = speed * k * wheel_radius m/s (docs/protocol.md, Units).
        distance: u16 limit 0..30000. distance units of encoder travel per side, each side along
            its own direction of travel (23000 per metre).
    """

    __slots__ = ()
    MSG_ID: ClassVar[int] = 8
    NAME: ClassVar[str] = "MOTION"
    LENGTH: ClassVar[int] = 6
    DIRECTION: ClassVar[str] = "host_to_controller"
    PRIORITY: ClassVar[str] = "motion"
    FIELDS: ClassVar[tuple[str, ...]] = ("seq", "command", "speed", "distance")
    ENUMS: ClassVar[dict[str, type[IntEnum]]] = {"command": Command}

    def pack(self, strict: bool = True) -> bytes:
        """Encode the payload; see :meth:`Message.pack`."""
        seq = self.seq
        command = self.command
        speed = self.speed
        distance = self.distance
        if not (isinstance(seq, int) and 0 <= seq <= 65535):
            raise field_error("MOTION", "seq", seq, 0, 65535)
        if not (isinstance(command, int) and 0 <= command <= 255):
            raise field_error("MOTION", "command", command, 0, 255)
        if not (isinstance(speed, int) and 0 <= speed <= 255):
            raise field_error("MOTION", "speed", speed, 0, 255)
        if not (isinstance(distance, int) and 0 <= distance <= 65535):
            raise field_error("MOTION", "distance", distance, 0, 65535)
        if strict:
            if not 0 <= command <= 4:
                raise field_error("MOTION", "command", command, 0, 4, limit=True)
            if not 0 <= speed <= 60:
                raise field_error("MOTION", "speed", speed, 0, 60, limit=True)
            if not 0 <= distance <= 30000:
                raise field_error("MOTION", "distance", distance, 0, 30000, limit=True)
        return _S_MOTION.pack(seq, command, speed, distance)

    @classmethod
    def unpack(cls, payload: bytes) -> Motion:
        """Strict decode of one payload.

        Raises:
            DecodeError: wrong length, or a value outside the wire range.
        """
        if len(payload) != 6:
            raise DecodeError(f"MOTION payload is {len(payload)} bytes, expected 6")
        decoded = _decode_motion(bytes(payload))
        if decoded is None:
            raise DecodeError("MOTION payload has a value outside its range")
        return decoded


def _decode_motion(payload: bytes) -> Motion | None:
    return _new(Motion, _S_MOTION.unpack(payload))


_S_ACK = struct.Struct("<HBBB")


class _AckFields(NamedTuple):
    seq: int
    result: int
    field: int
    queue_depth: int


class Ack(Message, _AckFields):
    """ACK (id 9, controller to host, motion). Acknowledgement (result ACCEPTED or DUPLICATE) or
    refusal (any other result) of a MOTION.

    Sent: once per MOTION received.

    Attributes:
        seq: u16. echo of MOTION.seq.
        result: u8 (AckResult) range 0..6.
        field: u8 (AckField) range 0..3. for OUT_OF_RANGE: the offending field.
        queue_depth: u8. steps queued after this request, the running one included.
    """

    __slots__ = ()
    MSG_ID: ClassVar[int] = 9
    NAME: ClassVar[str] = "ACK"
    LENGTH: ClassVar[int] = 5
    DIRECTION: ClassVar[str] = "controller_to_host"
    PRIORITY: ClassVar[str] = "motion"
    FIELDS: ClassVar[tuple[str, ...]] = ("seq", "result", "field", "queue_depth")
    ENUMS: ClassVar[dict[str, type[IntEnum]]] = {"result": AckResult, "field": AckField}

    def pack(self, strict: bool = True) -> bytes:
        """Encode the payload; see :meth:`Message.pack`."""
        seq = self.seq
        result = self.result
        field = self.field
        queue_depth = self.queue_depth
        if not (isinstance(seq, int) and 0 <= seq <= 65535):
            raise field_error("ACK", "seq", seq, 0, 65535)
        if not (isinstance(result, int) and 0 <= result <= 6):
            raise field_error("ACK", "result", result, 0, 6)
        if not (isinstance(field, int) and 0 <= field <= 3):
            raise field_error("ACK", "field", field, 0, 3)
        if not (isinstance(queue_depth, int) and 0 <= queue_depth <= 255):
            raise field_error("ACK", "queue_depth", queue_depth, 0, 255)
        return _S_ACK.pack(seq, result, field, queue_depth)

    @classmethod
    def unpack(cls, payload: bytes) -> Ack:
        """Strict decode of one payload.

        Raises:
            DecodeError: wrong length, or a value outside the wire range.
        """
        if len(payload) != 5:
            raise DecodeError(f"ACK payload is {len(payload)} bytes, expected 5")
        decoded = _decode_ack(bytes(payload))
        if decoded is None:
            raise DecodeError("ACK payload has a value outside its range")
        return decoded


def _decode_ack(payload: bytes) -> Ack | None:
    values = _S_ACK.unpack(payload)
    result = values[1]
    field = values[2]
    if not (0 <= result <= 6 and 0 <= field <= 3):
        return None
    return _new(Ack, values)


_S_STATUS = struct.Struct("<HBBH")


class _StatusFields(NamedTuple):
    seq: int
    state: int
    reason: int
    travel: int


class Status(Message, _StatusFields):
    """STATUS (id 32, controller to host, status). Progress of one step: STARTED, then COMPLETED
    when both sides' encoder travel reached the distance and the wheels are at rest, or
    ABORTED with a reason. A step with speed 0 or distance 0 is STARTED and COMPLETED in the
    same control tick, travel 0, when the wheels are at rest; started while a wheel still
    turns (after a new session or a clear before rest), it first brakes them to rest as a
    STOP does.

    Sent: when a step starts and when it ends.

    Attributes:
        seq: u16. MOTION.seq of the step.
        state: u8 (StepState) range 0..2.
        reason: u8 (AbortReason) range 0..5.
        travel: u16. distance units travelled so far, mean of both sides' encoders.
    """

    __slots__ = ()
    MSG_ID: ClassVar[int] = 32
    NAME: ClassVar[str] = "STATUS"
    LENGTH: ClassVar[int] = 6
    DIRECTION: ClassVar[str] = "controller_to_host"
    PRIORITY: ClassVar[str] = "status"
    FIELDS: ClassVar[tuple[str, ...]] = ("seq", "state", "reason", "travel")
    ENUMS: ClassVar[dict[str, type[IntEnum]]] = {"state": StepState, "reason": AbortReason}

    def pack(self, strict: bool = True) -> bytes:
        """Encode the payload; see :meth:`Message.pack`."""
        seq = self.seq
        state = self.state
        reason = self.reason
        travel = self.travel
        if not (isinstance(seq, int) and 0 <= seq <= 65535):
            raise field_error("STATUS", "seq", seq, 0, 65535)
        if not (isinstance(state, int) and 0 <= state <= 2):
            raise field_error("STATUS", "state", state, 0, 2)
        if not (isinstance(reason, int) and 0 <= reason <= 5):
            raise field_error("STATUS", "reason", reason, 0, 5)
        if not (isinstance(travel, int) and 0 <= travel <= 65535):
            raise field_error("STATUS", "travel", travel, 0, 65535)
        return _S_STATUS.pack(seq, state, reason, travel)

    @classmethod
    def unpack(cls, payload: bytes) -> Status:
        """Strict decode of one payload.

        Raises:
            DecodeError: wrong length, or a value outside the wire range.
        """
        if len(payload) != 6:
            raise DecodeError(f"STATUS payload is {len(payload)} bytes, expected 6")
        decoded = _decode_status(bytes(payload))
        if decoded is None:
            raise DecodeError("STATUS payload has a value outside its range")
        return decoded


def _decode_status(payload: bytes) -> Status | None:
    values = _S_STATUS.unpack(payload)
    state = values[1]
    reason = values[2]
    if not (0 <= state <= 2 and 0 <= reason <= 5):
        return None
    return _new(Status, values)


_S_STOPPED = struct.Struct("<HHH")


class _StoppedFields(NamedTuple):
    stop_id: int
    distance_mm: int
    duration_ms: int


class Stopped(Message, _StoppedFields):
    """STOPPED (id 33, controller to host, status). The wheels are at rest after a STOP (or a
    stop the controller started itself, stop_id 0: MOTION with command STOP, watchdog,
    stopping fault). Every new stop_id gets its own STOPPED, also while already latched and
    at rest (then distance 0); a repeat of a stop_id seen since the latch was last cleared
    gets none.

    Sent: once per stop_id new to the latch (a repeat gets none), when both wheels have come to rest; one owed is sent after CLEARED too.

    Attributes:
        stop_id: u16. the STOP being reported; 0 for watchdog and fault stops.
        distance_mm: u16 mm. wheel travel from STOP arrival to rest, mean of both sides.
        duration_ms: u16 ms. time from STOP arrival to rest.
    """

    __slots__ = ()
    MSG_ID: ClassVar[int] = 33
    NAME: ClassVar[str] = "STOPPED"
    LENGTH: ClassVar[int] = 6
    DIRECTION: ClassVar[str] = "controller_to_host"
    PRIORITY: ClassVar[str] = "status"
    FIELDS: ClassVar[tuple[str, ...]] = ("stop_id", "distance_mm", "duration_ms")
    ENUMS: ClassVar[dict[str, type[IntEnum]]] = {}

    def pack(self, strict: bool = True) -> bytes:
        """Encode the payload; see :meth:`Message.pack`."""
        stop_id = self.stop_id
        distance_mm = self.distance_mm
        duration_ms = self.duration_ms
        if not (isinstance(stop_id, int) and 0 <= stop_id <= 65535):
            raise field_error("STOPPED", "stop_id", stop_id, 0, 65535)
        if not (isinstance(distance_mm, int) and 0 <= distance_mm <= 65535):
            raise field_error("STOPPED", "distance_mm", distance_mm, 0, 65535)
        if not (isinstance(duration_ms, int) and 0 <= duration_ms <= 65535):
            raise field_error("STOPPED", "duration_ms", duration_ms, 0, 65535)
        return _S_STOPPED.pack(stop_id, distance_mm, duration_ms)

    @classmethod
    def unpack(cls, payload: bytes) -> Stopped:
        """Strict decode of one payload.

        Raises:
            DecodeError: wrong length, or a value outside the wire range.
        """
        if len(payload) != 6:
            raise DecodeError(f"STOPPED payload is {len(payload)} bytes, expected 6")
        decoded = _decode_stopped(bytes(payload))
        if decoded is None:
            raise DecodeError("STOPPED payload has a value outside its range")
        return decoded


def _decode_stopped(payload: bytes) -> Stopped | None:
    return _new(Stopped, _S_STOPPED.unpack(payload))


class _FaultFields(NamedTuple):
    code: int
    active: int
    detail: int
    latch_gen: int


class Fault(Message, _FaultFields):
    """FAULT (id 34, controller to host, status). A fault's condition became active (active = 1)
    or went away (active = 0). A stopping fault's latch outlives its condition: it holds
    until CLEAR_STOP.

    Sent: when a fault is raised or cleared.

    Attributes:
        code: u8 (FaultCode) range 1..8.
        active: u1.
        detail: u16. code-specific with active = 1: WATCHDOG ms since the last valid frame;
            STALL_* distance units still to go; ENCODER the failed side (1 left, 2 right, 3
            both); DRIVER, INTERNAL, IMU, POSE 0 or a vendor code; always 0 with active = 0.
        latch_gen: u8. the latch generation after this FAULT (a stopping fault's active = 1
            raises it).
    """

    __slots__ = ()
    MSG_ID: ClassVar[int] = 34
    NAME: ClassVar[str] = "FAULT"
    LENGTH: ClassVar[int] = 5
    DIRECTION: ClassVar[str] = "controller_to_host"
    PRIORITY: ClassVar[str] = "status"
    FIELDS: ClassVar[tuple[str, ...]] = ("code", "active", "detail", "latch_gen")
    ENUMS: ClassVar[dict[str, type[IntEnum]]] = {"code": FaultCode}

    def pack(self, strict: bool = True) -> bytes:
        """Encode the payload; see :meth:`Message.pack`."""
        code = self.code
        active = self.active
        detail = self.detail
        latch_gen = self.latch_gen
        if not (isinstance(code, int) and 1 <= code <= 8):
            raise field_error("FAULT", "code", code, 1, 8)
        if not (isinstance(active, int) and 0 <= active <= 1):
            raise field_error("FAULT", "active", active, 0, 1)
        if not (isinstance(detail, int) and 0 <= detail <= 65535):
            raise field_error("FAULT", "detail", detail, 0, 65535)
        if not (isinstance(latch_gen, int) and 0 <= latch_gen <= 255):
            raise field_error("FAULT", "latch_gen", latch_gen, 0, 255)
        value = (
            code
            | (active << 8)
            | (detail << 16)
            | (latch_gen << 32)
        )
        return value.to_bytes(5, "little")

    @classmethod
    def unpack(cls, payload: bytes) -> Fault:
        """Strict decode of one payload.

        Raises:
            DecodeError: wrong length, or a value outside the wire range.
        """
        if len(payload) != 5:
            raise DecodeError(f"FAULT payload is {len(payload)} bytes, expected 5")
        decoded = _decode_fault(bytes(payload))
        if decoded is None:
            raise DecodeError("FAULT payload has a value outside its range")
        return decoded


def _decode_fault(payload: bytes) -> Fault | None:
    value = int.from_bytes(payload, "little")
    code = value & 0xFF
    active = (value >> 8) & 0x1
    detail = (value >> 16) & 0xFFFF
    latch_gen = value >> 32
    if not (1 <= code <= 8):
        return None
    return _new(Fault, (code, active, detail, latch_gen))


class _HeartbeatFields(NamedTuple):
    state: int
    stop_latched: int
    handshake_ok: int
    latch_stop: int
    latch_watchdog: int
    latch_fault: int
    fault_bits: int
    queue_depth: int
    boot_nonce: int
    rx_errors: int
    latch_gen: int


class Heartbeat(Message, _HeartbeatFields):
    """HEARTBEAT (id 64, controller to host, telemetry). Controller liveness and summary state.
    A changed boot_nonce means the controller rebooted. The latch_* bits say what holds the
    latch; fault_bits say which fault conditions are active now.

    Sent: every controller_heartbeat_period_ms.

    Attributes:
        state: u3 (ControllerState) range 0..4.
        stop_latched: u1. motion inhibited until CLEAR_STOP: latch_stop OR latch_watchdog OR
            latch_fault.
        handshake_ok: u1. a session is open: the last HELLO since boot matched version and
            schema hash.
        latch_stop: u1. the latch was set (or set again) by a STOP frame or a MOTION with
            command STOP since the last CLEARED.
        latch_watchdog: u1. the latch was set (or set again) by the watchdog since the last
            CLEARED.
        latch_fault: u1. the latch was set (or set again) by a stopping fault other than
            WATCHDOG since the last CLEARED.
        fault_bits: u8. bit (FaultCode - 1) set while that fault's condition is active (not the
            latch it left).
        queue_depth: u8. steps queued, the running one included.
        boot_nonce: u16. random per boot, as in IDENT.
        rx_errors: u16. frames the controller dropped, for any reason of docs/protocol.md
            'Receive errors', wrapping.
        latch_gen: u8. the latch generation: raised by every new latch cause (docs/protocol.md,
            'Latch and faults'), wrapping.
    """

    __slots__ = ()
    MSG_ID: ClassVar[int] = 64
    NAME: ClassVar[str] = "HEARTBEAT"
    LENGTH: ClassVar[int] = 8
    DIRECTION: ClassVar[str] = "controller_to_host"
    PRIORITY: ClassVar[str] = "telemetry"
    FIELDS: ClassVar[tuple[str, ...]] = ("state", "stop_latched", "handshake_ok", "latch_stop", "latch_watchdog", "latch_fault", "fault_bits", "queue_depth", "boot_nonce", "rx_errors", "latch_gen")
    ENUMS: ClassVar[dict[str, type[IntEnum]]] = {"state": ControllerState}

    def pack(self, strict: bool = True) -> bytes:
        """Encode the payload; see :meth:`Message.pack`."""
        state = self.state
        stop_latched = self.stop_latched
        handshake_ok = self.handshake_ok
        latch_stop = self.latch_stop
        latch_watchdog = self.latch_watchdog
        latch_fault = self.latch_fault
        fault_bits = self.fault_bits
        queue_depth = self.queue_depth
        boot_nonce = self.boot_nonce
        rx_errors = self.rx_errors
        latch_gen = self.latch_gen
        if not (isinstance(state, int) and 0 <= state <= 4):
            raise field_error("HEARTBEAT", "state", state, 0, 4)
        if not (isinstance(stop_latched, int) and 0 <= stop_latched <= 1):
            raise field_error("HEARTBEAT", "stop_latched", stop_latched, 0, 1)
        if not (isinstance(handshake_ok, int) and 0 <= handshake_ok <= 1):
            raise field_error("HEARTBEAT", "handshake_ok", handshake_ok, 0, 1)
        if not (isinstance(latch_stop, int) and 0 <= latch_stop <= 1):
            raise field_error("HEARTBEAT", "latch_stop", latch_stop, 0, 1)
        if not (isinstance(latch_watchdog, int) and 0 <= latch_watchdog <= 1):
            raise field_error("HEARTBEAT", "latch_watchdog", latch_watchdog, 0, 1)
        if not (isinstance(latch_fault, int) and 0 <= latch_fault <= 1):
            raise field_error("HEARTBEAT", "latch_fault", latch_fault, 0, 1)
        if not (isinstance(fault_bits, int) and 0 <= fault_bits <= 255):
            raise field_error("HEARTBEAT", "fault_bits", fault_bits, 0, 255)
        if not (isinstance(queue_depth, int) and 0 <= queue_depth <= 255):
            raise field_error("HEARTBEAT", "queue_depth", queue_depth, 0, 255)
        if not (isinstance(boot_nonce, int) and 0 <= boot_nonce <= 65535):
            raise field_error("HEARTBEAT", "boot_nonce", boot_nonce, 0, 65535)
        if not (isinstance(rx_errors, int) and 0 <= rx_errors <= 65535):
            raise field_error("HEARTBEAT", "rx_errors", rx_errors, 0, 65535)
        if not (isinstance(latch_gen, int) and 0 <= latch_gen <= 255):
            raise field_error("HEARTBEAT", "latch_gen", latch_gen, 0, 255)
        value = (
            state
            | (stop_latched << 3)
            | (handshake_ok << 4)
            | (latch_stop << 5)
            | (latch_watchdog << 6)
            | (latch_fault << 7)
            | (fault_bits << 8)
            | (queue_depth << 16)
            | (boot_nonce << 24)
            | (rx_errors << 40)
            | (latch_gen << 56)
        )
        return value.to_bytes(8, "little")

    @classmethod
    def unpack(cls, payload: bytes) -> Heartbeat:
        """Strict decode of one payload.

        Raises:
            DecodeError: wrong length, or a value outside the wire range.
        """
        if len(payload) != 8:
            raise DecodeError(f"HEARTBEAT payload is {len(payload)} bytes, expected 8")
        decoded = _decode_heartbeat(bytes(payload))
        if decoded is None:
            raise DecodeError("HEARTBEAT payload has a value outside its range")
        return decoded


def _decode_heartbeat(payload: bytes) -> Heartbeat | None:
    value = int.from_bytes(payload, "little")
    state = value & 0x7
    stop_latched = (value >> 3) & 0x1
    handshake_ok = (value >> 4) & 0x1
    latch_stop = (value >> 5) & 0x1
    latch_watchdog = (value >> 6) & 0x1
    latch_fault = (value >> 7) & 0x1
    fault_bits = (value >> 8) & 0xFF
    queue_depth = (value >> 16) & 0xFF
    boot_nonce = (value >> 24) & 0xFFFF
    rx_errors = (value >> 40) & 0xFFFF
    latch_gen = value >> 56
    if not (0 <= state <= 4):
        return None
    return _new(Heartbeat, (state, stop_latched, handshake_ok, latch_stop, latch_watchdog, latch_fault, fault_bits, queue_depth, boot_nonce, rx_errors, latch_gen))


_S_HOST_HEARTBEAT = struct.Struct("<H")


class _HostHeartbeatFields(NamedTuple):
    counter: int


class HostHeartbeat(Message, _HostHeartbeatFields):
    """HOST_HEARTBEAT (id 65, host to controller, telemetry). Host liveness; any valid host-to-
    controller frame feeds the controller's watchdog, this one when nothing else is sent.

    Sent: every host_heartbeat_period_ms.

    Attributes:
        counter: u16. increments per heartbeat, wraps.
    """

    __slots__ = ()
    MSG_ID: ClassVar[int] = 65
    NAME: ClassVar[str] = "HOST_HEARTBEAT"
    LENGTH: ClassVar[int] = 2
    DIRECTION: ClassVar[str] = "host_to_controller"
    PRIORITY: ClassVar[str] = "telemetry"
    FIELDS: ClassVar[tuple[str, ...]] = ("counter",)
    ENUMS: ClassVar[dict[str, type[IntEnum]]] = {}

    def pack(self, strict: bool = True) -> bytes:
        """Encode the payload; see :meth:`Message.pack`."""
        counter = self.counter
        if not (isinstance(counter, int) and 0 <= counter <= 65535):
            raise field_error("HOST_HEARTBEAT", "counter", counter, 0, 65535)
        return _S_HOST_HEARTBEAT.pack(counter)

    @classmethod
    def unpack(cls, payload: bytes) -> HostHeartbeat:
        """Strict decode of one payload.

        Raises:
            DecodeError: wrong length, or a value outside the wire range.
        """
        if len(payload) != 2:
            raise DecodeError(f"HOST_HEARTBEAT payload is {len(payload)} bytes, expected 2")
        decoded = _decode_host_heartbeat(bytes(payload))
        if decoded is None:
            raise DecodeError("HOST_HEARTBEAT payload has a value outside its range")
        return decoded


def _decode_host_heartbeat(payload: bytes) -> HostHeartbeat | None:
    return _new(HostHeartbeat, _S_HOST_HEARTBEAT.unpack(payload))


class _EncodersFields(NamedTuple):
    t_ms: int
    left: int
    right: int


class Encoders(Message, _EncodersFields):
    """ENCODERS (id 66, controller to host, telemetry). Absolute wheel encoder counts since
    boot, polarity applied (forward positive on both sides), wrapping modulo 2^24; the host
    unwraps. They restart at 0 after a reboot: the host re-bases on the new boot nonce.

    Sent: encoders_rate_hz.

    Attributes:
        t_ms: u16 ms. controller clock, wraps every 65.536 s.
        left: i24. left side counts (distance units).
        right: i24. right side counts (distance units).
    """

    __slots__ = ()
    MSG_ID: ClassVar[int] = 66
    NAME: ClassVar[str] = "ENCODERS"
    LENGTH: ClassVar[int] = 8
    DIRECTION: ClassVar[str] = "controller_to_host"
    PRIORITY: ClassVar[str] = "telemetry"
    FIELDS: ClassVar[tuple[str, ...]] = ("t_ms", "left", "right")
    ENUMS: ClassVar[dict[str, type[IntEnum]]] = {}

    def pack(self, strict: bool = True) -> bytes:
        """Encode the payload; see :meth:`Message.pack`."""
        t_ms = self.t_ms
        left = self.left
        right = self.right
        if not (isinstance(t_ms, int) and 0 <= t_ms <= 65535):
            raise field_error("ENCODERS", "t_ms", t_ms, 0, 65535)
        if not (isinstance(left, int) and -8388608 <= left <= 8388607):
            raise field_error("ENCODERS", "left", left, -8388608, 8388607)
        if not (isinstance(right, int) and -8388608 <= right <= 8388607):
            raise field_error("ENCODERS", "right", right, -8388608, 8388607)
        value = (
            t_ms
            | ((left & 0xFFFFFF) << 16)
            | ((right & 0xFFFFFF) << 40)
        )
        return value.to_bytes(8, "little")

    @classmethod
    def unpack(cls, payload: bytes) -> Encoders:
        """Strict decode of one payload.

        Raises:
            DecodeError: wrong length, or a value outside the wire range.
        """
        if len(payload) != 8:
            raise DecodeError(f"ENCODERS payload is {len(payload)} bytes, expected 8")
        decoded = _decode_encoders(bytes(payload))
        if decoded is None:
            raise DecodeError("ENCODERS payload has a value outside its range")
        return decoded


def _decode_encoders(payload: bytes) -> Encoders | None:
    value = int.from_bytes(payload, "little")
    t_ms = value & 0xFFFF
    left = (((value >> 16) & 0xFFFFFF) ^ 0x800000) - 0x800000
    right = ((value >> 40) ^ 0x800000) - 0x800000
    return _new(Encoders, (t_ms, left, right))


class _WheelSpeedsFields(NamedTuple):
    t_ms: int
    left_mm_s: int
    right_mm_s: int
    left_target_mm_s: int
    right_target_mm_s: int


class WheelSpeeds(Message, _WheelSpeedsFields):
    """WHEEL_SPEEDS (id 67, controller to host, telemetry). Measured and target wheel surface
    speeds, polarity applied.

    Sent: wheel_speeds_rate_hz.

    Attributes:
        t_ms: u16 ms.
        left_mm_s: i12 mm/s.
        right_mm_s: i12 mm/s.
        left_target_mm_s: i12 mm/s.
        right_target_mm_s: i12 mm/s.
    """

    __slots__ = ()
    MSG_ID: ClassVar[int] = 67
    NAME: ClassVar[str] = "WHEEL_SPEEDS"
    LENGTH: ClassVar[int] = 8
    DIRECTION: ClassVar[str] = "controller_to_host"
    PRIORITY: ClassVar[str] = "telemetry"
    FIELDS: ClassVar[tuple[str, ...]] = ("t_ms", "left_mm_s", "right_mm_s", "left_target_mm_s", "right_target_mm_s")
    ENUMS: ClassVar[dict[str, type[IntEnum]]] = {}

    def pack(self, strict: bool = True) -> bytes:
        """Encode the payload; see :meth:`Message.pack`."""
        t_ms = self.t_ms
        left_mm_s = self.left_mm_s
        right_mm_s = self.right_mm_s
        left_target_mm_s = self.left_target_mm_s
        right_target_mm_s = self.right_target_mm_s
        if not (isinstance(t_ms, int) and 0 <= t_ms <= 65535):
            raise field_error("WHEEL_SPEEDS", "t_ms", t_ms, 0, 65535)
        if not (isinstance(left_mm_s, int) and -2048 <= left_mm_s <= 2047):
            raise field_error("WHEEL_SPEEDS", "left_mm_s", left_mm_s, -2048, 2047)
        if not (isinstance(right_mm_s, int) and -2048 <= right_mm_s <= 2047):
            raise field_error("WHEEL_SPEEDS", "right_mm_s", right_mm_s, -2048, 2047)
        if not (isinstance(left_target_mm_s, int) and -2048 <= left_target_mm_s <= 2047):
            raise field_error("WHEEL_SPEEDS", "left_target_mm_s", left_target_mm_s, -2048, 2047)
        if not (isinstance(right_target_mm_s, int) and -2048 <= right_target_mm_s <= 2047):
            raise field_error("WHEEL_SPEEDS", "right_target_mm_s", right_target_mm_s, -2048, 2047)
        value = (
            t_ms
            | ((left_mm_s & 0xFFF) << 16)
            | ((right_mm_s & 0xFFF) << 28)
            | ((left_target_mm_s & 0xFFF) << 40)
            | ((right_target_mm_s & 0xFFF) << 52)
        )
        return value.to_bytes(8, "little")

    @classmethod
    def unpack(cls, payload: bytes) -> WheelSpeeds:
        """Strict decode of one payload.

        Raises:
            DecodeError: wrong length, or a value outside the wire range.
        """
        if len(payload) != 8:
            raise DecodeError(f"WHEEL_SPEEDS payload is {len(payload)} bytes, expected 8")
        decoded = _decode_wheel_speeds(bytes(payload))
        if decoded is None:
            raise DecodeError("WHEEL_SPEEDS payload has a value outside its range")
        return decoded


def _decode_wheel_speeds(payload: bytes) -> WheelSpeeds | None:
    value = int.from_bytes(payload, "little")
    t_ms = value & 0xFFFF
    left_mm_s = (((value >> 16) & 0xFFF) ^ 0x800) - 0x800
    right_mm_s = (((value >> 28) & 0xFFF) ^ 0x800) - 0x800
    left_target_mm_s = (((value >> 40) & 0xFFF) ^ 0x800) - 0x800
    right_target_mm_s = ((value >> 52) ^ 0x800) - 0x800
    return _new(WheelSpeeds, (t_ms, left_mm_s, right_mm_s, left_target_mm_s, right_target_mm_s))


_S_IMU = struct.Struct("<Hhhh")


class _ImuFields(NamedTuple):
    t_ms: int
    yaw_rate_mrad_s: int
    accel_x_mm_s2: int
    accel_y_mm_s2: int


class Imu(Message, _ImuFields):
    """IMU (id 68, controller to host, telemetry). Body yaw rate (counter-clockwise positive)
    and planar acceleration in the body frame.

    Sent: imu_rate_hz.

    Attributes:
        t_ms: u16 ms.
        yaw_rate_mrad_s: i16 x0.001 rad/s.
        accel_x_mm_s2: i16 x0.001 m/s^2.
        accel_y_mm_s2: i16 x0.001 m/s^2.
    """

    __slots__ = ()
    MSG_ID: ClassVar[int] = 68
    NAME: ClassVar[str] = "IMU"
    LENGTH: ClassVar[int] = 8
    DIRECTION: ClassVar[str] = "controller_to_host"
    PRIORITY: ClassVar[str] = "telemetry"
    FIELDS: ClassVar[tuple[str, ...]] = ("t_ms", "yaw_rate_mrad_s", "accel_x_mm_s2", "accel_y_mm_s2")
    ENUMS: ClassVar[dict[str, type[IntEnum]]] = {}

    def pack(self, strict: bool = True) -> bytes:
        """Encode the payload; see :meth:`Message.pack`."""
        t_ms = self.t_ms
        yaw_rate_mrad_s = self.yaw_rate_mrad_s
        accel_x_mm_s2 = self.accel_x_mm_s2
        accel_y_mm_s2 = self.accel_y_mm_s2
        if not (isinstance(t_ms, int) and 0 <= t_ms <= 65535):
            raise field_error("IMU", "t_ms", t_ms, 0, 65535)
        if not (isinstance(yaw_rate_mrad_s, int) and -32768 <= yaw_rate_mrad_s <= 32767):
            raise field_error("IMU", "yaw_rate_mrad_s", yaw_rate_mrad_s, -32768, 32767)
        if not (isinstance(accel_x_mm_s2, int) and -32768 <= accel_x_mm_s2 <= 32767):
            raise field_error("IMU", "accel_x_mm_s2", accel_x_mm_s2, -32768, 32767)
        if not (isinstance(accel_y_mm_s2, int) and -32768 <= accel_y_mm_s2 <= 32767):
            raise field_error("IMU", "accel_y_mm_s2", accel_y_mm_s2, -32768, 32767)
        return _S_IMU.pack(t_ms, yaw_rate_mrad_s, accel_x_mm_s2, accel_y_mm_s2)

    @classmethod
    def unpack(cls, payload: bytes) -> Imu:
        """Strict decode of one payload.

        Raises:
            DecodeError: wrong length, or a value outside the wire range.
        """
        if len(payload) != 8:
            raise DecodeError(f"IMU payload is {len(payload)} bytes, expected 8")
        decoded = _decode_imu(bytes(payload))
        if decoded is None:
            raise DecodeError("IMU payload has a value outside its range")
        return decoded


def _decode_imu(payload: bytes) -> Imu | None:
    return _new(Imu, _S_IMU.unpack(payload))


class _PoseMsgFields(NamedTuple):
    x_mm: int
    y_mm: int
    yaw_ddeg: int
    sigma_cm: int
    age_4ms: int


class PoseMsg(Message, _PoseMsgFields):
    """POSE (id 69, controller to host, telemetry). Pose from a sensor that sees the ground
    (visual odometry or lab tracking) in the map frame: the frame of the map the gate plans
    on, x and y from its origin, never re-zeroed at boot; unlike the encoders it shows slip.
    Optional: a controller without such a sensor never sends it.

    Sent: pose_rate_hz.

    Attributes:
        x_mm: i20 x0.001 m.
        y_mm: i20 x0.001 m.
        yaw_ddeg: i12 x0.1 deg range -1800..1800. counter-clockwise from the map x axis.
        sigma_cm: u4 x0.01 m. 1-sigma position error; 0 = no fix, ignore the pose; 15 = 15 cm or
            worse.
        age_4ms: u8 x4 ms. age of the measurement when sent.
    """

    __slots__ = ()
    MSG_ID: ClassVar[int] = 69
    NAME: ClassVar[str] = "POSE"
    LENGTH: ClassVar[int] = 8
    DIRECTION: ClassVar[str] = "controller_to_host"
    PRIORITY: ClassVar[str] = "telemetry"
    FIELDS: ClassVar[tuple[str, ...]] = ("x_mm", "y_mm", "yaw_ddeg", "sigma_cm", "age_4ms")
    ENUMS: ClassVar[dict[str, type[IntEnum]]] = {}

    def pack(self, strict: bool = True) -> bytes:
        """Encode the payload; see :meth:`Message.pack`."""
        x_mm = self.x_mm
        y_mm = self.y_mm
        yaw_ddeg = self.yaw_ddeg
        sigma_cm = self.sigma_cm
        age_4ms = self.age_4ms
        if not (isinstance(x_mm, int) and -524288 <= x_mm <= 524287):
            raise field_error("POSE", "x_mm", x_mm, -524288, 524287)
        if not (isinstance(y_mm, int) and -524288 <= y_mm <= 524287):
            raise field_error("POSE", "y_mm", y_mm, -524288, 524287)
        if not (isinstance(yaw_ddeg, int) and -1800 <= yaw_ddeg <= 1800):
            raise field_error("POSE", "yaw_ddeg", yaw_ddeg, -1800, 1800)
        if not (isinstance(sigma_cm, int) and 0 <= sigma_cm <= 15):
            raise field_error("POSE", "sigma_cm", sigma_cm, 0, 15)
        if not (isinstance(age_4ms, int) and 0 <= age_4ms <= 255):
            raise field_error("POSE", "age_4ms", age_4ms, 0, 255)
        value = (
            (x_mm & 0xFFFFF)
            | ((y_mm & 0xFFFFF) << 20)
            | ((yaw_ddeg & 0xFFF) << 40)
            | (sigma_cm << 52)
            | (age_4ms << 56)
        )
        return value.to_bytes(8, "little")

    @classmethod
    def unpack(cls, payload: bytes) -> PoseMsg:
        """Strict decode of one payload.

        Raises:
            DecodeError: wrong length, or a value outside the wire range.
        """
        if len(payload) != 8:
            raise DecodeError(f"POSE payload is {len(payload)} bytes, expected 8")
        decoded = _decode_pose(bytes(payload))
        if decoded is None:
            raise DecodeError("POSE payload has a value outside its range")
        return decoded


def _decode_pose(payload: bytes) -> PoseMsg | None:
    value = int.from_bytes(payload, "little")
    x_mm = ((value & 0xFFFFF) ^ 0x80000) - 0x80000
    y_mm = (((value >> 20) & 0xFFFFF) ^ 0x80000) - 0x80000
    yaw_ddeg = (((value >> 40) & 0xFFF) ^ 0x800) - 0x800
    sigma_cm = (value >> 52) & 0xF
    age_4ms = value >> 56
    if not (-1800 <= yaw_ddeg <= 1800):
        return None
    return _new(PoseMsg, (x_mm, y_mm, yaw_ddeg, sigma_cm, age_4ms))


_S_PROGRESS = struct.Struct("<HBBHH")


class _ProgressFields(NamedTuple):
    ended_seq: int
    ended_state: int
    ended_reason: int
    ended_count: int
    travel: int


class Progress(Message, _ProgressFields):
    """PROGRESS (id 70, controller to host, telemetry). The last step that ended in this session
    and how many have ended, so a host that lost a STATUS frame on a noisy link can still
    settle every step.

    Sent: with every HEARTBEAT.

    Attributes:
        ended_seq: u16. MOTION.seq of the last step that ended; while ended_count is 0 every
            field is 0 and the host ignores them.
        ended_state: u8 (StepState) range 0..2. COMPLETED or ABORTED.
        ended_reason: u8 (AbortReason) range 0..5.
        ended_count: u16. steps ended in this session, wrapping; 0 after HELLO (the steps that
            HELLO aborted belong to the old session and are not counted).
        travel: u16. distance units the last ended step travelled.
    """

    __slots__ = ()
    MSG_ID: ClassVar[int] = 70
    NAME: ClassVar[str] = "PROGRESS"
    LENGTH: ClassVar[int] = 8
    DIRECTION: ClassVar[str] = "controller_to_host"
    PRIORITY: ClassVar[str] = "telemetry"
    FIELDS: ClassVar[tuple[str, ...]] = ("ended_seq", "ended_state", "ended_reason", "ended_count", "travel")
    ENUMS: ClassVar[dict[str, type[IntEnum]]] = {"ended_state": StepState, "ended_reason": AbortReason}

    def pack(self, strict: bool = True) -> bytes:
        """Encode the payload; see :meth:`Message.pack`."""
        ended_seq = self.ended_seq
        ended_state = self.ended_state
        ended_reason = self.ended_reason
        ended_count = self.ended_count
        travel = self.travel
        if not (isinstance(ended_seq, int) and 0 <= ended_seq <= 65535):
            raise field_error("PROGRESS", "ended_seq", ended_seq, 0, 65535)
        if not (isinstance(ended_state, int) and 0 <= ended_state <= 2):
            raise field_error("PROGRESS", "ended_state", ended_state, 0, 2)
        if not (isinstance(ended_reason, int) and 0 <= ended_reason <= 5):
            raise field_error("PROGRESS", "ended_reason", ended_reason, 0, 5)
        if not (isinstance(ended_count, int) and 0 <= ended_count <= 65535):
            raise field_error("PROGRESS", "ended_count", ended_count, 0, 65535)
        if not (isinstance(travel, int) and 0 <= travel <= 65535):
            raise field_error("PROGRESS", "travel", travel, 0, 65535)
        return _S_PROGRESS.pack(ended_seq, ended_state, ended_reason, ended_count, travel)

    @classmethod
    def unpack(cls, payload: bytes) -> Progress:
        """Strict decode of one payload.

        Raises:
            DecodeError: wrong length, or a value outside the wire range.
        """
        if len(payload) != 8:
            raise DecodeError(f"PROGRESS payload is {len(payload)} bytes, expected 8")
        decoded = _decode_progress(bytes(payload))
        if decoded is None:
            raise DecodeError("PROGRESS payload has a value outside its range")
        return decoded


def _decode_progress(payload: bytes) -> Progress | None:
    values = _S_PROGRESS.unpack(payload)
    ended_state = values[1]
    ended_reason = values[2]
    if not (0 <= ended_state <= 2 and 0 <= ended_reason <= 5):
        return None
    return _new(Progress, values)


_S_HELLO = struct.Struct("<BH")


class _HelloFields(NamedTuple):
    protocol_version: int
    schema_hash: int


class Hello(Message, _HelloFields):
    """HELLO (id 96, host to controller, config). Handshake: the host's protocol version and
    schema hash. The controller answers every HELLO with IDENT; a matching one opens a new
    session and arms the watchdog, a mismatched one closes any session.

    Sent: at connection, until IDENT.

    Attributes:
        protocol_version: u8.
        schema_hash: u16.
    """

    __slots__ = ()
    MSG_ID: ClassVar[int] = 96
    NAME: ClassVar[str] = "HELLO"
    LENGTH: ClassVar[int] = 3
    DIRECTION: ClassVar[str] = "host_to_controller"
    PRIORITY: ClassVar[str] = "config"
    FIELDS: ClassVar[tuple[str, ...]] = ("protocol_version", "schema_hash")
    ENUMS: ClassVar[dict[str, type[IntEnum]]] = {}

    def pack(self, strict: bool = True) -> bytes:
        """Encode the payload; see :meth:`Message.pack`."""
        protocol_version = self.protocol_version
        schema_hash = self.schema_hash
        if not (isinstance(protocol_version, int) and 0 <= protocol_version <= 255):
            raise field_error("HELLO", "protocol_version", protocol_version, 0, 255)
        if not (isinstance(schema_hash, int) and 0 <= schema_hash <= 65535):
            raise field_error("HELLO", "schema_hash", schema_hash, 0, 65535)
        return _S_HELLO.pack(protocol_version, schema_hash)

    @classmethod
    def unpack(cls, payload: bytes) -> Hello:
        """Strict decode of one payload.

        Raises:
            DecodeError: wrong length, or a value outside the wire range.
        """
        if len(payload) != 3:
            raise DecodeError(f"HELLO payload is {len(payload)} bytes, expected 3")
        decoded = _decode_hello(bytes(payload))
        if decoded is None:
            raise DecodeError("HELLO payload has a value outside its range")
        return decoded


def _decode_hello(payload: bytes) -> Hello | None:
    return _new(Hello, _S_HELLO.unpack(payload))


_S_IDENT = struct.Struct("<BBBBHH")


class _IdentFields(NamedTuple):
    protocol_version: int
    firmware_major: int
    firmware_minor: int
    firmware_patch: int
    schema_hash: int
    boot_nonce: int


class Ident(Message, _IdentFields):
    """IDENT (id 97, controller to host, config). Controller identity: protocol version and
    schema hash (compare with the host's), firmware version and a random boot nonce. Sent
    once at boot (unsolicited) and otherwise only in answer to HELLO.

    Sent: at boot and in answer to HELLO.

    Attributes:
        protocol_version: u8.
        firmware_major: u8.
        firmware_minor: u8.
        firmware_patch: u8.
        schema_hash: u16.
        boot_nonce: u16.
    """

    __slots__ = ()
    MSG_ID: ClassVar[int] = 97
    NAME: ClassVar[str] = "IDENT"
    LENGTH: ClassVar[int] = 8
    DIRECTION: ClassVar[str] = "controller_to_host"
    PRIORITY: ClassVar[str] = "config"
    FIELDS: ClassVar[tuple[str, ...]] = ("protocol_version", "firmware_major", "firmware_minor", "firmware_patch", "schema_hash", "boot_nonce")
    ENUMS: ClassVar[dict[str, type[IntEnum]]] = {}

    def pack(self, strict: bool = True) -> bytes:
        """Encode the payload; see :meth:`Message.pack`."""
        protocol_version = self.protocol_version
        firmware_major = self.firmware_major
        firmware_minor = self.firmware_minor
        firmware_patch = self.firmware_patch
        schema_hash = self.schema_hash
        boot_nonce = self.boot_nonce
        if not (isinstance(protocol_version, int) and 0 <= protocol_version <= 255):
            raise field_error("IDENT", "protocol_version", protocol_version, 0, 255)
        if not (isinstance(firmware_major, int) and 0 <= firmware_major <= 255):
            raise field_error("IDENT", "firmware_major", firmware_major, 0, 255)
        if not (isinstance(firmware_minor, int) and 0 <= firmware_minor <= 255):
            raise field_error("IDENT", "firmware_minor", firmware_minor, 0, 255)
        if not (isinstance(firmware_patch, int) and 0 <= firmware_patch <= 255):
            raise field_error("IDENT", "firmware_patch", firmware_patch, 0, 255)
        if not (isinstance(schema_hash, int) and 0 <= schema_hash <= 65535):
            raise field_error("IDENT", "schema_hash", schema_hash, 0, 65535)
        if not (isinstance(boot_nonce, int) and 0 <= boot_nonce <= 65535):
            raise field_error("IDENT", "boot_nonce", boot_nonce, 0, 65535)
        return _S_IDENT.pack(protocol_version, firmware_major, firmware_minor, firmware_patch, schema_hash, boot_nonce)

    @classmethod
    def unpack(cls, payload: bytes) -> Ident:
        """Strict decode of one payload.

        Raises:
            DecodeError: wrong length, or a value outside the wire range.
        """
        if len(payload) != 8:
            raise DecodeError(f"IDENT payload is {len(payload)} bytes, expected 8")
        decoded = _decode_ident(bytes(payload))
        if decoded is None:
            raise DecodeError("IDENT payload has a value outside its range")
        return decoded


def _decode_ident(payload: bytes) -> Ident | None:
    return _new(Ident, _S_IDENT.unpack(payload))


_S_SET_PARAM = struct.Struct("<Bi")


class _SetParamFields(NamedTuple):
    param: int
    value: int


class SetParam(Message, _SetParamFields):
    """SET_PARAM (id 98, host to controller, config). Set a run-time parameter; the controller
    answers PARAM_VALUE.

    Sent: on demand.

    Attributes:
        param: u8 (Param).
        value: i32.
    """

    __slots__ = ()
    MSG_ID: ClassVar[int] = 98
    NAME: ClassVar[str] = "SET_PARAM"
    LENGTH: ClassVar[int] = 5
    DIRECTION: ClassVar[str] = "host_to_controller"
    PRIORITY: ClassVar[str] = "config"
    FIELDS: ClassVar[tuple[str, ...]] = ("param", "value")
    ENUMS: ClassVar[dict[str, type[IntEnum]]] = {"param": Param}

    def pack(self, strict: bool = True) -> bytes:
        """Encode the payload; see :meth:`Message.pack`."""
        param = self.param
        value = self.value
        if not (isinstance(param, int) and 0 <= param <= 255):
            raise field_error("SET_PARAM", "param", param, 0, 255)
        if not (isinstance(value, int) and -2147483648 <= value <= 2147483647):
            raise field_error("SET_PARAM", "value", value, -2147483648, 2147483647)
        return _S_SET_PARAM.pack(param, value)

    @classmethod
    def unpack(cls, payload: bytes) -> SetParam:
        """Strict decode of one payload.

        Raises:
            DecodeError: wrong length, or a value outside the wire range.
        """
        if len(payload) != 5:
            raise DecodeError(f"SET_PARAM payload is {len(payload)} bytes, expected 5")
        decoded = _decode_set_param(bytes(payload))
        if decoded is None:
            raise DecodeError("SET_PARAM payload has a value outside its range")
        return decoded


def _decode_set_param(payload: bytes) -> SetParam | None:
    return _new(SetParam, _S_SET_PARAM.unpack(payload))


_S_PARAM_VALUE = struct.Struct("<BBi")


class _ParamValueFields(NamedTuple):
    param: int
    result: int
    value: int


class ParamValue(Message, _ParamValueFields):
    """PARAM_VALUE (id 99, controller to host, config). Answer to SET_PARAM: param echoed; value
    in force (OK, OUT_OF_RANGE) or 0 (UNKNOWN_PARAM).

    Sent: once per SET_PARAM.

    Attributes:
        param: u8.
        result: u8 (ParamResult) range 0..2.
        value: i32.
    """

    __slots__ = ()
    MSG_ID: ClassVar[int] = 99
    NAME: ClassVar[str] = "PARAM_VALUE"
    LENGTH: ClassVar[int] = 6
    DIRECTION: ClassVar[str] = "controller_to_host"
    PRIORITY: ClassVar[str] = "config"
    FIELDS: ClassVar[tuple[str, ...]] = ("param", "result", "value")
    ENUMS: ClassVar[dict[str, type[IntEnum]]] = {"result": ParamResult}

    def pack(self, strict: bool = True) -> bytes:
        """Encode the payload; see :meth:`Message.pack`."""
        param = self.param
        result = self.result
        value = self.value
        if not (isinstance(param, int) and 0 <= param <= 255):
            raise field_error("PARAM_VALUE", "param", param, 0, 255)
        if not (isinstance(result, int) and 0 <= result <= 2):
            raise field_error("PARAM_VALUE", "result", result, 0, 2)
        if not (isinstance(value, int) and -2147483648 <= value <= 2147483647):
            raise field_error("PARAM_VALUE", "value", value, -2147483648, 2147483647)
        return _S_PARAM_VALUE.pack(param, result, value)

    @classmethod
    def unpack(cls, payload: bytes) -> ParamValue:
        """Strict decode of one payload.

        Raises:
            DecodeError: wrong length, or a value outside the wire range.
        """
        if len(payload) != 6:
            raise DecodeError(f"PARAM_VALUE payload is {len(payload)} bytes, expected 6")
        decoded = _decode_param_value(bytes(payload))
        if decoded is None:
            raise DecodeError("PARAM_VALUE payload has a value outside its range")
        return decoded


def _decode_param_value(payload: bytes) -> ParamValue | None:
    values = _S_PARAM_VALUE.unpack(payload)
    result = values[1]
    if not (0 <= result <= 2):
        return None
    return _new(ParamValue, values)


MESSAGE_TYPES: dict[int, type[Message]] = {
    0: Stop,
    1: StopAck,
    2: ClearStop,
    3: ClearAck,
    8: Motion,
    9: Ack,
    32: Status,
    33: Stopped,
    34: Fault,
    64: Heartbeat,
    65: HostHeartbeat,
    66: Encoders,
    67: WheelSpeeds,
    68: Imu,
    69: PoseMsg,
    70: Progress,
    96: Hello,
    97: Ident,
    98: SetParam,
    99: ParamValue,
}
"""Message class by id."""

BY_NAME: dict[str, type[Message]] = {cls.NAME: cls for cls in MESSAGE_TYPES.values()}
"""Message class by protocol name."""

LENGTHS: dict[int, int] = {
    0: 3,
    1: 4,
    2: 3,
    3: 4,
    8: 6,
    9: 5,
    32: 6,
    33: 6,
    34: 5,
    64: 8,
    65: 2,
    66: 8,
    67: 8,
    68: 8,
    69: 8,
    70: 8,
    96: 3,
    97: 8,
    98: 5,
    99: 6,
}
"""Payload length by id."""

DECODERS: dict[int, Callable[[bytes], Message | None]] = {
    0: _decode_stop,
    1: _decode_stop_ack,
    2: _decode_clear_stop,
    3: _decode_clear_ack,
    8: _decode_motion,
    9: _decode_ack,
    32: _decode_status,
    33: _decode_stopped,
    34: _decode_fault,
    64: _decode_heartbeat,
    65: _decode_host_heartbeat,
    66: _decode_encoders,
    67: _decode_wheel_speeds,
    68: _decode_imu,
    69: _decode_pose,
    70: _decode_progress,
    96: _decode_hello,
    97: _decode_ident,
    98: _decode_set_param,
    99: _decode_param_value,
}
"""Fast decoder by id: payload of the right length -> message, or None if out of range."""
