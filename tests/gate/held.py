"""A worker pool for tests that holds its jobs until released (deterministic overload)."""

from __future__ import annotations

import threading
from concurrent.futures import Future

from gate.pool import ThreadWorkerPool
from gate.validator import Job, Validator

WAIT_S = 30.0


class HeldPool(ThreadWorkerPool):
    """A thread pool whose jobs, while :attr:`hold` is set, say :attr:`entered` and wait
    for :attr:`release`."""

    def __init__(self, validator: Validator, workers: int = 1, *, hold: bool = True) -> None:
        super().__init__(validator, workers)
        self.hold = threading.Event()
        if hold:
            self.hold.set()
        self.entered = threading.Event()
        self.release = threading.Event()
        self._submitted = 0
        self._cond = threading.Condition()

    @property
    def submitted(self) -> int:
        """Jobs handed to the pool so far."""
        with self._cond:
            return self._submitted

    def wait_submitted(self, count: int) -> bool:
        """Wait until ``count`` jobs have been admitted and handed to the pool."""
        with self._cond:
            return self._cond.wait_for(lambda: self._submitted >= count, WAIT_S)

    def _submit(self, job: Job, client: str) -> Future[bytes]:
        with self._cond:
            self._submitted += 1
            self._cond.notify_all()

        holding = self.hold.is_set()

        def held() -> bytes:
            if not holding:
                return self._run(job)
            self.entered.set()
            if not self.release.wait(WAIT_S):
                raise TimeoutError("test never released the held job")
            return self._run(job)

        return self._executor.submit(held)
