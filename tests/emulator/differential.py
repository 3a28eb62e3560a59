"""Seeded random host traffic for the differential test of the two controller
implementations (Python model, C firmware core), run in lockstep on identical twins.

:func:`traffic` draws, tick by tick, what a host (well-behaved or not) sends: heartbeats
with silent spells long enough to trip the watchdog, matching and mismatched HELLOs,
MOTION steps with repeated seqs and out-of-limit fields, STOPs and CLEAR_STOPs with a
few stop_ids, SET_PARAMs (unknown parameters, values out of range), frames in the wrong
direction, corrupted serial bytes, and fault conditions raised and cleared (an
encoder dropout, which stops and latches; an IMU dropout, which only reports).
Corrupted bytes go through the front end's decoder as on a pty: what survives is
delivered, what does not is counted (``rx_error``), exactly as :mod:`emulator.engine`
does.
"""

from __future__ import annotations

import random
from collections.abc import Iterator
from dataclasses import dataclass

from emulator.controller import ControllerModel
from firmware_proto.wire.framing import FrameDecoder, FrameEncoder
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import (
    PROTOCOL_VERSION,
    SCHEMA_HASH,
    Ack,
    ClearStop,
    FaultCode,
    Hello,
    HostHeartbeat,
    Motion,
    SetParam,
    Stop,
)

__all__ = [
    "PLANT_TICKS",
    "TOLERANCE",
    "Event",
    "Sent",
    "compare",
    "run_lockstep",
    "traffic",
]

CURRENT_GEN = -1
"""A CLEAR_STOP's ``latch_gen`` in :func:`traffic` that :func:`run_lockstep` replaces with
the controller's own when it sends it (a host that knows the latch)."""

SENSORS = frozenset({"ENCODERS", "WHEEL_SPEEDS", "IMU", "POSE"})

TOLERANCE: dict[str, int] = {
    "STATUS.travel": 8,
    "PROGRESS.travel": 8,
    "STOPPED.distance_mm": 2,
    "STOPPED.duration_ms": 6,
    "ENCODERS.left": 40,
    "ENCODERS.right": 40,
    "WHEEL_SPEEDS.left_mm_s": 5,
    "WHEEL_SPEEDS.right_mm_s": 5,
    "WHEEL_SPEEDS.left_target_mm_s": 5,
    "WHEEL_SPEEDS.right_target_mm_s": 5,
    "IMU.yaw_rate_mrad_s": 10,
    "IMU.accel_x_mm_s2": 400,
    "IMU.accel_y_mm_s2": 400,
    "POSE.x_mm": 3,
    "POSE.y_mm": 3,
    "POSE.yaw_ddeg": 3,
}
"""The only fields allowed to differ, and by how much: what the plant measures (encoder
travel, wheel speeds, IMU, pose) and what is computed from it (a step's travel, a
stop's distance and duration). The C core's step profile is integer (um/s, encoder
counts); the Python model's is float (m/s, unrounded travel): on the same twin they
brake a few micrometres apart, so the twins drift apart by that much. Every other field
of every frame must be equal. IMU acceleration is a difference of velocities over one
physics step, so a micrometre-per-second difference in a braking wheel shows as tens
of mm/s^2 there."""

PLANT_TICKS = 6
"""Frames timed by the plant (a step's end, STOPPED at rest) may come this many ticks
apart; every other frame must come in the same tick."""


@dataclass(frozen=True)
class Event:
    """What the host does before one tick: messages, or raw (possibly corrupted) bytes."""

    tick: int
    messages: tuple[Message, ...] = ()
    raw: bytes = b""
    fault: tuple[int, bool] | None = None
    """A fault condition raised (``(code, True)``) or cleared (``(code, False)``), as the
    injector does for encoder, IMU and pose dropouts."""


def _motion(rng: random.Random) -> Motion:
    seq = rng.randrange(12)
    roll = rng.random()
    if roll < 0.7:
        return Motion(seq, rng.choice((1, 2, 3, 4)), rng.randrange(5, 40), rng.randrange(0, 900))
    if roll < 0.8:
        return Motion(seq, 0, rng.randrange(256), rng.randrange(65536))
    return Motion(seq, rng.randrange(8), rng.randrange(80), rng.randrange(35000))


def _message(rng: random.Random) -> Message:
    roll = rng.random()
    if roll < 0.4:
        return _motion(rng)
    if roll < 0.47:
        return Stop(rng.randrange(1, 5), rng.randrange(5))
    if roll < 0.6:
        # Most name the controller's generation as it is when sent (CURRENT_GEN); some
        # an old one, which must release nothing.
        return ClearStop(
            rng.randrange(1, 5), rng.choice((CURRENT_GEN, CURRENT_GEN, rng.randrange(8)))
        )
    if roll < 0.7:
        good = rng.random() < 0.8
        return Hello(PROTOCOL_VERSION, SCHEMA_HASH if good else rng.randrange(65536))
    if roll < 0.8:
        return SetParam(rng.randrange(7), rng.choice((0, 1, 5, 30, 60, 100, 250, 20000, -3)))
    if roll < 0.9:
        return Ack(rng.randrange(65536), 0, 0, 0)  # wrong direction: counted, ignored
    return HostHeartbeat(rng.randrange(65536))


