"""The replaying peer: one end of a recorded session, played into the other end.

Both replays (docs/traffic-logs.md) use it: a HOST peer plays the recorded host into a
fresh emulator, a CONTROLLER peer the recorded controller into a fresh bridge link. A
:class:`ReplayPeer` puts recorded frames on its endpoint exactly as recorded and
collects, on a reader thread, every message the other end sends, with its arrival time.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter
from collections.abc import Callable
from types import TracebackType

from firmware_proto.linkio.endpoint import Endpoint
from firmware_proto.linkio.trafficlog import TrafficRecord
from firmware_proto.wire.message import Message

__all__ = ["ReplayPeer"]

logger = logging.getLogger(__name__)

_POLL_S = 0.05
"""How long one read waits, s (the reader looks at its stop flag this often)."""


class ReplayPeer:
    """Plays recorded frames on ``endpoint`` and collects what comes back.

    Attributes:
        endpoint: the peer's end of the link (opened by :meth:`start`, closed by
            :meth:`close`).
        received: every message taken in, with its arrival (``time.monotonic()``), in
            order; read it through :meth:`snapshot` while the reader runs.
    """

    def __init__(self, endpoint: Endpoint, counted: Callable[[Message], bool]) -> None:
        """Args:
        endpoint: the peer's end (not yet open).
        counted: which messages :meth:`wait_counts` counts (e.g. answers, requests).
        """
        self.endpoint = endpoint
        self.received: list[tuple[float, Message]] = []
        self._counted = counted
        self._since = float("-inf")
        self._counts: Counter[str] = Counter()
        self._cond = threading.Condition()
        self._write_lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="replay-peer-rx", daemon=True)

    def start(self) -> None:
        """Open the endpoint and start reading. Raises OSError when it cannot open."""
        self.endpoint.open()
        self._thread.start()

    def _loop(self) -> None:
        while not self._stop.is_set():
            try:
                messages = self.endpoint.read(_POLL_S)
            except OSError as exc:
                # The other end closed or is not there yet: a replay outlives that.
                logger.debug("replay peer: read failed: %s", exc)
                self._stop.wait(0.01)
                continue
            if messages:
                now = time.monotonic()
                with self._cond:
                    self.received += [(now, m) for m in messages]
                    if now >= self._since:
                        self._counts.update(m.NAME for m in messages if self._counted(m))
                    self._cond.notify_all()

    def play(self, record: TrafficRecord) -> None:
        """Put one recorded frame on the medium, as recorded (thread-safe; TypeError for a
        record of another medium). A frame the medium cannot take is logged at DEBUG and
        dropped: the comparison will show it."""
        with self._write_lock:
            try:
                self.endpoint.write_record(record)
            except OSError as exc:
                logger.debug("replayed frame not delivered: %s", exc)

    def play_on_time(self, records: list[TrafficRecord], offset: float) -> None:
        """Play each record at its recorded time plus ``offset`` (``time.monotonic()``),
        in order; returns after the last (run it on a thread of its own)."""
        for record in records:
            delay = record.time_s + offset - time.monotonic()
            if delay > 0:
                time.sleep(delay)  # replaying the recorded timing is the point
            self.play(record)

    def wait_first(self, timeout_s: float) -> bool:
        """Wait until the other end said anything; whether it did."""
        with self._cond:
            return self._cond.wait_for(lambda: bool(self.received), timeout_s)

    def count_from(self, start: float) -> None:
        """Count messages by type from ``start`` (``time.monotonic()``) on."""
        with self._cond:
            self._since = start
            self._counts = Counter(
                m.NAME for t, m in self.received if t >= start and self._counted(m)
            )

    def wait_counts(self, need: Counter[str], deadline: float) -> bool:
        """Wait until the messages counted reach every count in ``need``, or until
        ``deadline`` (``time.monotonic()``); whether they did."""

        def reached() -> bool:
            return all(self._counts[name] >= n for name, n in need.items())

        with self._cond:
            return self._cond.wait_for(reached, max(0.0, deadline - time.monotonic()))

    def snapshot(self) -> list[tuple[float, Message]]:
        """Everything received so far, with arrival times (``time.monotonic()``)."""
        with self._cond:
            return list(self.received)

    def close(self) -> None:
        """Stop the reader and close the endpoint (idempotent)."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=5.0)
            if self._thread.is_alive():
                logger.error("replay peer reader did not stop within 5 s")
        self.endpoint.close()

    def __enter__(self) -> ReplayPeer:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
