"""Worker pools that run validations off the HTTP threads.

A job is a :class:`gate.validator.Job`; its result is the verdict's JSON bytes. The
pools (their base: :class:`WorkerPool`):

- :class:`ProcessWorkerPool` (default): one ``spawn``-ed process per worker (never
  ``fork`` from a threaded server), each with its own validator; playback is CPU-bound
  pure Python, so processes are what runs plans in parallel. All start and prove ready
  at construction; calls are cancellable and shared fairly between clients (see the class).
- :class:`ThreadWorkerPool`: threads sharing one validator (one playback at a time under
  the GIL; a started call cannot be cancelled). For tests and small machines.

Admission (how many jobs may wait) is the server's business (:mod:`gate.admission`).
Why not ``concurrent.futures.ProcessPoolExecutor``: docs/gate.md, under that heading.
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
from collections import Counter, deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from itertools import count
from multiprocessing.connection import Connection, wait
from multiprocessing.process import BaseProcess
from typing import Any, TypeVar

from firmware_proto.runtime.procname import set_process_name
from gate.config import GateConfig
from gate.errors import CallCancelledError, GateConfigError
from gate.validator import Job, Validator

__all__ = [
    "CANCEL_GRACE_S",
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
CANCEL_GRACE_S = 5.0
"""How long an interrupted worker may take to stop its call before it is killed and replaced, s:
playback yields every twin step, so only a call stuck in native code needs the kill."""
INTERRUPT = signal.SIGUSR1
"""The signal that asks a worker to stop the call it runs."""

_validator: Validator | None = None  # the worker process's own validator
_running = 0  # the worker process's call under way (its id), 0 between calls
_control: Connection | None = None  # where the pool writes the id of the call to stop
_target = 0  # the last id read from there


class _Interrupted(BaseException):
    """Raised in a worker by :data:`INTERRUPT` into the call the pool wants stopped
    (a ``BaseException``: no ``except Exception`` of the call swallows it)."""


def _read_target() -> None:
    """The last call id the pool asked to stop (from the control pipe)."""
    global _target  # noqa: PLW0603 - per-process state of a pool worker
    if _control is not None:
        with contextlib.suppress(EOFError, OSError):
            while _control.poll():
                _target = int.from_bytes(_control.recv_bytes(), "little")


def _on_interrupt(signum: int, frame: object) -> None:
    _read_target()
    if _running and _target == _running:
        raise _Interrupted


def _worker_main(conn: Connection, validator: Validator, control: Connection) -> None:
    """A worker process: say ready, then run ``(id, fn, arg)`` calls from ``conn`` one at
    a time, answering ``("ok", result)``, ``("err", exception)`` or ``("cancelled",
    None)`` when interrupted, until ``None`` or the pool's end of the pipe closes."""
    global _validator, _running, _control  # noqa: PLW0603 - per-process state of a pool worker
    set_process_name("rover-gate-work")
    # The server owns shutdown: a Ctrl-C to the process group must not kill in-flight work.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    _validator = validator
    _control = control
    signal.signal(INTERRUPT, _on_interrupt)
    conn.send(("ready", os.getpid()))
    while True:
        try:
            call = conn.recv()
        except (EOFError, OSError):
            return
        if call is None:
            return
        ident, fn, arg = call
        answer: tuple[str, Any]
        try:
            _running = ident  # from here to the "finally", the call may be interrupted
            try:
                # Asked to stop before it began: the signal found nothing to interrupt.
                _read_target()
                if _target == ident:
                    raise _Interrupted
                result = fn(arg)
            finally:
                _running = 0
            answer = ("ok", result)
        except _Interrupted:
            answer = ("cancelled", None)
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
    """Base of the pools. Implementations fill :meth:`_submit_call` and may fill
    :meth:`_submit` (a job, by default :func:`run_job` as a call), :meth:`_cancel` and
    :meth:`_close`.

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

    def submit(self, job: Job, *, client: str = "") -> Future[bytes]:
        """Start ``job`` for ``client``; the future gives the verdict JSON bytes, or
        raises what validation raised (:class:`~gate.errors.CallCancelledError` once
        :meth:`cancel` stopped it).

        Raises:
            RuntimeError: the pool is closed.
        """
        with self._lock:
            if self._closed:
                raise RuntimeError(f"{self.kind} pool is closed")
        return self._submit(job, client)

    def _submit(self, job: Job, client: str) -> Future[bytes]:
        return self._submit_call(run_job, job, client, False)

    def submit_call(
        self,
        fn: Callable[[Any], _T],
        arg: Any,
        *,
        client: str = "",
        preemptible: bool = False,
    ) -> Future[_T]:
        """Run ``fn(arg)`` on a worker (``fn`` a module-level function, ``arg``
        picklable: a chunk of an uncertain verdict, :func:`gate.ensemble.run_chunk`) for
        ``client``. A ``preemptible`` call may be stopped and put back in line to make
        room for another client's (its work is lost, its result is not).

        Raises:
            RuntimeError: the pool is closed.
        """
        with self._lock:
            if self._closed:
                raise RuntimeError(f"{self.kind} pool is closed")
        return self._submit_call(fn, arg, client, preemptible)

    def _submit_call(
        self, fn: Callable[[Any], _T], arg: Any, client: str, preemptible: bool
    ) -> Future[_T]:
        raise NotImplementedError

    def cancel(self, future: Future[Any]) -> bool:
        """Stop the call of ``future``: a waiting one is dropped (the future is
        cancelled), a running one interrupted where the pool can (the future then raises
        :class:`~gate.errors.CallCancelledError`). Whether it will stop."""
        return self._cancel(future)

    def _cancel(self, future: Future[Any]) -> bool:
        return future.cancel()

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
    """Threads sharing this process's validator (one playback at a time under the GIL;
    a call that has started runs to its end: :meth:`cancel` drops only waiting ones)."""

    kind = "thread"

    def __init__(self, validator: Validator, workers: int) -> None:
        super().__init__(validator, workers)
        self._executor = ThreadPoolExecutor(workers, thread_name_prefix="gate-worker")
        # Start every thread now: none passes the barrier before all exist.
        barrier = threading.Barrier(workers)
        for future in [
            self._executor.submit(barrier.wait, WARM_UP_TIMEOUT_S) for _ in range(workers)
        ]:
            future.result(timeout=WARM_UP_TIMEOUT_S)

    def _run(self, job: Job) -> bytes:
        return self.validator.run(job).to_json().encode()

    def _submit_call(
        self, fn: Callable[[Any], _T], arg: Any, client: str, preemptible: bool
    ) -> Future[_T]:
        if fn is run_job:  # this process has no worker validator: use the pool's
            job: Future[Any] = self._executor.submit(self._run, arg)
            return job
        return self._executor.submit(fn, arg)

    def _close(self, wait: bool) -> None:
        self._executor.shutdown(wait=wait, cancel_futures=True)


_ids = count(1)


@dataclass(eq=False)
class _Call:
    """A call waiting for, or running on, a worker."""

    future: Future[Any]
    fn: Callable[[Any], Any]
    arg: Any
    client: str
    preemptible: bool
    ident: int = field(default_factory=lambda: next(_ids))
    started: bool = False
    """Its future was set running (it went to a worker, which may have died first)."""
    stopping: str = ""
    """Why the pool asked its worker to stop: ``"cancel"`` (for good), ``"preempt"`` (requeued)."""


@dataclass(eq=False)
class _Worker:
    """One worker process as the pool sees it."""

    process: BaseProcess
    conn: Connection
    control: Connection
    """Where the pool writes the id of the call to stop, before :data:`INTERRUPT`."""
    pid: int = 0
    ready: bool = False
    dead: bool = False
    call: _Call | None = None
    kill_at: float | None = None
    """When an interrupted worker that has not stopped its call is killed (monotonic)."""


class ProcessWorkerPool(WorkerPool):
    """Worker processes started with ``spawn``, each with its own validator and pipe.

    A call is written to an idle worker's pipe by the submitting thread (the event loop,
    for the gate), or queued until one is free; one thread (``gate-pool-results``) reads
    every answer and sets its future.

    **Fair.** Waiting calls queue per client; a free worker takes the next call of the
    client with the fewest calls running (round robin among equals). When a client with
    nothing running waits and no worker is free, a preemptible call of a client over its
    share (``workers`` over the clients with work, at least one) is stopped and put back
    first in its client's line.

    **Cancellable.** :meth:`cancel` drops a waiting call and interrupts a running one
    (its id on the worker's control pipe, then :data:`INTERRUPT`, whose handler raises
    into the call if it is still that one); a worker that has not answered within
    :data:`CANCEL_GRACE_S` is killed. A dead worker is replaced at once; its call fails
    with :class:`~gate.errors.CallCancelledError` (cancelled), goes back in line
    (preempted) or fails with ``BrokenProcessPool`` (died on its own; the gate retries
    once).
    """

    kind = "process"

    def __init__(self, validator: Validator, workers: int) -> None:
        super().__init__(validator, workers)
        self._context = multiprocessing.get_context("spawn")
        self._state = threading.Condition()
        self._workers: list[_Worker] = []
        self._idle: deque[_Worker] = deque()
        self._queues: dict[str, deque[_Call]] = {}
        self._running: Counter[str] = Counter()
        self._served: dict[str, int] = {}  # when each client's last call started
        self._serial = 0
        self._calls: dict[Future[Any], _Call] = {}
        self._stopping = False
        self.interrupted = 0
        """Calls interrupted (cancelled or preempted) so far."""
        self.killed = 0
        """Workers killed because they did not stop a call in time."""
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

    @property
    def waiting(self) -> int:
        """Calls waiting for a worker."""
        with self._state:
            return sum(len(q) for q in self._queues.values())

    def running(self, client: str) -> int:
        """Calls of ``client`` running on a worker now."""
        with self._state:
            return self._running[client]

    def _spawn(self) -> _Worker:
        ours, theirs = self._context.Pipe()
        control_r, control_w = self._context.Pipe(duplex=False)
        process = self._context.Process(
            target=_worker_main,
            args=(theirs, self.validator, control_r),
            name="gate-worker",
            daemon=True,
        )
        process.start()
        theirs.close()
        control_r.close()
        return _Worker(process, ours, control_w)

    def warm_up(self) -> None:
        """Wait until every worker has loaded the validator.

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
    def _submit_call(
        self, fn: Callable[[Any], _T], arg: Any, client: str, preemptible: bool
    ) -> Future[_T]:
        call = _Call(Future(), fn, arg, client, preemptible)
        with self._state:
            if self._stopping:
                raise RuntimeError("process pool is closed")
            self._calls[call.future] = call
            self._queues.setdefault(client, deque()).append(call)
            sends = self._pair_locked()
            if not sends:
                self._preempt_locked(client)
        call.future.add_done_callback(self._forget)
        self._send(sends)
        return call.future

    def _forget(self, future: Future[Any]) -> None:
        with self._state:
            self._calls.pop(future, None)

    def _next_locked(self) -> _Call | None:
        """The next call to run, by the class docstring's fairness rule."""
        best: str | None = None
        for client, queue in self._queues.items():
            if queue and (
                best is None
                or (self._running[client], self._served.get(client, 0))
                < (self._running[best], self._served.get(best, 0))
            ):
                best = client
        if best is None:
            return None
        queue = self._queues[best]
        call = queue.popleft()
        if not queue:
            del self._queues[best]
        self._serial += 1
        self._served[best] = self._serial
        return call

    def _pair_locked(self) -> list[_Worker]:
        """Give waiting calls to idle workers (under ``_state``); the workers to write to."""
        sends = []
        while self._idle:
            call = self._next_locked()
            if call is None:
                break
            if not call.started:
                if not call.future.set_running_or_notify_cancel():
                    continue  # cancelled while it waited
                call.started = True
            worker = self._idle.popleft()
            worker.call = call
            self._running[call.client] += 1
            sends.append(worker)
        return sends

    def _preempt_locked(self, client: str) -> None:
        """Preempt a call for ``client``, which waits with no worker free (class docstring)."""
        if self._running[client] > 0:
            return
        busy = {w.call.client for w in self._workers if w.call is not None}
        share = max(1, self.workers // max(1, len(busy | {client})))
        over = [
            w
            for w in self._workers
            if w.call is not None
            and w.call.preemptible
            and not w.call.stopping
            and self._running[w.call.client] > share
        ]
        if over:
            self._interrupt_locked(over[-1], "preempt")

    def _interrupt_locked(self, worker: _Worker, why: str) -> None:
        call = worker.call
        if call is None or call.stopping:
            return
        call.stopping = why
        self.interrupted += 1
        worker.kill_at = time.monotonic() + CANCEL_GRACE_S
        with contextlib.suppress(OSError, ValueError):  # gone: its death is seen anyway
            worker.control.send_bytes(call.ident.to_bytes(8, "little"))
            os.kill(worker.pid, INTERRUPT)
        logger.info("%s a call of %r on worker %d", why, call.client, worker.pid)
        self._wake()

    def _requeue_locked(self, call: _Call) -> None:
        """A preempted call, first in its client's line again, under a new id (the old
        one may still be in a worker's control pipe)."""
        call.stopping = ""
        call.ident = next(_ids)
        self._queues.setdefault(call.client, deque()).appendleft(call)

    def _cancel(self, future: Future[Any]) -> bool:
        with self._state:
            call = self._calls.get(future)
            if call is None:
                return future.cancel()
            if not call.started:
                queue = self._queues.get(call.client)
                if queue is not None and call in queue:
                    queue.remove(call)
                return future.cancel()
            worker = next((w for w in self._workers if w.call is call), None)
            if worker is None:  # between a worker and the line (a preempted call)
                queue = self._queues.get(call.client)
                if queue is not None and call in queue:
                    queue.remove(call)
                    call.future.set_exception(CallCancelledError("cancelled while waiting"))
                    return True
                return False
            self._interrupt_locked(worker, "cancel")
            return True

    def _send(self, workers: list[_Worker]) -> None:
        """Write each worker's call to its pipe (outside ``_state``)."""
        while workers:
            worker = workers.pop()
            call = worker.call
            if call is None:
                continue
            try:
                worker.conn.send((call.ident, call.fn, call.arg))
            except (OSError, ValueError):
                # Died while idle: the reader replaces it; the call, not run, goes back
                # first in line, to another worker if one is idle.
                with self._state:
                    if worker.call is call:
                        worker.call = None
                        self._running[call.client] -= 1
                        self._queues.setdefault(call.client, deque()).appendleft(call)
                    workers.extend(self._pair_locked())
            except Exception as exc:  # e.g. an argument that cannot be pickled
                with self._state:
                    worker.call = None
                    self._running[call.client] -= 1
                    if worker in self._workers:
                        self._idle.append(worker)
                    workers.extend(self._pair_locked())
                call.future.set_exception(exc)

    def _wake(self) -> None:
        with contextlib.suppress(OSError, ValueError):
            self._wake_w.send_bytes(b"x")

    # -- the reader thread ------------------------------------------------------------------
    def _read_answers(self) -> None:
        while True:
            with self._state:
                if self._stopping and not self._workers:
                    return
                by_conn = {w.conn: w for w in self._workers}
                by_sentinel = {w.process.sentinel: w for w in self._workers}
                kills = [w.kill_at for w in self._workers if w.kill_at is not None]
            timeout = None if not kills else max(0.0, min(kills) - time.monotonic())
            ready = wait([self._wake_r, *by_conn, *by_sentinel], timeout)
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
            self._kill_stuck()

    def _kill_stuck(self) -> None:
        """Kill the workers past their ``kill_at`` (then replaced like any dead worker)."""
        now = time.monotonic()
        with self._state:
            stuck = [w for w in self._workers if w.kill_at is not None and w.kill_at <= now]
            for worker in stuck:
                worker.kill_at = None
        for worker in stuck:
            logger.warning(
                "worker %d did not stop its call within %g s; killing it",
                worker.pid,
                CANCEL_GRACE_S,
            )
            self.killed += 1
            worker.process.kill()

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
        requeue = None
        with self._state:
            call, worker.call = worker.call, None
            worker.kill_at = None
            if call is not None:
                self._running[call.client] -= 1
                if word == "cancelled" and call.stopping == "preempt":
                    self._requeue_locked(call)
                    requeue = call
            if word == "ready":
                worker.pid, worker.ready = value, True
            if worker in self._workers:
                self._idle.append(worker)
            sends = self._pair_locked()
            self._state.notify_all()
        self._send(sends)
        if call is None or word == "ready" or requeue is not None:
            return
        if word == "ok":
            call.future.set_result(value)
        elif word == "cancelled":
            call.future.set_exception(CallCancelledError("the call was stopped"))
        else:
            call.future.set_exception(value)

    def _on_death(self, worker: _Worker) -> None:
        failure: BaseException | None = None
        with self._state:
            if worker.dead:
                return  # seen already
            worker.dead = True
            if worker in self._workers:
                self._workers.remove(worker)
            if worker in self._idle:
                self._idle.remove(worker)
            call, worker.call = worker.call, None
            if call is not None:
                self._running[call.client] -= 1
                if call.stopping == "preempt":
                    self._requeue_locked(call)
                elif call.stopping == "cancel":
                    failure = CallCancelledError("the call did not stop; its worker was killed")
                else:
                    failure = BrokenProcessPool("a worker process died during a job")
            replace_it = not self._stopping
            self._state.notify_all()
        if replace_it:
            _release(worker)
        else:
            worker.conn.close()  # its process is released by close(), once this thread ends
        if call is not None and failure is not None:
            call.future.set_exception(failure)
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
            cancelled = [c for q in self._queues.values() for c in q]
            self._queues.clear()
            if wait:
                self._state.wait_for(
                    lambda: not any(w.call for w in self._workers), WARM_UP_TIMEOUT_S
                )
        for call in cancelled:
            if not call.future.cancel():  # it had gone to a worker that died
                call.future.set_exception(RuntimeError("process pool is closed"))
        self._stop_workers(workers, 5.0)
        self._wake()  # the reader sees every death, then ends
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
    worker.control.close()
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
