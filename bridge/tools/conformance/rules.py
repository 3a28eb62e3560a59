"""The rules of docs/protocol.md, each played from the host side against a controller.

A rule is a function of a :class:`~bridge.tools.conformance.context.Context` registered with
:func:`rule`: it starts from a fresh session (the suite calls ``Context.prepare`` first),
sends frames, checks every answer, and returns a short note on success. It fails by
raising :class:`~bridge.errors.RuleFailedError` (through ``check``) or
:class:`~firmware_proto.linkio.errors.ExpectationError` (through the host's ``expect``
and ``absent``), and declines by raising :class:`~bridge.errors.RuleNotRunError` when
the device does not offer what it needs. :data:`RULES` holds them by id, in running
order, from the basics (handshake) to the disruptive (watchdog, faults, reboot).

Timeouts are generous: conformance is about what a controller answers and in which
order, not how fast. Motion (the ramp, braking, rest) is judged from the controller's
own reports against the rover description's limits, with margins for the plant and for
sampling. Every wait goes through the host's clock (:mod:`~bridge.tools.conformance.context`).
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TypeVar

from bridge.tools.conformance.context import REST_UNITS, Context, check
from bridge.tools.conformance.wirehost import SAMPLES
from firmware_proto.wire.faults import fault_bit
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import (
    CONTROLLER_HEARTBEAT_PERIOD_MS,
    ENCODERS_RATE_HZ,
    MOTION_QUEUE_DEPTH,
    PROTOCOL_VERSION,
    SCHEMA_HASH,
    AbortReason,
    Ack,
    AckField,
    AckResult,
    ClearAck,
    ClearResult,
    Command,
    ControllerState,
    Encoders,
    Fault,
    FaultCode,
    Heartbeat,
    Hello,
    HostHeartbeat,
    Ident,
    Motion,
    Param,
    ParamResult,
    PoseMsg,
    Progress,
    Status,
    StepState,
    Stop,
    StopAck,
    Stopped,
    StopSource,
    WheelSpeeds,
)

__all__ = ["RULES", "Rule", "rule"]

M = TypeVar("M", bound=Message)

RuleFunction = Callable[[Context], str]


@dataclass(frozen=True)
class Rule:
    """One rule of the suite.

    Attributes:
        id: short name (``stop``, ``watchdog``...), what ``--rule`` takes.
        section: the section of docs/protocol.md that states it.
        statement: what a conforming controller does, one sentence.
        needs: what the rule needs beyond a link (``control``, ``serial``), for ``--list``.
    """

    id: str
    section: str
    statement: str
    needs: str
    run: RuleFunction


RULES: dict[str, Rule] = {}
"""Every rule by id, in running order."""


def rule(rule_id: str, section: str, *, needs: str = "") -> Callable[[RuleFunction], RuleFunction]:
    """Register the decorated function as rule ``rule_id``; its docstring's first
    paragraph is the rule's statement."""

    def register(fn: RuleFunction) -> RuleFunction:
        if rule_id in RULES:
            raise ValueError(f"rule {rule_id!r} registered twice")
        doc = (fn.__doc__ or "").strip().split("\n\n")[0]
        RULES[rule_id] = Rule(rule_id, section, " ".join(doc.split()), needs, fn)
        return fn

    return register


# -- helpers ----------------------------------------------------------------------------

FWD = Command.FWD
_LONG = 30000
"""A step long enough to still be running when the rule interrupts it (1.3 m)."""
_GRACE_S = 0.05
"""Frames queued before a judged event may still cross it on the wire this long after it, s (a
paced serial line sends answers ahead of telemetry)."""
_REST_MM_S = 2
"""A measured wheel speed at or below this (mm/s, WHEEL_SPEEDS resolution 1) is rest."""


def _ack(ctx: Context, motion: Motion, *, unchecked: bool = False) -> Ack:
    host = ctx.host
    mark = host.send(motion, strict=not unchecked)
    seq = motion.seq
    return host.expect(Ack, lambda a: a.seq == seq, since=mark, what=f"ACK for seq {seq}")


def _expect_ack(ctx: Context, motion: Motion, result: int, field: int = AckField.NONE) -> Ack:
    ack = _ack(ctx, motion, unchecked=True)
    check(
        (ack.result, ack.field) == (result, field),
        f"{motion.describe()} answered {_name(AckResult, ack.result)}/{_name(AckField, ack.field)},"
        f" expected {_name(AckResult, result)}/{_name(AckField, field)}",
    )
    return ack


def _name(enum: type, value: int) -> str:
    try:
        return str(enum(value).name)
    except ValueError:
        return str(value)


def _started(ctx: Context, seq: int, since: int, timeout_s: float = 1.0) -> Status:
    return ctx.host.expect(
        Status,
        lambda s: s.seq == seq and s.state == StepState.STARTED,
        since=since,
        timeout_s=timeout_s,
        what=f"STATUS STARTED for seq {seq}",
    )


def _ended(ctx: Context, seq: int, since: int, timeout_s: float = 5.0) -> Status:
    return ctx.host.expect(
        Status,
        lambda s: s.seq == seq and s.state != StepState.STARTED,
        since=since,
        timeout_s=timeout_s,
        what=f"STATUS COMPLETED or ABORTED for seq {seq}",
    )


def _stopped(
    ctx: Context, stop_id: int, since: int, timeout_s: float = 3.0, what: str = ""
) -> Stopped:
    return ctx.host.expect(
        Stopped,
        lambda s: s.stop_id == stop_id,
        since=since,
        timeout_s=timeout_s,
        what=what or f"STOPPED {stop_id}",
    )


def _running_step(ctx: Context, command: int = FWD, speed: int = 60) -> tuple[int, int]:
    """A long step, accepted, started and under way (the encoders have counted 2 cm of
    it on each side, so a stop has something to brake); ``(seq, mark before it was
    sent)``."""
    host = ctx.host
    seq = ctx.seq()
    mark = host.mark()
    ack = _ack(ctx, Motion(seq, command, speed, _LONG))
    check(ack.result == AckResult.ACCEPTED, f"a valid step was refused: {ack.describe()}")
    _started(ctx, seq, mark)
    first = host.expect(Encoders, since=mark, what="ENCODERS during the step")
    host.expect(
        Encoders,
        lambda e: (
            abs(_delta24(first.left, e.left)) >= 460 and abs(_delta24(first.right, e.right)) >= 460
        ),
        since=mark,
        timeout_s=3.0,
        what="ENCODERS counting 460 units (2 cm) on each side into the step",
    )
    return seq, mark


def _encoder_speeds(ctx: Context, before: Encoders, after: Encoders) -> tuple[float, float]:
    """Each side's speed between two ENCODERS (by their t_ms), unsigned, m/s."""
    dt = _dt16_s(before.t_ms, after.t_ms)
    if dt <= 0:
        return 0.0, 0.0
    per_m = ctx.rover.drive.distance_units_per_m
    return (
        abs(_delta24(before.left, after.left)) / per_m / dt,
        abs(_delta24(before.right, after.right)) / per_m / dt,
    )


def _cruising(ctx: Context, since: int, speed: int, share: float = 0.9) -> float:
    """Wait for both sides to travel at ``share`` of the surface speed of ``speed``
    (either direction), by the ENCODERS (mandatory telemetry); the speed then, the mean
    of both sides, m/s."""
    want = share * ctx.rover.speed_to_mps(speed)
    previous: list[Encoders] = []
    found: list[float] = []

    def fast(e: Encoders) -> bool:
        if previous:
            left, right = _encoder_speeds(ctx, previous[0], e)
            if min(left, right) >= want:
                found.append((left + right) / 2)
                return True
        previous[:] = [e]
        return False

    ctx.host.expect(
        Encoders,
        fast,
        since=since,
        timeout_s=3.0,
        what=f"ENCODERS counting {want * 1000:.0f} mm/s or more on both sides (cruise)",
    )
    return found[0]


def _queue(ctx: Context, count: int, speed: int = 60) -> list[int]:
    """``count`` more long steps, each ACCEPTED; their seqs."""
    seqs = []
    for _ in range(count):
        seq = ctx.seq()
        ack = _ack(ctx, Motion(seq, FWD, speed, _LONG))
        check(ack.result == AckResult.ACCEPTED, f"a valid step was refused: {ack.describe()}")
        seqs.append(seq)
    return seqs


def _index(got: Sequence[Message], message: Message) -> int:
    """Where ``message`` (that very object) is in ``got``."""
    return next(i for i, m in enumerate(got) if m is message)


def _last_before(ctx: Context, kind: type[M], mark: int) -> M:
    """The last ``kind`` message received before position ``mark``."""
    items = ctx.host.inbox.indexed(max(0, mark - 500))
    found = [r.message for i, r in items if i < mark and isinstance(r.message, kind)]
    check(bool(found), f"no {kind.NAME} received before the STOP: nothing to judge it by")
    return found[-1]


def _latch(hb: Heartbeat) -> tuple[int, int, int, int]:
    return hb.stop_latched, hb.latch_stop, hb.latch_watchdog, hb.latch_fault


def _latch_text(hb: Heartbeat) -> str:
    return (
        f"stop_latched={hb.stop_latched} latch_stop={hb.latch_stop} "
        f"latch_watchdog={hb.latch_watchdog} latch_fault={hb.latch_fault} "
        f"fault_bits=0x{hb.fault_bits:02X} state={_name(ControllerState, hb.state)}"
    )


def _delta24(before: int, after: int) -> int:
    """Signed change of a 24-bit wrapping encoder count."""
    return ((after - before + (1 << 23)) % (1 << 24)) - (1 << 23)


def _dt16_s(before: int, after: int) -> float:
    """Seconds between two ``t_ms`` readings (wrapping every 65.536 s)."""
    return ((after - before) % (1 << 16)) / 1000.0


