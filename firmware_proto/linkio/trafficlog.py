"""Traffic logs of the controller link: records, the serial frame-log format, decoding,
and the comparison of a replayed session with a recorded one (docs/traffic-logs.md).

Pure: no files, no clocks, no buses. The **serial frame log** is ASCII text:
:data:`SERIAL_LOG_MAGIC`, optional ``# key: value`` lines, then one frame per line,
``time_s direction wire_hex`` (``H>C`` or ``C>H``; the frame's bytes exactly as they
went over the line, delimiters included, a frame damaged on purpose too). **CAN logs**
are candump ``-L`` logs (:class:`CanRecord` is one line); a CAN frame's direction
follows from its identifier.
"""

from __future__ import annotations

import difflib
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Protocol

from firmware_proto.errors import DecodeError
from firmware_proto.wire.canmap import CanDecoder
from firmware_proto.wire.framing import Frame, FrameDecoder, encode_raw_frame
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import BROADCAST_NODE, CAN_NODE_BITS, DEFAULT_NODE, MESSAGE_TYPES

__all__ = [
    "CONTROLLER_TO_HOST",
    "DIRECTIONS",
    "HOST_TO_CONTROLLER",
    "SERIAL_LOG_MAGIC",
    "VOLATILE_FIELDS",
    "CanRecord",
    "DecodedRecord",
    "Difference",
    "SerialLog",
    "SerialRecord",
    "TrafficRecord",
    "TrafficRecorder",
    "answer_key",
    "compare_answers",
    "counts_before",
    "decode_records",
    "diff_texts",
    "format_serial_record",
    "is_answer",
    "is_serial_log",
    "log_node",
    "message_direction",
    "parse_serial_log",
    "received_serial_records",
    "serial_log_header",
]


HOST_TO_CONTROLLER = "H>C"
CONTROLLER_TO_HOST = "C>H"
DIRECTIONS = {
    "host_to_controller": HOST_TO_CONTROLLER,
    "controller_to_host": CONTROLLER_TO_HOST,
}
"""Message direction (``Message.DIRECTION``) -> log direction tag."""
SERIAL_LOG_MAGIC = "# rover-hil serial frame log v1"
"""First line of every serial frame log."""

VOLATILE_FIELDS: dict[str, tuple[str, ...]] = {
    "ACK": ("queue_depth",),
    "STATUS": ("travel",),
    "STOPPED": ("distance_mm", "duration_ms"),
    "FAULT": ("detail",),
    "IDENT": ("boot_nonce",),
}
"""Answer fields measuring continuous time or motion, or differing per boot: a replay cannot
reproduce them exactly, so only a strict comparison includes them."""


@dataclass(frozen=True)
class SerialRecord:
    """One serial frame as it crossed the recorder's edge.

    Attributes:
        time_s: wall-clock time, s since the epoch.
        direction: :data:`HOST_TO_CONTROLLER` or :data:`CONTROLLER_TO_HOST`.
        wire: the frame's bytes on the wire, delimiters included.
    """

    time_s: float
    direction: str
    wire: bytes


@dataclass(frozen=True)
class CanRecord:
    """One CAN frame as seen by the recorder (one candump line).

    Attributes:
        time_s: wall-clock time, s since the epoch.
        channel: the bus channel name (``vcan0``).
        arbitration_id: the identifier (11-bit for this protocol).
        is_rx: the recorder received the frame (False: it sent it).
        data, is_extended_id, is_remote_frame, is_error_frame: as in python-can.
    """

    time_s: float
    channel: str
    arbitration_id: int
    data: bytes
    is_rx: bool
    is_extended_id: bool = False
    is_remote_frame: bool = False
    is_error_frame: bool = False

    @property
    def direction(self) -> str | None:
        """Protocol direction of the frame from its identifier, or ``None`` for a frame
        of no protocol message (another device's traffic, an error frame)."""
        if self.is_extended_id or self.is_error_frame or self.arbitration_id > 0x7FF:
            return None
        cls = MESSAGE_TYPES.get(self.arbitration_id >> CAN_NODE_BITS)
        return DIRECTIONS[cls.DIRECTION] if cls is not None else None


