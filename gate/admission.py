"""Admission by cost: what a validation will take of the workers, and whether it may
have it now. Pure bookkeeping (a lock, no clock, no I/O); the server asks before it
queues anything, and releases when the last of the request's calls has ended.

A request's **cost** is its estimated work in worker-seconds, from the plan and the
options alone (:meth:`Cost.of`): the twin steps of the nominal playback (the plan's
nominal duration plus settling, at the server's ``dt_s``) times :data:`STEP_WORK_S`,
plus, with ``samples`` > 1, the steps of every sample times :data:`SAMPLE_STEP_WORK_S`
(they are played in batches, cheaper per twin), plus :data:`CALL_WORK_S` per call. A
request is then, as a whole, before any of it is queued:

- **refused for good** when it asks for samples and its cost is over the per-request
  cap (a client's share): 400 ``invalid_option`` naming ``samples``, with the most
  samples this plan may ask for (no wait would make it fit); a single playback is
  always allowed (its deadline bounds it);
- **refused for now** when its client already holds validations and would hold more
  than its share of work (:attr:`Limits.share_s`), or, while other clients have
  validations admitted, more than its share of validations (``capacity - workers``:
  the others keep at least ``workers`` places): 429 ``too_many_requests`` with
  ``Retry-After``;
- **refused for now** when the gate holds all it takes, in validations (``capacity``)
  or, with validations admitted, in work (:attr:`Limits.budget_s`): 503 ``overloaded``
  with ``Retry-After``;
- else admitted, holding its count and cost until :meth:`Admission.release`.

The per-step figures are this machine's (docs/performance.md, ``bench_gate``), rounded
up: an estimate that is off by a factor of two still keeps the gate's queue within a
couple of deadlines, and the deadline itself (the server cancels a call past it) bounds
what a wrong estimate can cost.

A client is the peer's address: what a client cannot forge.
"""

from __future__ import annotations

import math
import threading
from collections import Counter
from dataclasses import dataclass

from gate.errors import OptionError, OverloadedError, TooManyRequestsError

__all__ = [
    "CALL_WORK_S",
    "SAMPLE_STEP_WORK_S",
    "STEP_WORK_S",
    "Admission",
    "Cost",
    "Limits",
    "Ticket",
]

STEP_WORK_S = 10e-6
"""Worker-seconds of one twin step of a single playback (about 8 us here)."""
SAMPLE_STEP_WORK_S = 4e-6
"""Worker-seconds of one twin step of one sample, played in a batch (2.7-4 us here)."""
CALL_WORK_S = 0.002
"""Worker-seconds of one call beyond its steps (hand-off, building the twin)."""
_MAX_RETRY_AFTER_S = 60


@dataclass(frozen=True)
class Cost:
    """A request's estimated work.

    Attributes:
        twin_s: twin seconds of one playback (the plan's nominal duration plus
            settling).
        samples: twins of the uncertainty (0 without).
        calls: calls it makes to the workers (the nominal playback and the chunks).
        work_s: the whole of it, in worker-seconds.
        chunk_extra_s: what each chunk does beyond its twins, worker-seconds: a
            calibrated twin's step error, the nominal twin played again at the gate's
            step and at a finer one (:func:`gate.ensemble.step_error`); 0 without.
    """

    twin_s: float
    samples: int
    calls: int
    work_s: float
    chunk_extra_s: float = 0.0

    @classmethod
    def of(
        cls,
        twin_s: float,
        dt_s: float,
        samples: int,
        chunks: int,
        *,
        fine_dt_s: float | None = None,
    ) -> Cost:
        """The cost of a playback of ``twin_s`` at ``dt_s`` and, when ``samples`` > 1,
        of ``samples`` more in ``chunks`` calls; with ``fine_dt_s`` each chunk also
        computes the step error (two single playbacks, at ``dt_s`` and ``fine_dt_s``)."""
        steps = math.ceil(twin_s / dt_s)
        extra = samples if samples > 1 else 0
        calls = 1 + (chunks if extra else 0)
        chunk_extra = 0.0
        if fine_dt_s is not None:
            chunk_extra = (steps + math.ceil(twin_s / fine_dt_s)) * STEP_WORK_S
        work = steps * STEP_WORK_S + extra * steps * SAMPLE_STEP_WORK_S + calls * CALL_WORK_S
        work += (calls - 1) * chunk_extra
        return cls(twin_s, extra, calls, work, chunk_extra)

    def most_samples(self, cap_s: float, dt_s: float) -> int:
        """The most samples a request of this plan may ask for under ``cap_s``."""
        steps = math.ceil(self.twin_s / dt_s)
        room = cap_s - steps * STEP_WORK_S - 2 * (CALL_WORK_S + self.chunk_extra_s)
        per_sample = steps * SAMPLE_STEP_WORK_S + (CALL_WORK_S + self.chunk_extra_s) / 100
        return max(0, math.floor(room / per_sample))