def _travel_mm(ctx: Context, before: Encoders, after: Encoders) -> float:
    """Mean of both sides' absolute travel between two ENCODERS, mm."""
    units = (abs(_delta24(before.left, after.left)) + abs(_delta24(before.right, after.right))) / 2
    return units / ctx.rover.drive.distance_units_per_m * 1000.0


# -- handshake and liveness ---------------------------------------------------------------


@rule("handshake", "Handshake")
def handshake(ctx: Context) -> str:
    """A matching HELLO is answered with IDENT carrying this protocol version and schema
    hash; a new session starts: HEARTBEAT handshake_ok 1 within one heartbeat period of
    the IDENT (by the controller's clock: before the ENCODERS of more than a period and a
    sample later), state IDLE, PROGRESS ended_count 0 with every other field 0."""
    host = ctx.host
    mark = host.send(Hello(PROTOCOL_VERSION, SCHEMA_HASH))
    got = host.find(Ident, since=mark)
    check(got is not None, "no IDENT in answer to HELLO within 1 s")
    assert got is not None
    ident = got[1].message
    assert isinstance(ident, Ident)
    check(
        (ident.protocol_version, ident.schema_hash) == (PROTOCOL_VERSION, SCHEMA_HASH),
        f"IDENT says v{ident.protocol_version}/0x{ident.schema_hash:04X}",
    )
    beat = host.find(Heartbeat, since=got[0])
    check(beat is not None, "no HEARTBEAT after IDENT within 1 s")
    assert beat is not None
    hb = beat[1].message
    assert isinstance(hb, Heartbeat)
    before_beat = [r.message for i, r in host.inbox.indexed(got[0] + 1) if i < beat[0]]
    samples = [m for m in before_beat if isinstance(m, Encoders)]
    if samples:
        late = _dt16_s(samples[0].t_ms, samples[-1].t_ms) * 1000.0
        most = CONTROLLER_HEARTBEAT_PERIOD_MS + 1000.0 / ENCODERS_RATE_HZ
        check(
            late <= most,
            f"the first HEARTBEAT of the session came after ENCODERS {late:.0f} ms of the "
            f"controller's clock into it: more than one period ({CONTROLLER_HEARTBEAT_PERIOD_MS}"
            " ms) after its IDENT",
        )
    check(bool(hb.handshake_ok), f"HEARTBEAT after a matching HELLO has handshake_ok 0: {hb}")
    check(hb.boot_nonce == ident.boot_nonce, "HEARTBEAT and IDENT disagree on the boot nonce")
    check(hb.state == ControllerState.IDLE, f"state {_name(ControllerState, hb.state)}, not IDLE")
    progress = host.expect(Progress, since=mark, what="PROGRESS")
    check(
        tuple(progress) == (0, 0, 0, 0, 0),
        f"PROGRESS of a new session must be all 0 (ended_count 0): {progress.describe()}",
    )
    return (
        f"firmware {ident.firmware_major}.{ident.firmware_minor}.{ident.firmware_patch}, "
        f"boot nonce 0x{ident.boot_nonce:04X}"
    )


@rule("heartbeat", "Watchdog and heartbeats")
def heartbeat(ctx: Context) -> str:
    """HEARTBEAT comes every CONTROLLER_HEARTBEAT_PERIOD_MS, each followed by PROGRESS;
    stop_latched is the OR of the latch bits; no IDENT comes without a HELLO."""
    host = ctx.host
    window_s = 1.0
    mark = host.mark()
    host.absent(Ident, since=mark, window_s=window_s, what="IDENT without a HELLO")
    got = host.received(mark)
    beats = [m for m in got if isinstance(m, Heartbeat)]
    expected = window_s * host.timeout_scale * 1000.0 / CONTROLLER_HEARTBEAT_PERIOD_MS
    check(
        0.5 * expected <= len(beats) <= 1.5 * expected + 1,
        f"{len(beats)} HEARTBEATs in {host.scaled(window_s):g} s, expected about {expected:g}",
    )
    for i, msg in enumerate(got[:-1]):
        if isinstance(msg, Heartbeat):
            after = next((m for m in got[i + 1 :] if not isinstance(m, SAMPLES)), None)
            check(
                after is None or isinstance(after, Progress),
                f"HEARTBEAT followed by {after.NAME if after else '-'}, not PROGRESS",
            )
    for hb in beats:
        check(
            hb.stop_latched == int(bool(hb.latch_stop or hb.latch_watchdog or hb.latch_fault)),
            f"stop_latched is not the OR of the latch bits: {_latch_text(hb)}",
        )
    return f"{len(beats)} heartbeats in {host.scaled(window_s):g} s"


@rule("telemetry", "Telemetry")
def telemetry(ctx: Context) -> str:
    """ENCODERS (mandatory) arrive at about ENCODERS_RATE_HZ; WHEEL_SPEEDS and IMU should;
    POSE is optional, and when sent its yaw is within +-180 deg."""
    host = ctx.host
    mark = host.mark()
    window_s = 1.0
    host.absent(Ident, since=mark, window_s=window_s, what="IDENT without a HELLO")
    got = host.received(mark)
    count = {kind.NAME: sum(isinstance(m, kind) for m in got) for kind in SAMPLES}
    expected = ENCODERS_RATE_HZ * window_s * host.timeout_scale
    check(
        count["ENCODERS"] >= 0.5 * expected,
        f"{count['ENCODERS']} ENCODERS in {host.scaled(window_s):g} s, expected about "
        f"{expected:g} (mandatory)",
    )
    for pose in (m for m in got if isinstance(m, PoseMsg)):
        check(-1800 <= pose.yaw_ddeg <= 1800, f"POSE yaw out of range: {pose.describe()}")
    missing = [name for name in ("WHEEL_SPEEDS", "IMU") if count[name] == 0]
    note = ", ".join(f"{n} {c}" for n, c in count.items())
    return note + (f"; should send {', '.join(missing)}" if missing else "")


@rule("samples-in-session", "Handshake")
def samples_in_session(ctx: Context) -> str:
    """No sensor sample (ENCODERS, WHEEL_SPEEDS, IMU, POSE) outside a session: none after
    the IDENT answering a mismatched HELLO; they start again after the IDENT answering a
    matching one."""
    host = ctx.host
    mark = host.send(Hello(PROTOCOL_VERSION, SCHEMA_HASH ^ 0xFFFF))
    got = host.find(Ident, since=mark)
    check(got is not None, "no IDENT in answer to a mismatched HELLO within 1 s")
    assert got is not None
    ended_at = got[1].arrived
    host.settle(0.6)
    mark = host.send(Hello(PROTOCOL_VERSION, SCHEMA_HASH))
    reply = host.find(Ident, since=mark)
    check(reply is not None, "no IDENT in answer to a matching HELLO within 1 s")
    assert reply is not None
    late = [
        r.message
        for i, r in host.inbox.indexed(got[0] + 1)
        if i < reply[0]
        and isinstance(r.message, SAMPLES)
        and r.arrived > ended_at + host.scaled(_GRACE_S)
    ]
    check(
        not late,
        f"{len(late)} sensor samples between the IDENT that ended the session (mismatched "
        f"HELLO) and the next session's, the first {late[0].describe() if late else ''}",
    )
    host.expect(Encoders, since=reply[0] + 1, what="ENCODERS once the session opened")
    return "none for 0.6 s without a session; back after IDENT"


@rule("hello-mismatch", "Handshake")
def hello_mismatch(ctx: Context) -> str:
    """A HELLO with another schema hash is answered with IDENT (the controller's own
    hash), closes the session (handshake_ok 0, state BOOT) and MOTION gets NOT_READY;
    a matching HELLO opens a session again."""
    host = ctx.host
    mark = host.send(Hello(PROTOCOL_VERSION, SCHEMA_HASH ^ 0xFFFF))
    ident = host.expect(Ident, since=mark, what="IDENT in answer to a mismatched HELLO")
    check(ident.schema_hash == SCHEMA_HASH, "IDENT must carry the controller's own schema hash")
    ctx.until("handshake_ok 0 and state BOOT", lambda hb: not hb.handshake_ok and hb.state == 0)
    _expect_ack(ctx, Motion(ctx.seq(), FWD, 10, 100), AckResult.NOT_READY)
    ctx.handshake()
    return "mismatch closes the session, a match reopens it"


@rule("mismatch-session", "Handshake")
def mismatch_session(ctx: Context) -> str:
    """A mismatched HELLO during a step ends the session as a new session would: STATUS
    ABORTED reason SESSION for the running step and each queued one in queue order,
    before its IDENT; no STOPPED and no latch; PROGRESS back to all 0."""
    host = ctx.host
    running, _ = _running_step(ctx)
    seqs = [running, *_queue(ctx, 2)]
    mark = host.send(Hello(PROTOCOL_VERSION, SCHEMA_HASH ^ 0xFFFF))
    ident = host.expect(Ident, since=mark, what="IDENT in answer to a mismatched HELLO")
    got = host.received(mark)
    ended = [m for m in got[: _index(got, ident)] if isinstance(m, Status)]
    check(
        [(s.seq, s.state, s.reason) for s in ended]
        == [(seq, StepState.ABORTED, AbortReason.SESSION) for seq in seqs],
        f"before IDENT: {[s.describe() for s in ended]}, expected ABORTED SESSION for "
        f"{seqs} in that order",
    )
    progress = host.expect(Progress, since=mark, what="PROGRESS after the mismatched HELLO")
    check(
        tuple(progress) == (0, 0, 0, 0, 0),
        f"PROGRESS after the session ended must be all 0: {progress.describe()}",
    )
    host.absent(Stopped, since=mark, window_s=1.0, what="STOPPED after a session ended")
    hb = host.heartbeat()
    check(
        not hb.stop_latched and not hb.handshake_ok and hb.state == ControllerState.BOOT,
        f"after the session ended: handshake_ok={hb.handshake_ok} {_latch_text(hb)}, "
        "expected BOOT, no latch",
    )
    return f"{len(seqs)} steps aborted (SESSION) before IDENT, no STOPPED, no latch"