TrafficRecord = SerialRecord | CanRecord


class TrafficRecorder(Protocol):
    """Where a transport or a front end hands every frame it sends or receives.

    ``record`` is called on I/O threads, so it must be thread-safe and quick, and must not
    raise for I/O trouble of its own (log it: the link must not fail because its log did). A
    serial medium hands :class:`SerialRecord`, a CAN medium :class:`CanRecord`.
    """

    def record(self, entry: TrafficRecord) -> None:
        """Keep one frame."""


def received_serial_records(frames: Iterable[Frame], time_s: float) -> list[SerialRecord]:
    """The log records of frames a serial decoder returned, all received at ``time_s``:
    a valid frame re-encodes to exactly the bytes that carried it."""
    return [
        SerialRecord(
            time_s,
            message_direction(frame.message),
            encode_raw_frame(frame.message.MSG_ID, frame.seq, frame.message.pack(strict=False)),
        )
        for frame in frames
    ]


def message_direction(message: Message) -> str:
    """The log direction tag of a message type."""
    return DIRECTIONS[message.DIRECTION]


# -- serial frame log ---------------------------------------------------------------------


def serial_log_header(metadata: Mapping[str, str] | None = None) -> str:
    """The magic line and ``# key: value`` lines that start a serial frame log; ValueError
    when a key or value holds a newline, or a key a ``:``."""
    lines = [SERIAL_LOG_MAGIC]
    for key, value in (metadata or {}).items():
        if "\n" in key or "\n" in value or ":" in key:
            raise ValueError(f"bad metadata entry {key!r}: {value!r}")
        lines.append(f"# {key}: {value}")
    lines.append("# time_s direction wire_hex")
    return "\n".join(lines) + "\n"


def format_serial_record(record: SerialRecord) -> str:
    """One log line, newline included."""
    return f"{record.time_s:.6f} {record.direction} {record.wire.hex()}\n"


def is_serial_log(first_line: str) -> bool:
    """Whether a file starting with ``first_line`` is a serial frame log."""
    return first_line.rstrip("\r\n") == SERIAL_LOG_MAGIC


@dataclass(frozen=True)
class SerialLog:
    """A parsed serial frame log: its metadata and its records in file order."""

    metadata: dict[str, str] = field(default_factory=dict)
    records: tuple[SerialRecord, ...] = ()


def parse_serial_log(lines: Iterable[str]) -> SerialLog:
    """Parse a serial frame log; DecodeError when the magic line is missing or a line is
    malformed (names its line number)."""
    metadata: dict[str, str] = {}
    records: list[SerialRecord] = []
    it = iter(lines)
    first = next(it, "")
    if not is_serial_log(first):
        raise DecodeError(f"not a serial frame log: first line must be {SERIAL_LOG_MAGIC!r}")
    for number, raw in enumerate(it, start=2):
        line = raw.strip()
        if not line:
            continue
        if line.startswith("#"):
            key, sep, value = line[1:].partition(":")
            if sep and key.strip() and " " not in key.strip():
                metadata[key.strip()] = value.strip()
            continue
        parts = line.split()
        if len(parts) != 3:
            raise DecodeError(f"line {number}: expected 'time direction hex', got {line!r}")
        text_time, direction, text_hex = parts
        if direction not in (HOST_TO_CONTROLLER, CONTROLLER_TO_HOST):
            raise DecodeError(f"line {number}: direction must be H>C or C>H, got {direction!r}")
        try:
            time_s = float(text_time)
            wire = bytes.fromhex(text_hex)
        except ValueError as exc:
            raise DecodeError(f"line {number}: {exc}") from None
        records.append(SerialRecord(time_s, direction, wire))
    return SerialLog(metadata, tuple(records))


