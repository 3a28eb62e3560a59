"""What a conformance rule works with: the wire host, the device's control port if any,
the rover description the controller drives, fresh sequence numbers and stop ids, and
the steps every rule shares (handshake, clear the latch, wait for the controller to be
idle).

Every wait goes through the host, and so through its clock: a rule is the same code in
real time and in lockstep (virtual time, :mod:`firmware_proto.linkio.clock`)."""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any, Protocol

from bridge.errors import RuleFailedError, RuleNotRunError
from bridge.tools.conformance.wirehost import WireHost
from firmware_proto.model.rover import RoverDescription, load_rover
from firmware_proto.wire.messages import (
    WATCHDOG_MS,
    ClearAck,
    ClearResult,
    ClearStop,
    ControllerState,
    Encoders,
    Heartbeat,
    Ident,
    Param,
    ParamResult,
    ParamValue,
    SetParam,
)

__all__ = ["REST_UNITS", "Context", "Control", "check"]

logger = logging.getLogger(__name__)

REST_UNITS = 3
"""Encoder counts that move less than this between two ENCODERS are at rest."""


def check(condition: bool, what: str) -> None:
    """Fail the rule with ``what`` unless ``condition`` holds.

    Raises:
        RuleFailedError: ``condition`` is false.
    """
    if not condition:
        raise RuleFailedError(what)


class Control(Protocol):
    """A device's control port: what makes it do what a host cannot cause.
    :class:`~bridge.tools.conformance.control.ControlClient` speaks to one over TCP; an
    in-process controller in lockstep offers the same ``inject``."""

    def inject(self, fault: str) -> dict[str, Any]:
        """Do ``fault`` now (``reboot``, ``encoder-dropout:left``, ``clear:stall``...).

        Raises:
            ConformanceError or InjectionError: refused, or the port failed.
        """


