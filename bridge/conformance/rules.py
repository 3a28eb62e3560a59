"""The rules of docs/protocol.md, each played from the host side against a controller.

A rule is a function of a :class:`~bridge.conformance.context.Context` registered with
:func:`rule`: it starts from a fresh session (the suite calls ``Context.prepare`` first),
sends frames, checks every answer, and returns a short note on success. It fails by
raising :class:`~bridge.errors.RuleFailedError` (through ``check`` or the host's
``expect``) and declines by raising :class:`~bridge.errors.RuleNotRunError` when the device
does not offer what it needs. :data:`RULES` holds them by id, in the order they run; the
order goes from the basics (handshake) to the disruptive (watchdog, faults, reboot).

Timeouts are generous (a rule waits for an answer up to a second, for a stop up to
three): conformance is about what a controller answers and in which order, not how fast.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from bridge.conformance.context import Context, check
from firmware_proto.faults import fault_bit
from firmware_proto.message import Message
from firmware_proto.messages import (
    CONTROLLER_HEARTBEAT_PERIOD_MS,
    ENCODERS_RATE_HZ,
    MOTION_QUEUE_DEPTH,
    PROTOCOL_VERSION,
    SCHEMA_HASH,
    AbortReason,
    Ack,
    AckField,
    AckResult,
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
    Imu,
    Motion,
    Param,
    ParamResult,
    Pose,
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

RuleFunction = Callable[[Context], str]


@dataclass(frozen=True)
class Rule:
    """One rule of the suite.

    Attributes:
        id: short name (``stop``, ``watchdog``...), what ``--rule`` takes.
        section: the section of docs/protocol.md that states it.
        statement: what a conforming controller does, one sentence.
        needs: what the rule needs beyond a link (``control``, ``serial``), for ``--list``.
        run: the check itself.
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


def _ack(ctx: Context, motion: Message, *, unchecked: bool = False) -> Ack:
    host = ctx.host
    mark = host.send_unchecked(motion) if unchecked else host.send(motion)
    seq = motion.seq  # type: ignore[attr-defined]
    return host.expect(Ack, f"ACK for seq {seq}", since=mark, where=lambda a: a.seq == seq)


def _expect_ack(ctx: Context, motion: Message, result: int, field: int = AckField.NONE) -> Ack:
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


def _started(ctx: Context, seq: int, since: int) -> Status:
    return ctx.host.expect(
        Status,
        f"STATUS STARTED for seq {seq}",
        since=since,
        where=lambda s: s.seq == seq and s.state == StepState.STARTED,
    )


def _ended(ctx: Context, seq: int, since: int, timeout_s: float = 5.0) -> Status:
    return ctx.host.expect(
        Status,
        f"STATUS COMPLETED or ABORTED for seq {seq}",
        since=since,
        where=lambda s: s.seq == seq and s.state != StepState.STARTED,
        timeout_s=timeout_s,
    )


def _running_step(ctx: Context) -> tuple[int, int]:
    """A long FWD step, accepted, started and under way (the encoders have counted 2 cm
    of it, so a stop has something to brake); ``(seq, mark before it was sent)``."""
    host = ctx.host
    seq = ctx.seq()
    mark = host.mark()
    ack = _ack(ctx, Motion(seq, FWD, 60, _LONG))
    check(ack.result == AckResult.ACCEPTED, f"a valid step was refused: {ack.describe()}")
    _started(ctx, seq, mark)
    first = host.expect(Encoders, "ENCODERS during the step", since=mark)
    host.expect(
        Encoders,
        "ENCODERS counting 460 units (2 cm) into the step",
        since=mark,
        where=lambda e: (
            _delta24(first.left, e.left) >= 460 and _delta24(first.right, e.right) >= 460
        ),
        timeout_s=3.0,
    )
    return seq, mark


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


# -- handshake and liveness ---------------------------------------------------------------


