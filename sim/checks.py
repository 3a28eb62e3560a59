"""The invariants of the wire simulator, and the ledger of what it saw on both sides.

docs/sim.md, "Invariants", states each rule in full. Checked as they happen (by
:class:`sim.rig.Rig`):

- ``once``: no step runs twice (the controller starts each MOTION seq at most once);
- ``fate``: every step the host took ends exactly once, with one final status,
  ``accepted`` at most once before it and nothing after it;
- ``truthful``: a step the host reports ``completed`` was completed by the controller;
- ``stop-zeroes``: a STOP that reaches the controller zeroes its wheel targets that tick;
- ``auto-clear``: an automatic CLEAR_STOP releases only a latch the watchdog alone holds
  (docs/protocol.md, "Latch and faults");
- ``release``: a latch is released only by a clear someone asked for, and a watchdog trip
  or a stopping fault in it only by an operator's clear asked for after the host had
  heard of it;
- ``stopped``: every operator STOP whose STOP_ACK reached the host is said ``stopped``;
- ``order``: a step submitted while an operator's clear is out is not refused
  ``stop_latched`` when that clear releases the latch;
- ``repeat``: copies of one CLEAR_STOP reach the wire at least ``stop_repeat_s`` apart;
- ``request-id``: a bridge started again on one controller boot repeats no request id
  of one before it on that boot, unless both random first ids met (``id_collisions``);
- ``odometry``: between two ENCODERS it uses, odometry moves no more than the encoders
  did (a v2 controller's sample of a boot the host cannot know yet is excused, counted);
- ``never-stuck``: after the last fault ends, a new step completes within
  :data:`sim.rig.RECOVERY_S`.

Checked at the end (:func:`final_checks`): every step has its fate, and the counters of
the bridge running at the end (``/diagnostics``) agree with what the simulator saw
(``counters``: steps, retries, reboots, reconnects, watchdog trips, lost frames, STOP
repeats; docs/sim.md's ``counters`` row gives each bound).

Pure: no I/O, no clock.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Protocol

from bridge.link.linktypes import LinkDiagnostics, StatusEvent
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import Heartbeat, Ident, Status, StepState

__all__ = ["RULES", "Judge", "Ledger", "Violation", "final_checks"]

RULES = (
    "once",
    "fate",
    "truthful",
    "stop-zeroes",
    "auto-clear",
    "release",
    "stopped",
    "order",
    "repeat",
    "request-id",
    "odometry",
    "never-stuck",
    "counters",
    "crash",
)
"""Every invariant by name (docs/sim.md)."""

_FINAL = ("completed", "rejected:", "aborted:", "fault:no_ack", "lost:")
"""Final statuses; ``lost:bridge_restart`` is the simulator's, for steps of a bridge that ended."""


class Judge(Protocol):
    """What records a violation the moment it happens (:class:`sim.rig.Rig`)."""

    def violate(self, rule: str, text: str) -> None:
        """Invariant ``rule`` broke now: ``text`` says how."""


@dataclass(frozen=True)
class Violation:
    """One invariant broken: which, when (virtual s), and what happened."""

    rule: str
    at_s: float
    text: str

    def line(self) -> str:
        """``t=1.234 auto-clear: ...``."""
        return f"t={self.at_s:.3f} {self.rule}: {self.text}"


