"""The HTTP serving layer of the gate and the live view: one stack for both.

Starlette's request and response types for the applications, uvicorn with h11 for
the connections, and what this project adds to bound every client
(:class:`~firmware_proto.http.protocol.GuardedH11Protocol`): a deadline for a
request's head (slowloris), for its body, for a reader that stops reading, a cap on
connections and on drained bodies, and errors worded by the server. docs/gate.md says
why this stack and what it costs.

- :mod:`~firmware_proto.http.limits`: :class:`ServeLimits`, the bounds;
- :mod:`~firmware_proto.http.protocol`: the guarded h11 connection;
- :mod:`~firmware_proto.http.service`: :class:`HttpService`, an ASGI app served on
  a thread of its own;
- :mod:`~firmware_proto.http.app`: the application layer both servers share
  (Starlette's router, the guard middleware, errors worded by the server);
- :mod:`~firmware_proto.http.body`: :func:`read_body`, a body under a size limit
  and a deadline;
- :mod:`~firmware_proto.http.errors`: the exceptions.

Importing the package loads neither uvicorn nor Starlette (the limits and errors are
plain data). Like :mod:`firmware_proto.linkio` it is a layer beside the pure protocol modules, which
never import it; the bind and token policy both servers share is pure and lives below
it (:mod:`firmware_proto.http.bindpolicy`).
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
"""Names whose modules load uvicorn or asyncio: imported on first use, so that a
configuration module can import the limits without loading a server."""


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'firmware_proto.http' has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)
