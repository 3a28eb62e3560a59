"""A run's stalls, said at its end, green or red (docs/testing.md, "Stalls in a run").

Every program a test starts logs its stalls to the run's stall log (tests/conftest.py:
``ROVER_STALL_LOG``), but a green run never showed them: the log went with the run, and
a failed test showed only its own. Whether a failure came from one process (its garbage
collector, a lock) or from the machine (every process held up at once) then rested on
one failure's lines.

So, in a session that runs real-time tests (marked ``slow`` and not ``virtual``):

- each pytest process watches itself with a :class:`StallMonitor` (its own stalls:
  in-process emulators, links and bridges run there), named ``pytest`` or ``pytest gw0``,
  writing to ``pytest-stalls.jsonl`` beside the log (not into it: a test may read the
  log, as ``rover stack status`` does); it is not installed as the process's monitor, so
  the loops of in-process parts are not watched through it;
- each real-time test's span (wall clock) goes to ``tests.jsonl`` beside the log;
- at the end the controlling process prints the stalls: how many, how many were the
  machine's (two or more processes held up over the same span), those with the tests
  that were running, and the longest of one process alone.

Cheap: a monitor thread that wakes every 50 ms, and one appended line per test.
"""

from __future__ import annotations

import contextlib
import json
import os
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

from firmware_proto.runtime.stall import (
    DEFAULT_STALL_THRESHOLD_S,
    StallMonitor,
    StallRecord,
    read_stalls,
)
from tests.lanes import keeps_wall_time

__all__ = ["TestSpan", "at_once", "read_spans", "summary_lines"]

TESTS_LOG = "tests.jsonl"
"""The tests' spans, beside the run's stall log."""
OWN_LOG = "pytest-stalls.jsonl"
"""The pytest processes' own stalls, beside the run's stall log."""
MAX_LINES = 10
"""At most this many stalls are listed per kind."""

_monitor: StallMonitor | None = None


@dataclass(frozen=True)
class TestSpan:
    """One test's run, wall clock (``time.time()``), s."""

    __test__ = False  # not a test class

    nodeid: str
    start_s: float
    end_s: float


def _log_path() -> Path | None:
    value = os.environ.get("ROVER_STALL_LOG", "")
    return Path(value) if value else None


def _process_name() -> str:
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")
    return f"pytest {worker}" if worker else "pytest"


def pytest_collection_finish(session: pytest.Session) -> None:
    """Start this process's monitor when it will run a real-time test."""
    global _monitor  # noqa: PLW0603 (one per pytest process)
    path = _log_path()
    if _monitor is None and path is not None and any(map(keeps_wall_time, session.items)):
        _monitor = StallMonitor(_process_name(), log_path=path.with_name(OWN_LOG))
        _monitor.start()


def pytest_unconfigure(config: pytest.Config) -> None:
    """Stop this process's monitor."""
    global _monitor  # noqa: PLW0603
    if _monitor is not None:
        _monitor.close()
        _monitor = None


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None) -> object:
    """Write a real-time test's span beside the stall log (one append of one line)."""
    start = time.time()
    yield
    path = _log_path()
    if path is None or not keeps_wall_time(item):
        return
    line = json.dumps({"nodeid": item.nodeid, "start_s": start, "end_s": time.time()})
    with contextlib.suppress(OSError), open(path.with_name(TESTS_LOG), "a") as out:
        out.write(line + "\n")


def read_spans(path: Path) -> list[TestSpan]:
    """The spans in ``path`` (a missing file: none; a malformed line is skipped)."""
    spans = []
    try:
        text = path.read_text(errors="replace")
    except OSError:
        return []
    for line in text.splitlines():
        try:
            spans.append(TestSpan(**json.loads(line)))
        except (ValueError, TypeError):
            continue
    return spans


def at_once(records: list[StallRecord]) -> list[list[StallRecord]]:
    """The stalls grouped by overlapping spans (each stall spans ``ms`` before its
    ``wall_s``); a group of two or more processes held up together is the machine's.
    Groups in time order."""
    groups: list[list[StallRecord]] = []
    group_end = float("-inf")
    for record in sorted(records, key=lambda r: r.wall_s - r.ms / 1e3):
        start = record.wall_s - record.ms / 1e3
        if groups and start <= group_end:
            groups[-1].append(record)
            group_end = max(group_end, record.wall_s)
        else:
            groups.append([record])
            group_end = record.wall_s
    return groups


def _during(records: list[StallRecord], spans: list[TestSpan]) -> str:
    start = min(r.wall_s - r.ms / 1e3 for r in records)
    end = max(r.wall_s for r in records)
    names = sorted({s.nodeid for s in spans if s.start_s <= end and s.end_s >= start})
    if not names:
        return "between tests"
    more = f" and {len(names) - 2} more" if len(names) > 2 else ""
    return "during " + ", ".join(names[:2]) + more


def _who(record: StallRecord) -> str:
    gc_part = f", {record.gc_ms:.0f} ms collecting garbage" if record.gc_ms >= 1 else ""
    thread = "" if record.thread == "*" else f" thread {record.thread}"
    return f"{record.process} (pid {record.pid}){thread} {record.ms:.0f} ms{gc_part}"


def summary_lines(records: list[StallRecord], spans: list[TestSpan]) -> list[str]:
    """What :func:`pytest_terminal_summary` prints (the module docstring)."""
    if not records:
        return [f"no stall of {DEFAULT_STALL_THRESHOLD_S * 1e3:.0f} ms or more"]
    groups = at_once(records)
    shared = [g for g in groups if len({r.pid for r in g}) > 1]
    alone = [r for g in groups if len({r.pid for r in g}) == 1 for r in g]
    longest = max(records, key=lambda r: r.ms)
    out = [
        f"{len(records)} stalls of {DEFAULT_STALL_THRESHOLD_S * 1e3:.0f} ms or more in "
        f"{len({r.pid for r in records})} processes, the longest {longest.ms:.0f} ms; "
        f"{len(shared)} times several processes at once (the machine)"
    ]
    for group in shared[:MAX_LINES]:
        when = time.strftime("%H:%M:%S", time.localtime(min(r.wall_s for r in group)))
        parts = "; ".join(_who(r) for r in sorted(group, key=lambda r: -r.ms))
        out.append(f"  at once, {when}: {parts}; {_during(group, spans)}")
    if len(shared) > MAX_LINES:
        out.append(f"  ... and {len(shared) - MAX_LINES} more at once")
    for record in sorted(alone, key=lambda r: -r.ms)[: MAX_LINES // 2]:
        when = time.strftime("%H:%M:%S", time.localtime(record.wall_s))
        out.append(f"  alone, {when}: {_who(record)}; {_during([record], spans)}")
    return out


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    """Print the run's stalls (the controlling process only)."""
    path = _log_path()
    if path is None or hasattr(terminalreporter.config, "workerinput"):
        return
    records = sorted(
        read_stalls(path) + read_stalls(path.with_name(OWN_LOG)), key=lambda r: r.wall_s
    )
    spans = read_spans(path.with_name(TESTS_LOG))
    if not records and not spans:
        return  # no real-time test ran, no program stalled
    terminalreporter.write_sep("-", "stalls (docs/testing.md, Stalls in a run)")
    for line in summary_lines(records, spans):
        terminalreporter.write_line(line)
