"""The time rules of one plan step in flight: when it has timed out, when drift control
has gone blind, when the operator hears ``accepted`` and ``running``, and when the rover
started it. :class:`StepWatch` is what :meth:`planner.ground.executor.PlanExecutor.execute`
consults while a step runs; no thread, no clock: it takes the time as an argument (any
one clock, seconds), so its rules are tested in virtual time.
"""

from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["StepWatch", "Watched"]

WAIT_SLICE_S = 0.1
"""The longest the executor waits for a status before it consults the watch again, s."""


@dataclass(frozen=True)
class Watched:
    """What the watch says at one moment.

    Attributes:
        end: ``timeout`` or ``blind`` when the step must end now, else ``None``.
        report: the progress status to tell the operator now (``accepted``, ``running``,
            ``published``), else ``None``.
        started_s: when the rover started the step (halfway through the round trip of
            its ``accepted``), ``None`` until it is known.
        accepted_now: this is the moment ``accepted`` was first seen.
    """

    end: str | None = None
    report: str | None = None
    started_s: float | None = None
    accepted_now: bool = False


@dataclass
class StepWatch:
    """One step's deadlines. Times in seconds on one clock.

    Attributes:
        published_s: when the step was published.
        timeout_s: how long it may take until ``completed`` (the executor's step timeout).
        progress_period_s: ``running`` is reported this often.
        blind_after_s: no pose for this long ends the step ``blind``; ``None``: not
            watched (no drift control).
        plan_started_s: when the plan started: silence counts from no earlier.
    """

    published_s: float
    timeout_s: float
    progress_period_s: float
    blind_after_s: float | None
    plan_started_s: float
    accepted_seen: bool = False
    next_report_s: float = field(init=False)

    def __post_init__(self) -> None:
        self.next_report_s = self.published_s + self.progress_period_s

    @property
    def deadline_s(self) -> float:
        """When the step times out."""
        return self.published_s + self.timeout_s

    def expired(self, now: float) -> bool:
        """The step has had its time."""
        return now >= self.deadline_s

    def wait_s(self, now: float) -> float:
        """How long to wait for a status before consulting the watch again, s."""
        return max(0.0, min(self.deadline_s - now, WAIT_SLICE_S))

    def started_s(self, accepted_s: float | None) -> float | None:
        """When the rover started the step: halfway between publishing it and hearing
        ``accepted``."""
        return (self.published_s + accepted_s) / 2.0 if accepted_s is not None else None

    def poll(self, now: float, *, last_pose_s: float, accepted_s: float | None) -> Watched:
        """The verdict at ``now``, given when the last pose reached drift control and when
        ``accepted`` came (``None``: not yet). Reports ``accepted`` once, then
        ``running`` (``published`` before acceptance) every ``progress_period_s``."""
        if self.blind_after_s is not None:
            heard = max(last_pose_s, self.plan_started_s)
            if now - heard > self.blind_after_s:
                return Watched(end="blind")
        started = self.started_s(accepted_s)
        if accepted_s is not None and not self.accepted_seen:
            self.accepted_seen = True
            self.next_report_s = now + self.progress_period_s
            return Watched(report="accepted", started_s=started, accepted_now=True)
        if now >= self.next_report_s:
            self.next_report_s = now + self.progress_period_s
            # Before 'accepted' comes back the step is only published: never say
            # 'running' for a step the rover has not confirmed.
            status = "running" if self.accepted_seen else "published"
            return Watched(report=status, started_s=started)
        return Watched(started_s=started)

    def next_due_s(self) -> float:
        """The next moment the watch has something to say (a report or the timeout; the
        blind limit moves with every pose)."""
        return min(self.deadline_s, self.next_report_s)
