"""The host core's side of the latch rules of protocol v4 (docs/protocol.md, "Latch and
faults"), in virtual time: each test plays one hole of issue #40 at exact moments and
fails on the core as it was before its fix (protocol v3's clear named no generation,
was sent again by itself after FAULT_PERSISTS, dropped the STOP it followed, refused a
step sent while it was out, and was queued copy after copy behind a stalled writer)."""

from __future__ import annotations

from bridge.link.linkcore import LinkCore, Outgoing
from bridge.link.linktypes import LinkConfig, StatusEvent, StepRequest
from firmware_proto.wire.faults import fault_bit
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import (
    PROTOCOL_VERSION,
    SCHEMA_HASH,
    Ack,
    AckField,
    AckResult,
    ClearAck,
    ClearResult,
    ClearStop,
    ControllerState,
    Fault,
    FaultCode,
    Heartbeat,
    Ident,
    Motion,
    Progress,
    StopAck,
)

FWD = StepRequest(1, 30, 500)
NONCE = 0x1234
FAULT = ControllerState.FAULT
LATCHED = ControllerState.STOP_LATCHED


def _written(core: LinkCore, now: float) -> list[Message]:
    """Every ordinary frame queued, written at ``now`` as the writer would."""
    out: list[Message] = []
    while (entry := core.take_write()) is not None:
        assert isinstance(entry, Outgoing)
        core.written(entry, now, True)
        out.append(entry.msg)
    return out


def _clears(frames: list[Message]) -> list[ClearStop]:
    return [m for m in frames if isinstance(m, ClearStop)]


def _texts(core: LinkCore) -> list[str]:
    return [e.text for e in core.take_events() if isinstance(e, StatusEvent)]


def _hb(
    state: int = ControllerState.IDLE,
    *,
    stop: int = 0,
    watchdog: int = 0,
    fault: int = 0,
    bits: int = 0,
    gen: int = 0,
) -> Heartbeat:
    latched = int(bool(stop or watchdog or fault))
    return Heartbeat(state, latched, 1, stop, watchdog, fault, bits, 0, NONCE, 0, gen)


def _beat(core: LinkCore, hb: Heartbeat, t: float) -> list[Message]:
    """A HEARTBEAT (and its PROGRESS) at ``t``, the core's tick, what it wrote."""
    core.on_frame(hb, t)
    core.on_frame(Progress(0, 0, 0, 0, 0), t)
    core.tick(t)
    return _written(core, t)


def _ready(first_request_id: int = 1) -> LinkCore:
    core = LinkCore(LinkConfig("sim://x"), first_request_id=first_request_id)
    core.on_connected(0.0)
    core.tick(0.0)
    _written(core, 0.0)
    core.on_frame(Ident(PROTOCOL_VERSION, 1, 0, 0, SCHEMA_HASH, NONCE), 0.002)
    _beat(core, _hb(), 0.01)
    assert _texts(core) == ["ready"]
    return core


ENCODER = fault_bit(FaultCode.ENCODER)


def test_hole_1_an_automatic_clear_names_its_generation_and_a_fault_ends_it() -> None:
    """The watchdog alone holds the latch at generation 1: the automatic clear names 1.
    An encoder fault rises (generation 2) while it is out: its FAULT frame ends the
    request, a refusal (LATCH_CHANGED) would too, and no automatic clear follows for a
    latch that holds a fault, whatever its condition does."""
    core = _ready()
    (clear,) = _clears(_beat(core, _hb(FAULT, watchdog=1, gen=1), 0.1))
    assert clear.latch_gen == 1
    core.on_frame(Fault(FaultCode.ENCODER, 1, 1, 2), 0.102)
    assert "fault:encoder" in _texts(core)
    core.tick(0.2)
    assert _clears(_written(core, 0.2)) == []  # no copy after the fault
    core.on_frame(ClearAck(clear.stop_id, ClearResult.LATCH_CHANGED, 2), 0.21)
    for k in range(10):  # the condition comes and goes: never the host's to clear
        bits = ENCODER if k < 3 else 0
        assert (
            _clears(_beat(core, _hb(FAULT, watchdog=1, fault=1, bits=bits, gen=2), 0.3 + k / 10))
            == []
        )
    assert core.stop_latched and "cleared" not in _texts(core)


