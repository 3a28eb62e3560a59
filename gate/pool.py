"""Worker pools that run validations off the HTTP threads.

:class:`WorkerPool` does the shared work (refusing jobs after close, logging) in
:meth:`~WorkerPool.submit` and calls one hook, :meth:`~WorkerPool._submit`, that each
implementation fills; :meth:`~WorkerPool._close` releases its resources. A job is a
:class:`gate.validator.Job`; its result is the verdict's JSON bytes.

- :class:`ProcessWorkerPool` (default): one process per worker, started with ``spawn``
  (never ``fork`` from a threaded server), each holding its own validator. The playback
  is pure Python and CPU-bound, so processes are what runs plans in parallel on several
  cores. All workers start at construction and prove ready (:meth:`warm_up`) before the
  server says it listens; a worker that dies is replaced at once. Each worker is fed
  through a pipe of its own and one thread reads the answers (see the class).
- :class:`ThreadWorkerPool`: threads in this process sharing one validator: no start-up
  cost, but the GIL runs one playback at a time. For tests and small machines.

Admission (how many jobs may wait) is the server's business, not the pool's.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import os
import pickle
import signal
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from multiprocessing.connection import Connection, wait
from multiprocessing.process import BaseProcess
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


def _worker_main(conn: Connection, validator: Validator) -> None:
    """A worker process: say ready, then run ``(fn, arg)`` calls from ``conn`` one at a
    time, answering ``("ok", result)`` or ``("err", exception)``, until ``None`` or the
    pool's end of the pipe closes."""
    global _validator  # noqa: PLW0603 - per-process state of a pool worker
    # The server process owns shutdown: a Ctrl-C or SIGTERM sent to the whole process
    # group must not kill workers under in-flight requests (they exit when it says so).
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    _validator = validator
    conn.send(("ready", os.getpid()))
    while True:
        try:
            call = conn.recv()
        except (EOFError, OSError):
            return
        if call is None:
            return
        fn, arg = call
        try:
            answer: tuple[str, Any] = ("ok", fn(arg))
        except BaseException as exc:  # every failure goes back to the caller
            answer = ("err", exc)
        try:
            conn.send(answer)
        except (pickle.PicklingError, TypeError, AttributeError) as exc:
            conn.send(("err", RuntimeError(f"a worker's answer could not be sent: {exc!r}")))


def run_job(job: Job) -> bytes:
    """Validate ``job`` with this process's validator; the verdict's JSON bytes."""
    if _validator is None:  # pragma: no cover - the worker always has one
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


@dataclass(eq=False)
class _Worker:
    """One worker process as the pool sees it."""

    process: BaseProcess
    conn: Connection
    pid: int = 0
    ready: bool = False
    dead: bool = False
    call: _Call | None = None


@dataclass(eq=False)
class _Call:
    """A call waiting for, or running on, a worker."""

    future: Future[Any]
    fn: Callable[[Any], Any]
    arg: Any
    started: bool = False
    """Its future was set running (it went to a worker, which may have died first)."""


