"""LinkCore on its own, in virtual time: the API the threaded shell and the simulator
drive, at exact moments (the same rules run against real controllers in
tests/bridge/test_link*.py and against both controllers in tests/sim)."""

from __future__ import annotations

import pytest

from bridge.link.linkcore import LinkCore, Outgoing
from bridge.link.linktypes import LinkConfig, LinkState, MediumStats, StatusEvent, StepRequest
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import (
    PROTOCOL_VERSION,
    SCHEMA_HASH,
    Ack,
    AckField,
    AckResult,
    ClearStop,
    ControllerState,
    Fault,
    FaultCode,
    Heartbeat,
    Hello,
    HostHeartbeat,
    Ident,
    Motion,
    Stop,
    StopAck,
)

FWD = StepRequest(1, 30, 500)


def _written(core: LinkCore, now: float) -> list[Message]:
    """Take every ordinary frame queued, as the writer would, written at ``now``."""
    out: list[Message] = []
    while (entry := core.take_write()) is not None:
        assert isinstance(entry, Outgoing)
        core.written(entry, now, True)
        out.append(entry.msg)
    return out


def _texts(core: LinkCore) -> list[str]:
    return [e.text for e in core.take_events() if isinstance(e, StatusEvent)]


def _ready(core: LinkCore) -> None:
    core.on_connected(0.0)
    core.tick(0.0)
    assert [type(m) for m in _written(core, 0.0)] == [Hello, HostHeartbeat]
    core.on_frame(Ident(PROTOCOL_VERSION, 1, 0, 0, SCHEMA_HASH, 0x1234), 0.002)
    assert core.state is LinkState.READY
    assert _texts(core) == ["ready"]


def test_a_motion_is_retransmitted_exactly_at_its_ack_timeout_from_its_write() -> None:
    core = LinkCore(LinkConfig("sim://x"))
    _ready(core)
    number = core.submit_step(FWD, 0.010)
    (motion,) = _written(core, 0.015)  # written 5 ms after it was decided
    assert isinstance(motion, Motion)
    due = core.next_deadline(0.016)
    assert due == pytest.approx(0.065)  # 50 ms from the write
    core.tick(due - 1e-6)
    assert _written(core, due) == []
    core.tick(due)
    assert _written(core, 0.066) == [motion]  # the same seq: deduplicated by the controller
    core.on_frame(Ack(motion.seq, AckResult.ACCEPTED, AckField.NONE, 1), 0.070)
    events = core.take_events()
    assert events == [StatusEvent("accepted", number)]
    assert core.diagnostics(0.07).retries == 1


def test_a_stop_is_claimed_at_once_and_repeated_until_acknowledged() -> None:
    core = LinkCore(LinkConfig("sim://x"))
    _ready(core)
    stop_id = core.emergency_stop(0, 0.050)
    assert core.take_stops() == [Stop(stop_id, 0)]  # before anything else is written
    core.stop_written(stop_id, 0.0505, True)
    due = core.next_deadline(0.051)
    assert due == pytest.approx(0.0605)  # 10 ms after the first copy left
    core.tick(due - 1e-6)
    assert core.take_stops() == []
    core.tick(due)
    assert core.take_stops() == [Stop(stop_id, 0)]
    core.on_frame(StopAck(stop_id, ControllerState.STOP_LATCHED, 1), 0.062)
    assert _texts(core) == ["stopped"]
    core.tick(0.08)
    assert core.take_stops() == []
    d = core.diagnostics(0.08)
    assert (d.stop_repeats, d.stop_latched) == (1, True)
    assert d.last_stop_latency_ms == pytest.approx(12.0)


def test_a_step_while_latched_is_refused_with_its_number() -> None:
    core = LinkCore(LinkConfig("sim://x"))
    _ready(core)
    core.emergency_stop(0, 1.0)
    number = core.submit_step(FWD, 1.001)
    assert core.take_events() == [StatusEvent("rejected:stop_latched", number)]


def test_a_transport_failure_drops_every_step_once_and_backs_off() -> None:
    core = LinkCore(LinkConfig("sim://x", reconnect_min_s=0.1, reconnect_max_s=0.4))
    _ready(core)
    numbers = [core.submit_step(FWD, 0.01) for _ in range(3)]
    _written(core, 0.01)
    core.failed(0.02, "unplugged")
    events = core.take_events()
    assert events[0] is LinkState.DISCONNECTED
    assert events[1:] == [StatusEvent("aborted:link_lost", n) for n in numbers] + [
        StatusEvent("fault:link_lost")
    ]
    assert not core.connect_due(0.119) and core.connect_due(0.121)
    core.connect_failed(0.121, "no such device")
    assert core.next_deadline(0.13) == pytest.approx(0.321)  # the backoff doubled