def test_hole_1_an_operators_clear_names_what_was_reported_when_asked() -> None:
    """The operator clears a STOP's latch (generation 1); before the clear goes out a
    fault's FAULT frame arrives (generation 2): the clear still names 1, so the
    controller answers LATCH_CHANGED, and the host says so; a clear asked for after the
    fault was reported names 2."""
    core = _ready()
    _beat(core, _hb(LATCHED, stop=1, gen=1), 0.1)
    core.clear_stop(0.11)
    core.on_frame(Fault(FaultCode.ENCODER, 1, 1, 2), 0.111)
    core.tick(0.112)
    (clear,) = _clears(_written(core, 0.112))
    assert clear.latch_gen == 1
    core.on_frame(ClearAck(clear.stop_id, ClearResult.LATCH_CHANGED, 2), 0.115)
    assert _texts(core) == ["fault:encoder", "fault:latch_changed"]
    core.clear_stop(0.2)
    core.tick(0.2)
    (again,) = _clears(_written(core, 0.2))
    assert again.latch_gen == 2 and again.stop_id != clear.stop_id


def test_hole_2_a_refused_clear_is_over_and_never_released_later() -> None:
    core = _ready()
    core.on_frame(Fault(FaultCode.ENCODER, 1, 1, 1), 0.05)
    _beat(core, _hb(FAULT, fault=1, bits=ENCODER, gen=1), 0.1)
    core.clear_stop(0.11)
    core.tick(0.11)
    (clear,) = _clears(_written(core, 0.11))
    core.on_frame(ClearAck(clear.stop_id, ClearResult.FAULT_PERSISTS, 1), 0.112)
    assert _texts(core)[-1] == "fault:fault_persists"
    core.on_frame(Fault(FaultCode.ENCODER, 0, 0, 1), 0.3)  # the condition goes
    for k in range(20):
        assert _clears(_beat(core, _hb(FAULT, fault=1, gen=1), 0.4 + k / 10)) == []
    assert core.stop_latched and "cleared" not in _texts(core)


def test_hole_3_a_clear_before_the_stop_ack_waits_for_it_and_stopped_is_said() -> None:
    """The operator stops at speed and clears before the STOP_ACK is back: ``stopped``
    comes when it arrives, then the clear goes out naming the STOP's generation, and
    ``cleared`` follows."""
    core = _ready()
    stop_id = core.emergency_stop(0, 0.1)
    core.take_stops()
    core.stop_written(stop_id, 0.1, True)
    core.clear_stop(0.101)
    core.tick(0.102)
    assert _clears(_written(core, 0.102)) == []  # waits for the STOP_ACK
    core.on_frame(StopAck(stop_id, LATCHED, 1), 0.103)
    core.tick(0.103)
    (clear,) = _clears(_written(core, 0.103))
    assert clear.latch_gen == 1
    core.on_frame(ClearAck(clear.stop_id, ClearResult.CLEARED, 1), 0.105)
    assert _texts(core) == ["stopped", "cleared"]
    assert not core.stop_latched


def test_hole_4_a_step_after_a_clear_waits_for_its_answer() -> None:
    core = _ready()
    _beat(core, _hb(LATCHED, stop=1, gen=1), 0.1)
    core.clear_stop(0.2)
    number = core.submit_step(FWD, 0.2005)  # before the CLEAR_ACK
    core.tick(0.201)
    frames = _written(core, 0.201)
    assert [type(m) for m in frames if isinstance(m, (ClearStop, Motion))] == [ClearStop]
    assert _texts(core) == []  # not refused: waiting
    (clear,) = _clears(frames)
    core.on_frame(ClearAck(clear.stop_id, ClearResult.CLEARED, 1), 0.21)
    (motion,) = [m for m in _written(core, 0.21) if isinstance(m, Motion)]
    core.on_frame(Ack(motion.seq, AckResult.ACCEPTED, AckField.NONE, 1), 0.22)
    assert core.take_events() == [StatusEvent("cleared"), StatusEvent("accepted", number)]
    # A stale HEARTBEAT (sent before the CLEAR_STOP arrived) does not latch it again.
    _beat(core, _hb(LATCHED, stop=1, gen=1), 0.25)
    assert not core.stop_latched


def test_hole_4_steps_waiting_for_a_refused_clear_are_refused_with_its_reason() -> None:
    core = _ready()
    _beat(core, _hb(FAULT, fault=1, bits=ENCODER, gen=1), 0.1)
    core.clear_stop(0.2)
    number = core.submit_step(FWD, 0.2)
    core.tick(0.2)
    (clear,) = _clears(_written(core, 0.2))
    core.on_frame(ClearAck(clear.stop_id, ClearResult.FAULT_PERSISTS, 1), 0.21)
    events = core.take_events()
    assert StatusEvent("rejected:fault_active", number) in events


