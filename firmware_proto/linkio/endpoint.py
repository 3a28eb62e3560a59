"""One end of the wire: protocol messages over a medium, for either side of the link
(docs/linkio.md).

An :class:`Endpoint` turns messages into frames on a medium and back, the same way at
both ends: the bridge's transports use ``side=HOST``, the emulator's front ends
``side=CONTROLLER``. The side decides what is taken in (on CAN, a controller takes its
own node's frames and broadcasts) and which way a written frame is logged.

An endpoint is synchronous and owns no thread: threads and queues are the owner's
policy, as with python-can's ``Bus`` and ``Notifier``.

**Listeners** get every frame written (just before it goes out, so an answer cannot be
logged ahead of it) and every frame received. A listener that raises is logged once and
called again with the next frame: the link never fails because its log did.

A medium subclasses :class:`Endpoint`, fills ``_open``, ``_close``, ``read``, ``write``
and, where it can, ``write_raw`` and ``write_record``, and hands frames to
:meth:`Endpoint._emit`.
"""

from __future__ import annotations

import logging
import random
from abc import ABC, abstractmethod
from types import TracebackType
from typing import Final, Literal

from firmware_proto.linkio.trafficlog import (
    CONTROLLER_TO_HOST,
    HOST_TO_CONTROLLER,
    TrafficRecord,
    TrafficRecorder,
)
from firmware_proto.wire.counters import RxCounters
from firmware_proto.wire.message import Message

__all__ = ["CONTROLLER", "HOST", "SIDES", "Endpoint", "Side"]

logger = logging.getLogger(__name__)

Side = Literal["host", "controller"]
HOST: Final = "host"
"""The bridge's end, or any host: sends requests, takes the controller's messages."""
CONTROLLER: Final = "controller"
"""The motor controller's end (the emulator): takes requests, sends telemetry."""
SIDES: tuple[Side, ...] = (HOST, CONTROLLER)

_TAKES = {HOST: "controller_to_host", CONTROLLER: "host_to_controller"}
_SENDS = {HOST: HOST_TO_CONTROLLER, CONTROLLER: CONTROLLER_TO_HOST}


