"""Mutant host cores: :class:`~bridge.link.linkcore.LinkCore` with exactly one fix undone.

They measure the wire simulator (docs/sim.md, "Mutants"): a simulator that cannot find a
bug we know of cannot be trusted to find the ones we do not. Each mutant is a small
mixin that overrides one of the core's seams; the product holds no switch.
``tests/sim/test_mutants.py`` shows that the simulator finds each by itself, and that
the same scenario passes with the fix in place.

:data:`MUTANTS` maps each name to what it undoes; :func:`make_link_core` builds a core
with the named ones (``rover sim --mutant NAME``, repeatable).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

from bridge.link.linkcore import LinkCore, _Pending
from bridge.link.linktypes import LinkConfig
from firmware_proto.wire.faults import STOPPING_FAULTS, fault_bit
from firmware_proto.wire.message import Message
from firmware_proto.wire.messages import Fault, Heartbeat, Progress

__all__ = ["MUTANTS", "DecoderTotalReader", "LinkMutant", "make_link_core"]


@dataclass(frozen=True)
class LinkMutant:
    """One fix of the host core, undone.

    Attributes:
        name: what ``--mutant`` takes.
        undoes: the bug it brings back, one sentence.
        mixin: the class that overrides the core's seam (placed before
            :class:`LinkCore` in the bases).
    """

    name: str
    undoes: str
    mixin: type


class _SamplesOutsideSession(LinkCore):
    def _forwards(self, msg: Message) -> bool:
        return True


class _SettleByGuess(LinkCore):
    def _ended_by_progress(self, progress: Progress) -> list[int]:
        return [progress.ended_seq] if progress.ended_seq in self._in_controller else []

    def _settle_latched(self) -> None:
        return


class _WatchdogFrameTwice(LinkCore):
    def _new_watchdog_trip(self, msg: Fault) -> bool:
        return True


class _AutoClearAfterFaultFrame(LinkCore):
    def _stopping_fault_frame(self, code: int) -> None:
        self._last_stopping_fault = code


class _AutoClearSurvives(LinkCore):
    def _stopping_fault_frame(self, code: int) -> None:
        self._last_stopping_fault = code

    def _auto_clear_may_start(self, hb: Heartbeat) -> bool:
        return bool(hb.latch_watchdog)

    def _auto_clear_outlived(self, hb: Heartbeat) -> bool:
        return False


class _RefusedClearRetried(LinkCore):
    """``refused-clear-retried`` (:data:`MUTANTS`): protocol v3's rule."""

    _retry = False

    def _refuse_operator_clear(self, why: str) -> None:
        super()._refuse_operator_clear(why)
        self._retry = why == "fault_persists"

    def clear_stop(self, now: float) -> int:
        self._retry = False
        return super().clear_stop(now)

    def emergency_stop(self, source: int, now: float) -> int:
        self._retry = False
        return super().emergency_stop(source, now)

    def _maybe_clear(self, hb: Heartbeat, now: float) -> None:
        super()._maybe_clear(hb, now)
        stopping = any(hb.fault_bits & fault_bit(code) for code in STOPPING_FAULTS)
        if self._retry and self._pending_clear is None and hb.stop_latched and not stopping:
            self._retry = False
            self._stop_counter = self._stop_counter % 0xFFFF + 1
            self._pending_clear = _Pending(self._stop_counter, now, latch_gen=hb.latch_gen)


class _ClearDropsStop(LinkCore):
    """``clear-drops-stop`` (:data:`MUTANTS`): protocol v3's host."""

    def clear_stop(self, now: float) -> int:
        clear_id = super().clear_stop(now)
        self._pending_stop = None
        self._last_stop_id = None
        clear = self._pending_clear
        if clear is not None and clear.after_stop:
            clear.after_stop = False
            clear.latch_gen = (self._latch_gen or 0) + 1 & 0xFF
        return clear_id


class _StepRefusedDuringClear(LinkCore):
    """``step-refused-during-clear`` (:data:`MUTANTS`): protocol v3's host."""

    def _refusal(self) -> str | None:
        if self._operator_clear_out() and self.stop_latched:
            return "stop_latched"
        return super()._refusal()


class _ClearCopiesQueue(LinkCore):
    """``clear-copies-queue`` (:data:`MUTANTS`): protocol v3's host."""

    def tick(self, now: float) -> None:
        clear = self._pending_clear
        if clear is not None:
            clear.unwritten = 0
        super().tick(now)


class DecoderTotalReader(LinkCore):
    """``lost-from-read-total`` (:data:`MUTANTS`): protocol v3's bridge. The rig sets
    :attr:`decoder_lost` to read its decoder's total, as the old driver read its
    transport's."""

    decoder_lost: Callable[[], int] | None = None

    def on_frame(self, msg: Message, now: float, *, rx_seq: int | None = None) -> bool:
        if rx_seq is not None and self.decoder_lost is not None:
            self._rx_lost = self.decoder_lost()
            rx_seq = None
        return super().on_frame(msg, now, rx_seq=rx_seq)


class _BlindClearTakesFault(LinkCore):
    """``blind-clear-takes-fault`` (:data:`MUTANTS`)."""

    def _stopping_cause_reported(self) -> None:
        return


class _NonceFromIdentOnly(LinkCore):
    """``nonce-from-ident-only`` (:data:`MUTANTS`): protocol v3's bridge."""

    def _on_heartbeat(self, hb: Heartbeat, t: float, *, serial: bool = False) -> None:
        unknown = self._boot_nonce is None
        super()._on_heartbeat(hb, t, serial=serial)
        if unknown:
            self._boot_nonce = None


