"""Worker pools that run validations off the HTTP threads.

:class:`WorkerPool` does the shared work (refusing jobs after close, logging) in
:meth:`~WorkerPool.submit` and calls one hook, :meth:`~WorkerPool._submit`, that each
implementation fills; :meth:`~WorkerPool._close` releases its resources. A job is a
:class:`gate.validator.Job`; its result is the verdict's JSON bytes.

- :class:`ProcessWorkerPool` (default): one process per worker, started with ``spawn``
  (never ``fork`` from a threaded server), each holding its own validator. The playback
  is pure Python and CPU-bound, so processes are what runs plans in parallel on several
  cores. All workers start at construction and prove ready (:meth:`warm_up`) before the
  server says it listens; a worker that dies is replaced on the next job.
- :class:`ThreadWorkerPool`: threads in this process sharing one validator: no start-up
  cost, but the GIL runs one playback at a time. For tests and small machines.

Admission (how many jobs may wait) is the server's business, not the pool's.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import signal
import threading
from collections.abc import Callable
from concurrent.futures import Future, ProcessPoolExecutor, ThreadPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any, TypeVar

from gate.config import GateConfig
from gate.errors import GateConfigError
from gate.validator import Job, Validator

__all__ = [
    "ProcessWorkerPool",
    "ThreadWorkerPool",
    "WorkerPool",
    "make_pool",
    "run_job",
]

logger = logging.getLogger(__name__)

_T = TypeVar("_T")

WARM_UP_TIMEOUT_S = 60.0
"""Longest wait for every worker process to start and load the maps."""

_validator: Validator | None = None  # the worker process's own validator
_arrived: Any = None  # multiprocessing Semaphore: released once by each warm-up job
_go: Any = None  # multiprocessing Event: set once every worker has arrived


def _init_worker(validator: Validator, arrived: Any, go: Any) -> None:
    global _validator, _arrived, _go  # noqa: PLW0603 - per-process state of a pool worker
    # The server process owns shutdown: a Ctrl-C or SIGTERM sent to the whole process
    # group must not kill workers under in-flight requests (they exit when it says so).
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    _validator = validator
    _arrived = arrived
    _go = go


def _warm_up() -> int:
    """Runs once in each new worker: check in, then wait until every worker has."""
    _arrived.release()
    if not _go.wait(WARM_UP_TIMEOUT_S):
        raise RuntimeError("not every gate worker started in time")
    return os.getpid()


def run_job(job: Job) -> bytes:
    """Validate ``job`` with this process's validator; the verdict's JSON bytes."""
    if _validator is None:  # pragma: no cover - the initializer always ran
        raise RuntimeError("worker process has no validator")
    return _validator.run(job).to_json().encode()


class WorkerPool:
    """Base of the pools. Implementations fill :meth:`_submit` and may fill :meth:`_close`.

    Thread-safe; :meth:`close` is idempotent.
    """

    kind = "base"

    def __init__(self, validator: Validator, workers: int) -> None:
        if workers < 1:
            raise GateConfigError(f"workers must be >= 1, got {workers}")
        self.validator = validator
        self.workers = workers
        self._closed = False
        self._lock = threading.Lock()

    def submit(self, job: Job) -> Future[bytes]:
        """Start ``job``; the future gives the verdict JSON bytes, or raises what
        validation raised.

        Raises:
            RuntimeError: the pool is closed.
        """
        with self._lock:
            if self._closed:
                raise RuntimeError(f"{self.kind} pool is closed")
        return self._submit(job)

    def _submit(self, job: Job) -> Future[bytes]:
        raise NotImplementedError

    def submit_call(self, fn: Callable[[Any], _T], arg: Any) -> Future[_T]:
        """Run ``fn(arg)`` on a worker (``fn`` a module-level function, ``arg``
        picklable: a chunk of an uncertain verdict, :func:`gate.ensemble.run_chunk`).

        Raises:
            RuntimeError: the pool is closed.
        """
        with self._lock:
            if self._closed:
                raise RuntimeError(f"{self.kind} pool is closed")
        return self._submit_call(fn, arg)

    def _submit_call(self, fn: Callable[[Any], _T], arg: Any) -> Future[_T]:
        raise NotImplementedError

    def close(self, *, wait: bool = True) -> None:
        """Stop taking jobs; with ``wait``, let the running ones finish first. Queued jobs
        that have not started are cancelled."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        self._close(wait)
        logger.debug("%s pool closed", self.kind)

    def _close(self, wait: bool) -> None:
        """Release the implementation's resources."""

    def __enter__(self) -> WorkerPool:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class ThreadWorkerPool(WorkerPool):
    """Threads sharing this process's validator (one playback at a time under the GIL)."""

    kind = "thread"

    def __init__(self, validator: Validator, workers: int) -> None:
        super().__init__(validator, workers)
        self._executor = ThreadPoolExecutor(workers, thread_name_prefix="gate-worker")
        # Start every thread now (the executor would add them one job at a time): no
        # thread can pass the barrier before all exist, so each submit adds one.
        barrier = threading.Barrier(workers)
        for future in [
            self._executor.submit(barrier.wait, WARM_UP_TIMEOUT_S) for _ in range(workers)
        ]:
            future.result(timeout=WARM_UP_TIMEOUT_S)

    def _submit(self, job: Job) -> Future[bytes]:
        return self._executor.submit(self._run, job)

    def _run(self, job: Job) -> bytes:
        return self.validator.run(job).to_json().encode()

    def _submit_call(self, fn: Callable[[Any], _T], arg: Any) -> Future[_T]:
        return self._executor.submit(fn, arg)

    def _close(self, wait: bool) -> None:
        self._executor.shutdown(wait=wait, cancel_futures=True)


