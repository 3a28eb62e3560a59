"""Traffic logs end to end: a real bridge link drives a real emulator over a pty and a
python-can bus while both ends record; the logs decode, replay into a fresh seeded
emulator with the same answers, and a deliberately altered log shows the difference."""

from __future__ import annotations

import json
import os
import re
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import can
import pytest

from bridge.link.controllerlink import ControllerLink, LinkConfig, StepRequest
from bridge.link.transport import Transport, open_transport
from bridge.tools.bridge_replay import BridgeReplayOptions, BridgeReplayResult, replay_into_bridge
from emulator.can_frontend import CanFrontEnd
from emulator.controller import ControllerConfig, ControllerModel
from emulator.emulator_replay import ReplayOptions, ReplayResult, replay_into_emulator
from emulator.engine import Emulator
from emulator.frontend import FrontEnd
from emulator.serial_frontend import SerialFrontEnd
from emulator.twin import Twin
from firmware_proto.cli import main as rover_cli
from firmware_proto.linkio.trafficio import open_recorder, read_log
from firmware_proto.linkio.trafficlog import (
    CanRecord,
    SerialRecord,
    TrafficRecord,
    decode_records,
    format_serial_record,
    serial_log_header,
)
from firmware_proto.model.rover import RoverDescription
from firmware_proto.runtime.realtime import EMULATOR_PRIORITY
from firmware_proto.wire.canmap import encode_can
from firmware_proto.wire.framing import encode_frame
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import Command, Ident, Motion, Stopped, WheelSpeeds
from tests.scheduling import threads_at

from .conftest import SPEED, Recorder

SEED = 5
FWD, LEFT, REV = Command.FWD, Command.LEFT, Command.REV


@dataclass(frozen=True)
class Session:
    kind: str
    channel: str
    node: int
    host_log: Path
    controller_log: Path
    statuses: list[str]


def _drive(
    link: ControllerLink, rec: Recorder, moving: threading.Event, halted: threading.Event
) -> None:
    """Steps that complete, a STOP that aborts two, a refusal while latched, a clear and
    a last step: every kind of answer the controller gives. The STOP waits until the
    wheels move, so that no answer hangs on sub-millisecond timing (a replay keeps the
    recorded timing only to a fraction of a millisecond). The clear waits for the STOPPED
    report (``halted``), which comes once the wheels stand still, about 0.2 s after the
    STOP: else the session could end before it and the log would lack it."""
    rec.wait_count("ready", 1)
    for _ in range(3):
        link.submit_step(StepRequest(FWD, 60, 3000))
    rec.wait_count("completed", 3)
    moving.clear()
    link.submit_step(StepRequest(FWD, 60, 30000))
    link.submit_step(StepRequest(LEFT, 30, 30000))
    rec.wait_count("accepted", 5)
    assert moving.wait(10.0), "the wheels never moved"
    mark = rec.mark()
    link.emergency_stop()
    rec.wait(lambda xs: "stopped" in xs and xs.count("aborted:stop") == 2, since=mark)
    assert halted.wait(10.0), "no STOPPED report"
    link.submit_step(StepRequest(FWD, 60, 100))
    rec.wait_count("rejected:stop_latched", 1, since=mark)
    link.clear_stop()
    rec.wait_count("cleared", 1, since=mark)
    link.submit_step(StepRequest(REV, 60, 2000))
    rec.wait_count("completed", 4)


