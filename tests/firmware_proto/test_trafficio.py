"""Traffic log writers and reader on in-memory streams: the formats round trip, a writer
and the reader own and close their streams, and concurrent records never
interleave within a line."""

from __future__ import annotations

import io
import threading

import can
import pytest

from firmware_proto.linkio.trafficio import (
    CAN_LOG_FORMATS,
    CanLogWriter,
    LogWriter,
    SerialLogWriter,
    parse_log,
    writer_for,
)
from firmware_proto.linkio.trafficlog import CanRecord, SerialRecord

T0 = 1795246430.225437

SERIAL = [
    SerialRecord(T0, "H>C", bytes.fromhex("0002600601249f879400")),
    SerialRecord(T0 + 0.000309, "C>H", bytes.fromhex("0005611a01010107249fb7f267cf00")),
]
CAN = [
    CanRecord(T0, "rec1", 0x602, bytes.fromhex("01249f"), is_rx=False),
    CanRecord(T0 + 0.003865, "rec1", 0x422, bytes(8), is_rx=True),
    CanRecord(T0 + 0.004001, "rec1", 0x7FF, b"", is_rx=True, is_remote_frame=True),
]


class _Kept(io.BytesIO):
    """A binary stream whose bytes outlive close()."""

    def close(self) -> None:
        self.kept = self.getvalue()
        super().close()


def _write(medium: str, suffix: str, records: list[SerialRecord] | list[CanRecord]) -> bytes:
    stream = _Kept()
    with writer_for(medium, suffix, channel="rec1", metadata={"role": "test"})(stream) as log:
        for r in records:
            log.record(r)
        assert log.frames == len(records)
    assert stream.closed  # the writer owned it
    return stream.kept


def test_serial_log_round_trips_with_its_metadata() -> None:
    data = _write("serial", ".rlog", SERIAL)
    assert data.decode("ascii").splitlines()[:2] == [
        "# rover-hil serial frame log v1",
        "# role: test",
    ]
    stream = io.BytesIO(data)
    log = parse_log(stream, "x.log")  # content first: a serial log under any suffix
    assert stream.closed  # the reader owned it
    assert (log.kind, log.metadata, log.records) == ("serial", {"role": "test"}, tuple(SERIAL))


@pytest.mark.parametrize("suffix", sorted(CAN_LOG_FORMATS))
def test_can_formats_round_trip(suffix: str) -> None:
    data = _write("can", suffix, CAN)
    log = parse_log(io.BytesIO(data), f"bus{suffix}")
    assert log.kind == "can"
    got = [r for r in log.records if isinstance(r, CanRecord)]
    assert len(got) == len(log.records) == len(CAN)
    for r, w in zip(got, CAN, strict=True):
        assert r.time_s == pytest.approx(w.time_s, abs=1e-6)
        assert (r.arbitration_id, r.data, r.is_rx, r.is_remote_frame) == (
            w.arbitration_id,
            w.data,
            w.is_rx,
            w.is_remote_frame,
        )


def test_candump_lines_carry_the_channel_and_direction() -> None:
    lines = _write("can", ".log", CAN).decode("ascii").splitlines()
    assert lines[:2] == [
        "(1795246430.225437) rec1 602#01249F T",
        "(1795246430.229302) rec1 422#0000000000000000 R",
    ]


def test_refusals_come_before_any_stream() -> None:
    with pytest.raises(ValueError, match="known: serial, can"):
        writer_for("usb", ".log")
    for suffix in (".asc", ".trc", ".csv", ".txt", ".db", ".mf4", ""):
        with pytest.raises(ValueError, match=r"known: \.log, \.blf"):
            writer_for("can", suffix)
    with pytest.raises(ValueError, match="not a serial frame log"):
        parse_log(io.BytesIO(b"(1.0) x 602#00 T\n"), "bus.asc")
    with pytest.raises(ValueError, match="malformed candump -L log"):
        parse_log(io.BytesIO(b"(1.0) x 6Z2#00 T\n"), "bus.log")


def test_a_writer_that_cannot_start_closes_its_stream() -> None:
    class Full(io.BytesIO):
        def write(self, data: object) -> int:
            raise OSError("No space left on device")

    stream = Full()
    with pytest.raises(OSError, match="No space"):
        writer_for("serial", ".rlog")(stream)
    assert stream.closed


def test_close_is_idempotent_and_later_records_are_dropped() -> None:
    text = io.StringIO()
    writer = SerialLogWriter(text)
    writer.record(SERIAL[0])
    written = text.getvalue()
    writer.close()
    writer.close()
    assert text.closed
    writer.record(SERIAL[1])  # a reader thread late at shutdown: dropped, no error
    assert writer.frames == 1
    assert written.endswith("1795246430.225437 H>C 0002600601249f879400\n")


def test_can_writer_stops_the_python_can_writer() -> None:
    text = io.StringIO()
    with CanLogWriter(can.CanutilsLogWriter(text, channel="can0")) as writer:
        writer.record(CanRecord(T0, "", 0x101, b"\x01", is_rx=False))
        assert text.getvalue() == "(1795246430.225437) can0 101#01 T\n"  # flushed per frame
    assert text.closed


@pytest.mark.parametrize("medium", ["serial", "can"])
def test_concurrent_records_stay_whole_lines(medium: str) -> None:
    stream = _Kept()
    writer: LogWriter = writer_for(medium, ".log", channel="c")(stream)
    per_thread = 300
    record = SERIAL[0] if medium == "serial" else CAN[0]
    start = threading.Barrier(4)

    def hammer() -> None:
        start.wait()
        for _ in range(per_thread):
            writer.record(record)

    threads = [threading.Thread(target=hammer) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    writer.close()
    log = parse_log(io.BytesIO(stream.kept), "x.log")
    assert writer.frames == len(log.records) == 4 * per_thread
    assert set(log.records) == {record}


@pytest.mark.parametrize(("medium", "records"), [("serial", SERIAL), ("can", CAN)])
def test_a_record_that_lost_the_race_to_the_log_never_goes_back_in_time(
    medium: str, records: list[SerialRecord] | list[CanRecord]
) -> None:
    """Two threads stamp their frames, then race to the log: the file's order (what a
    replay follows) and its time order must agree."""
    late_first = [records[1], records[0], *records[2:]]
    data = _write(medium, ".rlog" if medium == "serial" else ".log", late_first)
    lines = [x for x in data.decode("ascii").splitlines() if x and not x.startswith("#")]
    in_file_order = [float(x.split()[0].strip("()")) for x in lines]  # as canplayer reads
    assert in_file_order == sorted(in_file_order)
    assert in_file_order[:2] == pytest.approx([records[1].time_s] * 2, abs=1e-6)