@rule("boot-latch", "State machine")
def boot_latch(ctx: Context) -> str:
    """Without a session (BOOT), STOP latches (STOP_ACK STOP_LATCHED, STOPPED) and
    CLEAR_STOP releases it back to BOOT, not IDLE."""
    host = ctx.host
    host.send(Hello(PROTOCOL_VERSION, SCHEMA_HASH ^ 0xFFFF))
    ctx.until("state BOOT", lambda hb: hb.state == ControllerState.BOOT)
    stop_id = ctx.stop_id()
    mark = host.send(Stop(stop_id, StopSource.BENCH))
    ack = host.expect(StopAck, since=mark, what=f"STOP_ACK {stop_id}")
    check(
        (ack.stop_id, ack.state) == (stop_id, ControllerState.STOP_LATCHED),
        f"STOP in BOOT answered {ack.describe()}",
    )
    _stopped(ctx, stop_id, mark, timeout_s=1.0)
    ctx.clear(ClearResult.CLEARED)
    hb = host.heartbeat()
    check(
        hb.state == ControllerState.BOOT and not hb.stop_latched,
        f"after CLEARED without a session: {_latch_text(hb)}, expected BOOT, not latched",
    )
    return "latched and cleared in BOOT"


@rule("watchdog-unarmed", "Watchdog and heartbeats")
def watchdog_unarmed(ctx: Context) -> str:
    """Without a session (after a mismatched HELLO) the watchdog is disarmed: a silent
    host raises no WATCHDOG fault."""
    host = ctx.host
    watchdog_s = ctx.watchdog_ms() / 1000.0
    host.send(Hello(PROTOCOL_VERSION, SCHEMA_HASH ^ 0xFFFF))
    ctx.until("handshake_ok 0", lambda hb: not hb.handshake_ok)
    with host.silent():
        mark = host.mark()
        host.absent(
            Fault, lambda f: f.code == FaultCode.WATCHDOG, since=mark, window_s=3 * watchdog_s,
            what="WATCHDOG fault without a session",
        )  # fmt: skip
        hb = host.heartbeat()
    check(not hb.stop_latched, f"latched while the watchdog is disarmed: {_latch_text(hb)}")
    return f"silent {3 * watchdog_s:g} s without a session"


# -- motion ----------------------------------------------------------------------------