@rule("handshake", "Handshake")
def handshake(ctx: Context) -> str:
    """A matching HELLO is answered with IDENT carrying this protocol version and schema
    hash; a new session starts: HEARTBEAT handshake_ok 1, state IDLE, PROGRESS
    ended_count 0 with every other field 0."""
    host = ctx.host
    mark = host.send(Hello(PROTOCOL_VERSION, SCHEMA_HASH))
    ident = host.expect(Ident, "IDENT", since=mark)
    check(
        (ident.protocol_version, ident.schema_hash) == (PROTOCOL_VERSION, SCHEMA_HASH),
        f"IDENT says v{ident.protocol_version}/0x{ident.schema_hash:04X}",
    )
    hb = host.expect(Heartbeat, "HEARTBEAT after IDENT", since=mark)
    check(bool(hb.handshake_ok), f"HEARTBEAT after a matching HELLO has handshake_ok 0: {hb}")
    check(hb.boot_nonce == ident.boot_nonce, "HEARTBEAT and IDENT disagree on the boot nonce")
    check(hb.state == ControllerState.IDLE, f"state {_name(ControllerState, hb.state)}, not IDLE")
    progress = host.expect(Progress, "PROGRESS", since=mark)
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
    host.absent(Ident, "IDENT without a HELLO", since=mark, window_s=window_s)
    got = host.received(mark)
    beats = [m for m in got if isinstance(m, Heartbeat)]
    expected = window_s * host.timeout_scale * 1000.0 / CONTROLLER_HEARTBEAT_PERIOD_MS
    check(
        0.5 * expected <= len(beats) <= 1.5 * expected + 1,
        f"{len(beats)} HEARTBEATs in {window_s * host.timeout_scale:g} s, expected about "
        f"{expected:g}",
    )
    for i, msg in enumerate(got[:-1]):
        if isinstance(msg, Heartbeat):
            after = next((m for m in got[i + 1 :] if not isinstance(m, _SAMPLES)), None)
            check(
                after is None or isinstance(after, Progress),
                f"HEARTBEAT followed by {after.NAME if after else '-'}, not PROGRESS",
            )
    for hb in beats:
        check(
            hb.stop_latched == int(bool(hb.latch_stop or hb.latch_watchdog or hb.latch_fault)),
            f"stop_latched is not the OR of the latch bits: {_latch_text(hb)}",
        )
    return f"{len(beats)} heartbeats in {window_s * host.timeout_scale:g} s"


_SAMPLES = (Encoders, WheelSpeeds, Imu, Pose)


@rule("telemetry", "Telemetry")
def telemetry(ctx: Context) -> str:
    """ENCODERS (mandatory) arrive at about ENCODERS_RATE_HZ; WHEEL_SPEEDS and IMU should;
    POSE is optional, and when sent its yaw is within +-180 deg."""
    host = ctx.host
    mark = host.mark()
    window_s = 1.0
    host.absent(Ident, "IDENT without a HELLO", since=mark, window_s=window_s)
    got = host.received(mark)
    count = {kind.NAME: sum(isinstance(m, kind) for m in got) for kind in _SAMPLES}
    expected = ENCODERS_RATE_HZ * window_s * host.timeout_scale
    check(
        count["ENCODERS"] >= 0.5 * expected,
        f"{count['ENCODERS']} ENCODERS in {window_s * host.timeout_scale:g} s, expected about "
        f"{expected:g} (mandatory)",
    )
    for pose in (m for m in got if isinstance(m, Pose)):
        check(-1800 <= pose.yaw_ddeg <= 1800, f"POSE yaw out of range: {pose.describe()}")
    missing = [name for name in ("WHEEL_SPEEDS", "IMU") if count[name] == 0]
    note = ", ".join(f"{n} {c}" for n, c in count.items())
    return note + (f"; should send {', '.join(missing)}" if missing else "")


@rule("hello-mismatch", "Handshake")
def hello_mismatch(ctx: Context) -> str:
    """A HELLO with another schema hash is answered with IDENT (the controller's own
    hash), closes the session (handshake_ok 0, state BOOT) and MOTION gets NOT_READY;
    a matching HELLO opens a session again."""
    host = ctx.host
    mark = host.send(Hello(PROTOCOL_VERSION, SCHEMA_HASH ^ 0xFFFF))
    ident = host.expect(Ident, "IDENT in answer to a mismatched HELLO", since=mark)
    check(ident.schema_hash == SCHEMA_HASH, "IDENT must carry the controller's own schema hash")
    ctx.until("handshake_ok 0 and state BOOT", lambda hb: not hb.handshake_ok and hb.state == 0)
    _expect_ack(ctx, Motion(ctx.seq(), FWD, 10, 100), AckResult.NOT_READY)
    ctx.handshake()
    return "mismatch closes the session, a match reopens it"


