"""The gate's chunks of uncertain verdicts on a Dask distributed cluster.

``rover gate --cluster tcp://HOST:PORT`` connects to a running Dask scheduler (its
workers must have this project installed: they import :func:`gate.ensemble.run_chunk`)
and sends each chunk of a verdict with its uncertainty there instead of to the local
process pool; the nominal playback stays local. A chunk is a self-contained
:class:`~gate.ensemble.ChunkJob` and its result depends on nothing else, so the verdict
is the same bytes as from the local pool (docs/gate.md says why Dask and not Ray).

:class:`ClusterEngine` offers what the pool offers, :meth:`~ClusterEngine.submit_call`
returning a :class:`concurrent.futures.Future`; ``distributed`` is imported only here,
and only when a cluster is configured (the ``cluster`` extra).
"""

from __future__ import annotations

import importlib
import json
import logging
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TypeVar

from gate.errors import GateConfigError

__all__ = ["CONNECT_TIMEOUT_S", "WAITERS", "ClusterEngine", "local_cluster"]

logger = logging.getLogger(__name__)

CONNECT_TIMEOUT_S = 20.0
"""Longest wait for the scheduler to answer at start-up."""

WAITERS = 32
"""Chunks whose results are awaited at once (more wait their turn)."""

_T = TypeVar("_T")
_SCHEDULER = (sys.executable, "-m", "distributed.cli.dask_scheduler", "--port", "0")
_WORKER = (sys.executable, "-m", "distributed.cli.dask_worker")
_ONE_THREAD = ("--nthreads", "1", "--no-nanny", "--memory-limit", "0")


class ClusterEngine:
    """A client of the Dask scheduler at ``address`` (``tcp://host:port``), waited for up
    to ``timeout_s``; :meth:`close` is idempotent.

    Raises:
        GateConfigError: ``distributed`` is not installed, or the scheduler does not answer.
    """

    kind = "dask"

    def __init__(self, address: str, *, timeout_s: float = CONNECT_TIMEOUT_S) -> None:
        try:
            client_class: Any = importlib.import_module("distributed").Client
        except ImportError as exc:
            raise GateConfigError(
                "--cluster needs Dask distributed: pip install 'rover-hil[cluster]'"
            ) from exc
        self.address = address
        try:
            self._client: Any = client_class(address, timeout=f"{timeout_s}s", set_as_default=False)
        except (OSError, TimeoutError) as exc:
            raise GateConfigError(f"no Dask scheduler answers at {address}: {exc}") from exc
        self._lock = threading.Lock()
        self._closed = False
        # One thread per chunk in flight waits on its result (Dask's own done-callbacks
        # run on a thread of the library's that outlives the client).
        self._waiters = ThreadPoolExecutor(WAITERS, thread_name_prefix="gate-cluster")
        workers = self.workers
        logger.info("connected to Dask scheduler %s (%d workers)", address, workers)

    @property
    def workers(self) -> int:
        """Workers the scheduler has now."""
        info = self._client.scheduler_info()
        return len(info.get("workers", {}))

    def submit_call(self, fn: Callable[[Any], _T], arg: Any) -> Future[_T]:
        """Run ``fn(arg)`` on a worker; the future gives its result or raises its error.

        Raises:
            RuntimeError: the engine is closed.
        """
        with self._lock:
            if self._closed:
                raise RuntimeError("cluster engine is closed")
        remote = self._client.submit(fn, arg, pure=False)
        out: Future[_T] = self._waiters.submit(remote.result)
        out.add_done_callback(lambda f: remote.cancel() if f.cancelled() else None)
        return out

    def close(self) -> None:
        """Disconnect (the cluster itself keeps running)."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        self._client.close(timeout=10)  # cancels what is in flight: the waiters return
        self._waiters.shutdown(wait=True, cancel_futures=True)

    def __enter__(self) -> ClusterEngine:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@contextmanager
def local_cluster(directory: Path, workers: int = 2, timeout_s: float = 60.0) -> Iterator[str]:
    """A Dask scheduler and ``workers`` single-threaded workers, each its own process
    (this interpreter, ``python -m distributed.cli...``), listening on 127.0.0.1 only;
    yields the scheduler's address once every worker has joined. Every process is ended
    on exit (terminate, then kill after 3 s: a worker can hang in its own close once the
    scheduler is gone, and none holds state). For tests, benchmarks and a first try;
    their output goes to ``directory/cluster.log``.

    Raises:
        RuntimeError: a process exited early, or the cluster was not up in ``timeout_s``.
    """
    file = directory / "scheduler.json"
    common = ["--no-dashboard", "--host", "127.0.0.1"]
    procs: list[subprocess.Popen[bytes]] = []
    deadline = time.monotonic() + timeout_s
    with (directory / "cluster.log").open("wb") as log:
        try:
            procs.append(
                subprocess.Popen(
                    [*_SCHEDULER, *common, "--scheduler-file", str(file)],
                    stdout=log,
                    stderr=log,
                )
            )
            while not file.exists():
                if procs[0].poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError(f"no Dask scheduler came up; see {directory}/cluster.log")
                time.sleep(0.1)
            address = str(json.loads(file.read_text())["address"])
            for _ in range(workers):
                procs.append(
                    subprocess.Popen(
                        [*_WORKER, address, *common, *_ONE_THREAD],
                        stdout=log,
                        stderr=log,
                    )
                )
            engine = ClusterEngine(address, timeout_s=max(1.0, deadline - time.monotonic()))
            try:
                engine._client.wait_for_workers(
                    workers, timeout=max(1.0, deadline - time.monotonic())
                )
            finally:
                engine.close()
            yield address
        finally:
            for p in reversed(procs):
                p.terminate()
            for p in reversed(procs):
                try:
                    p.wait(timeout=3)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait(timeout=10)