def _record_session(
    rover: RoverDescription, tmp_path: Path, kind: str, channel: str, node: int = 2
) -> Session:
    suffix = "rlog" if kind == "serial" else "log"
    host_log = tmp_path / f"host.{suffix}"
    controller_log = tmp_path / f"controller.{suffix}"
    with (
        open_recorder(host_log, kind, channel=channel, metadata={"role": "bridge"}) as host_rec,
        open_recorder(
            controller_log,
            kind,
            channel=channel,
            metadata={"role": "emulator", "seed": str(SEED), "speed_factor": str(SPEED)},
        ) as ctrl_rec,
    ):
        model = ControllerModel(
            rover, Twin(rover), ControllerConfig(timeout_scale=SPEED), seed=SEED
        )
        frontend: FrontEnd
        if kind == "serial":
            frontend = SerialFrontEnd(seed=SEED, recorder=ctrl_rec)
        else:
            frontend = CanFrontEnd(
                interface="virtual", channel=channel, node=node, seed=SEED, recorder=ctrl_rec
            )
        with Emulator(model, frontend, speed_factor=SPEED):
            url = (
                frontend.device
                if isinstance(frontend, SerialFrontEnd)
                else f"can://virtual/{channel}?node={node}"
            )
            rec = Recorder()
            moving, halted = threading.Event(), threading.Event()

            def factory(u: str) -> Transport:
                return open_transport(u, recorder=host_rec)

            def on_telemetry(msg: Message, arrived: float) -> None:
                if isinstance(msg, WheelSpeeds) and msg.left_mm_s > 50:
                    moving.set()
                elif isinstance(msg, Stopped):
                    halted.set()

            with ControllerLink(
                LinkConfig(url),
                on_status=rec,
                on_telemetry=on_telemetry,
                transport_factory=factory,
                first_request_id=1,  # a bridge draws it at random; 1 keeps this readable
            ) as link:
                _drive(link, rec, moving, halted)
    return Session(kind, channel, node, host_log, controller_log, rec.items)


@pytest.fixture(scope="module")
def sessions(
    rover: RoverDescription, tmp_path_factory: pytest.TempPathFactory
) -> dict[str, Session]:
    """One recorded session per medium, shared by the tests of this module (read only).
    Recorded, like every replay below, at the emulator's real-time priority, as the
    programs run (``rover emulate``, ``rover replay``): on a busy machine a session at
    normal priority can record a watchdog trip that the replay then does not repeat."""
    with threads_at(EMULATOR_PRIORITY):
        return {
            kind: _record_session(rover, tmp_path_factory.mktemp(kind), kind, f"traffic-{kind}")
            for kind in ("serial", "can")
        }


def _replay(path: Path, options: ReplayOptions) -> ReplayResult:
    """:func:`replay_into_emulator` keeping time as ``rover replay`` does."""
    with threads_at(EMULATOR_PRIORITY):
        return replay_into_emulator(read_log(path), options)


def _replay_bridge(path: Path, options: BridgeReplayOptions) -> BridgeReplayResult:
    """:func:`replay_into_bridge` keeping time as ``rover replay --bridge`` does."""
    with threads_at(EMULATOR_PRIORITY):
        return replay_into_bridge(read_log(path), options)


@pytest.fixture(params=["serial", "can"])
def session(request: pytest.FixtureRequest, sessions: dict[str, Session]) -> Session:
    return sessions[request.param]


def _options(s: Session, **kw: object) -> ReplayOptions:
    return ReplayOptions(
        seed=SEED,
        speed_factor=SPEED,
        can_channel=f"{s.channel}-replay",
        **kw,  # type: ignore[arg-type]
    )


def test_both_ends_record_the_same_conversation(session: Session) -> None:
    host = read_log(session.host_log)
    ctrl = read_log(session.controller_log)
    assert host.kind == ctrl.kind == session.kind
    assert host.metadata.get("role") == ("bridge" if session.kind == "serial" else None)

    def conversation(records: tuple[TrafficRecord, ...], direction: str) -> list[str]:
        return [
            d.message.describe()
            for d in decode_records(records)
            if d.message is not None
            and d.direction == direction
            and d.message.PRIORITY in ("emergency", "motion")
        ]

    # The host's requests, and the controller's emergency and motion answers, in the same
    # order at both ends (each end's clock orders its own sends and receives only).
    for direction in ("H>C", "C>H"):
        assert conversation(host.records, direction) == conversation(ctrl.records, direction)
    names = [d.message.NAME for d in decode_records(host.records) if d.message is not None]
    for name in ("HELLO", "IDENT", "MOTION", "ACK", "STATUS", "STOP", "STOP_ACK", "CLEAR_STOP"):
        assert name in names
    assert all(d.message is not None for d in decode_records(host.records))


