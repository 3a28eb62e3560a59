"""Stall detection: a process that watches its own loops and says where time went
(docs/realtime.md, "Stalls").

:class:`StallMonitor` runs one thread that wakes every ``period_s``. When it wakes more
than ``threshold_s`` late, the whole process was held up (not scheduled, or one thread
held the interpreter lock in a C call): recorded with every thread's stack. A loop that
registers a :class:`Beat` and ticks it every iteration is stalled when its beat is older
than ``threshold_s``: recorded with that thread's stack (an INFO line with it at once,
the record when the loop runs again).

The garbage collector's collections are timed (:data:`gc.callbacks`) while a monitor
runs, so that a stall says how much of it was spent collecting garbage: a collection
holds the interpreter lock, and so the whole process, while it runs, and leaves no
trace in any thread's stack.

Not :func:`faulthandler.dump_traceback_later`: its watchdog reads other threads' frames
without the interpreter lock, which can crash a process resuming from a freeze.

Every stall is one WARNING line (rate-limited by :data:`CONSOLE_QUIET_S`) and, with a
stall log, one JSON line with the stacks (:class:`StallRecord`, :func:`read_stalls`).
All processes of a stack on one host share the log (:func:`stall_log_path`); each line
is one ``write`` in append mode, so lines never interleave.
"""

from __future__ import annotations

import contextlib
import gc
import json
import logging
import os
import sys
import tempfile
import threading
import time
import traceback
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from types import TracebackType

__all__ = [
    "CONSOLE_QUIET_S",
    "DEFAULT_STALL_THRESHOLD_S",
    "GC_PAUSE_MIN_S",
    "STALL_LOG_ENV",
    "STALL_LOG_MAX_BYTES",
    "Beat",
    "GcPauses",
    "StallMonitor",
    "StallRecord",
    "all_stacks",
    "current_monitor",
    "describe_stalls",
    "forget",
    "install",
    "read_stalls",
    "stall_log_path",
    "watch",
]

logger = logging.getLogger(__name__)

DEFAULT_STALL_THRESHOLD_S = 0.1
"""A loop or process held up longer than this is a stall, s."""
STALL_LOG_ENV = "ROVER_STALL_LOG"
"""Environment variable naming the stall log file (empty: none)."""
STALL_LOG_MAX_BYTES = 4 << 20
"""A stall log longer than this is renamed ``.1`` (one generation kept) before a write."""
_STACK_CHARS = 4000
CONSOLE_QUIET_S = 10.0
"""Stalls within this long, s, after a console line are only counted and said with the next one."""


def stall_log_path(env: dict[str, str] | None = None) -> Path | None:
    """The stall log this host's stack shares: :data:`STALL_LOG_ENV` if set (an empty
    value: none), else ``rover-<uid>/stalls.jsonl`` in the system's temporary directory."""
    source = os.environ if env is None else env
    if STALL_LOG_ENV in source:
        text = source[STALL_LOG_ENV].strip()
        return Path(text) if text else None
    return Path(tempfile.gettempdir()) / f"rover-{os.getuid()}" / "stalls.jsonl"


@dataclass(frozen=True)
class StallRecord:
    """One stall.

    Attributes:
        process: the program's name (``bridge``, ``emulator``, ``gate``, ...).
        pid: its process id.
        thread: the stalled loop's name, or ``*`` when the whole process was held up.
        ms: how long, ms.
        wall_s: when it ended (``time.time()``).
        stack: where it was (the stalled thread's stack, or every thread's).
        gc_ms: how much of it the garbage collector ran, ms (collections of 1 ms or
            more; a log written before this field reads 0).
    """

    process: str
    pid: int
    thread: str
    ms: float
    wall_s: float
    stack: str = ""
    gc_ms: float = 0.0

    def line(self) -> str:
        """``bridge (pid 12): thread link-timer stalled 312 ms at 12:00:01``, and
        ``(150 ms of it collecting garbage)`` when a collection ran in it."""
        when = time.strftime("%H:%M:%S", time.localtime(self.wall_s))
        who = "the whole process" if self.thread == "*" else f"thread {self.thread}"
        gc_part = f" ({self.gc_ms:.0f} ms of it collecting garbage)" if self.gc_ms >= 1 else ""
        return f"{self.process} (pid {self.pid}): {who} stalled {self.ms:.0f} ms at {when}{gc_part}"


