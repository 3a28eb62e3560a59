"""Exceptions raised by :mod:`planner`; each class says when it is raised.

Everything this package raises on purpose derives from :class:`PlannerError`::

    PlannerError
     +-- InvalidPoseError (ValueError)        a non-finite start, goal or waypoint
     |    +-- OutOfBoundsError                outside the map's bounds
     |    +-- GoalInObstacleError             in or too close to an obstacle
     +-- PlanTooLongError (ValueError)        one plan cannot hold the route
     +-- RepairError                          a repair has nothing to offer
     +-- UnreachableGoalError                 the orchestrator gave up (``result``)
     +-- GateCallError                        reaching the gate failed
     |    +-- GateStatusError                 an error status (4xx, 5xx)
     |    |    +-- GateOverloadedError        503 or 429 past the time budget
     |    +-- GateUnavailableError (ConnectionError)  no answer after the retries
     |    |    +-- GateTimeoutError (TimeoutError)    no complete answer in time
     |    +-- GateProtocolError               a success answer not the documented JSON
     +-- DomainBusyError (RuntimeError)       the ROS domain is held, or none is free
     +-- StackRegistryError (PermissionError) the stacks' registry is not this user's
     +-- ConsoleUnavailableError (OSError)    a stack's console socket did not answer
     +-- ConsoleRefusedError (ValueError)     it answered with an error

The gate's own tree (:mod:`gate.errors`) is what the server raises; these are what a
client of it meets. Programming errors raise the usual built-ins; errors from
:mod:`firmware_proto` are translated where they cross into this package, chained with
``raise ... from``.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any, Protocol

__all__ = [
    "ConsoleRefusedError",
    "ConsoleUnavailableError",
    "DomainBusyError",
    "GateCallError",
    "GateOverloadedError",
    "GateProtocolError",
    "GateStatusError",
    "GateTimeoutError",
    "GateUnavailableError",
    "GoalInObstacleError",
    "InvalidPoseError",
    "OutOfBoundsError",
    "PlanTooLongError",
    "PlannerError",
    "RepairError",
    "StackRegistryError",
    "UnreachableGoalError",
]


class PlannerError(Exception):
    """Root of every exception raised on purpose by the planner package."""


class InvalidPoseError(PlannerError, ValueError):
    """A pose cannot be planned for; ``name`` says which (``"goal"``, ``"via[1]"``...)."""

    def __init__(self, name: str, message: str) -> None:
        self.name = name
        super().__init__(f"{name}: {message}")


class OutOfBoundsError(InvalidPoseError):
    """A pose lies outside the map's bounds."""


class GoalInObstacleError(InvalidPoseError):
    """A pose lies inside an obstacle, or too close to one for the rover to stand there:
    ``clearance_m`` (m, negative inside) from the surface of ``obstacle_id`` (``"bounds"``
    for the walls)."""

    def __init__(self, name: str, message: str, obstacle_id: str, clearance_m: float) -> None:
        self.obstacle_id = obstacle_id
        self.clearance_m = clearance_m
        super().__init__(name, message)


class PlanTooLongError(PlannerError, ValueError):
    """The route needs ``steps`` steps, more than the ``limit`` one plan may hold."""

    def __init__(self, steps: int, limit: int) -> None:
        self.steps = steps
        self.limit = limit
        super().__init__(
            f"the route needs {steps} steps but a plan holds at most {limit}: "
            "plan it as a mission, leg by leg"
        )


class RepairError(PlannerError):
    """A repair cannot turn this rejection into a new plan (the message says why)."""


class GaveUp(Protocol):
    """What :class:`UnreachableGoalError` holds: an outcome that says why it failed
    (:class:`~planner.plan.orchestrator.PlanResult`,
    :class:`~planner.plan.orchestrator.MissionResult`; not imported, to avoid a cycle)."""

    @property
    def approved(self) -> bool:
        """Whether the outcome is an approval (never, when raised)."""

    @property
    def reason(self) -> str:
        """Why it was not approved."""


