"""The HTTP serving layer of the gate and the live view: one stack for both
(docs/gate.md says why this stack and what it costs).

Starlette's request and response types for the applications, uvicorn with h11 for the
connections, and what this project adds to bound every client: :mod:`~.limits` (the
bounds), :mod:`~.protocol` (the guarded h11 connection), :mod:`~.service` (an ASGI app
served on a thread of its own), :mod:`~.app` (the application layer both servers
share), :mod:`~.body` (a body under a size limit and a deadline), :mod:`~.errors`.

Importing the package loads neither uvicorn nor Starlette. The pure protocol modules
never import it; the bind and token policy (:mod:`~.bindpolicy`) is pure.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from firmware_proto.http.errors import (
    ClientGoneError,
    HttpServeError,
    RequestBodyError,
    StatusError,
)
from firmware_proto.http.limits import ErrorRenderer, ServeLimits

if TYPE_CHECKING:
    from firmware_proto.http.body import read_body
    from firmware_proto.http.service import HttpService

__all__ = [
    "ClientGoneError",
    "ErrorRenderer",
    "HttpServeError",
    "HttpService",
    "RequestBodyError",
    "ServeLimits",
    "StatusError",
    "read_body",
]

_LAZY = {
    "HttpService": "firmware_proto.http.service",
    "read_body": "firmware_proto.http.body",
}
"""Names whose modules load uvicorn or asyncio: imported on first use (limits need no server)."""


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'firmware_proto.http' has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)
