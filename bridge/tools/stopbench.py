"""The STOP bench test: how fast an emergency stop takes effect, under load, and whether it
latches (docs/bench.md).

:class:`StopBench` speaks the protocol directly through the scripted protocol host of the
link layer (:class:`~firmware_proto.linkio.host.ProtocolHost` on the endpoint its URL
names, arrival times on ``time.monotonic()``), against a real controller or the
emulator. What one trial does, measures (``ack_ms``, ``stopped_ms``, ``zero_ms``, from
the write of the first STOP) and checks, and the load it runs under (a full motion
queue, ``telemetry_hz``, on CAN a flood, :class:`FloodConfig`), is docs/bench.md.
"""

from __future__ import annotations

import contextlib
import logging
import random
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import asdict, dataclass, field
from types import TracebackType
from typing import Any, TypeVar

import can

from bridge.errors import BridgeError, TransportError
from bridge.link.transport import url_errors
from firmware_proto.linkio.endpoint import HOST
from firmware_proto.linkio.errors import LinkError, NotReceivedError
from firmware_proto.linkio.host import HEARTBEAT_S, ProtocolHost, Received
from firmware_proto.linkio.media import open_endpoint
from firmware_proto.linkio.trafficlog import TrafficRecorder
from firmware_proto.linkio.urls import parse_can_url
from firmware_proto.wire.canmap import MAX_NODE, can_id
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import (
    ENCODERS_RATE_HZ,
    STOP_REPEAT_MS,
    AbortReason,
    Ack,
    AckResult,
    ClearResult,
    Command,
    Ident,
    Motion,
    Param,
    ParamResult,
    ParamValue,
    SetParam,
    Status,
    StepState,
    Stop,
    StopAck,
    Stopped,
    StopSource,
    WheelSpeeds,
)

__all__ = [
    "FLOOD_MSG_ID",
    "BenchConfig",
    "BenchError",
    "BenchRun",
    "FloodConfig",
    "FloodStats",
    "StopBench",
    "TrialResult",
]

logger = logging.getLogger(__name__)

M = TypeVar("M", bound=Message)

FLOOD_MSG_ID = ParamValue.MSG_ID
"""The flood's frames: PARAM_VALUE of another node, lowest priority, ignored by every controller."""
_LONG_STEP = 30000
"""Distance units of the queued steps: the longest the protocol allows (1.3 m)."""
_MAX_FILL = 64
_REPEAT_S = STOP_REPEAT_MS / 1000.0
"""STOP and CLEAR_STOP are sent again this often until answered (the protocol's rule), s."""
_MOVING_MM_S = 10.0
"""A STOP's random moment counts from the first wheel speed this fast: it meets a moving rover."""


class BenchError(BridgeError, RuntimeError):
    """The bench cannot go on: no handshake, a protocol mismatch, a refused setup."""


@dataclass(frozen=True)
class FloodConfig:
    """The second sender on a CAN bus.

    Attributes:
        interface, channel: the python-can bus it sends on (a second adapter on the same
            wire for real contention; the bench's own bus otherwise).
        rate_hz: frames per second; 0 sends back to back as fast as the bus takes them
            (a real bus saturates; never use 0 on ``virtual``, which has no back-pressure).
        arbitration_id: the identifier flooded (default: PARAM_VALUE of another node).
        bus_options: more ``can.Bus`` options (``bitrate``...).
    """

    interface: str
    channel: str
    rate_hz: float = 2000.0
    arbitration_id: int | None = None
    bus_options: dict[str, Any] = field(default_factory=dict)
    malformed: bool = False
    """Flood malformed frames aimed at the bench's node instead (see :func:`malformed_frames`):
    each must be counted and ignored by the controller and never delay a STOP."""