class Beat:
    """A loop's sign of life (:meth:`StallMonitor.watch`). ``tick`` is one store."""

    __slots__ = ("_clock", "last", "name", "thread_id")

    def __init__(self, name: str, clock: Callable[[], float]) -> None:
        """Made by :meth:`StallMonitor.watch` on the loop's own thread."""
        self.name = name
        self._clock = clock
        self.thread_id = threading.get_ident()
        self.last = clock()

    def tick(self) -> None:
        """The loop is alive now (call it every iteration, from the loop's thread)."""
        self.last = self._clock()


GC_PAUSE_MIN_S = 0.001
"""Collections shorter than this, s, are not kept (the many young ones)."""
_GC_PAUSES_KEPT = 64


class GcPauses:
    """The garbage collector's collections, timed: a :data:`gc.callbacks` entry while
    :meth:`attach`-ed. Each collection of :data:`GC_PAUSE_MIN_S` or more is kept (the
    last 64) as ``(start, end, generation)`` on ``clock``."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        """Args: clock: monotonic seconds, the stall monitor's."""
        self._clock = clock
        self._started: float | None = None
        self.pauses: deque[tuple[float, float, int]] = deque(maxlen=_GC_PAUSES_KEPT)

    def __call__(self, phase: str, info: dict[str, int]) -> None:
        """The callback (runs inside the collector, on whichever thread triggered it)."""
        now = self._clock()
        if phase == "start":
            self._started = now
        elif self._started is not None:
            if now - self._started >= GC_PAUSE_MIN_S:
                self.pauses.append((self._started, now, info.get("generation", -1)))
            self._started = None

    def attach(self) -> None:
        """Start timing collections (idempotent)."""
        if self not in gc.callbacks:
            gc.callbacks.append(self)

    def detach(self) -> None:
        """Stop timing collections (idempotent)."""
        with contextlib.suppress(ValueError):
            gc.callbacks.remove(self)

    def within(self, lo: float, hi: float) -> float:
        """Seconds the collector ran between ``lo`` and ``hi`` (clock seconds)."""
        return sum(max(0.0, min(end, hi) - max(start, lo)) for start, end, _ in list(self.pauses))


@dataclass
class _Episode:
    started: float
    stack: str


