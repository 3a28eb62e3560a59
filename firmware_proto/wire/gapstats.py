"""Gaps between periodic events: how regularly a heartbeat was sent or received.

A process starved of the CPU shows it as one long gap. :class:`GapStats` is fed the time
of each event and keeps the longest gap since it started and the recent ones, for the
bridge's ``/diagnostics``, the emulator's status and the load benchmark
(docs/realtime.md). Pure: the caller says when each event happened (monotonic s).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

__all__ = ["GAP_WINDOW", "GapStats", "GapSummary"]

GAP_WINDOW = 1000
"""Gaps kept for the percentiles: at 10 Hz, the last 100 s."""


@dataclass(frozen=True)
class GapSummary:
    """What :class:`GapStats` has seen, in milliseconds (``None``: no gap yet).

    Attributes:
        count: gaps measured since the start (one fewer than the events).
        max_ms: the longest gap since the start.
        p99_ms: the 99th percentile of the last :data:`GAP_WINDOW` gaps (nearest rank).
        last_ms: the last gap.
        period_ms: the events' nominal period (0: none given).
    """

    count: int
    max_ms: float | None
    p99_ms: float | None
    last_ms: float | None
    period_ms: float = 0.0

    @property
    def late_max_ms(self) -> float | None:
        """The longest gap less the period, ms (at least 0)."""
        return None if self.max_ms is None else max(0.0, self.max_ms - self.period_ms)

    @property
    def late_p99_ms(self) -> float | None:
        """The 99th-percentile gap less the period, ms (at least 0)."""
        return None if self.p99_ms is None else max(0.0, self.p99_ms - self.period_ms)

    def line(self) -> str:
        """``max 112.3 ms, p99 101.1 ms (n=42)``, or ``none yet``."""
        if self.max_ms is None or self.p99_ms is None:
            return "none yet"
        return f"max {self.max_ms:.1f} ms, p99 {self.p99_ms:.1f} ms (n={self.count})"


class GapStats:
    """Gaps between the events it is told of. Not thread-safe: one owner feeds and reads it
    (or the owner's lock guards it)."""

    def __init__(self, period_s: float = 0.0, window: int = GAP_WINDOW) -> None:
        """Args:
        period_s: the events' nominal period, s (0: none), for the lateness figures.
        window: how many recent gaps the percentile is taken over (>= 1).

        Raises:
            ValueError: ``window`` < 1 or a negative period.
        """
        if window < 1:
            raise ValueError(f"window must be >= 1, got {window}")
        if not period_s >= 0:
            raise ValueError(f"period must be >= 0, got {period_s}")
        self.period_s = period_s
        self._recent: deque[float] = deque(maxlen=window)
        self._last: float | None = None
        self._max = 0.0
        self._count = 0

    def event(self, t_s: float) -> float | None:
        """An event at ``t_s`` (seconds, monotonic); returns the gap it ends, s (``None``
        for the first event, or one stamped before the previous: not counted)."""
        last, self._last = self._last, t_s
        if last is None or not math.isfinite(t_s) or t_s < last:
            return None
        gap = t_s - last
        self._recent.append(gap)
        self._count += 1
        self._max = max(self._max, gap)
        return gap

    def restart(self) -> None:
        """Forget the last event (the stream stopped on purpose: a link closed and
        reopened); the next event starts a new series. Totals are kept."""
        self._last = None

    def summary(self) -> GapSummary:
        """The gaps so far, in ms."""
        if not self._recent:
            return GapSummary(self._count, None, None, None, self.period_s * 1e3)
        ordered = sorted(self._recent)
        rank = max(0, math.ceil(0.99 * len(ordered)) - 1)
        return GapSummary(
            count=self._count,
            max_ms=self._max * 1e3,
            p99_ms=ordered[rank] * 1e3,
            last_ms=self._recent[-1] * 1e3,
            period_ms=self.period_s * 1e3,
        )
