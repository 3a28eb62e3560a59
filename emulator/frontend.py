"""Front ends carry protocol messages between the controller model and a host.

:class:`FrontEnd` does the shared work: the reader thread's lifecycle, link faults
(drop, corrupt, delay) drawn from a seeded generator, delayed delivery, counters, and a
write lock. An implementation (:mod:`emulator.serial_frontend`,
:mod:`emulator.can_frontend`) fills four hooks:

- ``_open()``: acquire the medium (called by :meth:`FrontEnd.start`);
- ``_read(timeout_s)``: wait at most ``timeout_s`` for input and return the messages
  received (decoding is pure: a :class:`~firmware_proto.framing.FrameDecoder` or
  :class:`~firmware_proto.canmap.CanDecoder`); called only by the reader thread;
- ``_write(message, corrupt)``: send one message, damaged if ``corrupt`` (serial flips a
  bit; a medium that cannot corrupt refuses the fault in ``_can_corrupt``);
- ``_close()``: release the medium (idempotent).

An implementation also hands every frame it puts on the medium and every frame it
receives to ``_record`` when :attr:`FrontEnd.recorder` is set (traffic logs,
docs/traffic-logs.md).

The reader thread does I/O only: it hands each received message, with the monotonic
time it arrived, to the ``deliver`` callback given to :meth:`FrontEnd.start`.
"""

from __future__ import annotations

import heapq
import itertools
import logging
import random
import threading
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from types import TracebackType

from emulator.errors import InjectionError
from firmware_proto.message import Message
from firmware_proto.trafficlog import RecordingEdge, TrafficRecorder

__all__ = ["MAX_LINK_DELAY_S", "Deliver", "FrontEnd", "FrontEndStats"]

logger = logging.getLogger(__name__)

MAX_LINK_DELAY_S = 10.0
"""Longest injected link delay, s."""

Deliver = Callable[[Message, float], None]
"""Called by the reader thread with each received message and its arrival time
(``time.monotonic()``)."""


@dataclass
class FrontEndStats:
    """What crossed the front end. Counts only grow.

    Attributes:
        rx_messages: valid messages delivered to the controller.
        tx_messages: messages handed to the medium.
        tx_dropped: messages the medium could not take (no reader on a pty, bus full).
        fault_dropped: messages dropped by an injected link fault (both directions).
        fault_corrupted: messages corrupted by an injected link fault.
    """

    rx_messages: int = 0
    tx_messages: int = 0
    tx_dropped: int = 0
    fault_dropped: int = 0
    fault_corrupted: int = 0