class _BootIdentIgnored(LinkCore):
    """``boot-ident-ignored`` (:data:`MUTANTS`): protocol v4's first bridge."""

    def _check_reboot(self, nonce: int, now: float, *, sign: str = "") -> bool:
        return super()._check_reboot(nonce, now)


class _RequestIdsFromOne(LinkCore):
    """``request-ids-from-one`` (:data:`MUTANTS`): protocol v3's bridge."""

    def __init__(self, config: LinkConfig, **options: int) -> None:
        options["first_request_id"] = 1
        super().__init__(config, **options)


MUTANTS: dict[str, LinkMutant] = {
    m.name: m
    for m in (
        LinkMutant(
            "auto-clear-survives",
            "an automatic clear survives a change of the latch's causes: a latch the watchdog "
            "holds is cleared once no stopping condition is active, whatever joined it, and a "
            "HEARTBEAT showing latch_stop or latch_fault does not end one (#22 bug 1 undone)",
            _AutoClearSurvives,
        ),
        LinkMutant(
            "samples-outside-session",
            "sensor samples are forwarded whatever the link state, also before the IDENT of "
            "a session told the boot nonce (#22 bug 2 undone)",
            _SamplesOutsideSession,
        ),
        LinkMutant(
            "settle-by-guess",
            "a step whose STATUS was lost stays open until a later step's STATUS settles it "
            "with that step's outcome, and PROGRESS settles only when it names an open step "
            "(a false 'completed', found by the simulator)",
            _SettleByGuess,
        ),
        LinkMutant(
            "watchdog-frame-twice",
            "every WATCHDOG FAULT frame counts a trip, also one received twice (a CAN frame "
            "sent again), found by the simulator",
            _WatchdogFrameTwice,
        ),
        LinkMutant(
            "refused-clear-retried",
            "an operator's clear answered FAULT_PERSISTS is kept and sent again (a new "
            "request) once a HEARTBEAT shows no stopping condition: the latch is released "
            "with no new command (issue #40, hole 2, protocol v3's rule)",
            _RefusedClearRetried,
        ),
        LinkMutant(
            "clear-drops-stop",
            "an operator's clear asked for before the STOP_ACK forgets the STOP: its "
            "STOP_ACK says nothing, 'stopped' is never published (issue #40, hole 3)",
            _ClearDropsStop,
        ),
        LinkMutant(
            "step-refused-during-clear",
            "a step submitted while an operator's clear is out is refused stop_latched "
            "instead of waiting for the clear's answer (issue #40, hole 4)",
            _StepRefusedDuringClear,
        ),
        LinkMutant(
            "clear-copies-queue",
            "CLEAR_STOP copies are queued every repeat interval behind a stalled writer and "
            "go out back to back when it resumes (issue #40, hole 7)",
            _ClearCopiesQueue,
        ),
        LinkMutant(
            "lost-from-read-total",
            "each frame's lost-frame count is the decoder's total after the read it came "
            "in: a reboot's frame-counter restart read with the old boot's last frame is "
            "counted as lost frames (issue #40, hole 6)",
            DecoderTotalReader,
        ),
        LinkMutant(
            "boot-ident-ignored",
            "a reboot is told by a changed boot nonce only: a boot IDENT (the serial frame "
            "counter restarted at 0) that repeats the nonce of the boot before is taken for "
            "an answer, so /odom jumps back to the restarted counts, the reboot is not "
            "counted and the counter's restart is counted as lost frames (issue #40, hole 5)",
            _BootIdentIgnored,
        ),
        LinkMutant(
            "request-ids-from-one",
            "a bridge numbers its STOP and CLEAR_STOP requests from 1 at every start instead "
            "of from a random id: a bridge started again repeats the ids of the one before "
            "on the same controller boot (issue #40, hole 8)",
            _RequestIdsFromOne,
        ),
        LinkMutant(
            "blind-clear-takes-fault",
            "an operator's clear asked for before the host knew any latch generation (a new "
            "bridge, a reboot) names the generation of a stopping fault reported after it, "
            "and releases that fault's latch (found by the simulator)",
            _BlindClearTakesFault,
        ),
        LinkMutant(
            "nonce-from-ident-only",
            "the first boot nonce is learned from an IDENT only: a bridge that read only "
            "HEARTBEATs of the old boot before the new boot's IDENT counts neither the "
            "reboot nor the restarted frame counter as one (found by the simulator)",
            _NonceFromIdentOnly,
        ),
        LinkMutant(
            "auto-clear-after-fault-frame",
            "an automatic clear goes on being repeated after a stopping FAULT frame arrived, "
            "until a HEARTBEAT shows the new cause (found by the simulator)",
            _AutoClearAfterFaultFrame,
        ),
    )
}
"""Every fix of the host core the simulator can undo, by name."""


def make_link_core(
    config: LinkConfig, mutants: Iterable[str] = (), *, first_request_id: int = 1
) -> LinkCore:
    """A host core with the fixes ``mutants`` undone (none: the product's core), whose
    first request id is ``first_request_id`` (a real bridge draws it at random).

    Raises:
        ValueError: an unknown mutant (the message lists the known ones).
    """
    names = sorted(set(mutants))
    unknown = [n for n in names if n not in MUTANTS]
    if unknown:
        raise ValueError(
            f"unknown link mutant(s) {', '.join(unknown)}; known: {', '.join(sorted(MUTANTS))}"
        )
    if not names:
        return LinkCore(config, first_request_id=first_request_id)
    bases = tuple(MUTANTS[n].mixin for n in names)
    cls = type("LinkCore_" + "_".join(n.replace("-", "_") for n in names), bases, {})
    core: LinkCore = cls(config, first_request_id=first_request_id)
    return core
