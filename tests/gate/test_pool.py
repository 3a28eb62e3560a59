"""The process pool on its own: calls, failures, a worker that dies mid-call, closing.

Real worker processes (``spawn``), as the gate runs them; the functions they run are
this module's, imported by each worker."""

from __future__ import annotations

import functools
import os
import signal
import time
from collections.abc import Iterator
from concurrent.futures import CancelledError
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

import pytest

from firmware_proto.runtime.procname import process_name
from gate.errors import CallCancelledError
from gate.pool import ProcessWorkerPool
from gate.validator import Validator

WAIT_S = 60.0


def _pid_after(seconds: float) -> int:
    time.sleep(seconds)
    return os.getpid()


def _hang_until(path: str) -> int:
    """Sleep until ``path`` exists (bounded): a call the test ends by hand."""
    deadline = time.monotonic() + WAIT_S
    while not Path(path).exists() and time.monotonic() < deadline:
        time.sleep(0.01)
    return os.getpid()


def _fail(message: str) -> None:
    raise ValueError(message)


def _unpicklable(_: object) -> object:
    return lambda: None


def _refuse_to_load() -> None:
    raise ValueError("not here")


class _Unloadable:
    """Pickles in the worker; unpickling it raises (in the pool's reader thread)."""

    def __reduce__(self) -> tuple[object, tuple[()]]:
        return _refuse_to_load, ()


def _unloadable(_: object) -> _Unloadable:
    return _Unloadable()


@pytest.fixture
def pool(validator: Validator) -> Iterator[ProcessWorkerPool]:
    """Two workers that have imported this module (a call's first use of its module
    imports it in the worker: seconds on a loaded machine)."""
    with ProcessWorkerPool(validator, 2) as made:
        assert isinstance(made, ProcessWorkerPool)
        warm = [made.submit_call(_pid_after, 0.2) for _ in range(2)]
        assert {f.result(WAIT_S) for f in warm} == set(made.pids)
        yield made


def test_calls_run_on_both_workers_each_once(pool: ProcessWorkerPool) -> None:
    futures = [pool.submit_call(_pid_after, 0.05) for _ in range(8)]
    pids = [f.result(WAIT_S) for f in futures]
    assert set(pids) == set(pool.pids) and len(pool.pids) == 2
    # Named for top and pgrep (firmware_proto/runtime/procname.py).
    assert [process_name(pid) for pid in pool.pids] == ["rover-gate-work"] * 2


def test_a_failure_in_a_worker_is_the_callers_exception(pool: ProcessWorkerPool) -> None:
    with pytest.raises(ValueError, match="no such plan"):
        pool.submit_call(_fail, "no such plan").result(WAIT_S)
    with pytest.raises(RuntimeError, match="could not be sent"):
        pool.submit_call(_unpicklable, None).result(WAIT_S)
    with pytest.raises(RuntimeError, match="could not be read"):
        pool.submit_call(_unloadable, None).result(WAIT_S)
    assert pool.submit_call(_pid_after, 0).result(WAIT_S) in pool.pids  # still serving


def test_a_worker_killed_mid_call_fails_that_call_and_is_replaced(
    pool: ProcessWorkerPool, tmp_path: Path
) -> None:
    gate_file = tmp_path / "go"
    stuck = pool.submit_call(_hang_until, str(gate_file))
    other = pool.submit_call(_hang_until, str(gate_file))
    deadline = time.monotonic() + WAIT_S
    while not (stuck.running() and other.running()) and time.monotonic() < deadline:
        time.sleep(0.01)
    before = pool.pids
    os.kill(before[0], signal.SIGKILL)
    failed = 0
    gate_file.touch()
    for future in (stuck, other):
        try:
            assert future.result(WAIT_S) == before[1]
        except BrokenProcessPool:
            failed += 1
    assert failed == 1  # the killed one's call, and only it
    pids = {pool.submit_call(_pid_after, 0.05).result(WAIT_S) for _ in range(6)}
    assert before[0] not in pids
    deadline = time.monotonic() + WAIT_S  # the replacement starts in about a second
    while len(pool.pids) < 2 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert len(pool.pids) == 2 and before[0] not in pool.pids


def test_close_waits_for_calls_under_way_and_cancels_the_waiting(
    validator: Validator, tmp_path: Path
) -> None:
    gate_file = tmp_path / "go"
    pool = ProcessWorkerPool(validator, 1)
    running = pool.submit_call(_hang_until, str(gate_file))
    waiting = pool.submit_call(_pid_after, 0)
    deadline = time.monotonic() + WAIT_S
    while not running.running() and time.monotonic() < deadline:
        time.sleep(0.01)
    pids = pool.pids
    gate_file.touch()
    pool.close(wait=True)
    assert running.result(0) == pids[0]
    with pytest.raises(CancelledError):
        waiting.result(0)
    with pytest.raises(RuntimeError, match="closed"):
        pool.submit_call(_pid_after, 0)
    for pid in pids:  # the workers are gone
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)