def traffic(seed: int, ticks: int) -> Iterator[Event]:
    """Host events for ``ticks`` control ticks, reproducible from ``seed``."""
    rng = random.Random(seed)
    enc = FrameEncoder()
    silent_until = -1
    hb = 0
    for tick in range(ticks):
        msgs: list[Message] = []
        raw = b""
        if tick == 0:
            msgs.append(Hello(PROTOCOL_VERSION, SCHEMA_HASH))
        if tick > silent_until:
            if rng.random() < 0.002:
                silent_until = tick + rng.randrange(100, 600)  # may trip the watchdog
            elif tick % 50 == 0:
                hb += 1
                msgs.append(HostHeartbeat(hb & 0xFFFF))
            if rng.random() < 0.03:
                msgs.append(_message(rng))
            if rng.random() < 0.0005:
                # A burst of new steps: the queue fills.
                base = rng.randrange(100, 60000)
                msgs += [Motion(base + k, rng.choice((1, 3)), 20, 200) for k in range(10)]
            if rng.random() < 0.003:
                msg = _message(rng)
                if isinstance(msg, ClearStop) and msg.latch_gen == CURRENT_GEN:
                    msg = ClearStop(msg.stop_id, rng.randrange(256))
                data = bytearray(enc.encode(msg, strict=False))
                data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
                raw = bytes(data) + bytes(rng.randrange(256) for _ in range(rng.randrange(4)))
        fault = None
        if rng.random() < 0.0004:
            fault = (rng.choice((FaultCode.ENCODER, FaultCode.IMU)), rng.random() < 0.5)
        if msgs or raw or fault:
            yield Event(tick, tuple(msgs), raw, fault)


@dataclass(frozen=True)
class Sent:
    """A frame the controller sent: the tick, whether in answer to the host (``handle``)
    or in a tick, and the message."""

    tick: int
    answer: bool
    message: Message

    @property
    def plant_timed(self) -> bool:
        """Sent when the plant reached a state (a step ended, the wheels came to rest),
        not when the host or the clock asked."""
        name = self.message.NAME
        return not self.answer and (name in ("STOPPED", "STATUS"))


def run_lockstep(model: ControllerModel, events: list[Event], ticks: int) -> list[Sent]:
    """Run ``model`` for ``ticks`` ticks with ``events``; every message it sent (boot
    first, at tick -1)."""
    out: list[Sent] = [Sent(-1, True, m) for m in model.boot()]
    decoder = FrameDecoder()
    by_tick = {e.tick: e for e in events}
    for tick in range(ticks):
        event = by_tick.get(tick)
        if event is not None:
            for msg in event.messages:
                given = msg
                if isinstance(msg, ClearStop) and msg.latch_gen == CURRENT_GEN:
                    given = ClearStop(msg.stop_id, model.latch_gen)
                out += [Sent(tick, True, m) for m in model.handle(given)]
            if event.raw:
                before = decoder.counters.rejected
                for frame in decoder.feed(event.raw):
                    out += [Sent(tick, True, m) for m in model.handle(frame.message)]
                if decoder.counters.rejected != before:
                    model.rx_error(decoder.counters.rejected - before)
            if event.fault is not None:
                code, active = event.fault
                sent = (
                    model.raise_fault(code, condition=True)
                    if active
                    else model.clear_fault_condition(code)
                )
                out += [Sent(tick, True, m) for m in sent]
        out += [Sent(tick, False, m) for m in model.tick()]
    return out


def _near(plant: list[int], tick: int) -> bool:
    return any(abs(t - tick) <= PLANT_TICKS for t in plant)


def compare(python: list[Sent], c: list[Sent]) -> list[str]:
    """The differences between two runs beyond :data:`TOLERANCE` and
    :data:`PLANT_TICKS` (empty: equivalent).

    Three streams are compared frame by frame, in order: the sensor telemetry, the
    plant-timed frames, and all the others. A HEARTBEAT or PROGRESS sent within
    :data:`PLANT_TICKS` of a plant-timed frame may see a step still running in one run
    and ended in the other: there ``state``, ``queue_depth`` and the PROGRESS fields are
    not compared (the rest of it is).
    """
    problems: list[str] = []
    plant_ticks = [s.tick for s in (*python, *c) if s.plant_timed]

    def streams(run: list[Sent]) -> tuple[list[Sent], list[Sent], list[Sent]]:
        sensors = [s for s in run if s.message.NAME in SENSORS]
        plant = [s for s in run if s.plant_timed]
        rest = [s for s in run if s.message.NAME not in SENSORS and not s.plant_timed]
        return sensors, plant, rest

    for kind, a, b in zip(
        ("sensor", "plant-timed", "other"), streams(python), streams(c), strict=True
    ):
        if len(a) != len(b):
            problems.append(f"{kind}: {len(a)} frames from Python, {len(b)} from C")
        for x, y in zip(a, b, strict=False):  # a length difference is reported above
            mx, my = x.message, y.message
            where = f"{kind} tick {x.tick}/{y.tick}: {mx} | {my}"
            if mx.NAME != my.NAME:
                problems.append(f"{where}: different messages")
                break
            slack = PLANT_TICKS if x.plant_timed else 0
            if abs(x.tick - y.tick) > slack:
                problems.append(f"{where}: {abs(x.tick - y.tick)} ticks apart")
            loose: set[str] = set()
            if mx.NAME in ("HEARTBEAT", "PROGRESS") and _near(plant_ticks, x.tick):
                loose = {"state", "queue_depth", "ended_seq", "ended_state", "ended_reason"}
                loose |= {"ended_count", "travel"}
            dx, dy = mx.to_dict(), my.to_dict()
            for name, vx in dx.items():
                vy = dy[name]
                if name in loose:
                    continue
                limit = TOLERANCE.get(f"{mx.NAME}.{name}", 0)
                if abs(int(vx) - int(vy)) > limit:
                    problems.append(f"{where}: {name} differs by {abs(int(vx) - int(vy))}")
        if len(problems) > 20:
            break
    return problems
