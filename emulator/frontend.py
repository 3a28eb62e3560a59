"""Front ends carry protocol messages between the controller model and a host.

A front end serves the controller's end of the link through a controller-side
:class:`~firmware_proto.linkio.endpoint.Endpoint` (framing, decoding, node filtering,
the traffic log: docs/traffic-logs.md). :class:`FrontEnd` adds what only an emulated
controller does: seeded link faults (drop, corrupt, delay), counters, the reader thread
and a write lock. :mod:`emulator.serial_frontend` and :mod:`emulator.can_frontend`
choose the endpoint. The reader thread does I/O only: it hands each message and its
``time.monotonic()`` arrival to the ``deliver`` callback of :meth:`FrontEnd.start`.
"""

from __future__ import annotations

import heapq
import itertools
import logging
import random
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from types import TracebackType

from emulator.errors import InjectionError
from firmware_proto.linkio.endpoint import Endpoint
from firmware_proto.linkio.trafficlog import TrafficRecorder
from firmware_proto.wire.message import Message

__all__ = ["MAX_LINK_DELAY_S", "Deliver", "FrontEnd", "FrontEndStats"]

logger = logging.getLogger(__name__)

MAX_LINK_DELAY_S = 10.0
"""Longest injected link delay, s."""

Deliver = Callable[[Message, float], None]
"""Called by the reader thread with each received message and its ``time.monotonic()``."""


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


class FrontEnd:
    """Base of the pty and CAN front ends; see the module docstring."""

    name = "front end"

    def __init__(
        self, endpoint: Endpoint, *, seed: int = 0, recorder: TrafficRecorder | None = None
    ) -> None:
        """Args:
        endpoint: the controller's end of the link on its medium, not yet open.
        seed: seeds the link-fault generators.
        recorder: the traffic log for every frame; the caller closes it after this.
        """
        self.endpoint = endpoint
        self.stats = FrontEndStats()
        self._recorder: TrafficRecorder | None = None
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

    @property
    def recorder(self) -> TrafficRecorder | None:
        """The traffic log of every frame (an endpoint listener); set before :meth:`start`."""
        return self._recorder

    @recorder.setter
    def recorder(self, recorder: TrafficRecorder | None) -> None:
        if self._recorder is not None:
            self.endpoint.remove_listener(self._recorder)
        self._recorder = recorder
        if recorder is not None:
            self.endpoint.add_listener(recorder)

    @property
    def device(self) -> str:
        """What a host opens: the pty's path, or ``interface:channel`` of the bus."""
        return self.endpoint.name

    # -- the medium, through the endpoint (hooks a front end may extend) -----------------
    def _open(self) -> None:
        self.endpoint.open()

    def _read(self, timeout_s: float) -> list[Message]:
        return self.endpoint.read(timeout_s)

    def _write(self, message: Message, corrupt: bool) -> bool:
        """Send one message (damaged if ``corrupt``); False if the medium dropped it or failed."""
        try:
            return self.endpoint.write(message, corrupt=self._rng_tx if corrupt else None)
        except OSError as exc:
            logger.debug("%s: send failed: %s", self.name, exc)
            return False

    def _close(self) -> None:
        self.endpoint.close()

    def restart(self) -> None:
        """The controller rebooted: its queued output is gone and its frame counter
        restarts at 0 (control thread, before the new boot's first frame)."""
        with self._write_lock:
            self.endpoint.restart_counter()

    @property
    def rx_errors(self) -> int:
        """Bad frames dropped so far: by the decoder, and damaged by an injected fault."""
        return self._rx_corrupted + self.endpoint.counters.rejected

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
        """Whether these link fault levels can apply (``None``: unchecked); changes nothing.

        Raises:
            InjectionError: a ratio outside 0..1, a delay outside
                0..:data:`MAX_LINK_DELAY_S` s, or corruption on CAN.
        """
        for kind, ratio in (("link-drop", drop), ("link-corrupt", corrupt)):
            if ratio is not None and not 0.0 <= ratio <= 1.0:
                raise InjectionError(f"{kind} ratio must be in 0..1, got {ratio:g}")
        if delay_s is not None and not 0.0 <= delay_s <= MAX_LINK_DELAY_S:
            raise InjectionError(
                f"link-delay must be in 0..{MAX_LINK_DELAY_S:g} s, got {delay_s:g}"
            )
        if corrupt and not self.endpoint.can_corrupt:
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
        """Send messages to the host in order, through the injected link faults (control
        thread); delayed ones go out from :meth:`flush_due`."""
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
