"""The process pool on its own: calls, failures, a worker that dies mid-call, closing.

Real worker processes (``spawn``), as the gate runs them; the functions they run are
this module's, imported by each worker."""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Iterator
from concurrent.futures import CancelledError
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

import pytest

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
    with ProcessWorkerPool(validator, 2) as made:
        assert isinstance(made, ProcessWorkerPool)
        yield made


def test_calls_run_on_both_workers_each_once(pool: ProcessWorkerPool) -> None:
    futures = [pool.submit_call(_pid_after, 0.05) for _ in range(8)]
    pids = [f.result(WAIT_S) for f in futures]
    assert set(pids) == set(pool.pids) and len(pool.pids) == 2


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