@dataclass(frozen=True)
class BenchConfig:
    """What to bench and how.

    Attributes:
        url: transport URL (a serial device or ``can://INTERFACE/CHANNEL?node=N``).
        trials: STOPs to measure.
        seed: seeds the STOP moments.
        speed: MOTION speed units of the queued steps (0..60).
        max_delay_s: STOP comes uniformly 0..this after the first step started, s.
        telemetry_hz: TELEMETRY_HZ set for the run (1..200); 0 leaves the rate alone.
        timeout_s: longest wait for any one answer, s.
        flood: the CAN flood, or ``None``.
    """

    url: str
    trials: int = 30
    seed: int = 0
    speed: int = 60
    max_delay_s: float = 0.5
    telemetry_hz: int = 100
    timeout_s: float = 5.0
    flood: FloodConfig | None = None

    def __post_init__(self) -> None:
        if self.trials < 1:
            raise ValueError(f"trials must be >= 1, got {self.trials}")
        if not 1 <= self.speed <= 60:
            raise ValueError(f"speed must be 1..60, got {self.speed}")
        if self.max_delay_s < 0 or self.timeout_s <= 0:
            raise ValueError("max delay must be >= 0 and timeout > 0")
        if self.telemetry_hz and not 1 <= self.telemetry_hz <= 200:
            raise ValueError(f"telemetry rate must be 1..200 Hz, got {self.telemetry_hz}")


@dataclass(frozen=True)
class TrialResult:
    """One STOP. Times in ms from the write of the first STOP; ``None`` when not seen.

    Attributes:
        trial: 1-based trial number.
        delay_s: wait between the first step's start and the STOP, s.
        speed_mm_s: mean measured wheel speed in the last WHEEL_SPEEDS before STOP, mm/s.
        queued: steps in the controller when STOP was sent (the queue was full).
        ack_ms, stopped_ms, zero_ms: the three measures (see the module docstring).
        controller_duration_ms, controller_distance_mm: from STOPPED.
        stop_repeats: STOP frames repeated before STOP_ACK.
        purged: queued steps reported ABORTED (reason STOP).
        targets_zero: every WHEEL_SPEEDS from STOP_ACK to STOPPED, or to the first at
            zero speed if that came later, reports zero targets (on CAN the first is
            not judged unless it is that one: it may have been queued before the STOP).
        latch_held: MOTION after the stop was refused STOP_LATCHED.
        clear_result: CLEAR_ACK result name.
        resumed: MOTION after CLEAR_STOP was accepted.
        error: what went wrong, "" if nothing.
    """

    trial: int
    stop_id: int
    delay_s: float
    speed_mm_s: float | None
    queued: int
    ack_ms: float | None
    stopped_ms: float | None
    zero_ms: float | None
    controller_duration_ms: int | None
    controller_distance_mm: int | None
    stop_repeats: int
    purged: int
    targets_zero: bool
    latch_held: bool
    clear_result: str
    resumed: bool
    error: str = ""

    @property
    def ok(self) -> bool:
        """Every measure seen and every check passed."""
        return (
            not self.error
            and None not in (self.ack_ms, self.stopped_ms, self.zero_ms)
            and self.purged == self.queued
            and self.targets_zero
            and self.latch_held
            and self.clear_result == "CLEARED"
            and self.resumed
        )

    def as_dict(self) -> dict[str, Any]:
        """Every field and ``ok``, for CSV and JSON."""
        return {**asdict(self), "ok": self.ok}


@dataclass
class FloodStats:
    """What the flood sent: frames, and sends the bus refused (full queue)."""

    sent: int = 0
    refused: int = 0


@dataclass(frozen=True)
class BenchRun:
    """A finished bench run: its configuration, what it found, and the conditions."""

    config: BenchConfig
    trials: tuple[TrialResult, ...]
    medium: str
    ident: str
    load: str
    arbitration_note: str
    telemetry_hz_set: int | None
    flood: FloodStats | None
    duration_s: float

    @property
    def passed(self) -> int:
        """Trials that passed every check."""
        return sum(t.ok for t in self.trials)


#: A protocol-violation (bit error) error frame: CAN_ERR_PROT class, no state change.
_CAN_ERR_PROT = 0x008