def test_serial_logs_keep_the_exact_wire_bytes(sessions: dict[str, Session]) -> None:
    s = sessions["serial"]
    text = s.host_log.read_text(encoding="ascii").splitlines()
    assert text[0] == "# rover-hil serial frame log v1"
    lines = [line for line in text if not line.startswith("#")]
    assert all(re.fullmatch(r"\d+\.\d{6} (H>C|C>H) 00[0-9a-f]+00", line) for line in lines)
    first_host = next(
        d for d in decode_records(read_log(s.host_log).records) if d.direction == "H>C"
    )
    assert first_host.message is not None
    assert first_host.raw == encode_frame(first_host.message, first_host.seq or 0).hex()


def test_can_logs_are_candump_logs_python_can_reads(sessions: dict[str, Session]) -> None:
    s = sessions["can"]
    can_channel = s.channel
    lines = s.host_log.read_text(encoding="ascii").splitlines()
    pattern = rf"\(\d+\.\d{{6}}\) {re.escape(can_channel)} [0-9A-F]{{3}}#[0-9A-F]* [RT]"
    assert all(re.fullmatch(pattern, line) for line in lines), lines[:3]
    with can.LogReader(str(s.host_log)) as reader:
        frames = list(reader)
    assert len(frames) == len(lines)
    sent = [f for f in frames if not f.is_rx]
    assert sent and all(f.arbitration_id & 0xF == s.node for f in sent)