# -- decoding --------------------------------------------------------------------------------


@dataclass(frozen=True)
class DecodedRecord:
    """A record and what it holds.

    Attributes:
        time_s: the record's time, s since the epoch.
        direction: ``H>C``, ``C>H``, or ``None`` (CAN frame of no protocol message).
        message: the decoded message, or ``None`` when the frame is not a valid one.
        node, seq: CAN node id, serial frame counter (``None`` on the other medium).
        raw: the frame as text: wire hex (serial) or ``ID#DATA`` (CAN).
        error: why ``message`` is ``None`` (the decoder's counter name), else ``""``.
        is_rx: CAN only: the recorder received the frame (``None`` on serial).
    """

    time_s: float
    direction: str | None
    message: Message | None
    node: int | None
    seq: int | None
    raw: str
    error: str = ""
    is_rx: bool | None = None


def _counter_reason(before: dict[str, int], after: dict[str, int]) -> str:
    changed = [
        k for k, v in after.items() if v != before.get(k) and k not in ("frames", "bytes", "lost")
    ]
    changed = [k for k in changed if k != "dropped_bytes"] or changed
    return ",".join(changed) or "incomplete"


def decode_records(records: Iterable[TrafficRecord]) -> list[DecodedRecord]:
    """Decode every record, in order. Never raises on bad frames: they come back with
    ``message=None`` and the reason in ``error``."""
    serial = {HOST_TO_CONTROLLER: FrameDecoder(), CONTROLLER_TO_HOST: FrameDecoder()}
    can = CanDecoder()
    out: list[DecodedRecord] = []
    for rec in records:
        if isinstance(rec, SerialRecord):
            decoder = serial[rec.direction]
            before = decoder.counters.as_dict()
            frames = decoder.feed(rec.wire)
            if not frames:
                reason = _counter_reason(before, decoder.counters.as_dict())
                out.append(
                    DecodedRecord(
                        rec.time_s, rec.direction, None, None, None, rec.wire.hex(), reason
                    )
                )
            for frame in frames:
                out.append(
                    DecodedRecord(
                        rec.time_s, rec.direction, frame.message, None, frame.seq, rec.wire.hex()
                    )
                )
        else:
            raw = f"{rec.arbitration_id:03X}#{rec.data.hex().upper()}"
            before = can.counters.as_dict()
            decoded = (
                None
                if rec.is_error_frame
                else can.decode(
                    rec.arbitration_id,
                    rec.data,
                    is_extended=rec.is_extended_id,
                    is_remote=rec.is_remote_frame,
                )
            )
            if decoded is None:
                reason = "error_frame" if rec.is_error_frame else ""
                reason = reason or _counter_reason(before, can.counters.as_dict())
                out.append(
                    DecodedRecord(
                        rec.time_s, rec.direction, None, None, None, raw, reason, rec.is_rx
                    )
                )
            else:
                out.append(
                    DecodedRecord(
                        rec.time_s,
                        message_direction(decoded.message),
                        decoded.message,
                        decoded.node,
                        None,
                        raw,
                        "",
                        rec.is_rx,
                    )
                )
    return out


# -- comparing answers -----------------------------------------------------------------------


def is_answer(message: Message) -> bool:
    """Whether a message is one of the controller's answers or reports (every
    controller-to-host message except periodic telemetry), i.e. what a replay compares."""
    return message.DIRECTION == "controller_to_host" and message.PRIORITY != "telemetry"


def answer_key(message: Message, strict: bool = False) -> str:
    """The message as compared: :meth:`Message.describe` without its volatile fields
    (:data:`VOLATILE_FIELDS`) unless ``strict``."""
    if strict:
        return message.describe()
    volatile = VOLATILE_FIELDS.get(message.NAME, ())
    return " ".join(
        part for part in message.describe().split(" ") if part.split("=", 1)[0] not in volatile
    )


