"""The process runtime: real-time scheduling asked for and reported once, stalls found
and said where they were, heartbeat gaps (docs/realtime.md)."""

from __future__ import annotations

import gc
import json
import os
import re
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from firmware_proto.runtime import stall
from firmware_proto.runtime.realtime import RealtimeConfig, RealtimeStatus
from firmware_proto.runtime.stall import (
    StallMonitor,
    StallRecord,
    describe_stalls,
    read_stalls,
    stall_log_path,
)
from firmware_proto.wire.gapstats import GapStats

ROOT = Path(__file__).resolve().parents[2]
IS_ROOT = os.geteuid() == 0


# -- gaps ----------------------------------------------------------------------------------
def test_gap_stats_measure_the_gaps_their_lateness_and_restart() -> None:
    gaps = GapStats(period_s=0.1)
    assert gaps.summary().max_ms is None
    assert gaps.summary().line() == "none yet"
    for t in (0.0, 0.1, 0.2, 0.55, 0.65):
        gaps.event(t)
    s = gaps.summary()
    assert s.count == 4
    assert s.max_ms == pytest.approx(350.0)
    assert s.late_max_ms == pytest.approx(250.0)
    assert s.last_ms == pytest.approx(100.0)
    gaps.restart()  # the link reopened: the silence between is no gap
    gaps.event(10.0)
    gaps.event(10.1)
    assert gaps.summary().count == 5
    assert gaps.summary().max_ms == pytest.approx(350.0)
    assert gaps.event(9.0) is None  # out of order: not counted


def test_gap_stats_p99_is_of_the_recent_window() -> None:
    gaps = GapStats(window=100)
    t = 0.0
    gaps.event(t)
    for i in range(300):
        t += 1.0 if i == 0 else 0.01  # one long gap, then 299 short ones
        gaps.event(t)
    s = gaps.summary()
    assert s.max_ms == pytest.approx(1000.0)
    assert s.p99_ms == pytest.approx(10.0)  # the long gap left the window
    with pytest.raises(ValueError, match="window"):
        GapStats(window=0)


# -- real-time scheduling ------------------------------------------------------------------
_PROBE = """
import json, os, sys, threading
from firmware_proto.runtime.realtime import RealtimeConfig, apply_realtime
status = apply_realtime(RealtimeConfig(int(sys.argv[1])))
seen = {}
t = threading.Thread(target=lambda: seen.update(policy=os.sched_getscheduler(0)))
t.start(); t.join()
print(json.dumps({"line": status.line(), "granted": status.granted,
                  "locked": status.memory_locked, "thread_policy": seen["policy"]}))
"""


