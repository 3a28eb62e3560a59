"""Replay a recorded session's host frames into a fresh emulator and compare its answers.

:func:`replay_into_emulator` starts a seeded emulator on a new pty or python-can bus,
re-sends every host frame at its recorded time (serial byte for byte), but not before
the answers that preceded it in the recording (waiting at most ``gate_s`` longer; host
heartbeats keep their own time), and compares the answers type by type
(:func:`firmware_proto.linkio.trafficlog.compare_answers`). Both windows are cut alike
(:data:`MAX_SETTLE_S`, ``edge_s``); telemetry is counted, not compared. The emulator
must run as recorded (seed, speed factor, map, rover). docs/traffic-logs.md, "Into the
emulator", says why each rule is there.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter
from dataclasses import dataclass

from emulator.can_frontend import CanFrontEnd
from emulator.controller import ControllerConfig, ControllerModel
from emulator.engine import Emulator
from emulator.frontend import FrontEnd
from emulator.serial_frontend import SerialFrontEnd
from emulator.twin import Twin, served_dt_s
from firmware_proto.linkio.can_endpoint import CanEndpoint
from firmware_proto.linkio.endpoint import HOST
from firmware_proto.linkio.replay_peer import ReplayPeer
from firmware_proto.linkio.serial_endpoint import SerialEndpoint
from firmware_proto.linkio.trafficio import LogFile
from firmware_proto.linkio.trafficlog import (
    CONTROLLER_TO_HOST,
    HOST_TO_CONTROLLER,
    Difference,
    TrafficRecord,
    TrafficRecorder,
    answer_key,
    compare_answers,
    counts_before,
    decode_records,
    is_answer,
    log_node,
)
from firmware_proto.model.rover import load_rover
from firmware_proto.model.worldmap import load_map
from firmware_proto.wire.message import Message

__all__ = [
    "MAX_SETTLE_S",
    "REPLAY_MAX_BACKLOG_S",
    "ReplayOptions",
    "ReplayResult",
    "replay_into_emulator",
]

logger = logging.getLogger(__name__)

MAX_SETTLE_S = 10.0
"""Longest wait for answers after the last host frame, s (wall)."""
REPLAY_MAX_BACKLOG_S = 2.0
"""How far behind the replay's emulator may fall and still catch up in a burst, wall s
(live: :data:`emulator.engine.MAX_BACKLOG_S`): a slip moves recorded frames to other ticks."""
_FIRST_FRAME_TIMEOUT_S = 5.0


@dataclass(frozen=True)
class ReplayOptions:
    """How to run the fresh emulator and the comparison.

    Attributes:
        seed: the emulator's seed (boot nonce, sensor noise).
        speed_factor: twin seconds per wall second, as when recorded.
        dt_s: the twin's step, s, as recorded (``None``: :func:`~emulator.twin.served_dt_s`).
        map_name: map name or JSON file.
        rover_path: rover description TOML ("" for the packaged one).
        node: CAN node id of the controller (``None``: the node the log's host addressed).
        can_interface, can_channel: the python-can bus for a CAN log.
        strict: compare volatile fields too.
        edge_s: answers this close to a window's end may fall on either side, s.
        gate_s: longest wait past a host frame's recorded time for the answers that
            preceded it, s.
    """

    seed: int = 0
    speed_factor: float = 1.0
    dt_s: float | None = None
    map_name: str = "lab"
    rover_path: str = ""
    node: int | None = None
    can_interface: str = "virtual"
    can_channel: str = "rover-replay"
    strict: bool = False
    edge_s: float = 0.05
    gate_s: float = 0.1


@dataclass(frozen=True)
class ReplayResult:
    """What a replay found.

    Attributes:
        medium: ``"serial"`` or ``"can"``.
        node: the CAN node replayed (``None`` on serial).
        sent: host frames re-sent.
        recorded_answers, replayed_answers: answers compared on each side.
        recorded_telemetry, replayed_telemetry: telemetry frames in the window, by type.
        differences: every difference; empty when the controller answered alike.
        duration_s: wall time of the replay.
    """

    medium: str
    node: int | None
    sent: int
    recorded_answers: int
    replayed_answers: int
    recorded_telemetry: dict[str, int]
    replayed_telemetry: dict[str, int]
    differences: tuple[Difference, ...]
    duration_s: float

    @property
    def ok(self) -> bool:
        """The controller answered as recorded."""
        return not self.differences

    def report(self) -> str:
        """A few lines for a terminal."""
        where = "serial (pty)" if self.medium == "serial" else f"CAN node {self.node}"
        lines = [
            f"replayed {self.sent} host frames into a fresh emulator over {where} "
            f"in {self.duration_s:.1f} s",
            f"answers compared: {self.recorded_answers} recorded, {self.replayed_answers} replayed",
        ]
        telemetry = sorted(set(self.recorded_telemetry) | set(self.replayed_telemetry))
        if telemetry:
            counts = ", ".join(
                f"{name} {self.recorded_telemetry.get(name, 0)}/"
                f"{self.replayed_telemetry.get(name, 0)}"
                for name in telemetry
            )
            lines.append(f"telemetry (not compared; recorded/replayed): {counts}")
        if self.ok:
            lines.append("same answers")
        else:
            lines.append(f"{len(self.differences)} difference(s):")
            lines += [f"  {d}" for d in self.differences]
        return "\n".join(lines)


def _telemetry_counts(messages: list[Message]) -> dict[str, int]:
    return dict(
        Counter(
            m.NAME
            for m in messages
            if m.DIRECTION == "controller_to_host" and m.PRIORITY == "telemetry"
        )
    )


def _is_heartbeat(record: TrafficRecord) -> bool:
    """A host frame that answers nothing and that nothing answers (HOST_HEARTBEAT)."""
    decoded = decode_records([record])
    return bool(decoded) and all(
        d.message is not None and d.message.PRIORITY == "telemetry" for d in decoded
    )


def _pair_at_the_edges(
    recorded: list[tuple[float, Message]],
    replayed: list[tuple[float, Message]],
    ends: tuple[float, float],
    edge_s: float,
    strict: bool,
) -> tuple[list[Message], list[Message]]:
    """Answers to compare, per type: all in a window's core, edge ones where both agree."""
    rec_end, rep_end = ends
    out_recorded: list[Message] = []
    out_replayed: list[Message] = []
    names = {m.NAME for _, m in recorded + replayed if is_answer(m)}
    for name in sorted(names):
        r = [(t, m) for t, m in recorded if name == m.NAME and t <= rec_end]
        p = [(t, m) for t, m in replayed if name == m.NAME and t <= rep_end + edge_s]
        r_core = sum(t <= rec_end - edge_s for t, _ in r)
        p_core = sum(t <= rep_end - edge_s for t, _ in p)
        keys_r = [answer_key(m, strict) for _, m in r]
        keys_p = [answer_key(m, strict) for _, m in p]
        low, high = max(r_core, p_core), min(len(r), len(p))
        agreeing = [n for n in range(low, high + 1) if keys_r[:n] == keys_p[:n]]
        if agreeing:
            n_r = n_p = agreeing[-1]
        else:  # they differ inside: keep the cores and what pairs beyond them
            n_r = max(r_core, min(len(r), low))
            n_p = max(p_core, min(len(p), low))
        out_recorded += [m for _, m in r[:n_r]]
        out_replayed += [m for _, m in p[:n_p]]
    return out_recorded, out_replayed


def replay_into_emulator(
    log: LogFile,
    options: ReplayOptions | None = None,
    *,
    recorder: TrafficRecorder | None = None,
) -> ReplayResult:
    """Replay ``log``'s host frames into a fresh emulator; see the module docstring.

    Args:
        log: a traffic log (serial or CAN) from :func:`firmware_proto.linkio.trafficio.read_log`.
        options: emulator and comparison settings.
        recorder: records the replay session itself (optional).

    Raises:
        ValueError: the log holds no host-to-controller frame.
        OSError: the pty or bus cannot be opened.
        TimeoutError: the fresh emulator said nothing within 5 s.
    """
    opts = options or ReplayOptions()
    decoded = decode_records(log.records)
    node = (opts.node or log_node(decoded)) if log.kind == "can" else None
    host_records = [rec for rec in log.records if rec.direction == HOST_TO_CONTROLLER]
    if not host_records:
        raise ValueError(f"{log.path}: no host-to-controller frame to replay")
    t_first = host_records[0].time_s
    t_last = host_records[-1].time_s
    ours = [
        d
        for d in decoded
        if d.message is not None
        and d.direction == CONTROLLER_TO_HOST
        and (node is None or d.node == node)
        and d.time_s >= t_first
    ]
    tail = max((d.time_s for d in ours), default=t_last) - t_last
    window = min(MAX_SETTLE_S, max(0.0, tail))
    # Per host frame, the recorded answers (by type) the replay waits for.
    needs = counts_before(
        (
            (d.time_s, d.message.NAME)
            for d in ours
            if d.message is not None and is_answer(d.message)
        ),
        (rec.time_s for rec in host_records),
    )
    is_beat = [_is_heartbeat(rec) for rec in host_records]
    recorded_timed = [
        (d.time_s - t_first, d.message)
        for d in ours
        if d.time_s <= t_last + window and d.message is not None
    ]

    rover = load_rover(opts.rover_path or None)
    model = ControllerModel(
        rover,
        Twin(
            rover,
            load_map(opts.map_name),
            dt_s=served_dt_s(opts.speed_factor) if opts.dt_s is None else opts.dt_s,
        ),
        ControllerConfig(timeout_scale=opts.speed_factor),
        seed=opts.seed,
    )
    frontend: FrontEnd
    host: ReplayPeer
    started = time.monotonic()
    if log.kind == "serial":
        frontend = SerialFrontEnd(seed=opts.seed, recorder=recorder)
    else:
        assert node is not None
        frontend = CanFrontEnd(
            interface=opts.can_interface,
            channel=opts.can_channel,
            node=node,
            seed=opts.seed,
            recorder=recorder,
        )
    # Answers are compared in twin time: catch up rather than let twin time slip.
    emulator = Emulator(
        model, frontend, speed_factor=opts.speed_factor, max_backlog_s=REPLAY_MAX_BACKLOG_S
    )
    try:
        if isinstance(frontend, CanFrontEnd):
            assert node is not None
            host = ReplayPeer(
                CanEndpoint(HOST, opts.can_interface, opts.can_channel, node=node), is_answer
            )
            host.start()  # before boot: the boot frames are answers too
            emulator.start()
        else:
            emulator.start()
            host = ReplayPeer(SerialEndpoint.for_url(HOST, frontend.device), is_answer)
            host.start()
        with host:
            if not host.wait_first(_FIRST_FRAME_TIMEOUT_S):
                raise TimeoutError("the fresh emulator sent nothing within 5 s")
            t0 = time.monotonic()
            host.count_from(t0)
            # Heartbeats keep their own time: gated, they would starve the watchdog.
            heartbeats = [r for r, beat in zip(host_records, is_beat, strict=True) if beat]
            pacer = threading.Thread(
                target=host.play_on_time,
                args=(heartbeats, t0 - t_first),
                name="replay-heartbeats",
                daemon=True,
            )
            pacer.start()
            late = 0
            last_sent = t0
            try:
                for rec, need, beat in zip(host_records, needs, is_beat, strict=True):
                    if beat:
                        continue
                    due = t0 + (rec.time_s - t_first)
                    delay = due - time.monotonic()
                    if delay > 0:
                        time.sleep(delay)  # replaying the recorded timing is the point
                    if need and not host.wait_counts(need, due + opts.gate_s):
                        late += 1
                    host.play(rec)
                    last_sent = time.monotonic()
            finally:
                pacer.join()
            if heartbeats:
                last_sent = max(last_sent, t0 + heartbeats[-1].time_s - t_first)
            if late:
                logger.info("%d host frame(s) sent without all the answers before them", late)
            boundary = last_sent + window
            end = boundary + opts.edge_s
            while (left := end - time.monotonic()) > 0:
                time.sleep(min(left, 0.05))
            received = host.snapshot()
    finally:
        emulator.close()
    replayed_timed = [(t - t0, m) for t, m in received if t >= t0]
    recorded_end = t_last - t_first + window
    replayed_end = boundary - t0
    recorded, replayed = _pair_at_the_edges(
        recorded_timed, replayed_timed, (recorded_end, replayed_end), opts.edge_s, opts.strict
    )
    differences = compare_answers(recorded, replayed, strict=opts.strict)
    return ReplayResult(
        medium=log.kind,
        node=node,
        sent=len(host_records),
        recorded_answers=sum(1 for m in recorded if is_answer(m)),
        replayed_answers=sum(1 for m in replayed if is_answer(m)),
        recorded_telemetry=_telemetry_counts([m for _, m in recorded_timed]),
        replayed_telemetry=_telemetry_counts([m for t, m in replayed_timed if t <= replayed_end]),
        differences=tuple(differences),
        duration_s=time.monotonic() - started,
    )
