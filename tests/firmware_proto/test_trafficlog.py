"""The traffic-log format and what is built on it: serial log lines round-trip, bad lines
are refused with their line number, records decode (and bad frames say why), and
answers compare type by type with volatile fields left out unless strict."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from firmware_proto.errors import DecodeError
from firmware_proto.linkio.trafficlog import (
    CONTROLLER_TO_HOST,
    HOST_TO_CONTROLLER,
    SERIAL_LOG_MAGIC,
    CanRecord,
    Difference,
    SerialRecord,
    answer_key,
    compare_answers,
    counts_before,
    decode_records,
    diff_texts,
    format_serial_record,
    is_answer,
    is_serial_log,
    log_node,
    message_direction,
    parse_serial_log,
    serial_log_header,
)
from firmware_proto.wire import cobs
from firmware_proto.wire.canmap import encode_can
from firmware_proto.wire.framing import encode_frame
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import (
    DEFAULT_NODE,
    Ack,
    AckField,
    AckResult,
    ControllerState,
    Encoders,
    Heartbeat,
    Hello,
    Ident,
    Motion,
    Status,
    StepState,
    Stop,
    StopAck,
    Stopped,
)

from .strategies import any_message

times = st.floats(0, 4e9, allow_nan=False).map(lambda t: round(t, 6))


@given(st.lists(st.tuples(times, any_message(), st.integers(0, 255)), max_size=20))
def test_serial_log_lines_round_trip(items: list[tuple[float, Message, int]]) -> None:
    records = [SerialRecord(t, message_direction(m), encode_frame(m, seq)) for t, m, seq in items]
    text = serial_log_header({"role": "bridge", "device": "/dev/pts/3"}) + "".join(
        format_serial_record(r) for r in records
    )
    parsed = parse_serial_log(text.splitlines(keepends=True))
    assert parsed.metadata == {"role": "bridge", "device": "/dev/pts/3"}
    assert list(parsed.records) == records
    decoded = decode_records(parsed.records)
    assert [d.message for d in decoded] == [m for _, m, _ in items]
    assert [d.seq for d in decoded] == [seq for _, _, seq in items]


def test_a_line_is_time_direction_and_wire_hex() -> None:
    wire = encode_frame(Stop(7, 4), 3)
    line = format_serial_record(SerialRecord(1731000000.5, HOST_TO_CONTROLLER, wire))
    assert line == f"1731000000.500000 H>C {wire.hex()}\n"
    assert wire.startswith(b"\x00") and wire.endswith(b"\x00")
    assert is_serial_log(serial_log_header().splitlines()[0])
    assert serial_log_header().splitlines()[0] == SERIAL_LOG_MAGIC


@pytest.mark.parametrize(
    ("body", "error"),
    [
        ("1.0 H>C 00ff00 extra\n", "line 2: expected 'time direction hex'"),
        ("1.0 X>Y 00ff00\n", "line 2: direction must be H>C or C>H"),
        ("soon H>C 00ff00\n", "line 2: could not convert"),
        ("1.0 H>C 0g\n", "line 2: non-hexadecimal"),
        ("\n# a comment\n1.0 C>H 0\n", "line 4"),
    ],
)
def test_malformed_lines_are_refused_with_their_number(body: str, error: str) -> None:
    with pytest.raises(DecodeError, match=error):
        parse_serial_log([SERIAL_LOG_MAGIC + "\n", *body.splitlines(keepends=True)])


def test_a_file_without_the_magic_line_is_not_a_serial_log() -> None:
    with pytest.raises(DecodeError, match="not a serial frame log"):
        parse_serial_log(["(1.0) vcan0 001#0100 T\n"])
    with pytest.raises(ValueError, match="bad metadata"):
        serial_log_header({"a:b": "c"})


def test_damaged_serial_frames_decode_to_nothing_and_say_why() -> None:
    motion = Motion(1, 1, 30, 100)
    raw = bytes((motion.MSG_ID, 5)) + motion.pack() + b"\x12\x34"  # a wrong CRC
    wire = b"\x00" + cobs.encode(raw) + b"\x00"
    records = [
        SerialRecord(1.0, HOST_TO_CONTROLLER, wire),
        SerialRecord(2.0, CONTROLLER_TO_HOST, encode_frame(Ack(1, 0, 0, 1), 0)),
    ]
    bad, good = decode_records(records)
    assert bad.message is None
    assert bad.error == "crc"
    assert bad.raw == wire.hex()
    assert good.message == Ack(1, 0, 0, 1)
    assert good.direction == CONTROLLER_TO_HOST


def test_can_records_decode_with_node_and_direction_from_the_identifier() -> None:
    arb, data = encode_can(Motion(5, 1, 30, 100), 3)
    arb_ack, data_ack = encode_can(Ack(5, 0, 0, 1), 3)
    records = [
        CanRecord(1.0, "vcan0", arb, data, is_rx=False),
        CanRecord(1.1, "vcan0", arb_ack, data_ack, is_rx=True),
        CanRecord(1.2, "vcan0", 0x7FF, b"\x01\x02", is_rx=True),
        CanRecord(1.3, "vcan0", arb, data[:3], is_rx=True),
    ]
    assert [r.direction for r in records] == [HOST_TO_CONTROLLER, CONTROLLER_TO_HOST, None, "H>C"]
    motion, ack, foreign, short = decode_records(records)
    assert (motion.message, motion.node, motion.is_rx) == (Motion(5, 1, 30, 100), 3, False)
    assert (ack.message, ack.direction, ack.raw) == (Ack(5, 0, 0, 1), "C>H", "093#0500000001")
    assert (foreign.message, foreign.error, foreign.direction) == (None, "unknown_id", None)
    assert (short.message, short.error) == (None, "bad_length")


def test_answers_are_controller_reports_not_telemetry_or_requests() -> None:
    assert is_answer(Ack(1, 0, 0, 1))
    assert is_answer(Stopped(1, 10, 20))
    assert not is_answer(Heartbeat(1, 0, 1, 0, 0, 0, 0, 0, 0, 0, 0))
    assert not is_answer(Encoders(1, 2, 3))
    assert not is_answer(Motion(1, 1, 30, 100))


def test_volatile_fields_are_left_out_unless_strict() -> None:
    assert answer_key(Ack(3, AckResult.ACCEPTED, AckField.NONE, 4)) == (
        "ACK seq=3 result=ACCEPTED field=NONE"
    )
    assert answer_key(Stopped(2, 85, 306)) == "STOPPED stop_id=2"
    assert answer_key(Stopped(2, 85, 306), strict=True) == (
        "STOPPED stop_id=2 distance_mm=85 duration_ms=306"
    )


SESSION: list[Message] = [
    Ident(1, 1, 0, 0, 0x9F24, 0x1234),
    Ack(1, AckResult.ACCEPTED, AckField.NONE, 1),
    Status(1, StepState.STARTED, 0, 0),
    Encoders(10, 0, 0),
    Status(1, StepState.COMPLETED, 0, 2300),
    StopAck(1, ControllerState.STOP_LATCHED, 1),
    Stopped(1, 40, 120),
]


def test_the_same_session_compares_alike_whatever_the_telemetry_and_interleaving() -> None:
    replayed: list[Message] = [
        Ident(1, 1, 0, 0, 0x9F24, 0x9999),  # another boot nonce: volatile
        Status(1, StepState.STARTED, 0, 0),  # before the ACK this time
        Ack(1, AckResult.ACCEPTED, AckField.NONE, 2),  # another queue depth: volatile
        Status(1, StepState.COMPLETED, 0, 2301),  # another travel: volatile
        StopAck(1, ControllerState.STOP_LATCHED, 1),
        Stopped(1, 41, 119),
    ]
    assert compare_answers(SESSION, replayed) == []
    strict = compare_answers(SESSION, replayed, strict=True)
    assert {d.name for d in strict} == {"ACK", "IDENT", "STATUS", "STOPPED"}


def test_a_changed_missing_or_extra_answer_is_a_difference() -> None:
    replayed: list[Message] = [
        SESSION[0],
        Ack(1, AckResult.STOP_LATCHED, AckField.NONE, 0),
        StopAck(1, ControllerState.STOP_LATCHED, 1),
        Stopped(1, 40, 120),
        Stopped(9, 0, 0),
    ]
    differences = compare_answers(SESSION, replayed)
    assert [str(d) for d in differences] == [
        "ACK #0: recorded ACK seq=1 result=ACCEPTED field=NONE | "
        "replayed ACK seq=1 result=STOP_LATCHED field=NONE",
        "STATUS #0: missing in replay: STATUS seq=1 state=STARTED reason=NONE",
        "STATUS #1: missing in replay: STATUS seq=1 state=COMPLETED reason=NONE",
        "STOPPED #1: extra in replay: STOPPED stop_id=9",
    ]
    assert differences[0] == Difference(
        "ACK",
        0,
        "ACK seq=1 result=ACCEPTED field=NONE",
        "ACK seq=1 result=STOP_LATCHED field=NONE",
    )
    requests: list[Message] = [Hello(1, 2)]
    assert compare_answers([], requests) == []  # requests are never compared


def test_counts_before_counts_each_name_strictly_before_each_time() -> None:
    events = [(2.0, "ACK"), (1.0, "ACK"), (3.0, "STATUS"), (3.0, "ACK")]
    needs = counts_before(events, [0.5, 2.0, 3.0, 9.0])
    assert needs == [{}, {"ACK": 1}, {"ACK": 2}, {"ACK": 3, "STATUS": 1}]


def test_diff_texts_names_each_difference_by_its_type_or_its_first_word() -> None:
    recorded = ["HELLO v=1", "MOTION seq=1", "STOP id=1"]
    replayed = ["HELLO v=1", "MOTION seq=2", "STOP id=1", "CLEAR_STOP id=1"]
    assert diff_texts(recorded, replayed) == [
        Difference("MOTION", 1, "MOTION seq=1", "MOTION seq=2"),
        Difference("CLEAR_STOP", 3, None, "CLEAR_STOP id=1"),
    ]
    assert [d.name for d in diff_texts(["a"], ["b"], name="ACK")] == ["ACK"]
    assert diff_texts(recorded, list(recorded)) == []


def test_log_node_is_the_node_the_host_addressed_most() -> None:
    def frame(node: int, message: Message) -> CanRecord:
        arbitration_id, data = encode_can(message, node)
        return CanRecord(1.0, "can0", arbitration_id, data, is_rx=False)

    records = [frame(3, Hello(1, 0x1234)), frame(3, Stop(1, 0)), frame(5, Stop(2, 0))]
    assert log_node(decode_records(records)) == 3
    assert log_node([]) == DEFAULT_NODE  # nothing addressed
