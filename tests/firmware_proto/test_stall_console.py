"""A stall on the console is one line (issue #41: a busy machine's thread dumps buried
the mission's lines): the process, the thread, how long, and where the stacks are; the
stacks go to the stall log; ``-v`` brings them back. In virtual time: a clock of the
test's own and the monitor's ``check`` called by hand, no monitor thread."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

import pytest

from firmware_proto.cli.runtimeargs import add_runtime_arguments, runtime_options
from firmware_proto.runtime.stall import StallMonitor, read_stalls


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def _stall_once(monitor: StallMonitor, clock: Clock) -> None:
    """A loop that does not turn for 0.3 s, then runs again."""
    beat = monitor.watch("link-tx")
    clock.now += 0.3
    monitor.check(clock.now)  # found stalled, while it still is
    beat.tick()
    clock.now += 0.01
    monitor.check(clock.now)  # it ran again: the stall is recorded


def _warnings(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]


def test_a_stall_is_one_line_naming_where_its_stacks_are(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    log = tmp_path / "stalls.jsonl"
    clock = Clock()
    monitor = StallMonitor("bridge", log_path=log, clock=clock)
    with caplog.at_level(logging.WARNING, logger="firmware_proto.runtime.stall"):
        _stall_once(monitor, clock)
    lines = _warnings(caplog)
    assert len(lines) == 1, lines
    line = lines[0]
    assert "\n" not in line
    assert line.startswith("stall: bridge (pid ") and "thread link-tx stalled 300 ms" in line
    assert line.endswith(f"stacks in {log}")
    # The stack is in the log, where the line says.
    (record,) = read_stalls(log)
    assert record.thread == "link-tx" and "_stall_once" in record.stack


def test_without_a_stall_log_the_line_says_the_stacks_are_not_kept(
    caplog: pytest.LogCaptureFixture,
) -> None:
    clock = Clock()
    monitor = StallMonitor("demo", clock=clock)
    with caplog.at_level(logging.WARNING, logger="firmware_proto.runtime.stall"):
        _stall_once(monitor, clock)
    (line,) = _warnings(caplog)
    assert "\n" not in line and "stacks not kept" in line and "-v shows them" in line


def test_verbose_brings_the_stacks_back_to_the_console(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    clock = Clock()
    monitor = StallMonitor(
        "go", log_path=tmp_path / "stalls.jsonl", clock=clock, stacks_on_console=True
    )
    with caplog.at_level(logging.WARNING, logger="firmware_proto.runtime.stall"):
        _stall_once(monitor, clock)
    (line,) = _warnings(caplog)
    first, _, stack = line.partition("\n")
    assert "thread link-tx stalled 300 ms" in first and "_stall_once" in stack


def test_the_found_stall_and_its_stack_are_said_at_info(caplog: pytest.LogCaptureFixture) -> None:
    """A loop that never comes back (a hang) is still told, with its stack, at -v."""
    clock = Clock()
    monitor = StallMonitor("emulator", clock=clock)
    beat = monitor.watch("emulator-control")
    clock.now += 0.5
    with caplog.at_level(logging.INFO, logger="firmware_proto.runtime.stall"):
        monitor.check(clock.now)
    (info,) = [r for r in caplog.records if r.levelno == logging.INFO]
    assert "emulator-control has not run for 500 ms" in info.getMessage()
    assert "test_the_found_stall" in info.getMessage()
    monitor.forget(beat)


@pytest.mark.parametrize(("verbose", "on_console"), [(0, False), (1, True), (2, True)])
def test_the_rover_commands_v_is_what_brings_them_back(verbose: int, on_console: bool) -> None:
    parser = argparse.ArgumentParser()
    add_runtime_arguments(parser, 0)
    args = parser.parse_args([])
    args.verbose = verbose  # the rover command's own -v (firmware_proto.cli)
    assert runtime_options(args, "demo").stall_stacks_on_console is on_console


def test_stalls_coming_again_and_again_are_counted_not_each_said(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """A machine that holds a process up again and again (at a load of 30 a demo was held
    up 60 times in a minute): one line, then the next after CONSOLE_QUIET_S naming how
    many more there were; the stall log keeps every one."""
    from firmware_proto.runtime.stall import CONSOLE_QUIET_S

    log = tmp_path / "stalls.jsonl"
    clock = Clock()
    monitor = StallMonitor("demo", log_path=log, clock=clock)
    with caplog.at_level(logging.WARNING, logger="firmware_proto.runtime.stall"):
        for _ in range(5):  # five stalls within a few seconds
            _stall_once(monitor, clock)
            clock.now += 1.0
        clock.now += CONSOLE_QUIET_S
        _stall_once(monitor, clock)
    lines = _warnings(caplog)
    assert len(lines) == 2, lines
    assert "more since" not in lines[0]
    assert "(4 more since the last line, the longest 300 ms)" in lines[1]
    assert all("\n" not in line for line in lines)
    assert len(read_stalls(log)) == 6