class ProcessWorkerPool(WorkerPool):
    """Worker processes started with ``spawn``, each with its own validator."""

    kind = "process"

    def __init__(self, validator: Validator, workers: int) -> None:
        super().__init__(validator, workers)
        self._context = multiprocessing.get_context("spawn")
        self._executor = self._start()

    def _start(self) -> ProcessPoolExecutor:
        # Semaphore and Event, not Barrier: a Barrier's shared counter lives in a
        # process-wide shared-memory arena that is never released.
        arrived, go = self._context.Semaphore(0), self._context.Event()
        executor = ProcessPoolExecutor(
            self.workers,
            mp_context=self._context,
            initializer=_init_worker,
            initargs=(self.validator, arrived, go),
        )
        try:
            self.pids = self.warm_up(executor, arrived, go)
        except BaseException:
            executor.shutdown(wait=True, cancel_futures=True)
            raise
        logger.info("started %d worker processes: %s", self.workers, self.pids)
        return executor

    def warm_up(self, executor: ProcessPoolExecutor, arrived: Any, go: Any) -> list[int]:
        """Start every worker now (the executor would start them one job at a time) and
        wait until each has loaded the validator; the workers' process ids.

        Raises:
            RuntimeError: a worker did not come up in time.
        """
        # No warm-up job can finish before all workers have checked in, so each submit
        # finds no idle worker and starts a new process.
        futures = [executor.submit(_warm_up) for _ in range(self.workers)]
        try:
            for _ in range(self.workers):
                if not arrived.acquire(timeout=WARM_UP_TIMEOUT_S):
                    raise RuntimeError("timed out")
            go.set()
            pids = sorted(f.result(timeout=WARM_UP_TIMEOUT_S) for f in futures)
        except Exception as exc:
            go.set()
            raise RuntimeError(f"gate worker processes did not start: {exc}") from exc
        return pids

    def _submit(self, job: Job) -> Future[bytes]:
        return self._submit_call(run_job, job)

    def _submit_call(self, fn: Callable[[Any], _T], arg: Any) -> Future[_T]:
        with self._lock:
            executor = self._executor
        try:
            return executor.submit(fn, arg)
        except BrokenProcessPool:
            logger.warning("a worker process died; restarting the pool")
            with self._lock:
                if self._executor is executor:
                    executor.shutdown(wait=True, cancel_futures=True)  # reaps the dead
                    self._executor = self._start()
                executor = self._executor
            return executor.submit(fn, arg)

    def _close(self, wait: bool) -> None:
        with self._lock:
            executor = self._executor
        executor.shutdown(wait=wait, cancel_futures=True)


def make_pool(config: GateConfig, validator: Validator) -> WorkerPool:
    """The pool a configuration asks for (``config.pool``: ``process`` or ``thread``)."""
    kinds: dict[str, type[WorkerPool]] = {
        "process": ProcessWorkerPool,
        "thread": ThreadWorkerPool,
    }
    try:
        cls = kinds[config.pool]
    except KeyError:
        raise GateConfigError(
            f"unknown pool {config.pool!r}; known: {', '.join(sorted(kinds))}"
        ) from None
    return cls(validator, config.workers)