@dataclass(frozen=True)
class Limits:
    """What the gate admits at once.

    Attributes:
        workers: the pool's workers (what the work is spread over).
        capacity: validations admitted at once (``workers + queue_depth``).
        client_count: of those, one client's while others have some (``capacity -
            workers``, at least 1).
        budget_s: work admitted at once, worker-seconds (``workers`` x the request
            deadline: what the workers can do before the deadlines pass).
        share_s: one client's work, worker-seconds (half the budget), and the most one
            request may cost.
    """

    workers: int
    capacity: int
    client_count: int
    budget_s: float
    share_s: float

    @classmethod
    def for_gate(cls, workers: int, queue_depth: int, request_timeout_s: float) -> Limits:
        """The limits of a gate with these settings."""
        capacity = workers + queue_depth
        budget = workers * request_timeout_s
        return cls(workers, capacity, max(1, capacity - workers), budget, budget / 2)


@dataclass(eq=False)
class Ticket:
    """An admitted request: its client and cost, until released."""

    client: str
    cost: Cost
    released: bool = False


class Admission:
    """The ledger of admitted requests (module docstring). Thread-safe."""

    def __init__(self, limits: Limits) -> None:
        self.limits = limits
        self._lock = threading.Lock()
        self._count = 0
        self._work_s = 0.0
        self._client_count: Counter[str] = Counter()
        self._client_work: dict[str, float] = {}

    def check_request(self, cost: Cost, dt_s: float) -> None:
        """Refuse a request no wait would let in (its cost over a client's share).

        Raises:
            OptionError: ``samples`` names the parameter, with the most this plan may
                ask for.
        """
        if not cost.samples or cost.work_s <= self.limits.share_s:
            return  # one playback is always allowed: its deadline bounds it
        most = cost.most_samples(self.limits.share_s, dt_s)
        raise OptionError(
            "samples",
            f"{cost.samples} twins of this plan ({cost.twin_s:,.0f} s of twin time each) "
            f"would take about {cost.work_s:,.0f} s of a worker, over the {self.limits.share_s:g} "
            f"s one request may take: at most {most} samples for this plan",
        )

    def admit(self, client: str, cost: Cost) -> Ticket:
        """Admit a request of ``client`` costing ``cost``, or refuse it.

        Raises:
            TooManyRequestsError: ``client`` holds its share (429).
            OverloadedError: the gate holds all it takes (503).
        """
        limits = self.limits
        with self._lock:
            mine = self._client_work.get(client, 0.0)
            held = self._client_count[client]
            others = len(self._client_count) - (1 if held else 0)
            if held and mine + cost.work_s > limits.share_s:
                raise TooManyRequestsError(
                    f"this client's validations would take about {mine + cost.work_s:.1f} s "
                    f"of the workers, over its share of {limits.share_s:g} s",
                    retry_after_s=_retry_after(mine + cost.work_s - limits.share_s, limits),
                )
            if others and held >= limits.client_count:
                raise TooManyRequestsError(
                    f"this client has {held} validations admitted already, its share of "
                    f"{limits.capacity} while others have some",
                    retry_after_s=1,
                )
            if self._count >= limits.capacity:
                raise OverloadedError(
                    f"all {limits.workers} workers busy and "
                    f"{limits.capacity - limits.workers} validations queued",
                    retry_after_s=1,
                )
            total = self._work_s + cost.work_s
            if self._count and total > limits.budget_s:
                raise OverloadedError(
                    f"the validations admitted would take about {total:.1f} s of the "
                    f"workers, over the {limits.budget_s:g} s they can do within the deadline",
                    retry_after_s=_retry_after(total - limits.budget_s, limits),
                )
            self._count += 1
            self._work_s += cost.work_s
            self._client_count[client] += 1
            self._client_work[client] = mine + cost.work_s
            return Ticket(client, cost)

    def release(self, ticket: Ticket) -> None:
        """Give back what ``ticket`` held (idempotent)."""
        with self._lock:
            if ticket.released:
                return
            ticket.released = True
            self._count -= 1
            self._work_s = max(0.0, self._work_s - ticket.cost.work_s) if self._count else 0.0
            self._client_count[ticket.client] -= 1
            if self._client_count[ticket.client] <= 0:
                del self._client_count[ticket.client]
                self._client_work.pop(ticket.client, None)
            else:
                left = self._client_work[ticket.client] - ticket.cost.work_s
                self._client_work[ticket.client] = max(0.0, left)

    @property
    def in_flight(self) -> int:
        """Validations admitted now."""
        with self._lock:
            return self._count

    @property
    def work_s(self) -> float:
        """Work admitted now, worker-seconds."""
        with self._lock:
            return self._work_s

    @property
    def clients(self) -> int:
        """Clients with validations admitted now."""
        with self._lock:
            return len(self._client_count)


def _retry_after(excess_s: float, limits: Limits) -> int:
    """Whole seconds until ``excess_s`` of work has drained through the workers."""
    return max(1, min(_MAX_RETRY_AFTER_S, math.ceil(excess_s / limits.workers)))