def malformed_frames(node: int) -> list[can.Message]:
    """One of each kind of malformed frame a controller at ``node`` must count and ignore
    (docs/protocol.md, "CAN mapping"): a MOTION of the wrong length, an identifier in the
    node's range that names no message, an extended-id MOTION, a remote (RTR) STOP and an
    error frame (a transient bit error, which changes no bus state)."""
    motion = can_id(Motion.MSG_ID, node)
    valid = Motion(1, Command.FWD, 10, 100).pack()
    return [
        can.Message(arbitration_id=motion, data=valid[:3], is_extended_id=False),
        can.Message(arbitration_id=can_id(UNUSED_MSG_ID, node), data=b"\0", is_extended_id=False),
        can.Message(arbitration_id=motion, data=valid, is_extended_id=True),
        can.Message(
            arbitration_id=can_id(Stop.MSG_ID, node), is_remote_frame=True, dlc=3,
            is_extended_id=False,
        ),
        can.Message(
            arbitration_id=_CAN_ERR_PROT, data=bytes([0, 0, 0x01, 0, 0, 0, 0, 0]),
            is_error_frame=True, is_extended_id=False,
        ),
    ]  # fmt: skip


#: A message id (CAN identifier bits 10..4) that the protocol leaves unused.
UNUSED_MSG_ID = 120


class _Flood:
    """A second CAN sender: lowest-priority (or malformed) frames at a fixed rate, own thread."""

    def __init__(self, config: FloodConfig, node: int) -> None:
        self.config = config
        self.stats = FloodStats()
        other = MAX_NODE if node != MAX_NODE else MAX_NODE - 1
        self.arbitration_id = (
            config.arbitration_id
            if config.arbitration_id is not None
            else can_id(FLOOD_MSG_ID, other)
        )
        self._malformed = malformed_frames(node) if config.malformed else []
        self._bus = can.Bus(
            interface=config.interface, channel=config.channel, **config.bus_options
        )
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="bench-flood", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def _run(self) -> None:
        rate = self.config.rate_hz
        burst_s = 0.005
        per_burst = max(1, round(rate * burst_s)) if rate > 0 else 1
        counter = 0
        next_burst = time.monotonic()
        while not self._stop.is_set():
            for _ in range(per_burst):
                counter += 1
                if self._malformed:
                    frame = self._malformed[counter % len(self._malformed)]
                else:
                    if self.config.arbitration_id is None:
                        data = ParamValue(0, ParamResult.OK, counter & 0x7FFFFFFF).pack()
                    else:
                        data = (counter & 0xFFFFFFFFFFFFFFFF).to_bytes(8, "little")
                    frame = can.Message(
                        arbitration_id=self.arbitration_id, data=data, is_extended_id=False
                    )
                try:
                    self._bus.send(frame, timeout=0.05)
                    self.stats.sent += 1
                except can.CanError:
                    self.stats.refused += 1
            if rate > 0:
                next_burst += per_burst / rate
                self._stop.wait(max(0.0, next_burst - time.monotonic()))

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=5.0)
        self._bus.shutdown()


