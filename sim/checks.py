"""The invariants of the wire simulator, and the ledger of what it saw on both sides.

Checked as they happen (by :class:`sim.rig.Rig`):

- ``once``: no step runs twice (the controller starts each MOTION seq at most once);
- ``fate``: every step the host took ends exactly once, with one final status
  (``completed``, ``rejected:...``, ``aborted:...``, ``fault:no_ack``), ``accepted`` at
  most once before it and nothing after it;
- ``truthful``: a step the host reports ``completed`` was completed by the controller;
- ``stop-zeroes``: a STOP that reaches the controller has its wheel targets at zero when
  it has been handled (the same tick);
- ``auto-clear``: an automatic CLEAR_STOP of the host never releases a latch that holds
  anything but the watchdog (docs/protocol.md, "Latch and faults");
- ``release``: a latch is released only by a clear someone asked for, and a watchdog trip
  or a stopping fault in it only by an operator's clear asked for after the host had
  heard of it (issue #40: no request made before the fault releases it);
- ``stopped``: every operator STOP whose STOP_ACK reached the host is said ``stopped``;
- ``order``: a step submitted while an operator's clear is out is not refused
  ``stop_latched`` when that clear releases the latch;
- ``repeat``: copies of one CLEAR_STOP reach the wire at least ``stop_repeat_s`` apart;
- ``odometry``: between two ENCODERS it uses, odometry never moves more than the
  encoders travelled (continuous across reboots; a v2 controller's sample of a boot the
  host could not know yet is excused and counted, see docs/sim.md);
- ``never-stuck``: after the last fault ends, a new step completes within
  :data:`sim.rig.RECOVERY_S`.

Checked at the end (:func:`final_checks`): every step has its fate, and the host's
counters (``/diagnostics``) agree with what the simulator saw: ``steps_sent`` and
``retries`` with the MOTION frames written, ``steps_completed``, ``steps_rejected`` and
``steps_aborted`` with the statuses, ``reboots`` with the boot nonces delivered (and no
more than the controller's reboots), ``reconnects`` with the transport failures caused,
``watchdog_trips`` no more than the controller's trips (a frame received twice is not
two trips) and not 0 once a WATCHDOG FAULT frame arrived (a trip whose every trace was
lost cannot be counted), ``lost_frames`` no more than the frames lost on this connection,
``stop_repeats`` no more than the STOP copies written beyond the first of each id.

Pure: no I/O, no clock.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import Protocol

from bridge.link.linktypes import LinkDiagnostics, StatusEvent
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
    "odometry",
    "never-stuck",
    "counters",
    "crash",
)
"""Every invariant by name (docs/sim.md)."""

_FINAL = ("completed", "rejected:", "aborted:", "fault:no_ack")


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
    """MOTION seq of each step number, from the frames the host wrote."""
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
    _nonce: int | None = None

    # -- the controller's side -----------------------------------------------------------
    def controller_status(self, msg: Status, now: float, rig: Judge) -> None:
        """A STATUS the controller sent."""
        if msg.state == StepState.STARTED:
            self.starts[msg.seq] += 1
            if self.starts[msg.seq] > 1:
                rig.violate("once", f"MOTION seq {msg.seq} started a second time")
        else:
            self.ended[msg.seq] = msg.state

    # -- the host's side -------------------------------------------------------------------
    def motion_written(self, seq: int, number: int | None) -> None:
        """The host wrote a MOTION frame (a first copy or a retransmission)."""
        self.motion_copies += 1
        if number is not None:
            self.seq_of[number] = seq

    def nonce_delivered(self, msg: Heartbeat | Ident) -> None:
        """A HEARTBEAT or IDENT reached the host: a boot nonce it learns or a reboot it
        must count (the first nonce is an IDENT's)."""
        if self._nonce is None:
            if isinstance(msg, Ident):
                self._nonce = msg.boot_nonce
        elif msg.boot_nonce != self._nonce:
            self._nonce = msg.boot_nonce
            self.expected_reboots += 1

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
    sent = len(set(ledger.seq_of.values()))
    expect = {
        "steps_sent": sent,
        "retries": ledger.motion_copies - sent,
        "steps_completed": ledger.statuses["completed"],
        "steps_rejected": sum(n for s, n in ledger.statuses.items() if s.startswith("rejected:")),
        "steps_aborted": sum(
            n for s, n in ledger.statuses.items() if s.startswith("aborted:") or s == "fault:no_ack"
        ),
        "reboots": ledger.expected_reboots,
        "reconnects": ledger.transport_failures,
    }
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
    if diag.lost_frames > ledger.frames_lost_to_host:
        bad(
            "counters",
            f"lost_frames {diag.lost_frames} > the {ledger.frames_lost_to_host} frames lost on "
            "this connection",
        )
    copies = len(ledger.stops_written) - len(set(ledger.stops_written))
    if diag.stop_repeats > copies:
        bad("counters", f"stop_repeats {diag.stop_repeats} > {copies} STOP copies beyond the first")
    return out