@rule("boot-latch", "State machine")
def boot_latch(ctx: Context) -> str:
    """Without a session (BOOT), STOP latches (STOP_ACK STOP_LATCHED, STOPPED) and
    CLEAR_STOP releases it back to BOOT, not IDLE."""
    host = ctx.host
    host.send(Hello(PROTOCOL_VERSION, SCHEMA_HASH ^ 0xFFFF))
    ctx.until("state BOOT", lambda hb: hb.state == ControllerState.BOOT)
    stop_id = ctx.stop_id()
    mark = host.send(Stop(stop_id, StopSource.BENCH))
    ack = host.expect(StopAck, f"STOP_ACK {stop_id}", since=mark)
    check(
        (ack.stop_id, ack.state) == (stop_id, ControllerState.STOP_LATCHED),
        f"STOP in BOOT answered {ack.describe()}",
    )
    host.expect(Stopped, f"STOPPED {stop_id}", since=mark, where=lambda s: s.stop_id == stop_id)
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
            Fault, "WATCHDOG fault without a session", since=mark, window_s=3 * watchdog_s,
            where=lambda f: f.code == FaultCode.WATCHDOG,
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
        Progress, "PROGRESS naming the step", since=mark, where=lambda p: p.ended_count > 0
    )
    check(
        (progress.ended_seq, progress.ended_state, progress.ended_count)
        == (seq, StepState.COMPLETED, 1),
        f"PROGRESS after one step: {progress.describe()}",
    )
    return f"travel {end.travel} of {distance}"


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
    host.absent(Status, f"a second run of seq {seq}", since=after, where=lambda s: s.seq == seq)
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
    ctx.host.expect(StopAck, "STOP_ACK", since=mark, where=lambda a: a.stop_id == stop_id)
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
    host.expect(Stopped, "STOPPED", since=mark, where=lambda s: s.stop_id == stop_id, timeout_s=3)
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
    ack = host.expect(StopAck, "STOP_ACK", since=mark)
    check(
        (ack.stop_id, ack.state) == (stop_id, ControllerState.STOP_LATCHED),
        f"STOP {stop_id} answered {ack.describe()}",
    )
    order = [m for m in host.received(mark) if isinstance(m, (StopAck, Status))]
    check(isinstance(order[0], StopAck), "the aborted STATUS came before STOP_ACK")
    end = _ended(ctx, seq, mark)
    check(
        (end.state, end.reason) == (StepState.ABORTED, AbortReason.STOP),
        f"the running step after STOP: {end.describe()}",
    )
    stopped = host.expect(
        Stopped, f"STOPPED {stop_id}", since=mark, where=lambda s: s.stop_id == stop_id, timeout_s=3
    )
    hb = host.heartbeat()
    check(
        _latch(hb) == (1, 1, 0, 0) and hb.state == ControllerState.STOP_LATCHED,
        f"after STOP: {_latch_text(hb)}, expected latch_stop only, STOP_LATCHED",
    )
    again = host.send(Stop(stop_id, StopSource.BENCH))
    host.expect(
        StopAck, "STOP_ACK to the repeat", since=again, where=lambda a: a.stop_id == stop_id
    )
    host.absent(
        Stopped, "second STOPPED for one stop_id", since=again,
        where=lambda s: s.stop_id == stop_id,
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
    host.expect(Stopped, f"STOPPED {first}", since=mark, where=lambda s: s.stop_id == first)
    second = ctx.stop_id()
    mark = host.send(Stop(second, StopSource.BENCH))
    stopped = host.expect(
        Stopped, f"STOPPED {second} while latched", since=mark, where=lambda s: s.stop_id == second
    )
    check(stopped.distance_mm == 0, f"at rest, yet {stopped.describe()}")
    ctx.clear()
    return "one STOPPED per stop_id"


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
    host.expect(Stopped, "STOPPED 0", since=mark, where=lambda s: s.stop_id == 0, timeout_s=3)
    hb = host.heartbeat()
    check(_latch(hb) == (1, 1, 0, 0), f"after MOTION STOP: {_latch_text(hb)}")
    _expect_ack(ctx, Motion(stop_seq, Command.STOP, 0, 0), AckResult.DUPLICATE)
    ctx.clear()
    return "stopped, latched, deduplicated"


@rule("session", "Handshake")
def session(ctx: Context) -> str:
    """A matching HELLO during a step aborts it (reason SESSION, before IDENT), brings
    no latch, restarts PROGRESS at ended_count 0 and forgets the old seqs."""
    host = ctx.host
    seq, _ = _running_step(ctx)
    mark = host.send(Hello(PROTOCOL_VERSION, SCHEMA_HASH))
    ident = host.expect(Ident, "IDENT", since=mark)
    end = _ended(ctx, seq, mark)
    check(
        (end.state, end.reason) == (StepState.ABORTED, AbortReason.SESSION),
        f"the running step after HELLO: {end.describe()}",
    )
    got = host.received(mark)
    check(got.index(end) < got.index(ident), "the SESSION abort came after IDENT")
    progress = host.expect(Progress, "PROGRESS", since=mark)
    check(progress.ended_count == 0, f"PROGRESS of the new session: {progress.describe()}")
    hb = host.heartbeat()
    check(not hb.stop_latched, f"a new session latched: {_latch_text(hb)}")
    _expect_ack(ctx, Motion(seq, FWD, 0, 0), AckResult.ACCEPTED)  # a new step, same seq
    return "aborted with SESSION, seqs forgotten"


# -- receive errors -------------------------------------------------------------------


@rule("wire-range", "Messages")
def wire_range(ctx: Context) -> str:
    """A frame with a field outside its wire range (STOP with stop_id 0) is dropped and
    counted in rx_errors, never obeyed."""
    host = ctx.host
    before = host.heartbeat()
    mark = host.send_raw(Stop.MSG_ID, bytes((0, 0, StopSource.BENCH)))  # stop_id 0
    host.absent(StopAck, "STOP_ACK to a STOP with stop_id 0", since=mark)
    after = host.heartbeat()
    check(not after.stop_latched, f"a STOP with stop_id 0 was obeyed: {_latch_text(after)}")
    delta = (after.rx_errors - before.rx_errors) & 0xFFFF
    check(delta == 1, f"rx_errors went up by {delta}, expected 1")
    return "dropped and counted"


@rule("rx-errors", "Receive errors")
def rx_errors(ctx: Context) -> str:
    """Frames with an unknown id, a wrong length, (serial) a bad CRC or the wrong
    direction are dropped without an answer, each counted once in rx_errors."""
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
        sent += 2
    host.absent(Ack, "an ACK to a malformed MOTION", since=mark)
    after = host.heartbeat()
    delta = (after.rx_errors - before.rx_errors) & 0xFFFF
    check(delta == sent, f"rx_errors went up by {delta} for {sent} bad frames")
    what = "unknown id, bad length" + (", bad CRC, wrong direction" if sent == 4 else "")
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


@rule("watchdog", "Watchdog and heartbeats")
def watchdog(ctx: Context) -> str:
    """A silent host trips the watchdog: FAULT WATCHDOG active 1, the step aborted with
    reason WATCHDOG, STOPPED 0, state FAULT with latch_watchdog only; the next frame ends
    the condition (FAULT active 0, bit clear) but not the latch (FAULT_ACTIVE) until
    CLEAR_STOP."""
    host = ctx.host
    watchdog_ms = ctx.watchdog_ms()
    seq, _ = _running_step(ctx)
    with host.silent():
        mark = host.mark()
        fault = host.expect(
            Fault, "FAULT WATCHDOG active", since=mark, timeout_s=3 * watchdog_ms / 1000,
            where=lambda f: f.code == FaultCode.WATCHDOG and f.active == 1,
        )  # fmt: skip
        end = _ended(ctx, seq, mark)
        host.expect(Stopped, "STOPPED 0", since=mark, where=lambda s: s.stop_id == 0, timeout_s=3)
        hb = host.heartbeat()
    check(fault.detail >= watchdog_ms, f"FAULT detail {fault.detail} ms < watchdog {watchdog_ms}")
    check(
        (end.state, end.reason) == (StepState.ABORTED, AbortReason.WATCHDOG),
        f"the step after the watchdog: {end.describe()}",
    )
    check(
        _latch(hb) == (1, 0, 1, 0)
        and hb.state == ControllerState.FAULT
        and bool(hb.fault_bits & fault_bit(FaultCode.WATCHDOG)),
        f"while silent: {_latch_text(hb)}, expected FAULT, latch_watchdog, WATCHDOG bit",
    )
    mark = host.send(HostHeartbeat(0))
    host.expect(
        Fault, "FAULT WATCHDOG active 0 after a valid frame", since=mark,
        where=lambda f: f.code == FaultCode.WATCHDOG and f.active == 0,
    )  # fmt: skip
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
            Fault, "FAULT ENCODER active 1", since=mark,
            where=lambda f: f.code == FaultCode.ENCODER and f.active == 1,
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
        Fault, "FAULT ENCODER active 0", since=mark,
        where=lambda f: f.code == FaultCode.ENCODER and f.active == 0,
    )  # fmt: skip
    hb = host.heartbeat()
    check(
        _latch(hb) == (1, 0, 0, 1) and not hb.fault_bits & fault_bit(FaultCode.ENCODER),
        f"condition gone: {_latch_text(hb)}, expected the latch held, the bit clear",
    )
    ctx.clear(ClearResult.CLEARED)
    ctx.idle()
    return "FAULT_PERSISTS, then CLEARED once the condition went"