class FrontEnd(RecordingEdge, ABC):
    """Base of the pty and CAN front ends; see the module docstring for the hooks."""

    name = "front end"

    def __init__(self, *, seed: int = 0, recorder: TrafficRecorder | None = None) -> None:
        """Args:
        seed: seeds the link-fault generators.
        recorder: where every frame sent and received goes (a traffic log); the caller
            keeps ownership and closes it after the front end.
        """
        self.stats = FrontEndStats()
        self.recorder = recorder
        # One generator per direction: each thread draws from its own, reproducibly.
        self._rng_tx = random.Random(f"link-faults-tx-{seed}")
        self._rng_rx = random.Random(f"link-faults-rx-{seed}")
        self._rx_corrupted = 0
        self._drop = 0.0
        self._corrupt = 0.0
        self._delay_s = 0.0
        self._write_lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._deliver: Deliver | None = None
        self._delayed_in: list[tuple[float, int, Message]] = []
        self._delayed_out: list[tuple[float, int, Message]] = []
        self._counter = itertools.count()
        self._closed = False

    # -- hooks ------------------------------------------------------------------------
    @abstractmethod
    def _open(self) -> None:
        """Acquire the medium."""

    @abstractmethod
    def _read(self, timeout_s: float) -> list[Message]:
        """Wait up to ``timeout_s`` for input; return the messages received."""

    @abstractmethod
    def _write(self, message: Message, corrupt: bool) -> bool:
        """Send one message (damaged if ``corrupt``); False if the medium dropped it."""

    @abstractmethod
    def _close(self) -> None:
        """Release the medium (idempotent)."""

    def _edge_name(self) -> str:
        return self.name

    def _can_corrupt(self) -> bool:
        """Whether this medium can deliver a damaged frame (CAN's own CRC cannot)."""
        return True

    @property
    def rx_errors(self) -> int:
        """Bad frames dropped so far: by the decoder, and damaged by an injected fault."""
        return self._rx_corrupted + self._decoder_rejects()

    def _decoder_rejects(self) -> int:
        """Frames the implementation's decoder rejected (override)."""
        return 0

    # -- lifecycle ----------------------------------------------------------------------
    def start(self, deliver: Deliver) -> None:
        """Open the medium and start the reader thread."""
        if self._thread is not None:
            raise RuntimeError(f"{self.name} already started")
        self._deliver = deliver
        self._open()
        self._thread = threading.Thread(
            target=self._reader, name=f"{self.name}-reader", daemon=True
        )
        self._thread.start()

    def close(self) -> None:
        """Stop the reader thread and release the medium (idempotent)."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5.0)
            if self._thread.is_alive():
                logger.error("%s reader did not stop within 5 s", self.name)
        self._thread = None
        if not self._closed:
            self._closed = True
            with self._write_lock:
                self._close()

    def __enter__(self) -> FrontEnd:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    # -- link faults --------------------------------------------------------------------
    def check_link_faults(
        self,
        *,
        drop: float | None = None,
        corrupt: float | None = None,
        delay_s: float | None = None,
    ) -> None:
        """Whether these link fault levels can apply; changes nothing. ``None`` is not
        checked.

        Raises:
            InjectionError: a ratio outside 0..1, a delay outside
                0..:data:`MAX_LINK_DELAY_S` s, or corruption on a medium that cannot
                deliver damaged frames (CAN).
        """
        for kind, ratio in (("link-drop", drop), ("link-corrupt", corrupt)):
            if ratio is not None and not 0.0 <= ratio <= 1.0:
                raise InjectionError(f"{kind} ratio must be in 0..1, got {ratio:g}")
        if delay_s is not None and not 0.0 <= delay_s <= MAX_LINK_DELAY_S:
            raise InjectionError(
                f"link-delay must be in 0..{MAX_LINK_DELAY_S:g} s, got {delay_s:g}"
            )
        if corrupt and not self._can_corrupt():
            raise InjectionError(
                f"link-corrupt cannot apply on {self.name}: the medium's own CRC rejects damaged "
                "frames; use link-drop instead"
            )

    def set_link_faults(
        self,
        *,
        drop: float | None = None,
        corrupt: float | None = None,
        delay_s: float | None = None,
    ) -> None:
        """Set injected link faults; ``None`` leaves a level unchanged.

        Raises:
            InjectionError: see :meth:`check_link_faults`; nothing is changed then.
        """
        self.check_link_faults(drop=drop, corrupt=corrupt, delay_s=delay_s)
        if drop is not None:
            self._drop = drop
        if corrupt is not None:
            self._corrupt = corrupt
        if delay_s is not None:
            self._delay_s = delay_s

    def _fate(self, rng: random.Random) -> tuple[bool, bool]:
        """(drop, corrupt) for the next message, drawn from a seeded generator."""
        drop = self._drop > 0.0 and rng.random() < self._drop
        corrupt = not drop and self._corrupt > 0.0 and rng.random() < self._corrupt
        return drop, corrupt

    # -- transmit -----------------------------------------------------------------------
    def send(self, messages: Sequence[Message]) -> None:
        """Send messages to the host in order, through the injected link faults.

        Called from the control thread. Delayed messages go out from :meth:`flush_due`.
        """
        for msg in messages:
            drop, corrupt = self._fate(self._rng_tx)
            if drop:
                self.stats.fault_dropped += 1
                continue
            if self._delay_s > 0.0:
                heapq.heappush(
                    self._delayed_out, (time.monotonic() + self._delay_s, next(self._counter), msg)
                )
                continue
            self._transmit(msg, corrupt)

    def flush_due(self) -> None:
        """Send delayed messages whose time has come (the control loop calls this)."""
        now = time.monotonic()
        while self._delayed_out and self._delayed_out[0][0] <= now:
            self._transmit(heapq.heappop(self._delayed_out)[2], False)

    def _transmit(self, msg: Message, corrupt: bool) -> None:
        if corrupt:
            self.stats.fault_corrupted += 1
        with self._write_lock:
            if self._closed:
                return
            ok = self._write(msg, corrupt)
        if ok:
            self.stats.tx_messages += 1
        else:
            self.stats.tx_dropped += 1

    # -- receive ------------------------------------------------------------------------
    def _reader(self) -> None:
        deliver = self._deliver
        assert deliver is not None
        while not self._stop.is_set():
            timeout = 0.05
            if self._delayed_in:
                timeout = max(0.0, min(timeout, self._delayed_in[0][0] - time.monotonic()))
            try:
                received = self._read(timeout)
            except Exception:
                if self._stop.is_set():
                    return
                logger.exception("%s: read failed; retrying", self.name)
                self._stop.wait(0.1)
                continue
            now = time.monotonic()
            for msg in received:
                drop, corrupt = self._fate(self._rng_rx)
                if drop or corrupt:
                    # A damaged frame on a CRC-protected link is a frame the decoder drops.
                    self.stats.fault_dropped += drop
                    self.stats.fault_corrupted += corrupt
                    self._rx_corrupted += corrupt
                    continue
                if self._delay_s > 0.0:
                    heapq.heappush(
                        self._delayed_in, (now + self._delay_s, next(self._counter), msg)
                    )
                    continue
                self.stats.rx_messages += 1
                deliver(msg, now)
            while self._delayed_in and self._delayed_in[0][0] <= time.monotonic():
                due, _, msg = heapq.heappop(self._delayed_in)
                self.stats.rx_messages += 1
                deliver(msg, due)