@rule("motion", "MOTION, acknowledgement and deduplication")
def motion(ctx: Context) -> str:
    """A valid MOTION is ACCEPTED (queue_depth 1), STARTED, then COMPLETED with travel
    equal to its distance; PROGRESS then names it with ended_count 1."""
    host = ctx.host
    seq, distance = ctx.seq(), 2300
    mark = host.mark()
    ack = _ack(ctx, Motion(seq, FWD, 30, distance))
    check(
        (ack.result, ack.queue_depth) == (AckResult.ACCEPTED, 1),
        f"expected ACCEPTED with queue_depth 1: {ack.describe()}",
    )
    _started(ctx, seq, mark)
    end = _ended(ctx, seq, mark)
    check(end.state == StepState.COMPLETED, f"the step ended {end.describe()}")
    check(
        abs(end.travel - distance) <= max(5, distance // 100),
        f"travel {end.travel} for a distance of {distance}",
    )
    progress = host.expect(
        Progress, lambda p: p.ended_count > 0, since=mark, what="PROGRESS naming the step"
    )
    check(
        (progress.ended_seq, progress.ended_state, progress.ended_count)
        == (seq, StepState.COMPLETED, 1),
        f"PROGRESS after one step: {progress.describe()}",
    )
    return f"travel {end.travel} of {distance}"


@rule("accel-ramp", "Units and drive")
def accel_ramp(ctx: Context) -> str:
    """A step from rest ramps each side's speed up at no more than the rover's
    acceleration limit a: the ENCODERS count no more than a * t^2 / 2 in the time t
    from the last sample before the step started, and the targets and measured speeds
    WHEEL_SPEEDS reports (when it is sent) rise by at most a * dt between two samples."""
    host = ctx.host
    a_mm_s2 = ctx.rover.drive.wheel_accel_limit_mps2 * 1000.0
    units_per_mm = ctx.rover.drive.distance_units_per_m / 1000.0
    seq = ctx.seq()
    mark = host.mark()
    check(_ack(ctx, Motion(seq, FWD, 60, 23000)).result == AckResult.ACCEPTED, "refused")
    started = _started(ctx, seq, mark)
    _cruising(ctx, mark, 60)
    got = host.received(mark)
    at = _index(got, started)
    base = _last_before(ctx, Encoders, mark + at)  # sampled before the step started
    worst_mm = 0.0
    for e in [m for m in got[at:] if isinstance(m, Encoders)][:15]:
        t = _dt16_s(base.t_ms, e.t_ms)
        limit_mm = a_mm_s2 * t * t / 2 * 1.25 + 2.0  # the plant and sampling
        units = max(abs(_delta24(base.left, e.left)), abs(_delta24(base.right, e.right)))
        travel_mm = units / units_per_mm
        worst_mm = max(worst_mm, travel_mm - a_mm_s2 * t * t / 2)
        check(
            travel_mm <= limit_mm,
            f"the encoders counted {travel_mm:.1f} mm in {t * 1000:.0f} ms from rest: more "
            f"than the acceleration limit {a_mm_s2 / 1000:g} m/s^2 allows ({limit_mm:.1f} mm)",
        )
    speeds = [m for m in got if isinstance(m, WheelSpeeds)]
    for before, after in itertools.pairwise(speeds):
        dt = _dt16_s(before.t_ms, after.t_ms)
        allowed = a_mm_s2 * dt * 1.25 + 6.0  # sampling and the plant's lag
        for name, v0, v1 in (
            ("left target", before.left_target_mm_s, after.left_target_mm_s),
            ("right target", before.right_target_mm_s, after.right_target_mm_s),
            ("left measured", before.left_mm_s, after.left_mm_s),
            ("right measured", before.right_mm_s, after.right_mm_s),
        ):
            check(
                v1 - v0 <= allowed,
                f"{name} speed rose {v1 - v0} mm/s in {dt * 1000:.0f} ms (t_ms {before.t_ms} -> "
                f"{after.t_ms}): more than the acceleration limit "
                f"{a_mm_s2 / 1000:g} m/s^2 allows ({allowed:.0f} mm/s)",
            )
    stop_id = ctx.stop_id()
    _stopped(ctx, stop_id, host.send(Stop(stop_id, StopSource.BENCH)))
    ctx.clear()
    checked = "ENCODERS" + (" and WHEEL_SPEEDS" if speeds else "")
    return f"{checked} within a = {a_mm_s2 / 1000:g} m/s^2 (worst {worst_mm:+.1f} mm)"


@rule("zero-step", "MOTION, acknowledgement and deduplication")
def zero_step(ctx: Context) -> str:
    """A step with speed 0 or distance 0 is accepted, STARTED and COMPLETED with travel
    0, and moves nothing."""
    notes = []
    for speed, distance in ((0, 1000), (30, 0)):
        seq = ctx.seq()
        mark = ctx.host.mark()
        ack = _ack(ctx, Motion(seq, FWD, speed, distance))
        check(ack.result == AckResult.ACCEPTED, f"refused: {ack.describe()}")
        _started(ctx, seq, mark)
        end = _ended(ctx, seq, mark, timeout_s=1.0)
        check(
            (end.state, end.travel) == (StepState.COMPLETED, 0),
            f"speed {speed} distance {distance} ended {end.describe()}",
        )
        notes.append(f"({speed}, {distance})")
    return "completed at once: " + " ".join(notes)


@rule("duplicate", "MOTION, acknowledgement and deduplication")
def duplicate(ctx: Context) -> str:
    """A retransmitted MOTION (same seq) is acknowledged DUPLICATE, during and after the
    step, and runs once."""
    host = ctx.host
    seq = ctx.seq()
    mark = host.mark()
    step = Motion(seq, FWD, 30, 1500)
    check(_ack(ctx, step).result == AckResult.ACCEPTED, "the step was refused")
    check(_ack(ctx, step).result == AckResult.DUPLICATE, "a retransmission was not DUPLICATE")
    _ended(ctx, seq, mark)
    after = host.mark()
    check(_ack(ctx, step).result == AckResult.DUPLICATE, "a late retransmission not DUPLICATE")
    host.absent(Status, lambda s: s.seq == seq, since=after, what=f"a second run of seq {seq}")
    starts = [m for m in host.received(mark) if isinstance(m, Status) and m.seq == seq]
    check(len(starts) == 2, f"seq {seq} reported {len(starts)} STATUS, expected 2")
    return "ran once, acknowledged three times"


@rule("ack-order", "MOTION, acknowledgement and deduplication")
def ack_order(ctx: Context) -> str:
    """The controller checks a MOTION in the documented order: session, duplicate,
    command, speed, distance, fault, latch, queue; a refused seq is not remembered."""
    seq = ctx.seq()
    _expect_ack(ctx, Motion(seq, 9, 10, 100), AckResult.OUT_OF_RANGE, AckField.COMMAND)
    _expect_ack(ctx, Motion(seq, FWD, 61, 30001), AckResult.OUT_OF_RANGE, AckField.SPEED)
    _expect_ack(ctx, Motion(seq, FWD, 10, 30001), AckResult.OUT_OF_RANGE, AckField.DISTANCE)
    # Refused, so not remembered: the same seq, now valid, is a new step (nothing to do).
    _expect_ack(ctx, Motion(seq, FWD, 0, 0), AckResult.ACCEPTED)
    # Duplicate before range: an accepted seq with a bad field is still a duplicate.
    _expect_ack(ctx, Motion(seq, FWD, 61, 0), AckResult.DUPLICATE)
    # Range before latch: a bad field is reported even while latched.
    stop_id = ctx.stop_id()
    mark = ctx.host.send(Stop(stop_id, StopSource.BENCH))
    ctx.host.expect(StopAck, lambda a: a.stop_id == stop_id, since=mark, what="STOP_ACK")
    _expect_ack(ctx, Motion(ctx.seq(), FWD, 61, 100), AckResult.OUT_OF_RANGE, AckField.SPEED)
    _expect_ack(ctx, Motion(ctx.seq(), FWD, 10, 100), AckResult.STOP_LATCHED)
    ctx.clear()
    return "command, speed, distance, duplicate, latch in order"


@rule("queue-full", "MOTION, acknowledgement and deduplication")
def queue_full(ctx: Context) -> str:
    """MOTION_QUEUE_DEPTH steps are accepted (queue_depth counting up), the next gets
    QUEUE_FULL; a STOP then aborts every one of them, reason STOP."""
    host = ctx.host
    seqs = [ctx.seq() for _ in range(MOTION_QUEUE_DEPTH)]
    for n, seq in enumerate(seqs, 1):
        ack = _ack(ctx, Motion(seq, FWD, 10, _LONG))
        check(
            (ack.result, ack.queue_depth) == (AckResult.ACCEPTED, n),
            f"step {n} of {MOTION_QUEUE_DEPTH}: {ack.describe()}",
        )
    extra = ctx.seq()
    _expect_ack(ctx, Motion(extra, FWD, 10, _LONG), AckResult.QUEUE_FULL)
    stop_id = ctx.stop_id()
    mark = host.send(Stop(stop_id, StopSource.BENCH))
    for seq in seqs:
        end = _ended(ctx, seq, mark)
        check(
            (end.state, end.reason) == (StepState.ABORTED, AbortReason.STOP),
            f"seq {seq} after STOP: {end.describe()}",
        )
    _stopped(ctx, stop_id, mark)
    ctx.clear()
    return f"{MOTION_QUEUE_DEPTH} queued, then QUEUE_FULL; all aborted by STOP"


# -- STOP --------------------------------------------------------------------------------


@rule("stop", "STOP semantics")
def stop(ctx: Context) -> str:
    """STOP is answered at once with STOP_ACK (before the aborted STATUS), aborts the
    step (reason STOP), reports one STOPPED, latches (latch_stop only) until CLEAR_STOP;
    a repeat is acknowledged again without a second STOPPED; MOTION meanwhile gets
    STOP_LATCHED; a second CLEAR_STOP gets NOT_LATCHED."""
    host = ctx.host
    seq, _ = _running_step(ctx)
    stop_id = ctx.stop_id()
    mark = host.send(Stop(stop_id, StopSource.BENCH))
    ack = host.expect(StopAck, since=mark, what="STOP_ACK")
    check(
        (ack.stop_id, ack.state) == (stop_id, ControllerState.STOP_LATCHED),
        f"STOP {stop_id} answered {ack.describe()}",
    )
    end = _ended(ctx, seq, mark)
    order = [m for m in host.received(mark) if isinstance(m, (StopAck, Status))]
    check(isinstance(order[0], StopAck), "the aborted STATUS came before STOP_ACK")
    check(
        (end.state, end.reason) == (StepState.ABORTED, AbortReason.STOP),
        f"the running step after STOP: {end.describe()}",
    )
    stopped = _stopped(ctx, stop_id, mark)
    hb = host.heartbeat()
    check(
        _latch(hb) == (1, 1, 0, 0) and hb.state == ControllerState.STOP_LATCHED,
        f"after STOP: {_latch_text(hb)}, expected latch_stop only, STOP_LATCHED",
    )
    again = host.send(Stop(stop_id, StopSource.BENCH))
    host.expect(StopAck, lambda a: a.stop_id == stop_id, since=again, what="STOP_ACK to the repeat")
    host.absent(
        Stopped, lambda s: s.stop_id == stop_id, since=again,
        what="second STOPPED for one stop_id",
    )  # fmt: skip
    _expect_ack(ctx, Motion(ctx.seq(), FWD, 10, 100), AckResult.STOP_LATCHED)
    ctx.clear(ClearResult.CLEARED)
    ctx.idle()
    ctx.clear(ClearResult.NOT_LATCHED)
    return f"stopped in {stopped.distance_mm} mm, {stopped.duration_ms} ms"


@rule("stop-new-id", "STOP semantics")
def stop_new_id(ctx: Context) -> str:
    """A STOP with a new stop_id while already latched and at rest gets its own STOPPED
    (distance 0)."""
    host = ctx.host
    first = ctx.stop_id()
    mark = host.send(Stop(first, StopSource.BENCH))
    _stopped(ctx, first, mark, timeout_s=1.0)
    second = ctx.stop_id()
    mark = host.send(Stop(second, StopSource.BENCH))
    stopped = _stopped(ctx, second, mark, timeout_s=1.0)
    check(stopped.distance_mm == 0, f"at rest, yet {stopped.describe()}")
    ctx.clear()
    return "one STOPPED per stop_id"


@rule("stopped-at-rest", "STOP semantics")
def stopped_at_rest(ctx: Context) -> str:
    """STOPPED comes only once the wheels are at rest, and measures a real stop: a STOP
    of a moving rover gets a STOPPED with a time and a distance above 0, its distance
    the ENCODERS' travel from the STOP to rest, and from then on the wheels are
    measured at rest (WHEEL_SPEEDS 0, ENCODERS still)."""
    host = ctx.host
    _, start = _running_step(ctx)
    cruise = _cruising(ctx, start, 60)
    stop_id = ctx.stop_id()
    mark = host.send(Stop(stop_id, StopSource.BENCH))
    at_stop = _last_before(ctx, Encoders, mark)
    stopped = _stopped(ctx, stop_id, mark)
    check(
        stopped.duration_ms > 0 and stopped.distance_mm > 0,
        f"a STOP at {cruise * 1000:.0f} mm/s answered {stopped.describe()}: no time and no "
        "distance to come to rest from a moving rover",
    )
    after = host.mark()
    host.settle(0.3)
    rest = host.received(after)
    speeds = [w for w in rest if isinstance(w, WheelSpeeds)]
    encoders = [e for e in rest if isinstance(e, Encoders)]
    check(bool(encoders), "no ENCODERS after STOPPED")
    moving = [w for w in speeds if max(abs(w.left_mm_s), abs(w.right_mm_s)) > _REST_MM_S]
    check(not moving, f"STOPPED came before rest: then {moving[0].describe() if moving else ''}")
    drift = max(
        max(abs(_delta24(encoders[0].left, e.left)), abs(_delta24(encoders[0].right, e.right)))
        for e in encoders
    )
    check(drift < REST_UNITS, f"the encoders still counted {drift} units after STOPPED")
    travel = _travel_mm(ctx, at_stop, encoders[0])
    # The last ENCODERS before the STOP is up to a sample period old: that much more.
    slack = ctx.rover.speed_to_mps(60) * 1000.0 / ENCODERS_RATE_HZ + 3.0
    check(
        stopped.distance_mm - 3.0 <= travel <= stopped.distance_mm + slack,
        f"STOPPED says {stopped.distance_mm} mm, the ENCODERS counted {travel:.1f} mm from "
        "the STOP to rest",
    )
    ctx.clear()
    return f"at rest after {stopped.distance_mm} mm, {stopped.duration_ms} ms"


@rule("braking", "STOP semantics")
def braking(ctx: Context) -> str:
    """A STOP brakes at the acceleration limit, not harder: from the speed measured when
    it arrives, STOPPED's distance and time are those of braking at the rover's limit a
    (v^2 / 2a and v / a, with margins for sampling and the plant)."""
    host = ctx.host
    a = ctx.rover.drive.wheel_accel_limit_mps2
    _, start = _running_step(ctx)
    v = _cruising(ctx, start, 60, share=0.97)  # the speed no longer changes
    stop_id = ctx.stop_id()
    mark = host.send(Stop(stop_id, StopSource.BENCH))
    stopped = _stopped(ctx, stop_id, mark)
    distance_mm, duration_ms = v * v / (2 * a) * 1000.0, v / a * 1000.0
    check(
        0.75 * distance_mm - 3.0 <= stopped.distance_mm <= 1.4 * distance_mm + 5.0,
        f"stopped in {stopped.distance_mm} mm from {v:.3f} m/s; braking at {a:g} m/s^2 takes "
        f"{distance_mm:.0f} mm",
    )
    check(
        0.75 * duration_ms - 5.0 <= stopped.duration_ms <= 1.4 * duration_ms + 40.0,
        f"stopped in {stopped.duration_ms} ms from {v:.3f} m/s; braking at {a:g} m/s^2 takes "
        f"{duration_ms:.0f} ms",
    )
    ctx.clear()
    return (
        f"{stopped.distance_mm} mm, {stopped.duration_ms} ms from {v:.3f} m/s "
        f"(at the limit: {distance_mm:.0f} mm, {duration_ms:.0f} ms)"
    )


@rule("stopped-distance", "STOP semantics")
def stopped_distance(ctx: Context) -> str:
    """STOPPED's distance is unsigned, the mean of both sides' absolute travel: a STOP
    during a spin (the sides turning opposite ways) reports what the wheels travelled,
    not their signed mean of about 0."""
    host = ctx.host
    _, start = _running_step(ctx, Command.LEFT)
    _cruising(ctx, start, 60)
    stop_id = ctx.stop_id()
    mark = host.send(Stop(stop_id, StopSource.BENCH))
    at_stop = _last_before(ctx, Encoders, mark)
    stopped = _stopped(ctx, stop_id, mark)
    after = host.expect(Encoders, since=host.mark(), what="ENCODERS after STOPPED")
    travel = _travel_mm(ctx, at_stop, after)
    slack = ctx.rover.speed_to_mps(60) * 1000.0 / ENCODERS_RATE_HZ + 3.0
    check(
        stopped.distance_mm - 3.0 <= travel <= stopped.distance_mm + slack,
        f"a STOP in a spin answered {stopped.describe()}; the wheels travelled "
        f"{travel:.1f} mm each (mean of |left| and |right|)",
    )
    ctx.clear()
    return f"spin stopped in {stopped.distance_mm} mm"


def _stop_then_clear_at_cruise(ctx: Context) -> tuple[int, int, StopAck, ClearAck]:
    """A step at cruise (speed 60), then a STOP and a CLEAR_STOP back to back, so that the
    CLEAR_STOP reaches the controller long before rest (a quarter of a second of braking)
    however slow the host is: ``(stop_id, mark before the STOP, its STOP_ACK, the
    CLEAR_ACK)``, whatever they say."""
    host = ctx.host
    _, start = _running_step(ctx)
    _cruising(ctx, start, 60)
    stop_id = ctx.stop_id()
    clear_id = ctx.stop_id()
    mark = host.send(Stop(stop_id, StopSource.BENCH))
    host.send(host.clear_stop_for(clear_id, ahead=1))  # after the STOP just sent
    ack = host.expect(StopAck, _acks(stop_id), since=mark, what="STOP_ACK")
    cleared = host.expect(
        ClearAck, lambda a: a.stop_id == clear_id, since=mark, what=f"CLEAR_ACK {clear_id}"
    )
    return stop_id, mark, ack, cleared


@rule("stopped-owed", "STOP semantics")
def stopped_owed(ctx: Context) -> str:
    """A STOPPED still owed survives a CLEAR_STOP that comes before rest: it comes, and a
    step sent meanwhile starts only after it; its stop_id, reported after the CLEARED it
    predates, is not remembered (a STOP with it is a new stop, with its own STOPPED)."""
    host = ctx.host
    stop_id, mark, _first, ack = _stop_then_clear_at_cruise(ctx)
    early = [m for m in host.received(mark) if isinstance(m, Stopped)]
    check(
        not early,
        f"STOPPED came before the CLEAR_ACK, {early[0].describe() if early else ''}: a rover "
        "moving at speed cannot be at rest that soon",
    )
    check(ack.result == ClearResult.CLEARED, f"CLEAR_STOP answered {ack.describe()}")
    seq = ctx.seq()
    step = Motion(seq, FWD, 30, 230)
    check(_ack(ctx, step).result == AckResult.ACCEPTED, "a step after CLEARED was refused")
    stopped = _stopped(ctx, stop_id, mark)
    started = _started(ctx, seq, mark, timeout_s=3.0)
    got = host.received(mark)
    check(
        _index(got, stopped) < _index(got, started),
        "the step sent after CLEARED started before the STOPPED owed (not from rest)",
    )
    _ended(ctx, seq, mark)
    again = host.send(Stop(stop_id, StopSource.BENCH))
    _stopped(ctx, stop_id, again, timeout_s=1.0)
    ctx.clear()
    return f"STOPPED {stop_id} after CLEARED ({stopped.distance_mm} mm), then the step"


@rule("stop-after-clear", "STOP semantics")
def stop_after_clear(ctx: Context) -> str:
    """A copy of a STOP that arrives after the CLEARED that released its latch, while its
    STOPPED is still owed, is a new cause of a new latch: its STOP_ACK names a new latch
    generation (so a clear naming the released one is answered LATCH_CHANGED and releases
    nothing) and it shares the STOPPED owed; a further copy is a repeat of that latch."""
    host = ctx.host
    stop_id, mark, first, cleared = _stop_then_clear_at_cruise(ctx)
    check(cleared.result == ClearResult.CLEARED, f"CLEAR_STOP answered {cleared.describe()}")
    gens = []
    for _copy in range(2):  # a copy that crossed the CLEAR_ACK, then a repeat of it
        sent = host.send(Stop(stop_id, StopSource.BENCH))
        gens.append(host.expect(StopAck, _acks(stop_id), since=sent, what="STOP_ACK").latch_gen)
    want = [(first.latch_gen + 1) & 0xFF] * 2
    check(
        gens == want,
        f"after CLEARED (generation {first.latch_gen}) the STOP's copies were acknowledged "
        f"with generations {gens}, expected {want}: the copy latches again, a new cause",
    )
    stale = ctx.clear_ack(ctx.stop_id(), latch_gen=first.latch_gen)
    check(
        stale.result == ClearResult.LATCH_CHANGED,
        f"a CLEAR_STOP naming the released generation {first.latch_gen} answered "
        f"{_name(ClearResult, stale.result)}, expected LATCH_CHANGED",
    )
    _stopped(ctx, stop_id, mark)
    ctx.clear()
    return f"the copy after CLEARED latched at generation {gens[0]}; a stale clear refused"


@rule("own-stops", "STOP semantics")
def own_stops(ctx: Context) -> str:
    """The controller's own stops (stop_id 0) are never taken for repeats: each MOTION
    STOP, also while latched and at rest, gets a STOPPED 0 of its own."""
    host = ctx.host
    for n in (1, 2):
        mark = host.mark()
        _expect_ack(ctx, Motion(ctx.seq(), Command.STOP, 0, 0), AckResult.ACCEPTED)
        _stopped(ctx, 0, mark, timeout_s=1.0, what=f"STOPPED 0 for MOTION STOP number {n}")
    ctx.clear()
    return "two MOTION STOPs, two STOPPED 0"


@rule("own-stops-share", "STOP semantics")
def own_stops_share(ctx: Context) -> str:
    """Own stops that come while a STOPPED 0 is still owed share it: two MOTION STOPs in
    a row during a step at cruise get one STOPPED 0, at rest, measured from the first."""
    host = ctx.host
    _, start = _running_step(ctx)
    _cruising(ctx, start, 60)
    mark = host.mark()
    _expect_ack(ctx, Motion(ctx.seq(), Command.STOP, 0, 0), AckResult.ACCEPTED)
    _expect_ack(ctx, Motion(ctx.seq(), Command.STOP, 0, 0), AckResult.ACCEPTED)
    first = _stopped(ctx, 0, mark, what="STOPPED 0 for the two MOTION STOPs")
    check(first.distance_mm > 0, f"{first.describe()}: the first stop braked from cruise")
    host.settle(0.3)
    got = [m for m in host.messages(Stopped, mark) if m.stop_id == 0]
    check(
        len(got) == 1,
        f"{len(got)} STOPPED 0 for two own stops while one was owed, expected one: "
        + ", ".join(m.describe() for m in got),
    )
    ctx.clear()
    return f"one STOPPED 0 for two own stops, {first.distance_mm} mm"


@rule("motion-stop", "STOP semantics")
def motion_stop(ctx: Context) -> str:
    """MOTION with command STOP stops whatever its speed and distance: ACK ACCEPTED, the
    running step aborted (reason STOP), STOPPED with stop_id 0, latch_stop; its repeat is
    DUPLICATE."""
    host = ctx.host
    seq, _ = _running_step(ctx)
    stop_seq = ctx.seq()
    mark = host.mark()
    # Speed and distance beyond their limits (inside the wire range): ignored for STOP.
    _expect_ack(ctx, Motion(stop_seq, Command.STOP, 255, 65535), AckResult.ACCEPTED)
    end = _ended(ctx, seq, mark)
    check(
        (end.state, end.reason) == (StepState.ABORTED, AbortReason.STOP),
        f"the running step after MOTION STOP: {end.describe()}",
    )
    _stopped(ctx, 0, mark)
    hb = host.heartbeat()
    check(_latch(hb) == (1, 1, 0, 0), f"after MOTION STOP: {_latch_text(hb)}")
    _expect_ack(ctx, Motion(stop_seq, Command.STOP, 0, 0), AckResult.DUPLICATE)
    ctx.clear()
    return "stopped, latched, deduplicated"


@rule("motion-stop-order", "STOP semantics")
def motion_stop_order(ctx: Context) -> str:
    """MOTION STOP's frames come in order: its ACK first, with queue_depth 0 (the queue
    after the purge), then STATUS ABORTED (reason STOP) of the running step and of each
    queued one in queue order, then STOPPED 0 at rest."""
    host = ctx.host
    running, _ = _running_step(ctx)
    seqs = [running, *_queue(ctx, 2)]
    stop_seq = ctx.seq()
    mark = host.send(Motion(stop_seq, Command.STOP, 0, 0))
    stopped = _stopped(ctx, 0, mark)
    got = host.received(mark)
    ack = next((m for m in got if isinstance(m, Ack) and m.seq == stop_seq), None)
    check(ack is not None, "no ACK for the MOTION STOP")
    assert ack is not None
    check(
        (ack.result, ack.queue_depth) == (AckResult.ACCEPTED, 0),
        f"MOTION STOP answered {ack.describe()}, expected ACCEPTED with queue_depth 0",
    )
    ended = [m for m in got if isinstance(m, Status) and m.state != StepState.STARTED]
    check(
        [(s.seq, s.state, s.reason) for s in ended]
        == [(seq, StepState.ABORTED, AbortReason.STOP) for seq in seqs],
        f"ended: {[s.describe() for s in ended]}, expected ABORTED STOP for {seqs} in order",
    )
    check(
        _index(got, ack) < _index(got, ended[0]) and _index(got, ended[-1]) < _index(got, stopped),
        "expected the ACK, then the aborted STATUS, then STOPPED 0: got "
        + ", ".join(m.NAME for m in got if isinstance(m, (Ack, Status, Stopped))),
    )
    ctx.clear()
    return f"ACK (queue 0), {len(seqs)} ABORTED in order, STOPPED 0"


@rule("session", "Handshake")
def session(ctx: Context) -> str:
    """A matching HELLO during a step aborts it (reason SESSION, before IDENT), brings
    no latch, restarts PROGRESS at ended_count 0 and forgets the old seqs."""
    host = ctx.host
    seq, _ = _running_step(ctx)
    mark = host.send(Hello(PROTOCOL_VERSION, SCHEMA_HASH))
    ident = host.expect(Ident, since=mark, what="IDENT")
    end = _ended(ctx, seq, mark)
    check(
        (end.state, end.reason) == (StepState.ABORTED, AbortReason.SESSION),
        f"the running step after HELLO: {end.describe()}",
    )
    got = host.received(mark)
    check(_index(got, end) < _index(got, ident), "the SESSION abort came after IDENT")
    progress = host.expect(Progress, since=mark, what="PROGRESS")
    check(progress.ended_count == 0, f"PROGRESS of the new session: {progress.describe()}")
    hb = host.heartbeat()
    check(not hb.stop_latched, f"a new session latched: {_latch_text(hb)}")
    _expect_ack(ctx, Motion(seq, FWD, 0, 0), AckResult.ACCEPTED)  # a new step, same seq
    return "aborted with SESSION, seqs forgotten"


# -- the latch ------------------------------------------------------------------------


@rule("clear-repeat", "Latch and faults")
def clear_repeat(ctx: Context) -> str:
    """A CLEAR_STOP that repeats the last request answered (its stop_id and latch_gen: a
    repeat that crossed its answer) gets the same answer and changes nothing: after
    CLEARED, without a latch it is CLEARED, not NOT_LATCHED, and a latch set since holds;
    a new request then clears it."""
    host = ctx.host
    stop_id = ctx.stop_id()
    mark = host.send(Stop(stop_id, StopSource.BENCH))
    host.expect(StopAck, lambda a: a.stop_id == stop_id, since=mark, what="STOP_ACK")
    first = ctx.clear_ack(ctx.stop_id())
    check(first.result == ClearResult.CLEARED, f"CLEAR_STOP answered {first.describe()}")
    request = ctx.last_clear
    assert request is not None
    repeat = ctx.send_clear(request)
    check(
        repeat.result == ClearResult.CLEARED,
        f"the repeat of {request.describe()} with nothing latched answered "
        f"{_name(ClearResult, repeat.result)}, expected CLEARED (a repeat of the last)",
    )
    again = ctx.stop_id()
    mark = host.send(Stop(again, StopSource.BENCH))
    host.expect(StopAck, lambda a: a.stop_id == again, since=mark, what="STOP_ACK")
    late = ctx.send_clear(request)
    check(
        late.result == ClearResult.CLEARED,
        f"a late repeat of {request.describe()} answered {_name(ClearResult, late.result)}",
    )
    hb = host.heartbeat()
    check(
        _latch(hb) == (1, 1, 0, 0),
        f"a repeated CLEAR_STOP released a latch set after its CLEARED: {_latch_text(hb)}",
    )
    _expect_ack(ctx, Motion(ctx.seq(), FWD, 10, 100), AckResult.STOP_LATCHED)
    ctx.clear(ClearResult.CLEARED)
    ctx.idle()
    return "repeats answered CLEARED, the latch held until a new request"


def _acks(stop_id: int) -> Callable[[StopAck], bool]:
    return lambda a: a.stop_id == stop_id


@rule("clear-generation", "Latch and faults")
def clear_generation(ctx: Context) -> str:
    """Every new latch cause raises latch_gen by one and a repeated STOP does not; STOP_ACK
    and HEARTBEAT name it. A CLEAR_STOP naming an older generation is answered
    LATCH_CHANGED and releases nothing; one naming the current generation is CLEARED."""
    host = ctx.host
    base = host.heartbeat().latch_gen
    gens = []
    for stop_id in (ctx.stop_id(), ctx.stop_id()):
        for copy in ("first", "repeat"):
            mark = host.send(Stop(stop_id, StopSource.BENCH))
            ack = host.expect(StopAck, _acks(stop_id), since=mark, what="STOP_ACK")
            gens.append((copy, ack.latch_gen))
    want = [("first", (base + 1) & 0xFF), ("repeat", (base + 1) & 0xFF)]
    want += [("first", (base + 2) & 0xFF), ("repeat", (base + 2) & 0xFF)]
    check(
        gens == want,
        f"STOP_ACK generations {gens} from {base}, expected {want}: a new STOP raises it by "
        "one, its repeat not",
    )
    hb = host.heartbeat()
    check(hb.latch_gen == (base + 2) & 0xFF, f"HEARTBEAT latch_gen {hb.latch_gen}")
    stale = ctx.clear_ack(ctx.stop_id(), latch_gen=(base + 1) & 0xFF)
    check(
        stale.result == ClearResult.LATCH_CHANGED,
        f"a CLEAR_STOP naming generation {(base + 1) & 0xFF} (the latch is at "
        f"{(base + 2) & 0xFF}) answered {_name(ClearResult, stale.result)}, expected "
        "LATCH_CHANGED",
    )
    hb = host.heartbeat()
    check(_latch(hb) == (1, 1, 0, 0), f"after LATCH_CHANGED: {_latch_text(hb)}, latch held")
    _expect_ack(ctx, Motion(ctx.seq(), FWD, 10, 100), AckResult.STOP_LATCHED)
    ok = ctx.clear_ack(ctx.stop_id(), latch_gen=(base + 2) & 0xFF)
    check(ok.result == ClearResult.CLEARED, f"the current generation: {ok.describe()}")
    ctx.idle()
    return "generations raised by new causes only; a stale clear released nothing"


# -- receive errors -------------------------------------------------------------------


@rule("wire-range", "Messages")
def wire_range(ctx: Context) -> str:
    """A frame with a field outside its wire range (STOP with stop_id 0) is dropped and
    counted in rx_errors, never obeyed."""
    host = ctx.host
    before = host.heartbeat()
    mark = host.send_raw(Stop.MSG_ID, bytes((0, 0, StopSource.BENCH)))  # stop_id 0
    host.absent(StopAck, since=mark, what="STOP_ACK to a STOP with stop_id 0")
    after = host.heartbeat()
    check(not after.stop_latched, f"a STOP with stop_id 0 was obeyed: {_latch_text(after)}")
    delta = (after.rx_errors - before.rx_errors) & 0xFFFF
    check(delta == 1, f"rx_errors went up by {delta}, expected 1")
    return "dropped and counted"


@rule("rx-errors", "Receive errors")
def rx_errors(ctx: Context) -> str:
    """Frames with an unknown id, a wrong length, (serial) a bad CRC, the wrong
    direction or a run of fewer than 4 decoded bytes between delimiters are dropped
    without an answer, each counted once in rx_errors."""
    host = ctx.host
    before = host.heartbeat()
    mark = host.send_raw(0x7E, b"\x01\x02")  # no message has id 126
    motion = Motion(ctx.seq(), FWD, 10, 100).pack()
    host.send_raw(Motion.MSG_ID, motion[:3])  # MOTION is 6 bytes
    sent = 2
    if host.kind == "serial":
        host.send_raw(HostHeartbeat.MSG_ID, HostHeartbeat(1).pack(), bad_crc=True)
        heartbeat_echo = before.pack()  # our controller's own HEARTBEAT, sent back to it
        host.send_raw(Heartbeat.MSG_ID, heartbeat_echo)
        host.write_bytes(b"\x00\x03\x41\x42\x00")  # valid COBS, 2 bytes: no id, seq, CRC
        sent += 3
    host.absent(Ack, since=mark, what="an ACK to a malformed MOTION")
    after = host.heartbeat()
    delta = (after.rx_errors - before.rx_errors) & 0xFFFF
    check(delta == sent, f"rx_errors went up by {delta} for {sent} bad frames")
    what = "unknown id, bad length" + (", bad CRC, wrong direction, short run" if sent == 5 else "")
    return f"{what}: {delta} counted"


@rule("param", "Parameters")
def param(ctx: Context) -> str:
    """SET_PARAM for an unknown parameter gets UNKNOWN_PARAM with value 0; a value out of
    range gets OUT_OF_RANGE with the value in force, which SET_PARAM then sets (OK)."""
    unknown = ctx.param(200, 5)
    check(
        (unknown.result, unknown.value) == (ParamResult.UNKNOWN_PARAM, 0),
        f"param 200: {unknown.describe()}",
    )
    notes = []
    for code, bad in (
        (Param.WATCHDOG_MS, 0),
        (Param.HEARTBEAT_HZ, 0),
        (Param.TELEMETRY_HZ, 10_000),
    ):
        refused = ctx.param(code, bad)
        check(
            refused.result == ParamResult.OUT_OF_RANGE,
            f"{Param(code).name}={bad}: {refused.describe()}",
        )
        kept = ctx.param(code, refused.value)
        check(
            (kept.result, kept.value) == (ParamResult.OK, refused.value),
            f"{Param(code).name}={refused.value} (in force): {kept.describe()}",
        )
        notes.append(f"{Param(code).name}={refused.value}")
    return ", ".join(notes)


# -- the watchdog, faults and reboots ------------------------------------------------------


def _trip(ctx: Context, since: int) -> Fault:
    """While the host is silent: the FAULT WATCHDOG active 1 from ``since`` on."""
    return ctx.host.expect(
        Fault,
        lambda f: f.code == FaultCode.WATCHDOG and f.active == 1,
        since=since,
        timeout_s=3 * ctx.watchdog_ms() / 1000,
        what="FAULT WATCHDOG active",
    )


def _watchdog_over(f: Message) -> bool:
    return isinstance(f, Fault) and f.code == FaultCode.WATCHDOG and f.active == 0


@rule("watchdog", "Watchdog and heartbeats")
def watchdog(ctx: Context) -> str:
    """A silent host trips the watchdog: FAULT WATCHDOG active 1, then the steps aborted
    with reason WATCHDOG, then STOPPED 0; state FAULT with latch_watchdog only; the next
    frame ends the condition (FAULT active 0, bit clear) but not the latch
    (FAULT_ACTIVE) until CLEAR_STOP."""
    host = ctx.host
    watchdog_ms = ctx.watchdog_ms()
    running, _ = _running_step(ctx)
    seqs = [running, *_queue(ctx, 1)]
    with host.silent():
        mark = host.mark()
        fault = _trip(ctx, mark)
        stopped = _stopped(ctx, 0, mark)
        hb = host.heartbeat()
    got = host.received(mark)
    ended = [m for m in got if isinstance(m, Status) and m.state != StepState.STARTED]
    check(
        [(s.seq, s.state, s.reason) for s in ended]
        == [(seq, StepState.ABORTED, AbortReason.WATCHDOG) for seq in seqs],
        f"the steps after the watchdog: {[s.describe() for s in ended]}",
    )
    check(
        _index(got, fault) < _index(got, ended[0])
        and _index(got, ended[-1]) < _index(got, stopped),
        "expected FAULT, then the aborted STATUS, then STOPPED 0: got "
        + ", ".join(m.NAME for m in got if isinstance(m, (Fault, Status, Stopped))),
    )
    check(fault.detail >= watchdog_ms, f"FAULT detail {fault.detail} ms < watchdog {watchdog_ms}")
    check(
        _latch(hb) == (1, 0, 1, 0)
        and hb.state == ControllerState.FAULT
        and bool(hb.fault_bits & fault_bit(FaultCode.WATCHDOG)),
        f"while silent: {_latch_text(hb)}, expected FAULT, latch_watchdog, WATCHDOG bit",
    )
    mark = host.send(HostHeartbeat(0))
    host.expect(
        Fault, _watchdog_over, since=mark, what="FAULT WATCHDOG active 0 after a valid frame"
    )
    hb = host.heartbeat()
    check(
        _latch(hb) == (1, 0, 1, 0)
        and hb.state == ControllerState.FAULT
        and not hb.fault_bits & fault_bit(FaultCode.WATCHDOG),
        f"frames again: {_latch_text(hb)}, expected the latch held, the condition gone",
    )
    _expect_ack(ctx, Motion(ctx.seq(), FWD, 10, 100), AckResult.FAULT_ACTIVE)
    ctx.clear(ClearResult.CLEARED)
    ctx.idle()
    return f"tripped after {fault.detail} ms, condition and latch apart"


@rule("watchdog-end", "Watchdog and heartbeats")
def watchdog_end(ctx: Context) -> str:
    """The frame that ends the watchdog condition is judged with the condition gone: a
    CLEAR_STOP as the first frame after a trip gets FAULT WATCHDOG active 0, then
    CLEAR_ACK CLEARED (not FAULT_PERSISTS); a STOP as the first frame gets its STOP_ACK
    first, then FAULT active 0."""
    host = ctx.host
    with host.silent():
        start = host.mark()
        _trip(ctx, start)
        ack = ctx.clear_ack(ctx.stop_id())
    got = host.received(start)
    over = next((m for m in got if _watchdog_over(m)), None)
    check(over is not None, "no FAULT WATCHDOG active 0 after the first frame")
    assert over is not None
    check(
        _index(got, over) < _index(got, ack),
        "CLEAR_ACK came before FAULT WATCHDOG active 0: the CLEAR_STOP was judged with the "
        "condition still on",
    )
    check(
        ack.result == ClearResult.CLEARED,
        f"the first frame after a trip, a CLEAR_STOP, answered "
        f"{_name(ClearResult, ack.result)}, expected CLEARED (judged after the condition ends)",
    )
    ctx.idle()
    with host.silent():
        _trip(ctx, host.mark())
        stop_id = ctx.stop_id()
        mark = host.send(Stop(stop_id, StopSource.BENCH))
        stop_ack = host.expect(StopAck, since=mark, what="STOP_ACK")
        ended = host.expect(Fault, _watchdog_over, since=mark, what="FAULT WATCHDOG active 0")
    got = host.received(mark)
    check(
        _index(got, stop_ack) < _index(got, ended),
        "FAULT WATCHDOG active 0 came before the STOP_ACK of the STOP that ended it",
    )
    ctx.clear()
    return "CLEAR_STOP after a trip CLEARED; STOP_ACK before FAULT 0"


@rule("fault-detail", "Latch and faults")
def fault_detail(ctx: Context) -> str:
    """FAULT carries its detail with active 1 (WATCHDOG: ms since the last valid frame,
    at least WATCHDOG_MS) and detail 0 with active 0, for every code (with the control
    port: ENCODER too)."""
    host = ctx.host
    watchdog_ms = ctx.watchdog_ms()
    with host.silent():
        fault = _trip(ctx, host.mark())
        mark = host.send(HostHeartbeat(0))
    over = host.expect(Fault, _watchdog_over, since=mark, what="FAULT WATCHDOG active 0")
    most = watchdog_ms + host.scaled(3 * CONTROLLER_HEARTBEAT_PERIOD_MS)
    check(
        watchdog_ms <= fault.detail <= most,
        f"FAULT WATCHDOG active 1 detail {fault.detail} ms, watchdog {watchdog_ms} ms",
    )
    check(over.detail == 0, f"FAULT WATCHDOG active 0 with detail {over.detail}, expected 0")
    notes = ["WATCHDOG"]
    if ctx.control is not None:
        mark = host.mark()
        ctx.control.inject("encoder-dropout:left")
        try:
            host.expect(
                Fault, lambda f: f.code == FaultCode.ENCODER and f.active == 1, since=mark,
                what="FAULT ENCODER active 1",
            )  # fmt: skip
        finally:
            mark = host.mark()
            ctx.control.inject("clear:encoder-dropout")
        gone = host.expect(
            Fault, lambda f: f.code == FaultCode.ENCODER and f.active == 0, since=mark,
            what="FAULT ENCODER active 0",
        )  # fmt: skip
        check(gone.detail == 0, f"FAULT ENCODER active 0 with detail {gone.detail}, expected 0")
        notes.append("ENCODER")
    ctx.clear()
    return f"detail 0 with active 0: {', '.join(notes)}"


@rule("fault-persists", "Latch and faults", needs="control")
def fault_persists(ctx: Context) -> str:
    """A stopping fault whose condition persists (ENCODER) latches (latch_fault, state
    FAULT, its bit set); CLEAR_STOP gets FAULT_PERSISTS while it lasts; when it goes
    (FAULT active 0, bit clear) the latch holds until CLEAR_STOP gets CLEARED."""
    control = ctx.require_control("raise and clear a fault (encoder-dropout)")
    host = ctx.host
    mark = host.mark()
    control.inject("encoder-dropout:left")
    try:
        host.expect(
            Fault, lambda f: f.code == FaultCode.ENCODER and f.active == 1, since=mark,
            what="FAULT ENCODER active 1",
        )  # fmt: skip
        ctx.until(
            "latch_fault, ENCODER bit, state FAULT",
            lambda hb: (
                _latch(hb) == (1, 0, 0, 1)
                and bool(hb.fault_bits & fault_bit(FaultCode.ENCODER))
                and hb.state == ControllerState.FAULT
            ),
        )
        ctx.clear(ClearResult.FAULT_PERSISTS)
    finally:
        mark = host.mark()
        control.inject("clear:encoder-dropout")
    host.expect(
        Fault, lambda f: f.code == FaultCode.ENCODER and f.active == 0, since=mark,
        what="FAULT ENCODER active 0",
    )  # fmt: skip
    hb = host.heartbeat()
    check(
        _latch(hb) == (1, 0, 0, 1) and not hb.fault_bits & fault_bit(FaultCode.ENCODER),
        f"condition gone: {_latch_text(hb)}, expected the latch held, the bit clear",
    )
    ctx.clear(ClearResult.CLEARED)
    ctx.idle()
    return "FAULT_PERSISTS, then CLEARED once the condition went"


@rule("clear-refused-repeat", "Latch and faults", needs="control")
def clear_refused_repeat(ctx: Context) -> str:
    """A refused clear never releases later: a repeat of a CLEAR_STOP answered
    FAULT_PERSISTS gets FAULT_PERSISTS again after the condition has gone, and the latch
    holds; a new request then clears it. A stopping FAULT active 1 names the generation
    it raised."""
    control = ctx.require_control("raise and clear a fault (encoder-dropout)")
    host = ctx.host
    base = host.heartbeat().latch_gen
    mark = host.mark()
    control.inject("encoder-dropout:left")
    try:
        raised = host.expect(
            Fault, lambda f: f.code == FaultCode.ENCODER and f.active == 1, since=mark,
            what="FAULT ENCODER active 1",
        )  # fmt: skip
        check(
            raised.latch_gen == (base + 1) & 0xFF,
            f"{raised.describe()} after generation {base}: expected {(base + 1) & 0xFF}",
        )
        ctx.until("latch_fault", lambda hb: _latch(hb) == (1, 0, 0, 1))
        refused = ctx.clear_ack(ctx.stop_id())
        check(refused.result == ClearResult.FAULT_PERSISTS, f"{refused.describe()}")
        request = ctx.last_clear
        assert request is not None
    finally:
        mark = host.mark()
        control.inject("clear:encoder-dropout")
    host.expect(
        Fault, lambda f: f.code == FaultCode.ENCODER and f.active == 0, since=mark,
        what="FAULT ENCODER active 0",
    )  # fmt: skip
    again = ctx.send_clear(request)
    check(
        again.result == ClearResult.FAULT_PERSISTS,
        f"the repeat of {request.describe()}, refused FAULT_PERSISTS, answered "
        f"{_name(ClearResult, again.result)} once the condition had gone: a refused clear "
        "must not release later",
    )
    hb = host.heartbeat()
    check(_latch(hb) == (1, 0, 0, 1), f"after the repeat: {_latch_text(hb)}, latch held")
    ctx.clear(ClearResult.CLEARED)
    ctx.idle()
    return "the refused request stayed refused; a new one cleared"


@rule("encoder-resume", "Telemetry", needs="control")
def encoder_resume(ctx: Context) -> str:
    """During an ENCODER fault the failed side repeats its last good count; when the
    condition ends it reports its true count since boot again: after a dropout of the
    left encoder while a straight step brakes, both sides show the same travel."""
    control = ctx.require_control("raise and clear a fault (encoder-dropout)")
    host = ctx.host
    _, start = _running_step(ctx)
    before = _last_before(ctx, Encoders, start)
    _cruising(ctx, start, 60)
    mark = host.mark()
    control.inject("encoder-dropout:left")
    try:
        _stopped(ctx, 0, mark, what="STOPPED 0 after the ENCODER fault")
        host.settle(0.1)
    finally:
        mark = host.mark()
        control.inject("clear:encoder-dropout")
    host.expect(
        Fault, lambda f: f.code == FaultCode.ENCODER and f.active == 0, since=mark,
        what="FAULT ENCODER active 0",
    )  # fmt: skip
    after = host.expect(Encoders, since=host.mark(), what="ENCODERS after the fault")
    left, right = _delta24(before.left, after.left), _delta24(before.right, after.right)
    check(
        abs(left - right) <= max(120, abs(right) // 20),
        f"after the dropout the left side counted {left} units, the right {right}: the "
        "left must report its true count again, not go on from the value it held",
    )
    ctx.clear()
    return f"both sides {right} units after the fault"


@rule("fault-order", "Latch and faults", needs="control")
def fault_order(ctx: Context) -> str:
    """A stopping fault's frames come in order: FAULT active 1 first, then STATUS
    ABORTED (reason FAULT) of the running step and of each queued one in queue order,
    then STOPPED 0 at rest."""
    control = ctx.require_control("raise a stopping fault (encoder-dropout)")
    host = ctx.host
    running, _ = _running_step(ctx)
    seqs = [running, *_queue(ctx, 2)]
    mark = host.mark()
    control.inject("encoder-dropout:left")
    try:
        stopped = _stopped(ctx, 0, mark)
    finally:
        control.inject("clear:encoder-dropout")
    got = host.received(mark)
    fault = next((m for m in got if isinstance(m, Fault) and m.active == 1), None)
    check(fault is not None and fault.code == FaultCode.ENCODER, "no FAULT ENCODER active 1")
    assert fault is not None
    ended = [m for m in got if isinstance(m, Status) and m.state != StepState.STARTED]
    check(
        [(s.seq, s.state, s.reason) for s in ended]
        == [(seq, StepState.ABORTED, AbortReason.FAULT) for seq in seqs],
        f"ended: {[s.describe() for s in ended]}, expected ABORTED FAULT for {seqs} in order",
    )
    check(
        _index(got, fault) < _index(got, ended[0])
        and _index(got, ended[-1]) < _index(got, stopped),
        "expected FAULT, then the aborted STATUS, then STOPPED 0: got "
        + ", ".join(m.NAME for m in got if isinstance(m, (Fault, Status, Stopped))),
    )
    ctx.clear()
    return f"FAULT, {len(seqs)} ABORTED in order, STOPPED 0"


def _locked_wheel_step(ctx: Context, control_what: str, speed: int, distance: int) -> str:
    """A step against a locked right wheel: aborted (STALL), STALL_RIGHT whose detail is
    that side's distance still to go, STOPPED 0, then FAULT active 0; latch_fault."""
    control = ctx.require_control(control_what)
    host = ctx.host
    control.inject("stall:right")
    try:
        seq = ctx.seq()
        mark = host.mark()
        check(_ack(ctx, Motion(seq, FWD, speed, distance)).result == AckResult.ACCEPTED, "refused")
        end = _ended(ctx, seq, mark, timeout_s=5.0)
        check(
            (end.state, end.reason) == (StepState.ABORTED, AbortReason.STALL),
            f"the step at speed {speed} on a locked wheel: {end.describe()}",
        )
        fault = host.expect(
            Fault, lambda f: f.code == FaultCode.STALL_RIGHT and f.active == 1, since=mark,
            what="FAULT STALL_RIGHT active 1",
        )  # fmt: skip
        check(
            distance - 100 <= fault.detail <= distance,
            f"STALL_RIGHT detail {fault.detail}: the locked side's distance to go is about "
            f"{distance}",
        )
        stopped = _stopped(ctx, 0, mark)
        over = host.expect(
            Fault, lambda f: f.code == FaultCode.STALL_RIGHT and f.active == 0, since=mark,
            what="FAULT STALL_RIGHT active 0 at rest",
        )  # fmt: skip
        got = host.received(mark)
        check(_index(got, stopped) < _index(got, over), "FAULT active 0 came before STOPPED")
        hb = host.heartbeat()
        check(
            _latch(hb) == (1, 0, 0, 1) and hb.fault_bits == 0,
            f"after the stall: {_latch_text(hb)}, expected latch_fault, no condition",
        )
    finally:
        control.inject("clear:stall")
    ctx.clear(ClearResult.CLEARED)
    ctx.idle()
    return f"speed {speed}: aborted, detail {fault.detail}, latched, condition over at rest"


@rule("stall", "Latch and faults", needs="control")
def stall(ctx: Context) -> str:
    """A locked wheel aborts the step (reason STALL) and raises STALL_*, whose detail is
    that side's distance still to go; the stall is an event: FAULT active 0 follows
    STOPPED; latch_fault holds until CLEAR_STOP."""
    return _locked_wheel_step(ctx, "lock a wheel (stall:right)", 30, 23000)


@rule("stall-speed-1", "MOTION, acknowledgement and deduplication", needs="control")
def stall_speed_1(ctx: Context) -> str:
    """Every step is watched for a stall, down to speed 1: a step at speed 1 against a
    locked wheel is aborted (reason STALL) as any other."""
    return _locked_wheel_step(ctx, "lock a wheel (stall:right)", 1, 2300)


@rule("reboot", "Handshake", needs="control")
def reboot(ctx: Context) -> str:
    """After a reboot the controller sends IDENT with a new boot nonce; it is in BOOT with
    no session and no latch, and sends no sensor samples until the IDENT answering a
    HELLO, after which its encoder counts and its clock t_ms start again near 0; its
    HEARTBEATs come every period from boot (by t_ms: as many as t_ms says, the first
    within a period of the IDENT)."""
    control = ctx.require_control("reboot the controller")
    host = ctx.host
    old = host.heartbeat().boot_nonce
    mark = host.mark()
    control.inject("reboot")
    booted = host.find(Ident, since=mark, timeout_s=3.0)
    check(booted is not None, "no IDENT after the reboot within 3 s")
    assert booted is not None
    ident, boot_at = booted[1].message, booted[1].arrived
    assert isinstance(ident, Ident)
    check(ident.boot_nonce != old, f"the boot nonce did not change (0x{old:04X})")
    beat = host.find(Heartbeat, lambda hb: hb.boot_nonce == ident.boot_nonce, since=booted[0])
    check(beat is not None, "no HEARTBEAT with the new nonce within 1 s")
    assert beat is not None
    hb = beat[1].message
    assert isinstance(hb, Heartbeat)
    check(
        hb.state == ControllerState.BOOT and not hb.handshake_ok and not hb.stop_latched,
        f"after the reboot: handshake_ok={hb.handshake_ok} {_latch_text(hb)}",
    )
    host.settle(0.3)
    samples = [
        r.message
        for r in host.inbox.items(booted[0] + 1)
        if isinstance(r.message, SAMPLES) and r.arrived > boot_at + host.scaled(_GRACE_S)
    ]
    check(not samples, f"a sensor sample before any HELLO: {samples[0] if samples else ''}")
    hello = host.send(Hello(PROTOCOL_VERSION, SCHEMA_HASH))
    reply = host.find(Ident, since=hello)
    check(reply is not None, "no IDENT in answer to HELLO within 1 s")
    assert reply is not None
    found = host.find(Encoders, since=reply[0] + 1)
    check(found is not None, "no ENCODERS within 1 s of the session's IDENT")
    assert found is not None
    first = found[1].message
    assert isinstance(first, Encoders)
    check(
        abs(first.left) < 1000 and abs(first.right) < 1000,
        f"the first ENCODERS of the new boot: {first.describe()}, expected counts near 0",
    )
    # The controller's own clock against its own heartbeats, both from boot: a count the
    # host's scheduling cannot disturb (every frame sent before the ENCODERS is before it).
    beats = sum(
        1
        for i, r in host.inbox.indexed(booted[0] + 1)
        if i < found[0]
        and isinstance(r.message, Heartbeat)
        and r.message.boot_nonce == ident.boot_nonce
    )
    period = CONTROLLER_HEARTBEAT_PERIOD_MS
    check(
        first.t_ms <= (beats + 1) * period + 1000 // ENCODERS_RATE_HZ,
        f"the first ENCODERS of the new boot says t_ms {first.t_ms} after {beats} "
        f"HEARTBEATs of that boot ({period} ms apart): its clock did not restart",
    )
    check(
        beats >= first.t_ms // period - 1,
        f"only {beats} HEARTBEATs of the new boot before t_ms {first.t_ms}: the first came "
        f"later than one period ({period} ms) after boot",
    )
    return (
        f"boot nonce 0x{old:04X} -> 0x{ident.boot_nonce:04X}, t_ms {first.t_ms} after "
        f"{beats} heartbeats"
    )


@rule("seq-restart", "Serial framing", needs="control, serial")
def seq_restart(ctx: Context) -> str:
    """The serial frame counter restarts at 0 at every boot: the boot IDENT has seq 0 and
    the frames after it count on from there."""
    ctx.require_serial("CAN frames carry no frame counter")
    control = ctx.require_control("reboot the controller")
    host = ctx.host
    mark = host.mark()
    control.inject("reboot")
    booted = host.find(Ident, since=mark, timeout_s=3.0)
    check(booted is not None, "no IDENT after the reboot within 3 s")
    assert booted is not None
    check(
        booted[1].seq == 0,
        f"the boot IDENT came with frame counter {booted[1].seq}, expected 0",
    )
    host.expect(Heartbeat, since=booted[0] + 1, what="HEARTBEAT after the boot IDENT")
    after = [r.seq for r in host.inbox.items(booted[0] + 1)][:3]
    check(
        after == list(range(1, len(after) + 1)),
        f"the frames after the boot IDENT came with counters {after}, expected 1, 2, ...",
    )
    ctx.handshake()
    return f"IDENT seq 0, then {after}"
