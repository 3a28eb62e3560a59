"""Responses as single byte strings, and the JSON error body.

Writing the status line, the headers and the body in *one* ``send`` is what avoids the
keep-alive stall of the stdlib server: with two writes, the second waits (Nagle) for the
ACK of the first, which the client delays by up to 40 ms because it has nothing to send.
:func:`encode_response` builds that one byte string; the server also sets
``TCP_NODELAY``, so either measure alone would do (the benchmark measures each).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from email.utils import formatdate
from http import HTTPStatus
from typing import Any

from gate.errors import BadRequestError, HttpError, MethodNotAllowedError, PlanSchemaError

__all__ = ["SERVER_NAME", "encode_response", "error_body", "json_bytes"]

SERVER_NAME = "rover-gate"


def json_bytes(obj: Any) -> bytes:
    """Compact JSON bytes (no NaN, no spaces)."""
    return json.dumps(obj, separators=(",", ":"), allow_nan=False).encode()


def error_body(error: HttpError) -> bytes:
    """The JSON body of an error response.

    ``{"error": code, "status": n, "message": text}``, plus ``violations`` (a list of
    ``{"pointer", "message"}``) for a plan that fails the schema, ``parameter`` for a bad
    option, ``allow`` for a method not allowed.
    """
    body: dict[str, Any] = {"error": error.code, "status": error.status, "message": error.message}
    if isinstance(error, PlanSchemaError):
        body["violations"] = [{"pointer": p, "message": m} for p, m in error.violations]
    elif isinstance(error, BadRequestError) and error.parameter:
        body["parameter"] = error.parameter
    if isinstance(error, MethodNotAllowedError):
        body["allow"] = error.allow
    return json_bytes(body)


def encode_response(
    status: int,
    body: bytes,
    *,
    content_type: str = "application/json",
    headers: Mapping[str, str] | None = None,
    keep_alive: bool = True,
    head: bool = False,
    date: str | None = None,
) -> bytes:
    """Status line, headers and body as one byte string (HTTP/1.1).

    Args:
        status: status code.
        body: the body (sent unless ``head``; its length is announced either way).
        content_type: the body's media type.
        headers: extra headers.
        keep_alive: ``False`` adds ``Connection: close``.
        head: a response to HEAD: headers only.
        date: the ``Date`` value; default now.
    """
    phrase = HTTPStatus(status).phrase
    lines = [
        f"HTTP/1.1 {status} {phrase}",
        f"Server: {SERVER_NAME}",
        f"Date: {date or formatdate(usegmt=True)}",
        f"Content-Type: {content_type}",
        f"Content-Length: {len(body)}",
        "Cache-Control: no-store",
    ]
    lines += [f"{k}: {v}" for k, v in (headers or {}).items()]
    if not keep_alive:
        lines.append("Connection: close")
    head_bytes = ("\r\n".join(lines) + "\r\n\r\n").encode("latin-1")
    return head_bytes if head else head_bytes + body