class StopBench:
    """Runs the STOP bench over one transport; see the module docstring.

    Use as a context manager (or call :meth:`close`): the transport, the heartbeat
    thread and the flood are released however the run ends.
    """

    def __init__(self, config: BenchConfig, *, recorder: TrafficRecorder | None = None) -> None:
        """Args:
        recorder: traffic log of the bench's link (optional).

        Raises:
            TransportUrlError: the URL is malformed.
        """
        self.config = config
        self._rng = random.Random(config.seed)
        with url_errors(config.url):
            endpoint = open_endpoint(config.url, HOST, recorder=recorder)
        self._host = ProtocolHost(endpoint)
        self._stop = threading.Event()
        self._flood: _Flood | None = None
        self._seq = 0
        self._stop_id = 0
        self.medium = endpoint.medium

    # -- lifecycle ------------------------------------------------------------------------
    def close(self) -> None:
        """Stop every thread and close the link (idempotent)."""
        self._stop.set()
        if self._flood is not None:
            self._flood.close()
            self._flood = None
        self._host.close()

    def __enter__(self) -> StopBench:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    # -- helpers ----------------------------------------------------------------------------
    @contextlib.contextmanager
    def _errors(self, what: str) -> Iterator[None]:
        """The host's errors as the bench's: a write that failed is a
        :class:`TransportError`; an answer that did not come, or a link that failed while
        waiting, a :class:`BenchError`."""
        try:
            yield
        except NotReceivedError as exc:
            raise BenchError(f"no {what} within {self.config.timeout_s:g} s") from exc
        except LinkError as exc:
            failed = self._host.inbox.failure is not None
            raise (
                BenchError(f"link failed: {exc}") if failed else TransportError(str(exc))
            ) from exc

    def _expect(
        self, kind: type[M], where: Callable[[M], bool], *, since: int, what: str
    ) -> tuple[int, Received]:
        """The first ``kind`` message from position ``since`` for which ``where`` holds,
        with its position, within the bench's timeout.

        Raises:
            BenchError: none came, or the link failed.
        """
        with self._errors(what):
            found = self._host.find(kind, where, since=since, timeout_s=self.config.timeout_s)
            if found is None:
                raise NotReceivedError(what)
        return found

    def _next_seq(self) -> int:
        self._seq = self._seq % 0xFFFF + 1
        return self._seq

    def _next_stop_id(self) -> int:
        self._stop_id = self._stop_id % 0xFFFF + 1
        return self._stop_id

    def _motion(self, distance: int) -> tuple[int, Ack]:
        seq = self._next_seq()
        what = f"ACK of seq {seq}"
        with self._errors(what):
            _, (_, got), _ = self._host.request(
                Motion(seq, Command.FWD, self.config.speed, distance),
                Ack,
                lambda a: a.seq == seq,
                timeout_s=self.config.timeout_s,
                what=what,
            )
        ack: Ack = got.message  # type: ignore[assignment]
        return seq, ack

    def _send_stop(self, stop_id: int) -> tuple[float, tuple[int, Received], int]:
        """STOP ``stop_id``, repeated every STOP_REPEAT_MS until its STOP_ACK: the time
        of the first send, the STOP_ACK with its position, the repeats."""
        with self._errors("STOP_ACK"):
            return self._host.request(
                Stop(stop_id, StopSource.BENCH),
                StopAck,
                lambda a: a.stop_id == stop_id,
                every_s=_REPEAT_S,
                timeout_s=self.config.timeout_s,
            )

    # -- the run ----------------------------------------------------------------------------
    def _handshake(self) -> Ident:
        try:
            ident = self._host.handshake(timeout_s=self.config.timeout_s, every_s=HEARTBEAT_S)
        except NotReceivedError as exc:
            raise BenchError(
                f"no IDENT from {self.config.url} within {self.config.timeout_s:g} s: is a "
                "controller (or rover emulate) there, at the right baud rate or node id?"
            ) from exc
        mismatch = self._host.matches(ident)
        if mismatch:
            raise BenchError(f"{mismatch}: refusing to drive")
        return ident

    def _set_telemetry(self, hz: int) -> int | None:
        try:
            _, (_, got), _ = self._host.request(
                SetParam(Param.TELEMETRY_HZ, hz),
                ParamValue,
                lambda p: p.param == Param.TELEMETRY_HZ,
                timeout_s=self.config.timeout_s,
            )
        except NotReceivedError:
            got = None
        except LinkError as exc:
            raise BenchError(f"link failed: {exc}") from exc
        answer: ParamValue | None = None if got is None else got.message  # type: ignore[assignment]
        if answer is None or answer.result != ParamResult.OK:
            logger.warning("controller did not set TELEMETRY_HZ=%d (%s)", hz, answer)
            return None
        return int(answer.value)

    def _clear(self) -> str:
        with self._errors("CLEAR_ACK"):
            ack = self._host.clear_stop(
                self._next_stop_id(), every_s=_REPEAT_S, timeout_s=self.config.timeout_s
            )
        return ClearResult(ack.result).name

    def run(self, progress: Callable[[TrialResult], None] | None = None) -> BenchRun:
        """Handshake, set up the load, run every trial, restore the telemetry rate.

        Args:
            progress: called after each trial (e.g. to print a line).

        Raises:
            TransportError: the device or bus cannot be opened.
            BenchError: no handshake, protocol mismatch, or the link failed.
        """
        cfg = self.config
        started = time.monotonic()
        try:
            self._host.open()
        except OSError as exc:
            raise TransportError(f"cannot open {cfg.url}: {exc}") from exc
        ident = self._handshake()
        if self._clear() == "FAULT_PERSISTS":
            raise BenchError("the controller has an active fault (CLEAR_STOP: FAULT_PERSISTS)")
        rate = self._set_telemetry(cfg.telemetry_hz) if cfg.telemetry_hz else None
        node = int(getattr(self._host.endpoint, "node", 1))
        load = "motion queue full"
        if rate is not None:
            load += f", telemetry {rate} Hz (SET_PARAM)"
        if cfg.flood is not None:
            self._flood = _Flood(cfg.flood, node)
            self._flood.start()
            pace = f"{cfg.flood.rate_hz:g} frames/s" if cfg.flood.rate_hz else "back to back"
            what = (
                "malformed frames (bad length, unknown id, extended id, RTR, error frame)"
                if cfg.flood.malformed
                else f"0x{self._flood.arbitration_id:03X}"
            )
            load += (
                f", CAN flood {what} at {pace} from a second "
                f"sender on {cfg.flood.interface}:{cfg.flood.channel}"
            )
        trials: list[TrialResult] = []
        try:
            for number in range(1, cfg.trials + 1):
                result = self._trial(number)
                trials.append(result)
                if progress is not None:
                    progress(result)
        finally:
            flood_stats = None
            if self._flood is not None:
                self._flood.close()
                flood_stats = self._flood.stats
                self._flood = None
            if rate is not None:
                try:
                    self._set_telemetry(ENCODERS_RATE_HZ)
                except BridgeError as exc:
                    logger.warning("telemetry rate not restored: %s", exc)
        return BenchRun(
            config=cfg,
            trials=tuple(trials),
            medium=self.medium,
            ident=(
                f"firmware {ident.firmware_major}.{ident.firmware_minor}."
                f"{ident.firmware_patch}, protocol v{ident.protocol_version}, "
                f"boot nonce 0x{ident.boot_nonce:04X}"
            ),
            load=load,
            arbitration_note=_arbitration_note(self.medium, cfg),
            telemetry_hz_set=rate,
            flood=flood_stats,
            duration_s=time.monotonic() - started,
        )

    def _trial(self, number: int) -> TrialResult:
        cfg = self.config
        delay = self._rng.uniform(0.0, cfg.max_delay_s)
        stop_id = 0
        fields: dict[str, Any] = {
            "speed_mm_s": None,
            "queued": 0,
            "ack_ms": None,
            "stopped_ms": None,
            "zero_ms": None,
            "controller_duration_ms": None,
            "controller_distance_mm": None,
            "stop_repeats": 0,
            "purged": 0,
            "targets_zero": False,
            "latch_held": False,
            "clear_result": "",
            "resumed": False,
        }
        error = ""
        try:
            stop_id = self._stop_trial(delay, fields)
        except BenchError as exc:
            if self._host.inbox.failure is not None:
                raise
            error = str(exc)
            logger.warning("trial %d: %s", number, error)
            try:  # leave the controller stopped and unlatched for the next trial
                self._send_stop(self._next_stop_id())
                fields["clear_result"] = fields["clear_result"] or self._clear()
            except BenchError as again:
                logger.warning("trial %d: recovery failed: %s", number, again)
        return TrialResult(trial=number, stop_id=stop_id, delay_s=delay, error=error, **fields)

    def _stop_trial(self, delay: float, out: dict[str, Any]) -> int:
        mark = self._host.mark()
        queued: list[int] = []
        for _ in range(_MAX_FILL):
            seq, ack = self._motion(_LONG_STEP)
            if ack.result == AckResult.ACCEPTED:
                queued.append(seq)
                continue
            if ack.result == AckResult.QUEUE_FULL and queued:
                break
            raise BenchError(f"MOTION refused: {AckResult(ack.result).name}")
        out["queued"] = len(queued)
        self._expect(
            WheelSpeeds,
            lambda w: abs(w.left_mm_s + w.right_mm_s) / 2.0 >= _MOVING_MM_S,
            since=mark,
            what=f"wheels moving (WHEEL_SPEEDS >= {_MOVING_MM_S:g} mm/s)",
        )
        if delay > 0 and self._stop.wait(delay):  # the random moment of the STOP
            raise BenchError("bench closed")
        speeds = self._host.messages(WheelSpeeds, mark)
        if speeds:
            last = speeds[-1]
            out["speed_mm_s"] = (last.left_mm_s + last.right_mm_s) / 2.0
        stop_id = self._next_stop_id()
        since = self._host.mark()
        t0, (i_ack, ack_received), repeats = self._send_stop(stop_id)
        out["ack_ms"] = (ack_received.arrived - t0) * 1e3
        out["stop_repeats"] = repeats
        i_stopped, stopped_received = self._expect(
            Stopped, lambda s: s.stop_id == stop_id, since=since, what="STOPPED"
        )
        stopped: Stopped = stopped_received.message  # type: ignore[assignment]
        out["stopped_ms"] = (stopped_received.arrived - t0) * 1e3
        out["controller_duration_ms"] = stopped.duration_ms
        out["controller_distance_mm"] = stopped.distance_mm
        i_zero, zero = self._expect(
            WheelSpeeds,
            lambda w: w.left_mm_s == 0 and w.right_mm_s == 0,
            since=i_ack + 1,
            what="WHEEL_SPEEDS at zero",
        )
        out["zero_ms"] = (zero.arrived - t0) * 1e3
        judged = judged_wheel_speeds(
            self._host.indexed(WheelSpeeds, i_ack + 1),
            stopped_at=i_stopped,
            zero_at=i_zero,
            grace=1 if self.medium == "can" else 0,
        )
        out["targets_zero"] = bool(judged) and all(
            w.left_target_mm_s == 0 and w.right_target_mm_s == 0 for w in judged
        )
        out["purged"] = len(
            {
                s.seq
                for s in self._host.messages(Status, since)
                if s.seq in queued and s.state == StepState.ABORTED and s.reason == AbortReason.STOP
            }
        )
        _, ack = self._motion(100)
        out["latch_held"] = ack.result == AckResult.STOP_LATCHED
        out["clear_result"] = self._clear()
        seq, ack = self._motion(0)  # zero distance: accepted and done, no motion
        out["resumed"] = ack.result == AckResult.ACCEPTED
        if out["resumed"]:
            self._expect(
                Status,
                lambda s: s.seq == seq and s.state != StepState.STARTED,
                since=since,
                what="the end of the zero-distance step",
            )
        return stop_id