class Endpoint(ABC):
    """One side's end of the link on one medium (see the module docstring).

    Attributes:
        side: :data:`HOST` or :data:`CONTROLLER`.
        counters: the decoder's receive counters (frames, bytes, rejects by cause).
        foreign: frames decoded but not for this side (another node's, our own kind
            echoed back on a bus).
    """

    medium = "medium"
    """``serial`` or ``can``: the traffic-log medium of this endpoint."""

    def __init__(self, side: Side, *, recorder: TrafficRecorder | None = None) -> None:
        """Args:
        side: which end of the link this is (ValueError if not one of :data:`SIDES`).
        recorder: a first listener (a traffic log); the caller keeps ownership.
        """
        if side not in SIDES:
            raise ValueError(f"side must be one of {', '.join(SIDES)}, got {side!r}")
        self.side: Side = side
        self.counters = RxCounters()
        self.foreign = 0
        self._listeners: list[TrafficRecorder] = [] if recorder is None else [recorder]
        self._failed: set[int] = set()
        """ids of the listeners that raised (each is logged once)."""

    # -- what the side decides ------------------------------------------------------
    def takes(self, message: Message) -> bool:
        """Whether this side takes ``message`` in (its direction is towards us)."""
        return _TAKES[self.side] == message.DIRECTION

    @property
    def sends(self) -> str:
        """The traffic-log direction of the frames this side writes."""
        return _SENDS[self.side]

    # -- listeners ----------------------------------------------------------------------
    def add_listener(self, listener: TrafficRecorder) -> None:
        """Hand every frame sent and received to ``listener`` from now on (called on the
        writing thread for frames sent, on the reading thread for frames received)."""
        self._listeners = [*self._listeners, listener]

    def remove_listener(self, listener: TrafficRecorder) -> None:
        """Stop handing frames to ``listener`` (no error if it was not there)."""
        self._listeners = [x for x in self._listeners if x is not listener]

    @property
    def recording(self) -> bool:
        """Whether any listener wants frames (build records only then)."""
        return bool(self._listeners)

    def _emit(self, record: TrafficRecord) -> None:
        for listener in self._listeners:
            try:
                listener.record(record)
            except Exception:
                if id(listener) not in self._failed:
                    self._failed.add(id(listener))
                    logger.exception(
                        "%s: traffic recorder failed (logged once; the link carries on)",
                        self.name,
                    )

    # -- the medium ---------------------------------------------------------------------
    @property
    @abstractmethod
    def name(self) -> str:
        """What this endpoint is on, for messages: a device path, ``interface:channel``."""

    @property
    def medium_state(self) -> str:
        """The medium's own condition: ``ok`` unless it knows better (CAN: its
        fault-confinement state). ``ok`` and ``error_active`` are healthy."""
        return "ok"

    @property
    def medium_errors(self) -> int:
        """Errors the medium itself reported (CAN: error frames)."""
        return 0

    @property
    def can_corrupt(self) -> bool:
        """Whether a damaged frame can reach the other end (CAN's own CRC stops one)."""
        return True

    def open(self) -> None:
        """Acquire the medium. Raises OSError (or a subclass) when it cannot be had."""
        self._open()

    def restart_counter(self) -> None:  # noqa: B027 (a hook: most media have no counter)
        """The sender rebooted: its frame counter starts again at 0 (docs/protocol.md,
        Serial framing). Media without a frame counter (CAN) have nothing to do."""

    def close(self) -> None:
        """Release the medium (idempotent)."""
        self._close()

    @abstractmethod
    def _open(self) -> None: ...

    @abstractmethod
    def _close(self) -> None: ...

    @abstractmethod
    def read(self, timeout_s: float) -> list[Message]:
        """Wait up to ``timeout_s`` for frames; return the messages this side takes, in
        the order received. Malformed frames are counted in :attr:`counters` and dropped.

        Raises:
            OSError: the medium is gone (device unplugged, bus off on the host side).
        """

    def read_numbered(self, timeout_s: float) -> list[tuple[Message, int | None]]:
        """Like :meth:`read`, each message with the sender's frame counter: the serial
        frame's ``seq``, or ``None`` on a medium without one (CAN)."""
        return [(message, None) for message in self.read(timeout_s)]

    def read_ready(self) -> list[tuple[Message, int | None]]:
        """Everything that has arrived, without waiting: :meth:`read_numbered` with no timeout
        until the counters stop moving (a CAN read takes one frame at a time, and a frame not
        for us returns nothing but still counts).

        Raises:
            OSError: the medium is gone.
        """
        out: list[tuple[Message, int | None]] = []
        while True:
            before = self._rx_progress()
            got = self.read_numbered(0.0)
            if got:
                out += got
            elif self._rx_progress() == before:
                return out

    def _rx_progress(self) -> tuple[int, ...]:
        c = self.counters
        return (c.bytes, c.frames, c.rejected, self.foreign, self.medium_errors)

    @abstractmethod
    def write(self, message: Message, *, corrupt: random.Random | None = None) -> bool:
        """Send one message now, on the calling thread; ``corrupt`` damages the frame with that
        generator (link-fault injection, only where :attr:`can_corrupt`).

        Returns:
            False when the medium dropped the frame without failing (a pty nobody has open).

        Raises:
            OSError: the write failed (device gone, bus off, send timeout).
        """

    def write_raw(self, msg_id: int, payload: bytes, *, bad_crc: bool = False) -> None:
        """Send an unchecked frame (a conformance host's malformed input); not logged.

        Raises:
            OSError: the write failed.
            ValueError: this medium cannot carry such a frame.
        """
        raise ValueError(f"a {self.medium} endpoint cannot send raw frames")

    @abstractmethod
    def write_record(self, record: TrafficRecord) -> None:
        """Put a recorded frame on the medium again, exactly as recorded (a replay).

        Raises:
            TypeError: the record is of another medium.
            OSError: the write failed.
        """

    def __enter__(self) -> Endpoint:
        self.open()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