def test_hole_6_a_reboot_read_with_the_old_boots_answer_costs_no_lost_frame() -> None:
    """Issue #40, hole 6: the controller answers HELLO and reboots at once, so the old
    boot's IDENT and the new boot's IDENT arrive in one read. The gap in the frame
    counter between them is the reboot's, not lost frames: counted frame by frame from
    the counter, it is forgiven exactly (from the decoder's total after the read, which
    already held the new boot's gap, it was counted as 244 lost frames)."""
    core = LinkCore(LinkConfig("sim://x"))
    core.on_connected(0.0)
    core.tick(0.0)
    _written(core, 0.0)
    old = Ident(PROTOCOL_VERSION, 1, 0, 0, SCHEMA_HASH, 0x1234)
    new = Ident(PROTOCOL_VERSION, 1, 0, 0, SCHEMA_HASH, 0x4321)
    for msg, seq in ((old, 10), (old, 11), (new, 0)):
        core.on_frame(msg, 0.002, rx_seq=seq)
    gap = (0 - 11 - 1) & 0xFF  # what the decoder counts between seq 11 and seq 0
    d = core.diagnostics(0.003, MediumStats(connected=True, rx_lost=gap))
    assert (d.reboots, d.lost_frames) == (1, 0)
    # A frame really lost afterwards is counted.
    core.on_frame(Heartbeat(0, 0, 0, 0, 0, 0, 0, 0, 0x4321, 0, 0), 0.1, rx_seq=2)
    d = core.diagnostics(0.1, MediumStats(connected=True, rx_lost=gap + 1))
    assert d.lost_frames == 1


def test_a_clear_asked_before_the_host_knew_any_generation_does_not_take_a_later_fault() -> None:
    """A new bridge (or a reboot) knows no latch generation yet; the operator clears at
    once, and a stopping fault is reported before the first HEARTBEAT: the clear was asked
    for before that fault, so it is refused, not sent naming the fault's generation
    (found by the wire simulator's bridge restarts, seed 5005 on CAN)."""
    core = LinkCore(LinkConfig("sim://x"))
    _ready(core)
    core.clear_stop(0.01)
    assert not [m for m in _written(core, 0.01) if isinstance(m, ClearStop)]  # no gen yet
    core.on_frame(Fault(FaultCode.ENCODER, 1, 0, 1), 0.02)
    assert _texts(core) == ["fault:encoder", "fault:latch_changed"]
    latched = Heartbeat(ControllerState.FAULT, 1, 1, 0, 0, 1, 0, 0, 0x1234, 0, 1)
    core.on_frame(latched, 0.05)
    core.tick(0.06)
    assert not [m for m in _written(core, 0.06) if isinstance(m, ClearStop)]
    core.clear_stop(0.1)  # asked for now, with the fault reported: it names generation 1
    core.tick(0.1)
    assert [m for m in _written(core, 0.1) if isinstance(m, ClearStop)] == [ClearStop(2, 1)]


def test_a_bridge_that_read_only_heartbeats_of_the_old_boot_still_tells_the_reboot() -> None:
    """A bridge started while its HELLO cannot go out (a stalled writer) reads only the old
    boot's HEARTBEATs; the new boot's IDENT is a reboot all the same: counted, and the
    frame counter's restart is no loss (found by the wire simulator's bridge restarts,
    seed 101284 on serial)."""
    core = LinkCore(LinkConfig("sim://x"))
    core.on_connected(0.0)
    old = Heartbeat(ControllerState.IDLE, 0, 0, 0, 0, 0, 0, 0, 0x1234, 0, 0)
    core.on_frame(old, 0.01, rx_seq=70)
    core.on_frame(old, 0.11, rx_seq=80)  # nine frames lost between them
    core.on_frame(Ident(PROTOCOL_VERSION, 1, 0, 0, SCHEMA_HASH, 0x4321), 0.2, rx_seq=0)
    gaps = 9 + ((0 - 80 - 1) & 0xFF)  # what the decoder counts
    d = core.diagnostics(0.2, MediumStats(connected=True, rx_lost=gaps))
    assert (d.reboots, d.lost_frames, d.boot_nonce) == (1, 9, 0x4321)


