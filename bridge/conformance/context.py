"""What a conformance rule works with: the wire host, the device's control port if any,
fresh sequence numbers and stop ids, and the steps every rule shares (handshake, clear
the latch, wait for the controller to be idle)."""

from __future__ import annotations

import logging
from collections.abc import Callable

from bridge.conformance.control import ControlClient
from bridge.conformance.host import WireHost
from bridge.errors import RuleFailedError, RuleNotRunError
from firmware_proto.messages import (
    PROTOCOL_VERSION,
    SCHEMA_HASH,
    WATCHDOG_MS,
    ClearAck,
    ClearResult,
    ClearStop,
    ControllerState,
    Heartbeat,
    Hello,
    Ident,
    Param,
    ParamResult,
    ParamValue,
    SetParam,
)

__all__ = ["Context", "check"]

logger = logging.getLogger(__name__)


def check(condition: bool, what: str) -> None:
    """Fail the rule with ``what`` unless ``condition`` holds.

    Raises:
        RuleFailedError: ``condition`` is false.
    """
    if not condition:
        raise RuleFailedError(what)


class Context:
    """One controller under test; shared by the rules of one run."""

    def __init__(self, host: WireHost, control: ControlClient | None = None) -> None:
        self.host = host
        self.control = control
        self._seq = 0x4000
        self._stop_id = 0x7000
        self._watchdog_ms: int | None = None

    def seq(self) -> int:
        """A MOTION seq not used before in this run."""
        self._seq = self._seq % 0xFFFF + 1
        return self._seq

    def stop_id(self) -> int:
        """A STOP or CLEAR_STOP id not used before in this run (never 0)."""
        self._stop_id = self._stop_id % 0xFFFF + 1
        return self._stop_id

    def require_control(self, what: str) -> ControlClient:
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
        mark = self.host.send(Hello(PROTOCOL_VERSION, SCHEMA_HASH))
        ident = self.host.expect(Ident, "IDENT in answer to HELLO", since=mark)
        check(
            (ident.protocol_version, ident.schema_hash) == (PROTOCOL_VERSION, SCHEMA_HASH),
            f"IDENT v{ident.protocol_version}/0x{ident.schema_hash:04X} does not match this "
            f"host's v{PROTOCOL_VERSION}/0x{SCHEMA_HASH:04X}: nothing else can be checked",
        )
        self.host.heartbeat_where("handshake_ok 1", lambda hb: bool(hb.handshake_ok))
        return ident

    def clear(self, expected: int = ClearResult.CLEARED) -> ClearAck:
        """CLEAR_STOP; its CLEAR_ACK, checked to answer ``expected``."""
        clear_id = self.stop_id()
        mark = self.host.send(ClearStop(clear_id))
        ack = self.host.expect(
            ClearAck,
            f"CLEAR_ACK for stop_id {clear_id}",
            since=mark,
            where=lambda a: a.stop_id == clear_id,
        )
        check(
            ack.result == expected,
            f"CLEAR_STOP answered {ClearResult(ack.result).name}, expected "
            f"{ClearResult(expected).name}",
        )
        return ack

    def prepare(self) -> Heartbeat:
        """A fresh session with no latch and nothing queued: HELLO (aborts whatever ran),
        CLEAR_STOP if latched, then a HEARTBEAT showing IDLE. Fails the rule if the
        controller cannot get there (a fault whose condition persists)."""
        self.handshake()
        hb = self.host.heartbeat()
        if hb.stop_latched:
            clear_id = self.stop_id()
            mark = self.host.send(ClearStop(clear_id))
            ack = self.host.expect(
                ClearAck, "CLEAR_ACK", since=mark, where=lambda a: a.stop_id == clear_id
            )
            check(
                ack.result != ClearResult.FAULT_PERSISTS,
                "the controller is latched with an active stopping fault (CLEAR_STOP "
                f"answered FAULT_PERSISTS; fault_bits 0x{hb.fault_bits:02X}): clear it first",
            )
        return self.idle()

    def idle(self, timeout_s: float = 3.0) -> Heartbeat:
        """The first HEARTBEAT that shows IDLE, unlatched, nothing queued."""
        return self.host.heartbeat_where(
            "state IDLE, not latched, queue empty",
            _is_idle,
            timeout_s=timeout_s,
        )

    def param(self, param: int, value: int) -> ParamValue:
        """SET_PARAM; its PARAM_VALUE (param echoed)."""
        mark = self.host.send_unchecked(SetParam(param, value))
        return self.host.expect(
            ParamValue,
            f"PARAM_VALUE for param {param}",
            since=mark,
            where=lambda p: p.param == param,
        )

    def watchdog_ms(self) -> int:
        """The controller's watchdog in force, asked without changing it (a value out of
        range is refused with the value in force); the protocol's default if it does not
        say."""
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