class Context:
    """One controller under test; shared by the rules of one run."""

    def __init__(
        self,
        host: WireHost,
        control: Control | None = None,
        rover: RoverDescription | None = None,
    ) -> None:
        """Args:
        host: the open wire host.
        control: the device's control port, if it has one.
        rover: the rover description the controller drives (its acceleration limit,
            units and speed scale); default: the packaged one.
        """
        self.host = host
        self.control = control
        self.rover = rover or load_rover()
        self._seq = 0x4000
        self._stop_id = 0x7000
        self.last_clear: ClearStop | None = None
        """The last CLEAR_STOP :meth:`clear_ack` had answered."""
        self._watchdog_ms: int | None = None

    def seq(self) -> int:
        """A MOTION seq not used before in this run."""
        self._seq = self._seq % 0xFFFF + 1
        return self._seq

    def stop_id(self) -> int:
        """A STOP or CLEAR_STOP id not used before in this run (never 0)."""
        self._stop_id = self._stop_id % 0xFFFF + 1
        return self._stop_id

    def require_control(self, what: str) -> Control:
        """The control port, for a rule that needs the device to ``what``.

        Raises:
            RuleNotRunError: none was given (``--control``).
        """
        if self.control is None:
            raise RuleNotRunError(
                f"needs the device's control port (--control HOST:PORT) to {what}"
            )
        return self.control

    def require_serial(self, why: str) -> None:
        """Raises :class:`RuleNotRunError` unless the link is serial."""
        if self.host.kind != "serial":
            raise RuleNotRunError(f"needs a serial link: {why}")

    # -- shared steps ---------------------------------------------------------------------
    def handshake(self) -> Ident:
        """HELLO with our version and schema hash; the IDENT, checked to match, and a
        HEARTBEAT with ``handshake_ok`` 1 after it."""
        ident = self.host.handshake(timeout_s=1.0)
        mismatch = self.host.matches(ident)
        check(not mismatch, f"{mismatch}: nothing else can be checked")
        self.host.heartbeat_where("handshake_ok 1", lambda hb: bool(hb.handshake_ok))
        return ident

    def clear(self, expected: int = ClearResult.CLEARED) -> ClearAck:
        """CLEAR_STOP; its CLEAR_ACK, checked to answer ``expected``."""
        clear_id = self.stop_id()
        ack = self.clear_ack(clear_id)
        check(
            ack.result == expected,
            f"CLEAR_STOP answered {ClearResult(ack.result).name}, expected "
            f"{ClearResult(expected).name}",
        )
        return ack

    def clear_ack(self, clear_id: int, latch_gen: int | None = None) -> ClearAck:
        """CLEAR_STOP ``clear_id`` naming ``latch_gen``; its CLEAR_ACK, whatever it says.

        Without ``latch_gen`` it names the generation the last frame told
        (:attr:`ProtocolHost.latch_gen`), and a LATCH_CHANGED answer is followed by one
        new request naming the generation that answer gives (the suite tests a
        controller, not an operator). :attr:`last_clear` is the request answered."""
        msg = ClearStop(clear_id, self.host.latch_gen if latch_gen is None else latch_gen)
        ack = self.send_clear(msg)
        if latch_gen is None and ack.result == ClearResult.LATCH_CHANGED:
            msg = ClearStop(self.stop_id(), ack.latch_gen)
            ack = self.send_clear(msg)
        self.last_clear = msg
        return ack

    def send_clear(self, msg: ClearStop) -> ClearAck:
        """Send ``msg`` (a repeat too); its CLEAR_ACK, whatever it says."""
        return self.host.clear_stop(msg.stop_id, latch_gen=msg.latch_gen)

    def prepare(self) -> Heartbeat:
        """A fresh session with no latch and nothing queued, the wheels at rest: HELLO
        (aborts whatever ran), CLEAR_STOP if latched, a HEARTBEAT showing IDLE, two
        ENCODERS in a row that did not count. Fails the rule if the controller cannot
        get there (a fault whose condition persists, wheels that do not stop)."""
        self.handshake()
        hb = self.host.heartbeat()
        if hb.stop_latched:
            ack = self.clear_ack(self.stop_id())
            check(
                ack.result != ClearResult.FAULT_PERSISTS,
                "the controller is latched with an active stopping fault (CLEAR_STOP "
                f"answered FAULT_PERSISTS; fault_bits 0x{hb.fault_bits:02X}): clear it first",
            )
        idle = self.idle()
        self.at_rest()
        return idle

    def at_rest(self, timeout_s: float = 3.0) -> Encoders:
        """The first ENCODERS from now on whose counts moved less than
        :data:`REST_UNITS` on each side since the one before."""
        previous: list[Encoders] = []

        def still(e: Encoders) -> bool:
            last = previous[0] if previous else None
            previous[:] = [e]
            return last is not None and all(
                abs(((b - a + (1 << 23)) % (1 << 24)) - (1 << 23)) < REST_UNITS
                for a, b in ((last.left, e.left), (last.right, e.right))
            )

        return self.host.expect(
            Encoders,
            still,
            since=self.host.mark(),
            timeout_s=timeout_s,
            what="two ENCODERS in a row that did not count (the wheels at rest)",
        )

    def idle(self, timeout_s: float = 3.0) -> Heartbeat:
        """The first HEARTBEAT that shows IDLE, unlatched, nothing queued."""
        return self.host.heartbeat_where(
            "state IDLE, not latched, queue empty",
            _is_idle,
            timeout_s=timeout_s,
        )

    def param(self, param: int, value: int) -> ParamValue:
        """SET_PARAM; its PARAM_VALUE (param echoed)."""
        mark = self.host.send(SetParam(param, value), strict=False)
        return self.host.expect(
            ParamValue,
            lambda p: p.param == param,
            since=mark,
            what=f"PARAM_VALUE for param {param}",
        )

    def watchdog_ms(self) -> int:
        """The controller's watchdog in force, asked without changing it (an out-of-range
        SET_PARAM answers with the value in force); else the protocol's default."""
        if self._watchdog_ms is None:
            answer = self.param(Param.WATCHDOG_MS, 0)
            good = answer.result == ParamResult.OUT_OF_RANGE and answer.value > 0
            self._watchdog_ms = answer.value if good else WATCHDOG_MS
        return self._watchdog_ms

    def until(self, what: str, pred: Callable[[Heartbeat], bool], timeout_s: float = 3.0) -> None:
        """Wait for a HEARTBEAT for which ``pred`` holds."""
        self.host.heartbeat_where(what, pred, timeout_s=timeout_s)


def _is_idle(hb: Heartbeat) -> bool:
    return (
        hb.state == ControllerState.IDLE
        and not hb.stop_latched
        and hb.queue_depth == 0
        and bool(hb.handshake_ok)
    )