def test_hole_7_a_stalled_writer_gets_one_clear_copy_and_repeats_run_from_its_write() -> None:
    core = _ready()
    _beat(core, _hb(LATCHED, stop=1, gen=1), 0.1)
    core.clear_stop(0.2)
    queued: list[Outgoing] = []
    t = 0.2
    while t < 0.8:  # the writer is stuck for 565 ms: the core ticks, nothing is written
        core.tick(t)
        while (entry := core.take_write()) is not None:
            queued.append(entry)
        t += 0.005
    copies = [e for e in queued if isinstance(e.msg, ClearStop)]
    assert len(copies) == 1
    core.written(copies[0], 0.8, True)
    core.tick(0.805)
    assert _clears(_written(core, 0.805)) == []  # 10 ms from the write, not from the queue
    core.tick(0.81)
    assert len(_clears(_written(core, 0.81))) == 1


def test_hole_8_request_ids_start_where_the_host_says() -> None:
    core = _ready(first_request_id=40_000)
    assert core.clear_stop(0.1) == 40_000
    assert core.emergency_stop(0, 0.2) == 40_001
    wrap = _ready(first_request_id=0xFFFF)
    assert [wrap.clear_stop(0.1), wrap.clear_stop(0.2)] == [0xFFFF, 1]


def test_9_a_watchdog_latch_whose_fault_frame_was_lost_is_reported_before_any_clear() -> None:
    core = _ready()
    _beat(core, _hb(FAULT, watchdog=1, gen=1), 0.1)
    texts = _texts(core)
    assert texts[0] == "fault:watchdog"
    assert core.diagnostics(0.1).watchdog_trips == 1


def _latch(core: LinkCore) -> tuple[bool, tuple[str, ...]]:
    """Latched or not, and by what, as the bridge's diagnostics say."""
    return core.stop_latched, core.latch


def _stopped(core: LinkCore, t: float, gen: int) -> int:
    """The operator's STOP at ``t``, written and acknowledged (generation ``gen``) 3 ms later."""
    stop_id = core.emergency_stop(0, t)
    core.take_stops()
    core.stop_written(stop_id, t, True)
    core.on_frame(StopAck(stop_id, LATCHED, gen), t + 0.003)
    return stop_id


def test_a_stop_acknowledged_shows_in_the_latch_before_the_next_heartbeat() -> None:
    """The latch's causes come from HEARTBEATs, and the bridge's /diagnostics may be
    composed between a STOP_ACK and the next one: they showed the controller latched by
    nothing (a console's ``rover status`` right after ``rover stop``, a loaded CI run).
    Now ``stop`` is a cause from its STOP_ACK on, until a HEARTBEAT of its generation."""
    core = _ready()
    _beat(core, _hb(), 0.1)
    _stopped(core, 0.15, gen=1)
    assert _texts(core) == ["stopped"]
    assert _latch(core) == (True, ("stop",)) and core.diagnostics(0.16).latch == ("stop",)
    _beat(core, _hb(LATCHED, stop=1, gen=1), 0.2)
    assert _latch(core) == (True, ("stop",))
    # A watchdog latch already held: the STOP adds its cause, sorted as HEARTBEATs give.
    held = _ready()
    _beat(held, _hb(FAULT, watchdog=1, gen=1), 0.1)
    _stopped(held, 0.15, gen=2)
    assert _latch(held) == (True, ("stop", "watchdog"))


def test_a_heartbeat_sent_before_the_stop_does_not_unlatch_it() -> None:
    """A HEARTBEAT of the generation before the STOP's, arriving after its STOP_ACK,
    leaves the latch as the STOP_ACK said; one of the STOP's generation decides again,
    and a clear, or a reboot, ends what the STOP_ACK said."""
    core = _ready()
    _stopped(core, 0.15, gen=1)
    _beat(core, _hb(gen=0), 0.16)  # sent before the STOP reached the controller
    assert _latch(core) == (True, ("stop",))
    core.clear_stop(0.2)
    core.tick(0.2)
    (clear,) = _clears(_written(core, 0.2))
    assert clear.latch_gen == 1  # not the older HEARTBEAT's generation
    core.on_frame(ClearAck(clear.stop_id, ClearResult.CLEARED, 1), 0.21)
    assert _latch(core) == (False, ())
    _beat(core, _hb(gen=1), 0.3)
    assert _latch(core) == (False, ())
    rebooted = _ready()
    _stopped(rebooted, 0.15, gen=7)
    # A new boot (its nonce) latched by its watchdog at generation 1: the old boot's
    # STOP (generation 7) is no cause of it.
    rebooted.on_frame(Heartbeat(FAULT, 1, 0, 0, 1, 0, 0, 0, NONCE + 1, 0, 1), 0.3)
    rebooted.on_frame(Heartbeat(FAULT, 1, 0, 0, 1, 0, 0, 0, NONCE + 1, 0, 1), 0.4)
    assert _latch(rebooted) == (True, ("watchdog",))