@rule("stall", "Latch and faults", needs="control")
def stall(ctx: Context) -> str:
    """A locked wheel aborts the step (reason STALL) and raises STALL_*; the stall is an
    event: FAULT active 0 follows STOPPED; latch_fault holds until CLEAR_STOP."""
    control = ctx.require_control("lock a wheel (stall:right)")
    host = ctx.host
    control.inject("stall:right")
    try:
        seq = ctx.seq()
        mark = host.mark()
        check(_ack(ctx, Motion(seq, FWD, 30, 23000)).result == AckResult.ACCEPTED, "refused")
        end = _ended(ctx, seq, mark, timeout_s=5.0)
        check(
            (end.state, end.reason) == (StepState.ABORTED, AbortReason.STALL),
            f"the step on a locked wheel: {end.describe()}",
        )
        host.expect(
            Fault, "FAULT STALL_RIGHT active 1", since=mark,
            where=lambda f: f.code == FaultCode.STALL_RIGHT and f.active == 1,
        )  # fmt: skip
        stopped = host.expect(Stopped, "STOPPED 0", since=mark, where=lambda s: s.stop_id == 0)
        over = host.expect(
            Fault, "FAULT STALL_RIGHT active 0 at rest", since=mark,
            where=lambda f: f.code == FaultCode.STALL_RIGHT and f.active == 0,
        )  # fmt: skip
        got = host.received(mark)
        check(got.index(stopped) < got.index(over), "FAULT active 0 came before STOPPED")
        hb = host.heartbeat()
        check(
            _latch(hb) == (1, 0, 0, 1) and hb.fault_bits == 0,
            f"after the stall: {_latch_text(hb)}, expected latch_fault, no condition",
        )
    finally:
        control.inject("clear:stall")
    ctx.clear(ClearResult.CLEARED)
    ctx.idle()
    return "aborted, latched, condition over at rest"