def judged_wheel_speeds(
    after_ack: Iterable[tuple[int, Received]], *, stopped_at: int, zero_at: int, grace: int
) -> list[WheelSpeeds]:
    """The WHEEL_SPEEDS a trial judges for zero targets after its STOP.

    Args:
        after_ack: (position, message) of what arrived after STOP_ACK, in arrival order;
            only WHEEL_SPEEDS count.
        stopped_at: STOPPED's position.
        zero_at: the position of the first WHEEL_SPEEDS after STOP_ACK at zero speed.
        grace: how many of the first are not judged: 1 on CAN, where the first may have
            been queued before the STOP; 0 on a serial line.

    Returns:
        Those up to STOPPED or the one at zero speed, whichever came later, so that at
        least one sent after the STOP is judged however slow the telemetry (at 20 Hz,
        as in the VM, none may fall between STOP_ACK and STOPPED), less the first
        ``grace``; when only the one at zero speed is left, that one (the wheels were
        moving before the STOP, so it was sent after it).
    """
    end = max(stopped_at, zero_at + 1)
    speeds = [m for i, r in after_ack if i < end and isinstance(m := r.message, WheelSpeeds)]
    return speeds[grace:] or speeds[-1:]


def _arbitration_note(medium: str, cfg: BenchConfig) -> str:
    if medium != "can":
        return (
            "serial: STOP goes out ahead of anything the host has queued; the controller "
            "purges its full motion queue"
        )
    interface, channel, _ = parse_can_url(cfg.url)
    if interface == "virtual":
        return (
            "python-can 'virtual' bus: no arbitration; frames are delivered in send order, "
            "so the flood adds queueing, not contention"
        )
    if interface == "socketcan" and channel.startswith("vcan"):
        return (
            "SocketCAN vcan: no arbitration (a software loopback); on a real bus with the "
            "flood from a second adapter, STOP must win arbitration"
        )
    return (
        "real CAN bus: the flood contends for the bus; it is true arbitration only when "
        "it comes from a second adapter (--flood-can), otherwise both share one "
        "controller's transmit queue"
    )