def _stubborn(path: str) -> int:
    """A call that cannot be interrupted (it ignores the pool's signal), until ``path``
    exists: what native code that never returns to the interpreter looks like to the
    pool. It says it has started by creating ``path + ".started"``."""
    signal.signal(signal.SIGUSR1, signal.SIG_IGN)
    Path(path + ".started").touch()
    return _hang_until(path)


def _started(path: str) -> int:
    """:func:`_hang_until`, saying it has started by creating ``path + ".started"``."""
    Path(path + ".started").touch()
    return _hang_until(path)


def _wait_file(path: Path) -> None:
    deadline = time.monotonic() + WAIT_S
    while not path.exists():
        assert time.monotonic() < deadline, f"{path} never appeared"
        time.sleep(0.01)


def _record(order: list[str], name: str, _future: object) -> None:
    order.append(name)


def _wait_running(pool: ProcessWorkerPool, client: str, count: int) -> None:
    deadline = time.monotonic() + WAIT_S
    while pool.running(client) < count:
        assert time.monotonic() < deadline, f"{client!r} never had {count} calls running"
        time.sleep(0.01)


def test_a_running_call_is_cancelled_and_its_worker_kept(
    pool: ProcessWorkerPool, tmp_path: Path
) -> None:
    running = pool.submit_call(_hang_until, str(tmp_path / "never"), client="a")
    waiting = pool.submit_call(_hang_until, str(tmp_path / "never"), client="a")
    third = pool.submit_call(_pid_after, 0, client="a")
    _wait_running(pool, "a", 2)
    before = pool.pids
    assert pool.cancel(running) and pool.cancel(waiting)
    for future in (running, waiting):
        with pytest.raises(CallCancelledError):
            future.result(WAIT_S)
    assert third.result(WAIT_S) in before
    assert pool.pids == before and pool.killed == 0 and pool.interrupted == 2
    queued = pool.submit_call(_hang_until, str(tmp_path / "never"), client="a")
    blocker = pool.submit_call(_hang_until, str(tmp_path / "never"), client="a")
    late = pool.submit_call(_pid_after, 0, client="a")  # waits: both workers hang
    assert pool.cancel(late)  # dropped from the line, never run
    with pytest.raises(CancelledError):
        late.result(WAIT_S)
    for future in (queued, blocker):
        pool.cancel(future)
        with pytest.raises(CallCancelledError):
            future.result(WAIT_S)


def test_a_worker_that_cannot_stop_its_call_is_killed_and_replaced(
    pool: ProcessWorkerPool, tmp_path: Path
) -> None:
    stuck = pool.submit_call(_stubborn, str(tmp_path / "never"), client="a")
    _wait_file(tmp_path / "never.started")
    before = set(pool.pids)
    assert pool.cancel(stuck)
    with pytest.raises(CallCancelledError, match="killed"):
        stuck.result(WAIT_S)
    assert pool.killed == 1
    deadline = time.monotonic() + WAIT_S  # the replacement starts in about a second
    while (len(pool.pids) < 2 or set(pool.pids) == before) and time.monotonic() < deadline:
        time.sleep(0.01)
    assert len(pool.pids) == 2 and set(pool.pids) != before
    assert {pool.submit_call(_pid_after, 0.05).result(WAIT_S) for _ in range(4)} <= set(pool.pids)


def test_a_client_over_its_share_makes_room_for_another(
    pool: ProcessWorkerPool, tmp_path: Path
) -> None:
    """Client a's two preemptible calls hold both workers; client b's call is not kept
    waiting: one of a's is stopped, b's runs, and a's goes back first in a's line and
    still gives its result."""
    gate_file = tmp_path / "go"
    a = [pool.submit_call(_started, str(gate_file), client="a", preemptible=True) for _ in range(2)]
    _wait_running(pool, "a", 2)
    _wait_file(tmp_path / "go.started")
    b = pool.submit_call(_pid_after, 0, client="b")
    assert b.result(WAIT_S) in pool.pids
    assert not any(f.done() for f in a)  # b did not wait for a
    assert pool.interrupted == 1 and pool.killed == 0
    gate_file.touch()
    assert {f.result(WAIT_S) for f in a} <= set(pool.pids)


def test_a_free_worker_takes_the_client_with_fewest_calls_running(
    validator: Validator, tmp_path: Path
) -> None:
    gate_file = tmp_path / "go"
    order: list[str] = []
    with ProcessWorkerPool(validator, 1) as pool:
        first = pool.submit_call(_hang_until, str(gate_file), client="a")
        assert isinstance(pool, ProcessWorkerPool)
        _wait_running(pool, "a", 1)
        calls = [
            (name, pool.submit_call(_pid_after, 0, client=name))
            for name in ("a", "a", "a", "b", "c", "b")
        ]
        for name, future in calls:
            future.add_done_callback(functools.partial(_record, order, name))
        gate_file.touch()
        first.result(WAIT_S)
        for _, future in calls:
            future.result(WAIT_S)
    # a had one running when the others came: b and c go first, then round robin.
    assert order == ["b", "c", "a", "b", "a", "a"], order