@rule("reboot", "Handshake", needs="control")
def reboot(ctx: Context) -> str:
    """After a reboot the controller sends IDENT with a new boot nonce before any
    restarted encoder count; it is in BOOT with no session and no latch, and its encoder
    counts start again near 0."""
    control = ctx.require_control("reboot the controller")
    host = ctx.host
    old = host.heartbeat().boot_nonce
    mark = host.mark()
    control.inject("reboot")
    ident = host.expect(Ident, "IDENT after the reboot", since=mark, timeout_s=3)
    check(ident.boot_nonce != old, f"the boot nonce did not change (0x{old:04X})")
    after_ident = mark + host.received(mark).index(ident) + 1
    first = host.expect(Encoders, "ENCODERS after the reboot's IDENT", since=after_ident)
    check(
        abs(first.left) < 1000 and abs(first.right) < 1000,
        f"the first ENCODERS after IDENT: {first.describe()}, expected counts near 0",
    )
    hb = host.heartbeat_where("the new nonce", lambda hb: hb.boot_nonce == ident.boot_nonce)
    check(
        hb.state == ControllerState.BOOT and not hb.handshake_ok and not hb.stop_latched,
        f"after the reboot: handshake_ok={hb.handshake_ok} {_latch_text(hb)}",
    )
    return f"boot nonce 0x{old:04X} -> 0x{ident.boot_nonce:04X}"
