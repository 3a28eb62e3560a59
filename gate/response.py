"""The JSON bodies of the gate's answers, errors included.

Every body the gate sends is JSON: verdicts and documents, the errors its handlers and
the shared application layer raise (:func:`error_json`), and the errors its connection
layer answers by itself (malformed request, slow head, too many connections:
:func:`render_connection_error`).
"""

from __future__ import annotations

import json
from typing import Any

from firmware_proto.http.errors import StatusError

__all__ = [
    "JSON_CONTENT_TYPE",
    "SERVER_NAME",
    "error_json",
    "json_bytes",
    "render_connection_error",
]

SERVER_NAME = "rover-gate"
JSON_CONTENT_TYPE = "application/json"


def json_bytes(obj: Any) -> bytes:
    """Compact JSON bytes (no NaN, no spaces)."""
    return json.dumps(obj, separators=(",", ":"), allow_nan=False).encode()


def error_json(error: StatusError) -> bytes:
    """The JSON body of an error response.

    ``{"error": code, "status": n, "message": text}``, plus the error's own fields
    (:meth:`~firmware_proto.http.errors.StatusError.fields`): ``violations`` (a list of
    ``{"pointer", "message"}``, and ``truncated`` when they are not all) for a plan
    that fails the schema, ``parameter`` for a bad option, ``allow`` for a method not
    allowed.
    """
    body: dict[str, Any] = {"error": error.code, "status": error.status, "message": error.message}
    return json_bytes(body | error.fields())


def render_connection_error(status: int, code: str, message: str) -> tuple[str, bytes]:
    """The gate's wording of an error the connection layer answers itself (a
    :data:`firmware_proto.http.ErrorRenderer`): the same JSON as every error."""
    return JSON_CONTENT_TYPE, json_bytes({"error": code, "status": status, "message": message})