def test_rover_decode_prints_direction_time_and_messages(
    session: Session, capsys: pytest.CaptureFixture[str]
) -> None:
    assert rover_cli(["decode", str(session.host_log), "--only", "STOP,STOP_ACK,CLEAR_ACK"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith(f"{session.host_log}: {session.kind} log, ")
    body = out[1:-1]
    # STOP is repeated every 10 ms until acknowledged, so it may appear more than once.
    assert "H>C" in body[0]
    assert "STOP stop_id=1 source=OPERATOR" in body[0]
    assert any("C>H" in line and "STOP_ACK stop_id=1 state=STOP_LATCHED" in line for line in body)
    assert "C>H" in body[-1]
    assert "CLEAR_ACK stop_id=2 result=CLEARED" in body[-1]
    where = "seq" if session.kind == "serial" else f"node  {session.node}"
    assert all(where in line for line in body)
    times = [float(line.split()[0]) for line in body]
    assert times == sorted(times) and times[0] > 0
    assert out[-1].startswith("-- ") and out[-1].endswith("undecodable 0")

    assert rover_cli(["decode", str(session.host_log), "--json", "--no-telemetry"]) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert {r["name"] for r in rows} >= {"HELLO", "IDENT", "MOTION", "ACK", "STATUS"}
    assert not {r["name"] for r in rows} & {"HEARTBEAT", "ENCODERS", "WHEEL_SPEEDS"}


def test_a_recorded_session_replays_with_the_same_answers(session: Session) -> None:
    for path in (session.host_log, session.controller_log):
        result = _replay(path, _options(session))
        assert result.ok, result.report()
        assert result.sent > 10
        assert result.recorded_answers == result.replayed_answers > 20
        assert result.node == (session.node if session.kind == "can" else None)


def _rewrite(path: Path, out: Path, edit: Callable[[TrafficRecord], TrafficRecord | None]) -> Path:
    log = read_log(path)
    records = [r for r in (edit(r) for r in log.records) if r is not None]
    if log.kind == "serial":
        text = serial_log_header(log.metadata) + "".join(
            format_serial_record(r) for r in records if isinstance(r, SerialRecord)
        )
        out.write_text(text, encoding="ascii")
    else:
        with open_recorder(out, "can") as writer:
            for r in records:
                writer.record(r)
    return out


def test_an_altered_log_shows_where_behaviour_differs(session: Session, tmp_path: Path) -> None:
    def drop_clear(r: TrafficRecord) -> TrafficRecord | None:
        decoded = decode_records([r])[0]
        return None if decoded.message is not None and decoded.message.NAME == "CLEAR_STOP" else r

    altered = _rewrite(
        session.host_log, tmp_path / f"no-clear.{session.host_log.suffix}", drop_clear
    )
    result = _replay(altered, _options(session))
    text = [str(d) for d in result.differences]
    assert not result.ok
    assert any(
        t.startswith("CLEAR_ACK #0: missing in replay: CLEAR_ACK stop_id=2 result=CLEARED")
        for t in text
    ), text
    # Still latched: the last step is refused, and never starts or completes.
    assert any(
        d.name == "ACK" and d.actual is not None and "result=STOP_LATCHED" in d.actual
        for d in result.differences
    )
    assert any(d.name == "STATUS" and d.actual is None for d in result.differences)


def test_a_changed_request_changes_the_answer(session: Session, tmp_path: Path) -> None:
    """The first step asks for speed 61 (beyond the limit): refused, and nothing runs."""

    def too_fast(r: TrafficRecord) -> TrafficRecord:
        message = decode_records([r])[0].message
        if not isinstance(message, Motion) or message.seq != 1:
            return r
        bad = Motion(1, FWD, 61, message.distance)
        if isinstance(r, SerialRecord):
            return SerialRecord(r.time_s, r.direction, encode_frame(bad, 2, strict=False))
        arb, data = encode_can(bad, session.node, strict=False)
        assert isinstance(r, CanRecord)
        return CanRecord(r.time_s, r.channel, arb, data, r.is_rx)

    altered = _rewrite(session.host_log, tmp_path / f"fast.{session.host_log.suffix}", too_fast)
    result = _replay(altered, _options(session))
    assert (
        "ACK #0: recorded ACK seq=1 result=ACCEPTED field=NONE | "
        "replayed ACK seq=1 result=OUT_OF_RANGE field=SPEED"
    ) in [str(d) for d in result.differences]


def test_rover_replay_takes_its_defaults_from_an_emulator_log(
    sessions: dict[str, Session], capsys: pytest.CaptureFixture[str]
) -> None:
    s = sessions["serial"]
    assert rover_cli(["replay", str(s.controller_log)]) == 0
    out, err = capsys.readouterr()
    # It keeps time as `rover emulate` does, and leaves this process as it found it.
    if os.geteuid() == 0:
        assert err.startswith("realtime: SCHED_RR priority 30, memory not locked"), err
    assert os.sched_getscheduler(0) == os.SCHED_OTHER
    assert f"emulator seed {SEED}, speed factor {SPEED:g}, map lab" in out
    assert "same answers" in out
    assert rover_cli(["replay", str(s.controller_log), "--seed", str(SEED + 1), "--strict"]) == 1
    assert "difference(s):" in capsys.readouterr().out  # another boot nonce, strictly


class _Broken:
    """A recorder whose disk is full."""

    def __init__(self) -> None:
        self.calls = 0

    def record(self, entry: TrafficRecord) -> None:
        self.calls += 1
        raise OSError("No space left on device")


def test_a_failing_recorder_never_stops_the_link(
    emulators: Callable[..., Emulator], caplog: pytest.LogCaptureFixture
) -> None:
    emu = emulators()
    broken = _Broken()
    rec = Recorder()
    url = emu.frontend.device
    link = ControllerLink(
        LinkConfig(url),
        on_status=rec,
        transport_factory=lambda u: open_transport(u, recorder=broken),
    )
    with link:
        rec.wait_count("ready", 1)
        link.submit_step(StepRequest(FWD, 60, 2300))
        rec.wait_count("completed", 1)
    assert broken.calls > 10
    assert sum("traffic recorder failed" in r.message for r in caplog.records) == 1


def test_recorders_refuse_the_other_medium_and_unknown_formats(tmp_path: Path) -> None:
    with open_recorder(tmp_path / "a.rlog", "serial") as serial_writer, pytest.raises(TypeError):
        serial_writer.record(CanRecord(1.0, "x", 1, b"", is_rx=True))
    with open_recorder(tmp_path / "b.log", "can") as can_writer, pytest.raises(TypeError):
        can_writer.record(SerialRecord(1.0, "H>C", b"\x00"))
    with pytest.raises(ValueError, match="known: serial, can"):
        open_recorder(tmp_path / "c", "usb")
    with pytest.raises(ValueError, match=r"known: \.log, \.blf"):
        open_recorder(tmp_path / "c.asc", "can")
    assert not (tmp_path / "c").exists()
    assert not (tmp_path / "c.asc").exists()  # refused before a file was made
    (tmp_path / "d.txt").write_text("hello\n")
    with pytest.raises(ValueError, match="not a serial frame log"):
        read_log(tmp_path / "d.txt")


def test_the_controller_side_replays_into_a_fresh_bridge(session: Session) -> None:
    result = _replay_bridge(
        session.host_log, BridgeReplayOptions(can_channel=f"{session.channel}-bridge")
    )
    assert result.ok, result.report()
    assert result.inputs == 8  # six steps sent, a stop, a clear (the refused step never left)
    assert result.recorded_requests == result.replayed_requests
    assert result.statuses.count("completed") == 4
    assert "stopped" in result.statuses
    assert "cleared" in result.statuses


def test_a_controller_of_another_schema_makes_the_bridge_refuse(
    session: Session, tmp_path: Path
) -> None:
    def other_schema(r: TrafficRecord) -> TrafficRecord:
        message = decode_records([r])[0].message
        if not isinstance(message, Ident):
            return r
        other = message._replace(schema_hash=message.schema_hash ^ 0x0F0F)
        if isinstance(r, SerialRecord):
            seq = decode_records([r])[0].seq or 0
            return SerialRecord(r.time_s, r.direction, encode_frame(other, seq))
        assert isinstance(r, CanRecord)
        arb, data = encode_can(other, session.node)
        return CanRecord(r.time_s, r.channel, arb, data, r.is_rx)

    altered = _rewrite(
        session.host_log, tmp_path / f"schema.{session.host_log.suffix}", other_schema
    )
    result = _replay_bridge(altered, BridgeReplayOptions(can_channel=f"{session.channel}-schema"))
    assert not result.ok
    assert "fault:schema_mismatch" in result.statuses
    assert "rejected:schema_mismatch" in result.statuses
    missing = [d.expected for d in result.differences if d.actual is None]
    assert "MOTION seq=1 command=FWD speed=60 distance=3000" in missing


@pytest.mark.parametrize(("name", "medium"), [("link.rlog", "serial"), ("link.log", "can")])
def test_a_recording_already_there_is_kept_not_truncated(
    tmp_path: Path, name: str, medium: str
) -> None:
    """A bridge restarted by its service with the same ``--record`` truncated the
    recording of the run that failed (the #40 clean-room check). The log already there is
    kept beside it, its suffix (its format) kept; an empty one is not."""

    def record(stamp: float) -> None:
        with open_recorder(tmp_path / name, medium) as writer:
            if medium == "serial":
                writer.record(SerialRecord(stamp, "C>H", encode_frame(Ident(4, 1, 0, 0, 1, 2))))
            else:
                data = encode_can(Ident(4, 1, 0, 0, 1, 2), 1)
                writer.record(CanRecord(stamp, "c", data[0], data[1], is_rx=True))

    record(1.0)
    record(2.0)
    record(3.0)
    stem, suffix = name.split(".")
    first, second = tmp_path / f"{stem}.1.{suffix}", tmp_path / f"{stem}.2.{suffix}"
    stamps = [read_log(p).records[0].time_s for p in (first, second, tmp_path / name)]
    assert stamps == pytest.approx([1.0, 2.0, 3.0])
    (tmp_path / "empty.rlog").touch()
    with open_recorder(tmp_path / "empty.rlog", "serial"):
        pass
    assert not (tmp_path / "empty.1.rlog").exists()
