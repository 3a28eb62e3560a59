"""Exceptions raised by the HTTP serving layer (:mod:`firmware_proto.http`)::

    HttpServeError           the root
     +-- RequestBodyError    a request body cannot be taken: too large (413) or too slow
     |                       (408); ``status`` and ``code`` say which
     +-- ClientGoneError     the client closed the connection before its body ended

Each server turns a :class:`RequestBodyError` into its own error body.
"""

from __future__ import annotations

__all__ = ["ClientGoneError", "HttpServeError", "RequestBodyError"]


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
    """The client closed the connection before its request body ended (nobody is left
    to answer)."""