def _python(
    code: str,
    *args: str,
    prefix: tuple[str, ...] = (),
    check: bool = True,
    env: dict[str, str] | None = None,
) -> subprocess.CompletedProcess[str]:
    """``python -c code args`` in a process of its own (its scheduling is its own);
    ``env``: variables added to this process's environment."""
    done = subprocess.run(
        [*prefix, sys.executable, "-c", code, *args],
        cwd=ROOT,
        env={**os.environ, **(env or {})},
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert not check or done.returncode == 0, (done.returncode, done.stderr[-3000:])
    return done


def _probe(priority: int, *prefix: str) -> dict[str, object]:
    done = _python(_PROBE, str(priority), prefix=prefix)
    result: dict[str, object] = json.loads(done.stdout)
    assert done.stderr == ""  # said once, by the program: the library logs nothing
    return result


@pytest.mark.skipif(not IS_ROOT, reason="granting real time needs root here")
def test_real_time_is_granted_and_every_thread_started_after_inherits_it() -> None:
    result = _probe(20)
    assert result["granted"] is True
    assert result["locked"] is True
    assert result["thread_policy"] == os.SCHED_RR
    assert result["line"] == "realtime: SCHED_RR priority 20, memory locked"


@pytest.mark.skipif(
    not IS_ROOT or shutil.which("setpriv") is None,
    reason="needs root and setpriv to take the permission away",
)
def test_without_permission_it_runs_on_and_says_why() -> None:
    result = _probe(20, "setpriv", "--bounding-set=-sys_nice")
    assert result["granted"] is False
    assert result["thread_policy"] == os.SCHED_OTHER
    line = str(result["line"])
    assert line.startswith("realtime: NOT granted (sched_setscheduler: Operation not permitted")
    assert "docs/realtime.md" in line


_PROCESS_PROBE = """
import json, os, sys, threading
from firmware_proto.runtime.realtime import RealtimeConfig, apply_realtime_to_process
go = threading.Event()
# Started at normal priority, as a library's thread would be; it waits to be counted.
t = threading.Thread(target=go.wait, args=(10,)); t.start()
status = apply_realtime_to_process(RealtimeConfig(int(sys.argv[1]), lock_memory=False))
policies = {}
for tid in os.listdir("/proc/self/task"):
    policies[tid] = os.sched_getscheduler(int(tid))
go.set(); t.join()
print(json.dumps({"granted": status.granted, "policies": sorted(set(policies.values())),
                  "threads": len(policies)}))
"""


@pytest.mark.skipif(not IS_ROOT, reason="granting real time needs root here")
def test_a_whole_process_is_promoted_with_the_threads_it_already_started() -> None:
    done = _python(_PROCESS_PROBE, "15")
    result = json.loads(done.stdout)
    assert result["granted"] is True and result["threads"] >= 2
    assert result["policies"] == [os.SCHED_RR]  # the thread started before too
    normal = json.loads(_python(_PROCESS_PROBE, "0").stdout)
    assert normal["granted"] is False and normal["policies"] == [os.SCHED_OTHER]


_WIND_DOWN_PROBE = """
import json, os, sys, threading
from firmware_proto.runtime import ProcessRuntime, RuntimeOptions
go = threading.Event()
seen = {}
def policies():
    found = set()
    for tid in os.listdir("/proc/self/task"):
        try:
            found.add(os.sched_getscheduler(int(tid)))
        except ProcessLookupError:  # a thread that ended meanwhile (the stall monitor's)
            pass
    return sorted(found)
os.setpriority(os.PRIO_PROCESS, 0, 4)
with ProcessRuntime(RuntimeOptions("probe", priority=int(sys.argv[1]), lock_memory=False)) as rt:
    t = threading.Thread(target=go.wait, args=(10,)); t.start()
    seen["running"] = policies()
    rt.wind_down()
    seen["ending"] = policies()
    seen["thread_nice"] = os.getpriority(os.PRIO_PROCESS, t.native_id)
    rt.wind_down()  # again: nothing left to do
    go.set(); t.join()
seen["after"] = policies()
print(json.dumps(seen))
"""


@pytest.mark.skipif(not IS_ROOT, reason="granting real time needs root here")
def test_an_ending_program_leaves_real_time_every_thread_of_it() -> None:
    result = json.loads(_python(_WIND_DOWN_PROBE, "20").stdout)
    assert result["running"] == [os.SCHED_RR]
    assert result["ending"] == [os.SCHED_OTHER]  # the thread it started too
    assert result["thread_nice"] == 4  # its nice is kept
    assert result["after"] == [os.SCHED_OTHER]
    normal = json.loads(_python(_WIND_DOWN_PROBE, "0").stdout)
    assert normal["running"] == normal["ending"] == [os.SCHED_OTHER]


def test_priority_zero_is_normal_scheduling() -> None:
    result = _probe(0)
    assert result["granted"] is False
    assert result["thread_policy"] == os.SCHED_OTHER
    assert str(result["line"]).startswith("realtime: off")


_SCOPED_PROBE = """
import json, os, sys, threading
from firmware_proto.runtime import ProcessRuntime, RuntimeOptions
from firmware_proto.runtime.realtime import RealtimeConfig, realtime_threads
os.setpriority(os.PRIO_PROCESS, 0, 3)
seen = {}
def policy_of_a_new_thread(key):
    t = threading.Thread(target=lambda: seen.update({key: os.sched_getscheduler(0)}))
    t.start(); t.join()
with realtime_threads(RealtimeConfig(25, lock_memory=False)) as status:
    policy_of_a_new_thread("inside")
    seen["granted"] = status.granted
policy_of_a_new_thread("after")
seen["caller_after"] = [os.sched_getscheduler(0), os.getpriority(os.PRIO_PROCESS, 0)]
switch = sys.getswitchinterval()
with ProcessRuntime(RuntimeOptions("probe", priority=25, short_switch=True, lock_memory=False)):
    policy_of_a_new_thread("program")
    seen["short_switch"] = sys.getswitchinterval() < switch
seen["caller_after_program"] = [os.sched_getscheduler(0), os.getpriority(os.PRIO_PROCESS, 0)]
seen["switch_back"] = sys.getswitchinterval() == switch
print(json.dumps(seen))
"""


@pytest.mark.skipif(not IS_ROOT, reason="granting real time needs root here")
def test_scoped_real_time_reaches_the_threads_started_inside_and_puts_the_caller_back() -> None:
    """``realtime_threads`` and :class:`ProcessRuntime` (as ``rover replay`` run
    in-process uses it) leave the calling thread as they found it: policy, nice, and the
    interpreter's switch interval."""
    seen = json.loads(_python(_SCOPED_PROBE).stdout)
    assert seen["granted"] is True
    assert seen["inside"] == seen["program"] == os.SCHED_RR
    assert seen["after"] == os.SCHED_OTHER
    assert seen["caller_after"] == seen["caller_after_program"] == [os.SCHED_OTHER, 3]
    assert seen["short_switch"] is True
    assert seen["switch_back"] is True


_CHILD_PROBE = """
import json, os, subprocess, sys
from firmware_proto.runtime.realtime import (
    RealtimeConfig, module_command_at_normal_priority, realtime_threads,
)
def child(argv):
    out = subprocess.run(argv + ["one", "two"], capture_output=True, text=True, check=True)
    return json.loads(out.stdout)
with realtime_threads(RealtimeConfig(25, lock_memory=False)):
    plain = child([sys.executable, "-m", "rt_child_probe"])
    launched = child(module_command_at_normal_priority("rt_child_probe"))
print(json.dumps({"plain": plain, "launched": launched}))
"""

_CHILD_MODULE = """
import json, os, sys
print(json.dumps({"policy": os.sched_getscheduler(0), "name": __name__,
                  "argv": sys.argv[1:], "nice": os.getpriority(os.PRIO_PROCESS, 0)}))
"""


@pytest.mark.skipif(not IS_ROOT, reason="granting real time needs root here")
def test_a_child_launched_at_normal_priority_does_its_imports_at_normal_priority(
    tmp_path: Path,
) -> None:
    """A real-time caller's child inherits real time, and a Python child's imports then
    hold a core at that priority; ``module_command_at_normal_priority`` starts the module
    under ``SCHED_OTHER`` from its first line, as ``python -m`` would run it (its name
    ``__main__``, its arguments), its nice kept."""
    (tmp_path / "rt_child_probe.py").write_text(_CHILD_MODULE)
    env = {"PYTHONPATH": os.pathsep.join((str(tmp_path), str(ROOT)))}
    seen = json.loads(_python(_CHILD_PROBE, env=env).stdout)
    assert seen["plain"]["policy"] == os.SCHED_RR  # the hazard: inherited
    launched = seen["launched"]
    assert launched["policy"] == os.SCHED_OTHER
    assert launched["name"] == "__main__" and launched["argv"] == ["one", "two"]
    assert launched["nice"] == seen["plain"]["nice"]


def test_config_is_checked() -> None:
    with pytest.raises(ValueError, match=r"0\.\.99"):
        RealtimeConfig(100)
    with pytest.raises(ValueError, match="policy"):
        RealtimeConfig(10, policy="deadline")
    status = RealtimeStatus("SCHED_FIFO", 30, 0, False, True, "memory not locked: x")
    assert status.line() == (
        "realtime: SCHED_FIFO priority 30, memory not locked (memory not locked: x)"
    )


@pytest.mark.skipif(
    not IS_ROOT or shutil.which("setpriv") is None,
    reason="needs root and setpriv to take the permission away",
)
def test_rover_emulate_without_permission_serves_and_says_so_once() -> None:
    proc = subprocess.run(
        [
            "setpriv",
            "--bounding-set=-sys_nice",
            sys.executable,
            "-m",
            "firmware_proto.cli",
            "emulate",
            "--serial",
            "--duration",
            "1",
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("DEVICE /dev/pts/")
    said = [line for line in proc.stderr.splitlines() if "realtime" in line]
    assert len(said) == 1 and said[0].startswith("realtime: NOT granted"), proc.stderr


# -- stalls ---------------------------------------------------------------------------------
def test_a_stalled_loop_is_reported_with_its_stack_and_logged(tmp_path: Path) -> None:
    log = tmp_path / "stalls.jsonl"
    resumed = threading.Event()

    def stalling_loop(monitor: StallMonitor) -> None:
        beat = monitor.watch("test-loop")
        try:
            for _ in range(5):
                beat.tick()
                time.sleep(0.01)
            time.sleep(0.4)  # the stall
            beat.tick()
            resumed.set()
            for _ in range(10):
                beat.tick()
                time.sleep(0.01)
        finally:
            monitor.forget(beat)

    with StallMonitor("tester", threshold_s=0.1, log_path=log) as monitor:
        thread = threading.Thread(target=stalling_loop, args=(monitor,), name="stalling")
        thread.start()
        thread.join(10)
        assert resumed.is_set()
        deadline = time.monotonic() + 5
        # A loaded machine may hold the loop up before the stall as well (132 ms was
        # seen beside 4 busy processes): the 0.4 s stall is the longest record.
        while not any(r.thread == "test-loop" and r.ms >= 350 for r in monitor.records):
            assert time.monotonic() < deadline, monitor.records
            time.sleep(0.02)
    record = max((r for r in read_stalls(log) if r.thread == "test-loop"), key=lambda r: r.ms)
    assert record.process == "tester" and record.pid == os.getpid()
    assert record.ms >= 350
    assert "stalling_loop" in record.stack and "time.sleep(0.4)" in record.stack
    assert "thread test-loop stalled" in record.line()


def test_a_process_held_up_in_c_is_caught_with_every_thread_stack(tmp_path: Path) -> None:
    """A C call that keeps the interpreter lock (here a regular expression that
    backtracks; in the field, a middleware publish) stops every Python thread, the
    monitor's too: the interpreter's own watchdog names the culprit."""
    log = tmp_path / "stalls.jsonl"
    pattern = re.compile(r"(a+)+$")
    with StallMonitor("tester", threshold_s=0.1, log_path=log) as monitor:
        size = 22
        while True:  # long enough to hold the lock over the threshold on this machine
            start = time.monotonic()
            pattern.match("a" * size + "b")
            held_ms = (time.monotonic() - start) * 1e3
            if held_ms > 300:
                break
            size += 1
            assert size < 40
        deadline = time.monotonic() + 5
        while not any(r.thread == "*" for r in monitor.records):
            assert time.monotonic() < deadline, monitor.records
            time.sleep(0.02)
    whole = [r for r in read_stalls(log) if r.thread == "*"]
    # The stall caught is this one, past the threshold. How much of the hold it measured
    # is timing, not behaviour: the monitor wakes every 50 ms, and beside busy work it may
    # have woken late before the hold, or the hold was preempted (236 ms were recorded
    # of a hold that took 473 ms of wall time, beside the test command's other parts).
    assert whole and max(r.ms for r in whole) >= 100
    assert any("test_a_process_held_up_in_c" in r.stack for r in whole), whole[0].stack


def test_a_stall_says_how_much_of_it_the_garbage_collector_ran() -> None:
    """A collection holds the whole process and shows in no stack: the record says how
    much of the stall it took (here on the monitor's own clock, by hand)."""
    now = [0.0]
    monitor = StallMonitor("tester", threshold_s=0.1, clock=lambda: now[0])
    beat = monitor.watch("loop")
    now[0] = 0.05
    monitor.gc("start", {"generation": 2})
    now[0] = 0.20
    monitor.check(now[0])  # the loop is 200 ms old: a stall begins
    now[0] = 0.25
    monitor.gc("stop", {"generation": 2})
    now[0] = 0.30
    beat.tick()
    monitor.check(now[0])
    now[0] = 0.70
    monitor.gc("start", {"generation": 0})  # a collection after the stall is not in it
    now[0] = 0.80
    monitor.gc("stop", {"generation": 0})
    (record,) = monitor.records
    assert record.thread == "loop" and record.ms == 300.0 and record.gc_ms == 200.0
    assert record.line().endswith("(200 ms of it collecting garbage)")
    assert monitor.gc.within(0.6, 0.9) == pytest.approx(0.1)


def test_the_monitor_times_real_collections_while_it_runs(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(stall, "GC_PAUSE_MIN_S", 0.0)
    monitor = StallMonitor("tester", threshold_s=0.1)
    with monitor:
        assert monitor.gc in gc.callbacks
        gc.collect()
    assert monitor.gc not in gc.callbacks
    assert any(generation == 2 for _, _, generation in monitor.gc.pauses), monitor.gc.pauses
    count = len(monitor.gc.pauses)
    gc.collect()  # detached: not timed
    assert len(monitor.gc.pauses) == count


def test_the_stall_log_reads_back_skips_bad_lines_and_describes(tmp_path: Path) -> None:
    log = tmp_path / "stalls.jsonl"
    records = [
        StallRecord("bridge", 10, "link-timer", 312.0, 1000.0, "stack a"),
        StallRecord("bridge", 10, "*", 150.0, 1001.0),
        StallRecord("emulator", 11, "emulator-control", 120.0, 999.0),
    ]
    log.write_text(
        # As written before records had gc_ms: such a log still reads.
        "\n".join(
            json.dumps({k: v for k, v in r.__dict__.items() if k != "gc_ms"}) for r in records
        )
        + "\nnot json\n{}\n",
        encoding="utf-8",
    )
    back = read_stalls(log)
    assert [r.wall_s for r in back] == [999.0, 1000.0, 1001.0]
    assert read_stalls(log, since_wall_s=1000.5) == [records[1]]
    lines = describe_stalls(back, 0.1)
    assert lines[0].startswith("stall: bridge (pid 10): thread link-timer stalled 312 ms")
    assert lines[0].endswith("(2 stalls)")
    assert lines[1].startswith("stall: emulator (pid 11)")
    assert describe_stalls([], 0.1) == [
        "no process of the stack on this host stalled longer than 100 ms"
    ]
    assert read_stalls(tmp_path / "missing.jsonl") == []
    assert all(r.gc_ms == 0.0 for r in back)


def test_the_stall_log_path_comes_from_the_environment() -> None:
    assert stall_log_path({"ROVER_STALL_LOG": "/x/y.jsonl"}) == Path("/x/y.jsonl")
    assert stall_log_path({"ROVER_STALL_LOG": ""}) is None
    default = stall_log_path({})
    assert default is not None and default.name == "stalls.jsonl"


def test_sigusr1_logs_every_threads_stack_and_the_program_runs_on() -> None:
    code = (
        "import logging, os, signal, sys, threading, time\n"
        "logging.basicConfig(level=logging.WARNING)\n"
        "from firmware_proto.runtime import ProcessRuntime, RuntimeOptions\n"
        "def worker_loop(stop):\n"
        "    while not stop.wait(0.01):\n"
        "        pass\n"
        "stop = threading.Event()\n"
        "with ProcessRuntime(RuntimeOptions('tester')):\n"
        "    t = threading.Thread(target=worker_loop, args=(stop,), name='worker'); t.start()\n"
        "    os.kill(os.getpid(), signal.SIGUSR1)\n"
        "    time.sleep(0.2)\n"
        "    stop.set(); t.join()\n"
        "print('still here')\n"
    )
    done = _python(code, check=False)
    assert done.returncode == 0, done.stderr
    assert done.stdout == "still here\n"
    assert "stacks on request (SIGUSR1)" in done.stderr
    assert "thread worker:" in done.stderr and "worker_loop" in done.stderr