class UnreachableGoalError(PlannerError):
    """The orchestrator gave up on a goal; ``result`` is the :class:`GaveUp` outcome, with
    every attempt and verdict (narrow it with ``isinstance`` to reach them)."""

    def __init__(self, result: GaveUp) -> None:
        self.result = result
        super().__init__(result.reason)


def _json_or_none(body: str) -> dict[str, Any] | None:
    try:
        obj = json.loads(body)
    except ValueError:
        return None
    return obj if isinstance(obj, dict) else None


class GateCallError(PlannerError):
    """Reaching the gate failed (one of the three subclasses)."""


class GateStatusError(GateCallError):
    """The gate answered with an error status.

    Attributes:
        status, body: the HTTP status code and the response body as text.
        code: the gate's machine-readable error name (``"plan_schema"``,
            ``"invalid_option"``...), ``""`` when the body is not the gate's error JSON.
        message: its human-readable sentence (else the body, shortened).
        violations: for a plan that fails the schema, ``(json_pointer, message)`` pairs.
        parameter: for a bad query option, its name; else ``""``.
    """

    def __init__(self, status: int, body: str, *, url: str = "") -> None:
        self.status = status
        self.body = body
        self.url = url
        obj = _json_or_none(body) or {}
        self.code = str(obj.get("error", ""))
        self.message = str(obj.get("message", body[:200]))
        raw = obj.get("violations")
        self.violations: tuple[tuple[str, str], ...] = tuple(
            (str(v.get("pointer", "")), str(v.get("message", "")))
            for v in (raw if isinstance(raw, list) else [])
            if isinstance(v, dict)
        )
        self.parameter = str(obj.get("parameter", ""))
        where = f" ({url})" if url else ""
        what = f"{self.code}: {self.message}" if self.code else self.message
        super().__init__(f"gate answered {status}{where}: {what}")

    @property
    def pointers(self) -> tuple[str, ...]:
        """The JSON pointers of the schema violations, in the gate's order."""
        return tuple(p for p, _ in self.violations)


class GateOverloadedError(GateStatusError):
    """The gate kept answering 503 (busy or shutting down) or 429 (this client holds
    its share) past the time budget; ``retry_after_s``: its last ``Retry-After``, s."""

    def __init__(self, status: int, body: str, *, url: str = "", retry_after_s: float) -> None:
        self.retry_after_s = retry_after_s
        super().__init__(status, body, url=url)


class GateUnavailableError(GateCallError, ConnectionError):
    """No answer from the gate at ``url`` after ``attempts`` connection attempts;
    ``reason``: the last low-level error, as text."""

    def __init__(self, url: str, attempts: int, reason: str) -> None:
        self.url = url
        self.attempts = attempts
        self.reason = reason
        plural = "s" if attempts != 1 else ""
        super().__init__(
            f"the gate at {url} is not answering ({attempts} attempt{plural}): {reason}; "
            "is it running (rover gate)?"
        )


class GateTimeoutError(GateUnavailableError, TimeoutError):
    """The gate accepted the connection but did not answer within ``timeout_s`` (s)."""

    def __init__(self, url: str, attempts: int, timeout_s: float) -> None:
        self.timeout_s = timeout_s
        super().__init__(url, attempts, f"no complete answer within {timeout_s:g} s")


class DomainBusyError(PlannerError, RuntimeError):
    """The ROS domain asked for is held by another stack, or none is free
    (:mod:`planner.stack.domains`)."""


class StackRegistryError(PlannerError, PermissionError):
    """The stacks' registry directory (:mod:`planner.stack.domains`) could have been
    planted or read by another user: nothing is read from it or written to it."""


class ConsoleUnavailableError(PlannerError, OSError):
    """A stack's console socket did not answer (:mod:`planner.ground.console_client`):
    nothing listens there, or the connection failed."""


class ConsoleRefusedError(PlannerError, ValueError):
    """A stack's console answered with an error; ``status``: its HTTP status (0: the URL
    itself was refused before any call)."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status = status


class GateProtocolError(GateCallError):
    """A success answer that is not the documented JSON; ``pointers``: where it departs
    from the expected shape."""

    def __init__(self, message: str, pointers: Sequence[str] = ()) -> None:
        self.pointers = tuple(pointers)
        super().__init__(message)