class ProcessWorkerPool(WorkerPool):
    """Worker processes started with ``spawn``, each with its own validator, each fed
    through a pipe of its own.

    A call is written to an idle worker's pipe by the thread that submits it (the event
    loop, for the gate), or queued until a worker is free; one thread
    (``gate-pool-results``) reads every answer and sets its future. That is one thread
    hand-off per call, where ``concurrent.futures.ProcessPoolExecutor`` makes three
    (its manager thread, its queue's feeder thread, then the manager again): about 60
    against 160 us per call from an event loop here (docs/gate.md, Performance).

    A worker that dies fails its call with ``BrokenProcessPool`` (the gate retries it
    once) and is replaced at once; calls wait for the replacement meanwhile.
    """

    kind = "process"

    def __init__(self, validator: Validator, workers: int) -> None:
        super().__init__(validator, workers)
        self._context = multiprocessing.get_context("spawn")
        self._state = threading.Condition()
        self._workers: list[_Worker] = []
        self._idle: deque[_Worker] = deque()
        self._pending: deque[_Call] = deque()
        self._stopping = False
        self._wake_r, self._wake_w = self._context.Pipe(duplex=False)
        try:
            self._workers = [self._spawn() for _ in range(workers)]
            self.warm_up()
        except BaseException:
            self._stop_workers(self._workers, 0.0)
            for worker in self._workers:
                _release(worker)
            raise
        self._reader = threading.Thread(
            target=self._read_answers, name="gate-pool-results", daemon=True
        )
        self._reader.start()
        logger.info("started %d worker processes: %s", self.workers, self.pids)

    @property
    def pids(self) -> list[int]:
        """The process ids of the workers that are up."""
        with self._state:
            return sorted(w.pid for w in self._workers if w.ready)

    def _spawn(self) -> _Worker:
        ours, theirs = self._context.Pipe()
        process = self._context.Process(
            target=_worker_main, args=(theirs, self.validator), name="gate-worker", daemon=True
        )
        process.start()
        theirs.close()
        return _Worker(process, ours)

    def warm_up(self) -> None:
        """Wait until every worker has loaded the validator (before the server says it
        listens).

        Raises:
            RuntimeError: a worker did not come up within ``WARM_UP_TIMEOUT_S``.
        """
        deadline = time.monotonic() + WARM_UP_TIMEOUT_S
        for worker in self._workers:
            try:
                if not worker.conn.poll(max(0.0, deadline - time.monotonic())):
                    raise TimeoutError("timed out")
                _ready, pid = worker.conn.recv()
            except (EOFError, OSError, TimeoutError) as exc:
                why = "a worker exited while starting" if isinstance(exc, EOFError) else exc
                raise RuntimeError(f"gate worker processes did not start: {why}") from exc
            worker.pid, worker.ready = pid, True
            self._idle.append(worker)

    # -- calls ------------------------------------------------------------------------------
    def _submit(self, job: Job) -> Future[bytes]:
        return self._submit_call(run_job, job)

    def _submit_call(self, fn: Callable[[Any], _T], arg: Any) -> Future[_T]:
        call = _Call(Future(), fn, arg)
        with self._state:
            if self._stopping:
                raise RuntimeError("process pool is closed")
            self._pending.append(call)
            sends = self._pair_locked()
        self._send(sends)
        return call.future

    def _pair_locked(self) -> list[_Worker]:
        """Give pending calls to idle workers (the caller holds ``_state``); the workers
        whose call is to be written."""
        sends = []
        while self._idle and self._pending:
            call = self._pending.popleft()
            if not call.started:
                if not call.future.set_running_or_notify_cancel():
                    continue  # cancelled while it waited
                call.started = True
            worker = self._idle.popleft()
            worker.call = call
            sends.append(worker)
        return sends

    def _send(self, workers: list[_Worker]) -> None:
        """Write each worker's call to its pipe (outside ``_state``)."""
        while workers:
            worker = workers.pop()
            call = worker.call
            if call is None:
                continue
            try:
                worker.conn.send((call.fn, call.arg))
            except (OSError, ValueError):
                # Died while idle: the reader replaces it; the call, not run, goes back
                # first in line, to another worker if one is idle.
                with self._state:
                    if worker.call is call:
                        worker.call = None
                        self._pending.appendleft(call)
                    workers.extend(self._pair_locked())
            except Exception as exc:  # e.g. an argument that cannot be pickled
                with self._state:
                    worker.call = None
                    if worker in self._workers:
                        self._idle.append(worker)
                    workers.extend(self._pair_locked())
                call.future.set_exception(exc)

    # -- the reader thread ------------------------------------------------------------------
    def _read_answers(self) -> None:
        while True:
            with self._state:
                if self._stopping and not self._workers:
                    return
                by_conn = {w.conn: w for w in self._workers}
                by_sentinel = {w.process.sentinel: w for w in self._workers}
            ready = wait([self._wake_r, *by_conn, *by_sentinel])
            if self._wake_r in ready:
                while self._wake_r.poll():
                    self._wake_r.recv_bytes()
            for obj in ready:
                worker = by_conn.get(obj) if isinstance(obj, Connection) else None
                if worker is not None and not worker.dead:
                    self._on_answer(worker)
                    continue
                worker = by_sentinel.get(obj) if isinstance(obj, int) else None
                if worker is not None and not worker.dead:
                    if worker.conn.poll():  # its last answer first
                        self._on_answer(worker)
                    self._on_death(worker)

    def _on_answer(self, worker: _Worker) -> None:
        if worker.dead:
            return
        try:
            word, value = worker.conn.recv()
        except (EOFError, OSError):
            self._on_death(worker)
            return
        except Exception as exc:  # read whole, but it cannot be unpickled here
            word, value = "err", RuntimeError(f"a worker's answer could not be read: {exc!r}")
        with self._state:
            call, worker.call = worker.call, None
            if word == "ready":
                worker.pid, worker.ready = value, True
            if worker in self._workers:
                self._idle.append(worker)
            sends = self._pair_locked()
            self._state.notify_all()
        self._send(sends)
        if call is not None and word != "ready":
            if word == "ok":
                call.future.set_result(value)
            else:
                call.future.set_exception(value)

    def _on_death(self, worker: _Worker) -> None:
        with self._state:
            if worker.dead:
                return  # seen already
            worker.dead = True
            if worker in self._workers:
                self._workers.remove(worker)
            if worker in self._idle:
                self._idle.remove(worker)
            call, worker.call = worker.call, None
            replace_it = not self._stopping
            self._state.notify_all()
        if replace_it:
            _release(worker)
        else:
            worker.conn.close()  # its process is released by close(), once this thread ends
        if call is not None:
            call.future.set_exception(BrokenProcessPool("a worker process died during a job"))
        if replace_it:
            logger.warning("worker process %d died; starting another", worker.pid)
            try:
                fresh = self._spawn()
            except Exception:
                logger.exception("could not start a worker process")
                return
            with self._state:
                if not self._stopping:
                    self._workers.append(fresh)  # idle once it says ready
                    return
            fresh.process.kill()  # closed meanwhile
            _release(fresh)

    # -- the end ----------------------------------------------------------------------------
    def _close(self, wait: bool) -> None:
        with self._state:
            self._stopping = True
            workers = list(self._workers)  # no worker is added from now on
            cancelled = list(self._pending)
            self._pending.clear()
            if wait:
                self._state.wait_for(
                    lambda: not any(w.call for w in self._workers), WARM_UP_TIMEOUT_S
                )
        for call in cancelled:
            if not call.future.cancel():  # it had gone to a worker that died
                call.future.set_exception(RuntimeError("process pool is closed"))
        self._stop_workers(workers, 5.0)
        self._wake_w.send_bytes(b"x")  # the reader sees every death, then ends
        self._reader.join(5.0)
        if not self._reader.is_alive():  # else it may still wait on their sentinels
            for worker in workers:
                _release(worker)
        self._wake_r.close()
        self._wake_w.close()

    def _stop_workers(self, workers: list[_Worker], timeout_s: float) -> None:
        """Tell ``workers`` to exit after their call; end those that have not within
        ``timeout_s``. Their process objects stay open (see :func:`_release`)."""
        for worker in workers:
            if not worker.ready:  # still starting (a replacement): nothing to finish
                worker.process.kill()
                continue
            with contextlib.suppress(OSError, ValueError):  # gone already
                worker.conn.send(None)
        deadline = time.monotonic() + timeout_s
        for worker in workers:
            worker.process.join(max(0.0, deadline - time.monotonic()))
            if worker.process.is_alive():
                worker.process.kill()
                worker.process.join(5.0)


def _release(worker: _Worker) -> None:
    """Close a worker's pipe and, once it has exited (killed after 5 s), its process's
    file descriptors (idempotent). Only the reader thread, for a worker it saw die while
    the pool runs, or :meth:`ProcessWorkerPool.close` once the reader has ended, calls
    this: the reader waits on the process's sentinel."""
    worker.conn.close()
    process = worker.process
    process.join(5.0)
    if process.is_alive():
        process.kill()
        process.join(5.0)
    with contextlib.suppress(ValueError, AttributeError):  # still running, or released
        process.close()


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