def test_hole_5_a_boot_ident_that_repeats_the_nonce_is_a_reboot_all_the_same() -> None:
    """Issue #40, hole 5: a controller that breaks the nonce rule (an RNG without entropy)
    reboots with the nonce of the boot before. Its boot IDENT restarts the serial frame
    counter (seq 0, not after frame 255): the host takes it for the reboot it is, counts
    it, drops the steps in flight and handshakes again, and the restart's gap is no loss;
    an IDENT numbered 0 that follows frame 255 is the counter wrapping, no reboot."""
    core = LinkCore(LinkConfig("sim://x"))
    core.on_connected(0.0)
    core.tick(0.0)
    _written(core, 0.0)
    ident = Ident(PROTOCOL_VERSION, 1, 0, 0, SCHEMA_HASH, 0x1234)
    core.on_frame(ident, 0.002, rx_seq=254)
    core.on_frame(
        Heartbeat(ControllerState.IDLE, 0, 1, 0, 0, 0, 0, 0, 0x1234, 0, 0), 0.01, rx_seq=255
    )
    core.tick(0.02)
    _written(core, 0.02)  # as if a HELLO had been answered again: the counter wraps to 0
    core.on_frame(ident, 0.03, rx_seq=0)
    assert (core.reboots, core.state) == (0, LinkState.READY)
    number = core.submit_step(FWD, 0.04)
    _written(core, 0.04)
    core.take_events()
    core.on_frame(
        Heartbeat(ControllerState.IDLE, 0, 1, 0, 0, 0, 0, 0, 0x1234, 0, 0), 0.05, rx_seq=40
    )
    core.on_frame(ident, 0.3, rx_seq=0)  # the reboot: same nonce, the counter restarted
    assert (core.reboots, core.state) == (1, LinkState.HANDSHAKE)
    assert _texts(core) == ["aborted:controller_reboot", "fault:controller_reboot"]
    gaps = 39 + ((0 - 40 - 1) & 0xFF)  # what the decoder counts
    d = core.diagnostics(0.3, MediumStats(connected=True, rx_lost=gaps))
    assert (d.reboots, d.lost_frames) == (1, 39)
    assert number is not None


@pytest.mark.parametrize("serial", [True, False], ids=["serial", "can"])
def test_hole_5_a_session_lost_on_a_serial_link_is_a_reboot_whatever_the_nonce(
    serial: bool,
) -> None:
    """The boot IDENT of a reboot that repeats the nonce was lost: the next HEARTBEAT has
    no session, which the controller had confirmed. On a serial link no other host can
    have ended it: a reboot. On CAN another host's mismatched HELLO may have: the host
    handshakes again and counts no reboot (docs/protocol.md, "Boot IDENT or reply?")."""
    seq = iter(range(10, 20))

    def frame(msg: Message, t: float) -> None:
        core.on_frame(msg, t, rx_seq=next(seq) if serial else None)

    core = LinkCore(LinkConfig("sim://x"))
    core.on_connected(0.0)
    core.tick(0.0)
    _written(core, 0.0)
    frame(Ident(PROTOCOL_VERSION, 1, 0, 0, SCHEMA_HASH, 0x1234), 0.002)
    session = Heartbeat(ControllerState.IDLE, 0, 1, 0, 0, 0, 0, 0, 0x1234, 0, 0)
    none = Heartbeat(ControllerState.BOOT, 0, 0, 0, 0, 0, 0, 0, 0x1234, 0, 0)
    frame(session, 0.1)
    core.take_events()
    frame(none, 0.2)
    assert (core.reboots, core.state) == (
        (1, LinkState.HANDSHAKE) if serial else (0, LinkState.HANDSHAKE)
    )
    texts = _texts(core)
    assert ("fault:controller_reboot" in texts) is serial
    # A session never confirmed (the IDENT taken for a reply was a boot IDENT that
    # crossed the HELLO): its end is no new reboot.
    core.tick(0.3)
    _written(core, 0.3)
    frame(Ident(PROTOCOL_VERSION, 1, 0, 0, SCHEMA_HASH, 0x1234), 0.31)
    assert core.state is LinkState.READY
    frame(none, 0.4)
    assert core.reboots == (1 if serial else 0)
