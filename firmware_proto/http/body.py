"""Reading a request body under a size limit and a deadline (ASGI ``receive``)."""

from __future__ import annotations

import asyncio
import sys
from collections.abc import Awaitable, Callable, MutableMapping
from typing import Any

from firmware_proto.http.errors import ClientGoneError, RequestBodyError

__all__ = ["Receive", "read_body"]

Receive = Callable[[], Awaitable[MutableMapping[str, Any]]]
"""An ASGI ``receive`` callable."""


async def read_body(receive: Receive, *, limit_bytes: int, timeout_s: float) -> bytes:
    """The whole request body, at most ``limit_bytes``, within ``timeout_s`` seconds. h11
    has checked the framing; refuse a declared length over the limit before calling this,
    so that the client is not asked to send it (``Expect: 100-continue``).

    Raises:
        RequestBodyError: 413 ``payload_too_large`` once the running size passes the limit;
            408 ``request_timeout`` when the body has not ended in time.
        ClientGoneError: the client closed the connection first.
    """

    async def collect() -> bytes:
        parts: list[bytes] = []
        total = 0
        while True:
            message = await receive()
            if message["type"] == "http.disconnect":
                raise ClientGoneError("the client left before its body ended")
            chunk: bytes = message.get("body", b"")
            total += len(chunk)
            if total > limit_bytes:
                raise RequestBodyError(
                    413,
                    "payload_too_large",
                    f"body over the limit of {limit_bytes} bytes",
                )
            parts.append(chunk)
            if not message.get("more_body", False):
                return b"".join(parts)

    # A deadline on this task: asyncio.wait_for would cost a task and a loop turn more.
    task = asyncio.current_task()
    assert task is not None
    expired = False

    def expire() -> None:
        nonlocal expired
        expired = True
        task.cancel()

    deadline = asyncio.get_running_loop().call_later(timeout_s, expire)
    try:
        return await collect()
    except asyncio.CancelledError as exc:
        if not expired:
            raise  # cancelled by someone else
        if sys.version_info >= (3, 11):
            task.uncancel()
        raise RequestBodyError(
            408, "request_timeout", f"the body did not arrive whole within {timeout_s:g} s"
        ) from exc
    finally:
        deadline.cancel()
