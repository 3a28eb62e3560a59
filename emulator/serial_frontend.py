"""Serial front end: the controller on a pty, as a host sees a USB-serial device.

A host opens :attr:`SerialFrontEnd.device` (``/dev/pts/N``, or the symlink ``link``);
frames are docs/protocol.md's, byte for byte. With ``baud``, frames to the host are
paced by a transmit thread in :data:`PRIORITY_ORDER`, stale telemetry dropped. While
nobody reads, frames to the host are dropped (counted), never blocking the controller;
:meth:`SerialFrontEnd.unplug` and :meth:`SerialFrontEnd.replug` pull and replug the
device under the same link. docs/emulator.md, "Front ends".
"""

from __future__ import annotations

import heapq
import itertools
import logging
import threading
import time
from pathlib import Path

from emulator.frontend import FrontEnd
from firmware_proto.linkio.endpoint import CONTROLLER
from firmware_proto.linkio.serial_endpoint import PtyPort, SerialEndpoint
from firmware_proto.linkio.trafficlog import TrafficRecorder
from firmware_proto.wire.framing import FrameDecoder
from firmware_proto.wire.message import Message

__all__ = ["PRIORITY_ORDER", "SerialFrontEnd"]

logger = logging.getLogger(__name__)

PRIORITY_ORDER = {"emergency": 0, "motion": 1, "status": 2, "telemetry": 2, "config": 2}
"""Transmit order on a paced line: STOP, motion, then the rest as queued (strict priority
among those would starve IDENT behind telemetry on a saturated line)."""

STALE_TELEMETRY_S = 0.1
"""A telemetry frame that waited this long for the paced line is dropped (a newer one is
coming), so a backlog can never starve the classes behind it."""