class StallMonitor:
    """Watches the process and its registered loops (see the module docstring)."""

    def __init__(
        self,
        process: str,
        *,
        threshold_s: float = DEFAULT_STALL_THRESHOLD_S,
        period_s: float | None = None,
        log_path: Path | None = None,
        clock: Callable[[], float] = time.monotonic,
        stacks_on_console: bool = False,
    ) -> None:
        """Args:
        process: the program's name in the records.
        threshold_s: a stall is longer than this, s (> 0, else ValueError).
        period_s: how often the monitor looks, s (> 0); default half the threshold.
        log_path: the stall log to append records to, stacks included (``None``: none).
        clock: monotonic seconds (tests may pass their own).
        stacks_on_console: log each stall's stacks with its line (a program's ``-v``);
            otherwise the line says where they are.
        """
        if not threshold_s > 0:
            raise ValueError(f"stall threshold must be > 0, got {threshold_s}")
        self.process = process
        self.threshold_s = threshold_s
        self.period_s = period_s if period_s is not None else threshold_s / 2
        if not self.period_s > 0:
            raise ValueError(f"stall monitor period must be > 0, got {self.period_s}")
        self.log_path = log_path
        self.stacks_on_console = stacks_on_console
        self._clock = clock
        self._beats: list[Beat] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._episodes: dict[str, _Episode] = {}
        self._said_at: float | None = None
        self._held_back = 0
        self._held_back_ms = 0.0
        self.records: list[StallRecord] = []
        """Every stall so far (also logged, and appended to the stall log)."""
        self.longest_ms = 0.0
        """The longest stall so far, ms (0: none)."""
        self.gc = GcPauses(clock)
        """The collections timed while the monitor runs."""

    # -- lifecycle ------------------------------------------------------------------------
    def start(self) -> None:
        """Start the monitor thread."""
        if self._thread is not None:
            raise RuntimeError("stall monitor already started")
        self.gc.attach()
        self._thread = threading.Thread(target=self._run, name="stall-monitor", daemon=True)
        self._thread.start()

    def close(self) -> None:
        """Stop the thread (idempotent)."""
        self._stop.set()
        self.gc.detach()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5.0)
        self._thread = None

    def __enter__(self) -> StallMonitor:
        self.start()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def watch(self, name: str) -> Beat:
        """A beat for the calling thread's loop (call it from that thread: a stall is
        reported with its stack); tick it every iteration and :meth:`forget` it when the
        loop ends."""
        beat = Beat(name, self._clock)
        with self._lock:
            self._beats.append(beat)
        return beat

    def forget(self, beat: Beat) -> None:
        """Stop watching ``beat`` (its loop ended)."""
        with self._lock:
            if beat in self._beats:
                self._beats.remove(beat)
            self._episodes.pop(beat.name + f"#{id(beat)}", None)

    # -- the monitor ---------------------------------------------------------------------
    def _run(self) -> None:
        expected = self._clock() + self.period_s
        while not self._stop.wait(max(0.0, expected - self._clock())):
            now = self._clock()
            late = now - expected
            if late > self.threshold_s:
                self._record("*", late + self.period_s, all_stacks(), now)
            self.check(now)
            expected = max(expected + self.period_s, now)

    def check(self, now: float) -> None:
        """Look at every beat (the monitor thread does this every period)."""
        with self._lock:
            beats = list(self._beats)
        for beat in beats:
            key = beat.name + f"#{id(beat)}"
            age = now - beat.last
            episode = self._episodes.get(key)
            if age > self.threshold_s and episode is None:
                stack = _thread_stack(beat.thread_id)
                self._episodes[key] = _Episode(beat.last, stack)
                logger.info(
                    "stall: %s thread %s has not run for %.0f ms; it is at:\n%s",
                    self.process,
                    beat.name,
                    age * 1e3,
                    stack,
                )
            elif age <= self.threshold_s and episode is not None:
                del self._episodes[key]
                self._record(beat.name, (beat.last - episode.started), episode.stack, beat.last)

    def _record(self, thread: str, duration_s: float, stack: str, ended: float) -> None:
        """``ended``: when the stall ended, on the monitor's clock."""
        gc_s = self.gc.within(ended - duration_s, ended)
        record = StallRecord(
            process=self.process,
            pid=os.getpid(),
            thread=thread,
            ms=round(duration_s * 1e3, 1),
            wall_s=time.time(),
            stack=stack[-_STACK_CHARS:],
            gc_ms=round(gc_s * 1e3, 1),
        )
        self.records.append(record)
        self.longest_ms = max(self.longest_ms, record.ms)
        if self.log_path is not None:
            _append(self.log_path, record)
        if self.stacks_on_console:
            logger.warning("stall: %s\n%s", record.line(), record.stack)
            return
        # One line per CONSOLE_QUIET_S at most, naming how many more there were; the
        # stall log has all of them.
        now = self._clock()
        if self._said_at is not None and now - self._said_at < CONSOLE_QUIET_S:
            self._held_back += 1
            self._held_back_ms = max(self._held_back_ms, record.ms)
            return
        more = ""
        if self._held_back:
            more = (
                f" ({self._held_back} more since the last line, the longest "
                f"{self._held_back_ms:.0f} ms)"
            )
        self._said_at, self._held_back, self._held_back_ms = now, 0, 0.0
        logger.warning("stall: %s%s; %s", record.line(), more, self.where_stacks_are())

    def where_stacks_are(self) -> str:
        """Where a stall's stacks can be read, in words, for its one console line."""
        if self.log_path is not None:
            return f"stacks in {self.log_path}"
        return "stacks not kept (no stall log: $ROVER_STALL_LOG is empty); -v shows them"


