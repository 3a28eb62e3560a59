"""Exceptions raised by the HTTP serving layer (:mod:`firmware_proto.http`)::

    HttpServeError           the root
     +-- RequestBodyError    a request body is too large (413) or too slow (408)
     +-- ClientGoneError     the client closed the connection before its body ended
     +-- StatusError         a request answered with an error status: raised by the
                             application layer (:mod:`~.app`) and the base of each
                             server's own errors

Each server words these in its own error body.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

__all__ = ["ClientGoneError", "HttpServeError", "RequestBodyError", "StatusError"]


class HttpServeError(Exception):
    """Root of every exception raised on purpose by :mod:`firmware_proto.http`."""


class RequestBodyError(HttpServeError):
    """A request body that will not be read whole.

    Attributes:
        status: the HTTP status to answer (413 too large, 408 too slow).
        code: a short machine-readable name (``payload_too_large``, ``request_timeout``).
        message: one sentence for people.
    """

    def __init__(self, status: int, code: str, message: str) -> None:
        super().__init__(message)
        self.status = status
        self.code = code
        self.message = message


class ClientGoneError(HttpServeError):
    """The client closed the connection before its request body ended: nobody to answer."""


class StatusError(HttpServeError):
    """A request that gets an error answer. A subclass fixes ``status`` and
    ``default_code``; an instance may override both.

    Attributes:
        status: the HTTP status.
        code: a short machine-readable name (``not_found``, ``cross_origin``...).
        message: one sentence for people.
        headers: extra response headers (``Allow``, ``Retry-After``...).
        extra: further fields of the JSON body (``allow``, ``parameter``...): :meth:`fields`.
    """

    status = 500
    default_code = "internal_error"

    def __init__(
        self,
        message: str,
        *,
        code: str | None = None,
        headers: Mapping[str, str] | None = None,
        status: int | None = None,
        extra: Mapping[str, Any] | None = None,
    ) -> None:
        super().__init__(message)
        self.message = message
        self.code = code or self.default_code
        self.headers = dict(headers or {})
        if status is not None:
            self.status = status
        self.extra = dict(extra or {})

    def fields(self) -> dict[str, Any]:
        """The JSON body's fields beyond ``error``, ``status`` and ``message`` (a
        subclass adds its own to :attr:`extra`'s)."""
        return dict(self.extra)