class SerialFrontEnd(FrontEnd):
    """The controller's end of a pty pair. See the module docstring."""

    name = "pty"

    def __init__(
        self,
        *,
        link: str | Path | None = None,
        baud: int | None = None,
        seed: int = 0,
        recorder: TrafficRecorder | None = None,
    ) -> None:
        """Args:
        link: path of a stable symlink to the device (e.g. /tmp/rover-motor).
        baud: pace frames to the host at this rate (bits/s); ``None``: no pacing.
        seed: seeds the link-fault generators.
        recorder: traffic log for every frame written and received (see FrontEnd).

        Raises:
            ValueError: baud not positive.
        """
        if baud is not None and baud <= 0:
            raise ValueError(f"baud must be > 0, got {baud}")
        self.link = Path(link) if link is not None else None
        self.serial = SerialEndpoint(CONTROLLER, lambda: PtyPort(self.link))
        super().__init__(self.serial, seed=seed, recorder=recorder)
        self.baud = baud
        self._plug_request: str | None = None
        self._plug_done = threading.Event()
        self._tx_heap: list[tuple[int, int, float, bool, Message, tuple[float, int] | None]] = []
        """Frames waiting for the paced line: (class order, queue order, queued at,
        telemetry?, message, corruption draws). They are numbered as they are written."""
        self.stale_dropped = 0
        self._tx_order = itertools.count()
        self._tx_ready = threading.Condition()
        self._tx_thread: threading.Thread | None = None

    # -- medium -------------------------------------------------------------------------
    @property
    def decoder(self) -> FrameDecoder:
        """The endpoint's frame decoder (its counters say what was rejected)."""
        return self.serial.decoder

    def _open(self) -> None:
        self.serial.open()
        logger.info("serving on %s%s", self.device, f" (link {self.link})" if self.link else "")
        if self.baud is not None:
            self._tx_thread = threading.Thread(
                target=self._paced_writer, name="pty-tx", daemon=True
            )
            self._tx_thread.start()

    def close(self) -> None:
        """Stop the transmit thread (it holds the write lock per frame), then as
        :meth:`FrontEnd.close` (idempotent)."""
        self._stop.set()
        with self._tx_ready:
            self._tx_ready.notify_all()
        thread = self._tx_thread
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=5.0)
            if thread.is_alive():
                logger.error("pty transmit thread did not stop within 5 s")
        super().close()

    def _close(self) -> None:
        with self._tx_ready:
            self._tx_ready.notify_all()
        if self._tx_thread is not None and self._tx_thread is not threading.current_thread():
            self._tx_thread.join(timeout=5.0)
        self._tx_thread = None
        self.serial.close()

    # -- unplug / replug ----------------------------------------------------------------
    def unplug(self, timeout_s: float = 2.0) -> None:
        """Make the device disappear (done by the reader thread; waits for it)."""
        self._request_plug("unplug", timeout_s)

    def replug(self, timeout_s: float = 2.0) -> None:
        """Bring a new device back under the same link (a new /dev/pts/N)."""
        self._request_plug("replug", timeout_s)

    def _request_plug(self, what: str, timeout_s: float) -> None:
        self._plug_done.clear()
        self._plug_request = what
        if not self._plug_done.wait(timeout_s):
            raise TimeoutError(f"{what} not done within {timeout_s} s")

    def _handle_plug(self) -> None:
        what, self._plug_request = self._plug_request, None
        with self._write_lock:
            if what == "unplug" and self.serial.is_open:
                self.serial.close()
                logger.warning("unplugged: device gone")
            elif what == "replug" and not self.serial.is_open:
                self.serial.open()
                logger.warning("replugged: serving on %s", self.device)
        self._plug_done.set()

    @property
    def plugged(self) -> bool:
        """Whether the device exists."""
        return self.serial.is_open

    # -- I/O ----------------------------------------------------------------------------
    def _read(self, timeout_s: float) -> list[Message]:
        if self._plug_request is not None:
            self._handle_plug()
        if not self.serial.is_open:
            self._stop.wait(timeout_s)
            return []
        return self.serial.read(timeout_s)

    def _write(self, message: Message, corrupt: bool) -> bool:
        if self.baud is not None:
            # Numbered by the paced writer; damage drawn here so that a seed replays.
            draws = (self._rng_tx.random(), self._rng_tx.randrange(8)) if corrupt else None
            with self._tx_ready:
                telemetry = message.PRIORITY == "telemetry"
                entry = (
                    PRIORITY_ORDER[message.PRIORITY],
                    next(self._tx_order),
                    time.monotonic(),
                    telemetry,
                    message,
                    draws,
                )
                heapq.heappush(self._tx_heap, entry)
                self._tx_ready.notify()
            return True
        return self.serial.write_wire(
            self.serial.encode(message, corrupt=self._rng_tx if corrupt else None)
        )

    def restart(self) -> None:
        """A reboot: the paced queue is dropped (a reset UART loses it) and the counter
        restarts (:meth:`FrontEnd.restart`)."""
        with self._tx_ready:
            self._tx_heap.clear()
        super().restart()

    def _paced_writer(self) -> None:
        assert self.baud is not None
        seconds_per_byte = 10.0 / self.baud
        line_free = time.monotonic()
        while not self._stop.is_set():
            with self._tx_ready:
                while not self._tx_heap and not self._stop.is_set():
                    self._tx_ready.wait(0.1)
                if self._stop.is_set():
                    return
                _, _, queued, telemetry, message, draws = heapq.heappop(self._tx_heap)
            if telemetry and time.monotonic() - queued > STALE_TELEMETRY_S:
                self.stale_dropped += 1
                continue
            wait = line_free - time.monotonic()
            if wait > 0 and self._stop.wait(wait):
                return
            with self._write_lock:
                wire = self.serial.encode(message)
                if draws is not None:
                    damaged = bytearray(wire)
                    damaged[int(draws[0] * len(damaged))] ^= 1 << draws[1]
                    wire = bytes(damaged)
                ok = self.serial.write_wire(wire)
            if not ok:
                self.stats.tx_dropped += 1
            line_free = max(line_free, time.monotonic()) + len(wire) * seconds_per_byte