_installed: StallMonitor | None = None


def install(monitor: StallMonitor | None) -> None:
    """Make ``monitor`` the process's own (:func:`watch` registers loops with it);
    ``None`` uninstalls. :class:`~firmware_proto.runtime.process.ProcessRuntime` does
    this for a program."""
    global _installed  # noqa: PLW0603 (one monitor per process, like logging's root)
    _installed = monitor


def current_monitor() -> StallMonitor | None:
    """The process's monitor, if one is installed."""
    return _installed


def watch(name: str) -> Beat:
    """A beat for the calling thread's loop, watched by the process's monitor; where
    none is installed (a library used in a test), a beat nobody watches."""
    monitor = _installed
    return monitor.watch(name) if monitor is not None else Beat(name, time.monotonic)


def forget(beat: Beat) -> None:
    """Stop watching ``beat`` (its loop ended); harmless when nobody watched it."""
    monitor = _installed
    if monitor is not None:
        monitor.forget(beat)


def _thread_stack(thread_id: int) -> str:
    frame = sys._current_frames().get(thread_id)
    if frame is None:
        return "(thread gone)"
    return "".join(traceback.format_stack(frame)).rstrip()


def all_stacks() -> str:
    names = {t.ident: t.name for t in threading.enumerate()}
    parts = []
    for ident, frame in sys._current_frames().items():
        if ident == threading.get_ident():
            continue
        stack = "".join(traceback.format_stack(frame)).rstrip()
        parts.append(f"thread {names.get(ident, ident)}:\n{stack}")
    return "\n".join(parts)


def _append(path: Path, record: StallRecord) -> None:
    """One JSON line, one ``write`` (see the module docstring); errors are logged."""
    line = json.dumps(asdict(record), separators=(",", ":")) + "\n"
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with contextlib.suppress(FileNotFoundError):
            if path.stat().st_size > STALL_LOG_MAX_BYTES:
                path.replace(path.with_name(path.name + ".1"))
        fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        try:
            os.write(fd, line.encode())
        finally:
            os.close(fd)
    except OSError as exc:
        logger.warning("cannot write the stall log %s: %s", path, exc)


def read_stalls(path: Path | None, since_wall_s: float = 0.0) -> list[StallRecord]:
    """The stalls in the log at ``path`` that ended at or after ``since_wall_s``
    (``time.time()``), oldest first; malformed lines are skipped (counted in the log)."""
    if path is None:
        return []
    records: list[StallRecord] = []
    bad = 0
    for candidate in (path.with_name(path.name + ".1"), path):
        for line in _lines(candidate):
            try:
                record = StallRecord(**json.loads(line))
            except (ValueError, TypeError):
                bad += 1
                continue
            if record.wall_s >= since_wall_s:
                records.append(record)
    if bad:
        logger.warning("stall log %s: %d malformed line(s) skipped", path, bad)
    return sorted(records, key=lambda r: r.wall_s)


def _lines(path: Path) -> Iterator[str]:
    try:
        text = path.read_text(errors="replace")
    except OSError:
        return
    yield from (line for line in text.splitlines() if line.strip())


def describe_stalls(records: list[StallRecord], threshold_s: float) -> list[str]:
    """Lines for the operator: each process's longest stall, longest first; or one line
    saying that none stalled longer than ``threshold_s``."""
    if not records:
        return [
            f"no process of the stack on this host stalled longer than {threshold_s * 1e3:.0f} ms"
        ]
    longest: dict[tuple[str, int], StallRecord] = {}
    for record in records:
        key = (record.process, record.pid)
        if key not in longest or record.ms > longest[key].ms:
            longest[key] = record
    counts: dict[tuple[str, int], int] = {}
    for record in records:
        counts[(record.process, record.pid)] = counts.get((record.process, record.pid), 0) + 1
    out = []
    for key, record in sorted(longest.items(), key=lambda kv: -kv[1].ms):
        more = f" ({counts[key]} stalls)" if counts[key] > 1 else ""
        out.append(f"stall: {record.line()}{more}")
    return out