@dataclass
class Ledger:
    """What the simulator saw on both sides of the wire (see the module docstring)."""

    submitted: int = 0
    """Steps the operator submitted (STOP commands excluded)."""
    starts: Counter[int] = field(default_factory=Counter)
    """STARTED STATUS frames the controller sent, by MOTION seq."""
    ended: dict[int, int] = field(default_factory=dict)
    """How the controller ended each seq (StepState)."""
    seq_of: dict[int, int] = field(default_factory=dict)
    """MOTION seq of each step number, from the frames the host wrote (see :class:`sim.rig.Rig`)."""
    host_seqs: set[int] = field(default_factory=set)
    """The MOTION seqs the bridge now running wrote."""
    motion_copies: int = 0
    motions_handled: int = 0
    fates: dict[int, list[str]] = field(default_factory=dict)
    """Every status the host said about each step number, in order."""
    statuses: Counter[str] = field(default_factory=Counter)
    stops_written: list[int] = field(default_factory=list)
    controller_reboots: int = 0
    transport_failures: int = 0
    watchdog_trips: int = 0
    """WATCHDOG FAULT frames (active) the controller sent: its trips."""
    watchdog_fault_frames: int = 0
    """... of those, delivered to the host (a CAN frame received twice counts twice)."""
    frames_lost_to_host: int = 0
    """Controller frames sent on the current connection that did not arrive whole."""
    queue_full: int = 0
    excused_jumps: int = 0
    expected_reboots: int = 0
    untold_reboots: int = 0
    """Reboots that repeated the nonce and whose boot IDENT the host did not read: it may
    count them (a session lost on a serial link) or not."""
    id_collisions: int = 0
    """Request ids of a restarted bridge that met an earlier bridge's by chance (both random)."""
    _nonce: int | None = None
    _boot: int | None = None
    """The boot whose nonce the host knows, as the simulator counts boots."""
    _last_rx_seq: int | None = None
    _gaps: int = 0
    """Gaps in the serial frame counter of the frames received on this connection."""
    _gaps_mark: int = 0
    _gaps_forgiven: int = 0
    _gaps_untold: int = 0
    """The frame counter's gaps of the untold reboots: loss unless the host told them."""

    # -- the controller's side -----------------------------------------------------------
    def controller_status(self, msg: Status, key: int, rig: Judge) -> None:
        """A STATUS the controller sent; ``key``: its MOTION seq, told apart from the seqs
        of other bridges (as :meth:`motion_written` was given it)."""
        if msg.state == StepState.STARTED:
            self.starts[key] += 1
            if self.starts[key] > 1:
                rig.violate("once", f"MOTION seq {msg.seq} started a second time")
        else:
            self.ended[key] = msg.state

    # -- the host's side -------------------------------------------------------------------
    def motion_written(self, seq: int, number: int | None) -> None:
        """The host wrote a MOTION frame (a first copy or a retransmission): ``seq`` its
        seq, told apart from other bridges' (:class:`sim.rig.Rig`)."""
        self.motion_copies += 1
        self.host_seqs.add(seq)
        if number is not None:
            self.seq_of[number] = seq

    def connected(self) -> None:
        """The host opened its device: its frame counting starts anew."""
        self.frames_lost_to_host = 0
        self._last_rx_seq = None
        self._gaps = self._gaps_mark = self._gaps_forgiven = self._gaps_untold = 0

    def frame_delivered(self, msg: Message, boot: int, rx_seq: int | None) -> None:
        """A controller frame of ``boot`` (the simulator's count of boots) reached the host,
        with its serial frame counter (``None`` on CAN). A HEARTBEAT or IDENT tells a boot:
        the first one makes it known; a later one is a reboot the host must count when
        it can tell it: its nonce differs from the one known, or it is the boot IDENT
        (serial frame counter restarted at 0). A reboot that repeats the nonce (against
        docs/protocol.md, Handshake 1) shown by no boot IDENT is one the host may count
        or not (:attr:`untold_reboots`). A counted reboot's restart of the frame counter
        is no loss, from the last frame known to be of the old boot to the first that
        shows the new one."""
        boot_ident = False
        if rx_seq is not None:
            if self._last_rx_seq is not None:
                gap = (rx_seq - self._last_rx_seq - 1) & 0xFF
                self._gaps += gap
                boot_ident = isinstance(msg, Ident) and rx_seq == 0 and gap != 0
            self._last_rx_seq = rx_seq
        if not isinstance(msg, (Heartbeat, Ident)):
            return
        known = self._boot
        if known is not None and boot != known:
            if msg.boot_nonce != self._nonce or boot_ident:
                self.expected_reboots += 1
                self._gaps_forgiven += self._gaps - self._gaps_mark
            else:
                # A repeated nonce and a lost boot IDENT: the host may tell the reboot
                # by a lost session, or not at all.
                self.untold_reboots += 1
                self._gaps_untold += self._gaps - self._gaps_mark
        self._boot, self._nonce = boot, msg.boot_nonce
        self._gaps_mark = self._gaps

    @property
    def expected_lost_frames(self) -> int:
        """What ``lost_frames`` must say on this connection (see :meth:`frame_delivered`),
        at most; less by up to :attr:`untold_gaps` where the host told an untold reboot."""
        return self._gaps - self._gaps_forgiven

    @property
    def untold_gaps(self) -> int:
        """The frame counter's gaps of the reboots the host may tell or not."""
        return self._gaps_untold

    def new_host(self, last_number: int) -> None:
        """The bridge process ended and a new one starts: the steps numbered up to
        ``last_number`` that have no fate end here (``lost:bridge_restart``), and the new
        bridge's counters start from zero; what the controller did stays."""
        for number in range(1, last_number + 1):
            fates = self.fates.setdefault(number, [])
            if not any(s.startswith(_FINAL) for s in fates):
                fates.append("lost:bridge_restart")
        self.host_seqs.clear()
        self.motion_copies = 0
        self.statuses = Counter()
        self.stops_written = []
        self.transport_failures = 0
        self.watchdog_fault_frames = 0
        self.expected_reboots = self.untold_reboots = 0
        self._nonce = self._boot = None
        self.connected()

    def status(self, event: StatusEvent, rig: Judge) -> None:
        """A status the host reported."""
        text = event.text
        self.statuses[text] += 1
        number = event.step
        if number is None:
            return
        seen = self.fates.setdefault(number, [])
        if any(s.startswith(_FINAL) for s in seen):
            rig.violate("fate", f"step {number} got {text!r} after its fate {seen}")
        elif text == "accepted" and "accepted" in seen:
            rig.violate("fate", f"step {number} accepted twice")
        elif text == "completed":
            seq = self.seq_of.get(number)
            if seq is None or self.ended.get(seq) != StepState.COMPLETED:
                how = "never sent" if seq is None else f"seq {seq}: {self.ended.get(seq)}"
                rig.violate(
                    "truthful",
                    f"step {number} reported completed, the controller did not complete it ({how})",
                )
        seen.append(text)

    def counts(self) -> dict[str, int]:
        """What happened, by name, for the soak's summary."""
        final = [s for fates in self.fates.values() for s in fates if s.startswith(_FINAL)]
        return {
            "steps": self.submitted,
            "completed": sum(1 for s in final if s == "completed"),
            "rejected": sum(1 for s in final if s.startswith("rejected:")),
            "aborted": sum(1 for s in final if s.startswith(("aborted:", "fault:"))),
            "motion_copies": self.motion_copies,
            "stops_written": len(self.stops_written),
            "reboots": self.controller_reboots,
            "watchdog_trips": self.watchdog_trips,
            "queue_full": self.queue_full,
            "excused_jumps": self.excused_jumps,
            "id_collisions": self.id_collisions,
        }


