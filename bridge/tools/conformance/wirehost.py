"""The conformance suite's host: the scripted protocol host with a log per rule.

:class:`WireHost` is a :class:`~firmware_proto.linkio.host.ProtocolHost` (any endpoint
on the host's side, the wall clock or a lockstep clock) that also keeps, for the report,
every frame sent and received while a rule runs (:class:`FrameRecord`), sensor samples
counted rather than listed. How it awaits is the protocol host's (``expect``,
``absent``...); nothing here knows a rule (:mod:`bridge.tools.conformance.rules`).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

from firmware_proto.linkio.clock import WALL, Clock
from firmware_proto.linkio.endpoint import Endpoint
from firmware_proto.linkio.host import HEARTBEAT_S, ProtocolHost, Received
from firmware_proto.wire.messages import Encoders, Imu, PoseMsg, WheelSpeeds

__all__ = ["SAMPLES", "FrameRecord", "WireHost"]

SAMPLES = (Encoders, WheelSpeeds, Imu, PoseMsg)
"""Sensor samples: counted in a rule's log, not listed."""

KEEP = 100_000
"""Received messages kept for the rules: about 9 min at protocol rates (halved past twice that)."""


@dataclass(frozen=True)
class FrameRecord:
    """One frame of a rule's exchange.

    Attributes:
        t_s: seconds since the rule started (host clock).
        direction: ``"H>C"`` (sent by the host) or ``"C>H"``.
        text: the message, fields by name (``MOTION seq=3 command=FWD ...``), or the
            raw frame (``RAW id=8 payload=0a0b0c``) for unchecked frames.
    """

    t_s: float
    direction: str
    text: str

    def line(self) -> str:
        """``  0.0123 H>C MOTION seq=3 ...``."""
        return f"{self.t_s:8.4f} {self.direction} {self.text}"


class WireHost(ProtocolHost):
    """A protocol host that logs each rule's frames (see the module docstring); the
    arguments are :class:`ProtocolHost`'s (``keep`` defaults to :data:`KEEP`)."""

    def __init__(
        self,
        endpoint: Endpoint,
        *,
        clock: Clock = WALL,
        heartbeat_s: float | None = HEARTBEAT_S,
        timeout_scale: float = 1.0,
        keep: int | None = KEEP,
    ) -> None:
        super().__init__(
            endpoint,
            clock=clock,
            heartbeat_s=heartbeat_s,
            timeout_scale=timeout_scale,
            keep=keep,
        )
        self._log_lock = threading.Lock()
        self._sent_log: list[FrameRecord] = []
        self._log_mark = 0
        self._t0 = self.clock.now()

    def start_log(self) -> None:
        """Start a new rule's frame log (and its clock)."""
        with self._log_lock:
            self._sent_log = []
            self._log_mark = self.mark()
            self._t0 = self.clock.now()

    def _sent(self, note: str) -> None:
        with self._log_lock:
            self._sent_log.append(FrameRecord(self._at(self.clock.now()), "H>C", note))

    def _at(self, t: float) -> float:
        return round(t - self._t0, 6)

    def take_log(self) -> tuple[tuple[FrameRecord, ...], int]:
        """The frames logged since :meth:`start_log` in time order (sent before received
        at the same instant), and the sensor samples counted."""
        received: list[Received] = self.inbox.items(self._log_mark)
        samples = sum(isinstance(r.message, SAMPLES) for r in received)
        with self._log_lock:
            sent = list(self._sent_log)
        got = [
            FrameRecord(self._at(r.arrived), "C>H", r.message.describe())
            for r in received
            if not isinstance(r.message, SAMPLES)
        ]
        merged = sorted(
            [(f.t_s, 0, i, f) for i, f in enumerate(sent)]
            + [(f.t_s, 1, i, f) for i, f in enumerate(got)]
        )
        return tuple(f for *_, f in merged), samples