@dataclass(frozen=True)
class Difference:
    """One difference between recorded and replayed answers of one message type.

    Attributes:
        name: the message type (``ACK``, ``STATUS``...).
        index: position in the recorded answers of that type (where the replay diverged).
        expected: the recorded answer, or ``None`` (the replay has an extra one).
        actual: the replayed answer, or ``None`` (the replay lacks it).
    """

    name: str
    index: int
    expected: str | None
    actual: str | None

    def __str__(self) -> str:
        if self.expected is None:
            return f"{self.name} #{self.index}: extra in replay: {self.actual}"
        if self.actual is None:
            return f"{self.name} #{self.index}: missing in replay: {self.expected}"
        return f"{self.name} #{self.index}: recorded {self.expected} | replayed {self.actual}"


def compare_answers(
    expected: Sequence[Message], actual: Sequence[Message], *, strict: bool = False
) -> list[Difference]:
    """The differences between the controller's answers (:func:`is_answer`) of two sessions,
    ordered by type name then position; empty when they answered alike.

    Each type's answers are compared in order, volatile fields left out unless ``strict``;
    types apart, since answers of different types may interleave differently from run to run.
    """
    by_type_expected: dict[str, list[str]] = {}
    by_type_actual: dict[str, list[str]] = {}
    for source, target in ((expected, by_type_expected), (actual, by_type_actual)):
        for message in source:
            if is_answer(message):
                target.setdefault(message.NAME, []).append(answer_key(message, strict))
    differences: list[Difference] = []
    for name in sorted(set(by_type_expected) | set(by_type_actual)):
        differences += diff_texts(
            by_type_expected.get(name, []), by_type_actual.get(name, []), name=name
        )
    return differences


def diff_texts(
    expected: Sequence[str], actual: Sequence[str], *, name: str | None = None
) -> list[Difference]:
    """The differences between the recorded (``expected``) and replayed (``actual``) message
    texts, in order, paired where replaced (:class:`difflib.SequenceMatcher`, no autojunk).
    ``name`` is the message type of every text; ``None``: each difference is named by the
    first word of its text (``Message.describe`` starts with the name)."""
    differences: list[Difference] = []
    matcher = difflib.SequenceMatcher(a=expected, b=actual, autojunk=False)
    for tag, i1, i2, j1, j2 in matcher.get_opcodes():
        if tag == "equal":
            continue
        for k in range(max(i2 - i1, j2 - j1)):
            exp = expected[i1 + k] if i1 + k < i2 else None
            act = actual[j1 + k] if j1 + k < j2 else None
            label = name if name is not None else (exp or act or "?").split(" ", 1)[0]
            differences.append(Difference(label, min(i1 + k, len(expected)), exp, act))
    return differences


def log_node(decoded: Iterable[DecodedRecord]) -> int:
    """The CAN node a log's host talked to: the most common non-broadcast node of its
    host-to-controller frames (:data:`~firmware_proto.wire.messages.DEFAULT_NODE` if none)."""
    nodes = Counter(
        d.node
        for d in decoded
        if d.message is not None
        and d.direction == HOST_TO_CONTROLLER
        and d.node not in (None, BROADCAST_NODE)
    )
    return int(nodes.most_common(1)[0][0]) if nodes else DEFAULT_NODE


def counts_before(
    events: Iterable[tuple[float, str]], times: Iterable[float]
) -> list[Counter[str]]:
    """For each of ``times`` (ascending), how many ``events`` ``(time, name)`` of each
    name came strictly before it: what a replay waits for before its next frame."""
    ordered = sorted(events)
    out: list[Counter[str]] = []
    seen: Counter[str] = Counter()
    i = 0
    for t in times:
        while i < len(ordered) and ordered[i][0] < t:
            seen[ordered[i][1]] += 1
            i += 1
        out.append(Counter(seen))
    return out