def final_checks(ledger: Ledger, diag: LinkDiagnostics, now: float) -> list[Violation]:
    """The checks at the end of a scenario (see the module docstring)."""
    out: list[Violation] = []

    def bad(rule: str, text: str) -> None:
        out.append(Violation(rule, now, text))

    for number in range(1, max(ledger.fates, default=0) + 1):
        fates = ledger.fates.get(number, [])
        if not any(s.startswith(_FINAL) for s in fates):
            bad("fate", f"step {number} has no fate ({fates})")
    sent = len(ledger.host_seqs)
    expect = {
        "steps_sent": sent,
        "retries": ledger.motion_copies - sent,
        "steps_completed": ledger.statuses["completed"],
        "steps_rejected": sum(n for s, n in ledger.statuses.items() if s.startswith("rejected:")),
        "steps_aborted": sum(
            n for s, n in ledger.statuses.items() if s.startswith("aborted:") or s == "fault:no_ack"
        ),
        "reconnects": ledger.transport_failures,
    }
    told = diag.reboots - ledger.expected_reboots
    if not 0 <= told <= ledger.untold_reboots:
        untold = f" and {ledger.untold_reboots} more it may tell" if ledger.untold_reboots else ""
        bad(
            "counters",
            f"reboots is {diag.reboots}, the simulator saw {ledger.expected_reboots}{untold}",
        )
    for name, value in expect.items():
        got = getattr(diag, name)
        if got != value:
            bad("counters", f"{name} is {got}, the simulator saw {value}")
    if diag.reboots > ledger.controller_reboots:
        bad("counters", f"reboots {diag.reboots} > the controller's {ledger.controller_reboots}")
    if diag.watchdog_trips > ledger.watchdog_trips:
        bad(
            "counters",
            f"watchdog_trips {diag.watchdog_trips} > the controller's {ledger.watchdog_trips} "
            f"trips ({ledger.watchdog_fault_frames} WATCHDOG FAULT frames delivered)",
        )
    if ledger.watchdog_fault_frames and not diag.watchdog_trips:
        bad("counters", "watchdog_trips 0 although a WATCHDOG FAULT frame was delivered")
    if not (
        ledger.expected_lost_frames - ledger.untold_gaps
        <= diag.lost_frames
        <= ledger.expected_lost_frames
    ):
        bad(
            "counters",
            f"lost_frames {diag.lost_frames}, the frame counter's gaps on this connection "
            f"less each reboot's say {ledger.expected_lost_frames}"
            + (
                f" (down to {ledger.expected_lost_frames - ledger.untold_gaps} for the reboots "
                "it may tell)"
                if ledger.untold_gaps
                else ""
            ),
        )
    if diag.lost_frames > ledger.frames_lost_to_host + ledger.untold_gaps:
        bad(
            "counters",
            f"lost_frames {diag.lost_frames} > the {ledger.frames_lost_to_host} frames lost on "
            "this connection"
            + (
                f" and {ledger.untold_gaps} of the reboots it may tell"
                if ledger.untold_gaps
                else ""
            ),
        )
    copies = len(ledger.stops_written) - len(set(ledger.stops_written))
    if diag.stop_repeats > copies:
        bad("counters", f"stop_repeats {diag.stop_repeats} > {copies} STOP copies beyond the first")
    return out
