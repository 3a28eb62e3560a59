"""tests/stalls.py: a run's stalls said at its end, and which were the machine's."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from firmware_proto.runtime.stall import StallRecord
from tests.stalls import TESTS_LOG, TestSpan, at_once, read_spans, summary_lines

ROOT = Path(__file__).resolve().parents[1]


def _stall(process: str, pid: int, ms: float, end_s: float, gc_ms: float = 0.0) -> StallRecord:
    return StallRecord(process, pid, "*", ms, end_s, "", gc_ms)


def test_overlapping_stalls_of_several_processes_are_one_machine_stall() -> None:
    bridge = _stall("rover_bridge", 11, 166.0, 100.166)
    stop = _stall("rover_bridge_stop", 12, 165.0, 100.169)
    test = _stall("pytest gw1", 13, 350.0, 100.300)
    later = _stall("rover_bridge", 11, 120.0, 200.0)
    groups = at_once([later, test, stop, bridge])
    assert [{r.pid for r in g} for g in groups] == [{11, 12, 13}, {11}]


def test_stalls_that_only_follow_each_other_are_not_together() -> None:
    first = _stall("a", 1, 100.0, 10.0)
    second = _stall("b", 2, 100.0, 10.101)  # starts 1 ms after the first ended
    assert len(at_once([first, second])) == 2


def test_the_summary_names_the_machine_stalls_with_their_tests_and_the_longest_alone() -> None:
    records = [
        _stall("rover_bridge", 11, 166.0, 100.166),
        _stall("rover_bridge_stop", 12, 165.0, 100.169),
        _stall("pytest gw0", 13, 180.0, 300.18, gc_ms=150.0),
    ]
    spans = [
        TestSpan("tests/a.py::test_frozen", 99.0, 101.0),
        TestSpan("tests/b.py::test_after", 102.0, 103.0),
        TestSpan("tests/c.py::test_gc", 299.0, 301.0),
    ]
    lines = summary_lines(records, spans)
    assert lines[0].startswith("3 stalls of 100 ms or more in 3 processes, the longest 180 ms")
    assert "1 times several processes at once" in lines[0]
    together = [line for line in lines if "at once," in line]
    assert len(together) == 1
    assert "rover_bridge (pid 11) 166 ms; rover_bridge_stop (pid 12) 165 ms" in together[0]
    assert together[0].endswith("during tests/a.py::test_frozen")
    alone = [line for line in lines if "alone," in line]
    assert len(alone) == 1
    assert "pytest gw0 (pid 13) 180 ms, 150 ms collecting garbage" in alone[0]
    assert alone[0].endswith("during tests/c.py::test_gc")


def test_no_stall_says_so() -> None:
    assert summary_lines([], []) == ["no stall of 100 ms or more"]


def test_a_malformed_span_line_is_skipped(tmp_path: Path) -> None:
    path = tmp_path / TESTS_LOG
    path.write_text('{"nodeid": "t::a", "start_s": 1.0, "end_s": 2.0}\nnot json\n{"nodeid": 3}\n')
    assert read_spans(path) == [TestSpan("t::a", 1.0, 2.0)]
    assert read_spans(tmp_path / "missing.jsonl") == []


@pytest.mark.slow
def test_a_run_that_holds_its_interpreter_says_so_at_its_end(tmp_path: Path) -> None:
    """A real pytest run whose real-time test holds the interpreter lock for 0.4 s: its
    summary names the pytest process's stall and the test it fell in; a test that keeps no
    wall clock leaves no span."""
    (tmp_path / "test_hold.py").write_text(
        textwrap.dedent(
            """
            import sys, time
            import pytest

            @pytest.mark.slow
            def test_holds_the_interpreter():
                sys.setswitchinterval(5.0)  # the monitor's thread waits for the lock
                end = time.monotonic() + 0.4
                while time.monotonic() < end:
                    pass

            def test_keeps_no_clock():
                pass
            """
        )
    )
    log = tmp_path / "run" / "stalls.jsonl"
    log.parent.mkdir()
    env = {
        **os.environ,
        "ROVER_STALL_LOG": str(log),
        "PYTHONPATH": str(ROOT),
    }
    env.pop("PYTEST_XDIST_WORKER", None)
    args = ["-p", "tests.stalls", "-p", "no:cacheprovider", "-q", "test_hold.py"]
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "-W", "ignore::pytest.PytestUnknownMarkWarning", *args],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=100,
        check=False,
    )
    out = done.stdout + done.stderr
    assert done.returncode == 0, out
    assert "stalls (docs/testing.md, Stalls in a run)" in out, out
    assert "alone," in out and "pytest (pid" in out, out
    assert "during test_hold.py::test_holds_the_interpreter" in out, out
    spans = read_spans(log.with_name(TESTS_LOG))
    assert [s.nodeid for s in spans] == ["test_hold.py::test_holds_the_interpreter"]
