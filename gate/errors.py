"""Exceptions raised by :mod:`gate`.

Everything this package raises on purpose derives from :class:`GateError`::

    GateError
     +-- CallCancelledError     a worker pool's call was stopped before its end
     +-- GateConfigError        a setting out of range or refused by the bind policy (ValueError)
     +-- OptionError            a query parameter unknown, repeated or out of range (ValueError)
     +-- HttpError              cannot be served: ``status``, ``code``, ``headers``;
          |                     also :class:`firmware_proto.http.errors.StatusError`
          +-- BadRequestError        400: not JSON, bad option, malformed framing
          |    +-- PlanSchemaError   400: fails Listing 1; ``violations``
          |         +-- GoalRangeError  400: a goal beyond the twin's arithmetic
          +-- NotFoundError          404: unknown path or map
          +-- RequestTimeoutError    408: the body did not arrive whole in time
          +-- LengthRequiredError    411: a body without length or chunked framing
          +-- PayloadTooLargeError   413: the body exceeds the limit
          +-- UnsupportedMediaError  415: the body is not ``application/json``
          +-- TooManyRequestsError   429: the client holds its share; ``retry_after_s``
          +-- OverloadedError        503: full or shutting down; ``retry_after_s``

The shared application layer (:mod:`firmware_proto.http.app`) answers 401 (token), 404
(path), 405 (method; ``allow`` lists the path's), 421 (Host) and 501 (a method HTTP does
not define) itself with :class:`firmware_proto.http.errors.StatusError`, which the gate
words as its own. Errors from the twin (:mod:`emulator.errors`) and the plan schema
(:class:`firmware_proto.errors.PlanError`) are translated at the boundary, chained with
``raise ... from``.
"""

from __future__ import annotations

from typing import Any

from firmware_proto.http.errors import StatusError

__all__ = [
    "BadRequestError",
    "CallCancelledError",
    "GateConfigError",
    "GateError",
    "GoalRangeError",
    "HttpError",
    "LengthRequiredError",
    "NotFoundError",
    "OptionError",
    "OverloadedError",
    "PayloadTooLargeError",
    "PlanSchemaError",
    "RequestTimeoutError",
    "TooManyRequestsError",
    "UnsupportedMediaError",
]


class GateError(Exception):
    """Root of every exception raised on purpose by the gate package."""


class GateConfigError(GateError, ValueError):
    """A gate setting is out of range or refused by the bind policy."""


class CallCancelledError(GateError):
    """A call to the worker pool was stopped before its end (cancelled past its
    deadline, or because its client left); its future raises this."""


class OptionError(GateError, ValueError):
    """A request option is unknown, repeated or out of range.

    Attributes:
        parameter: the query parameter's name (``""`` for the query string as a whole).
    """

    def __init__(self, parameter: str, message: str) -> None:
        self.parameter = parameter
        self.reason = message
        super().__init__(f"{parameter}: {message}" if parameter else message)

    def __reduce__(self) -> tuple[type[OptionError], tuple[str, str]]:
        # Crosses process boundaries (worker pools): rebuild from both arguments.
        return (type(self), (self.parameter, self.reason))


class HttpError(GateError, StatusError):
    """A request that gets an error response instead of a verdict.

    Attributes:
        status: HTTP status code.
        code: short machine-readable error name (``"not_json"``, ``"plan_schema"``...).
        message: one human-readable sentence.
        headers: extra response headers (``Allow``, ``Retry-After``...).
    """

    status = 500
    default_code = "internal_error"

    def __init__(
        self, message: str, *, code: str | None = None, headers: dict[str, str] | None = None
    ) -> None:
        StatusError.__init__(self, message, code=code, headers=headers)


class BadRequestError(HttpError):
    """400: the request is malformed (not JSON, bad option, bad framing).

    Attributes:
        parameter: for a bad option, the query parameter's name; else ``""``.
    """

    status = 400
    default_code = "bad_request"

    def __init__(
        self,
        message: str,
        *,
        code: str | None = None,
        parameter: str = "",
        headers: dict[str, str] | None = None,
    ) -> None:
        super().__init__(message, code=code, headers=headers)
        self.parameter = parameter

    def fields(self) -> dict[str, Any]:
        """``parameter`` for a bad option."""
        return super().fields() | ({"parameter": self.parameter} if self.parameter else {})


class PlanSchemaError(BadRequestError):
    """400: the plan fails the Listing 1 schema.

    Attributes:
        violations: ``(json_pointer, message)`` pairs, sorted by pointer.
        complete: whether ``violations`` are all of them (``False``: the first ones
            found; the gate stops looking after a few, so that a large bad body costs
            little).
    """

    default_code = "plan_schema"

    def __init__(self, violations: list[tuple[str, str]], *, complete: bool = True) -> None:
        self.violations = list(violations)
        self.complete = complete
        text = "; ".join(f"{ptr or '/'}: {msg}" for ptr, msg in self.violations)
        more = "" if complete else "; and more, not listed"
        super().__init__(f"plan fails the schema: {text}{more}")

    def fields(self) -> dict[str, Any]:
        """``violations`` (and ``truncated`` when they are not all)."""
        out = super().fields() | {
            "violations": [{"pointer": p, "message": m} for p, m in self.violations]
        }
        if not self.complete:
            out["truncated"] = True
        return out


class GoalRangeError(PlanSchemaError):
    """400: the plan's goal lies beyond what the twin's arithmetic can measure (the
    schema allows any finite number); ``violations`` names the coordinates."""

    default_code = "goal_out_of_range"

    def __init__(self, violations: list[tuple[str, str]]) -> None:
        super().__init__(violations)
        text = "; ".join(f"{ptr}: {msg}" for ptr, msg in self.violations)
        self.message = f"goal out of range: {text}"
        self.args = (self.message,)


class NotFoundError(HttpError):
    """404: no such path or map."""

    status = 404
    default_code = "not_found"


class RequestTimeoutError(HttpError):
    """408: the request's body did not arrive whole within the body timeout."""

    status = 408
    default_code = "request_timeout"


class LengthRequiredError(HttpError):
    """411: a request body without Content-Length and without chunked framing."""

    status = 411
    default_code = "length_required"


class PayloadTooLargeError(HttpError):
    """413: the body is larger than the limit."""

    status = 413
    default_code = "payload_too_large"


class UnsupportedMediaError(HttpError):
    """415: the body's Content-Type is not ``application/json``."""

    status = 415
    default_code = "unsupported_media_type"


class TooManyRequestsError(HttpError):
    """429: this client already holds its share of the gate (validations or their
    estimated work); others' requests are served meanwhile. The client may retry after
    ``retry_after_s`` whole seconds."""

    status = 429
    default_code = "too_many_requests"

    def __init__(self, message: str, *, code: str | None = None, retry_after_s: int = 1) -> None:
        self.retry_after_s = retry_after_s
        super().__init__(message, code=code, headers={"Retry-After": str(retry_after_s)})


class OverloadedError(HttpError):
    """503: no capacity now (all workers and queue slots busy) or shutting down; the
    client may retry after ``retry_after_s`` whole seconds."""

    status = 503
    default_code = "overloaded"

    def __init__(self, message: str, *, code: str | None = None, retry_after_s: int = 1) -> None:
        self.retry_after_s = retry_after_s
        super().__init__(message, code=code, headers={"Retry-After": str(retry_after_s)})
