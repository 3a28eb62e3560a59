"""A tiny HTTP client for the gate's tests: real sockets on 127.0.0.1, always closed."""

from __future__ import annotations

import http.client
import json
import socket
from dataclasses import dataclass
from typing import Any

TIMEOUT_S = 30.0
JSON_HEADERS = {"Content-Type": "application/json"}


@dataclass(frozen=True)
class Reply:
    """One response: status, headers (names lower-case), body."""

    status: int
    headers: dict[str, str]
    body: bytes

    def json(self) -> Any:
        return json.loads(self.body)

    def without_wall_time(self) -> bytes:
        """The body up to ``wall_time_s`` (the last field, the only one that varies)."""
        head, sep, _ = self.body.rpartition(b',"wall_time_s":')
        assert sep, "no wall_time_s in the body"
        return head


def _reply(response: http.client.HTTPResponse) -> Reply:
    body = response.read()
    return Reply(response.status, {k.lower(): v for k, v in response.getheaders()}, body)


class Client:
    """One keep-alive connection (a context manager)."""

    def __init__(
        self,
        address: tuple[str, int],
        token: str | None = None,
        source: str | None = None,
        timeout_s: float = TIMEOUT_S,
    ) -> None:
        self.conn = http.client.HTTPConnection(
            *address, timeout=timeout_s, source_address=(source, 0) if source else None
        )
        self.token = token

    def request(
        self,
        method: str,
        path: str,
        body: bytes | str | None = None,
        headers: dict[str, str] | None = None,
    ) -> Reply:
        all_headers = dict(headers or {})
        if self.token is not None:
            all_headers.setdefault("Authorization", f"Bearer {self.token}")
        self.conn.request(method, path, body=body, headers=all_headers)
        return _reply(self.conn.getresponse())

    def post_plan(self, plan: Any, query: str = "", headers: dict[str, str] | None = None) -> Reply:
        path = "/validate_plan" + (f"?{query}" if query else "")
        body = plan if isinstance(plan, (bytes, str)) else json.dumps(plan)
        return self.request("POST", path, body, JSON_HEADERS | (headers or {}))

    def close(self) -> None:
        self.conn.close()

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def call(
    address: tuple[str, int],
    method: str,
    path: str,
    body: bytes | str | None = None,
    *,
    headers: dict[str, str] | None = None,
    token: str | None = None,
    source: str | None = None,
) -> Reply:
    """One request on a fresh connection (from ``source``, another loopback address such
    as 127.0.0.2: another client), closed afterwards."""
    with Client(address, token, source) as client:
        return client.request(method, path, body, headers)


def post_plan(
    address: tuple[str, int],
    plan: Any,
    query: str = "",
    token: str | None = None,
    source: str | None = None,
    timeout_s: float = TIMEOUT_S,
) -> Reply:
    """POST a plan to /validate_plan on a fresh connection (from ``source``)."""
    with Client(address, token, source, timeout_s) as client:
        return client.post_plan(plan, query)


def raw_exchange(address: tuple[str, int], data: bytes, *, half_close: bool = False) -> bytes:
    """Send raw bytes and read until the server closes (or its first response arrives
    whole, when it keeps the connection open)."""
    with socket.create_connection(address, timeout=TIMEOUT_S) as sock:
        sock.sendall(data)
        if half_close:
            sock.shutdown(socket.SHUT_WR)
        chunks: list[bytes] = []
        while True:
            chunk = sock.recv(65536)
            if not chunk:
                break
            chunks.append(chunk)
            whole = b"".join(chunks)
            head, sep, rest = whole.partition(b"\r\n\r\n")
            if sep:
                length = _content_length(head)
                if length is not None and len(rest) >= length:
                    return whole
        return b"".join(chunks)


def _content_length(head: bytes) -> int | None:
    for line in head.split(b"\r\n")[1:]:
        name, _, value = line.partition(b":")
        if name.strip().lower() == b"content-length":
            return int(value.strip())
    return None


def parse_raw(data: bytes) -> Reply:
    """Split a raw HTTP/1.1 response into a :class:`Reply`."""
    head, _, body = data.partition(b"\r\n\r\n")
    lines = head.decode("latin-1").split("\r\n")
    status = int(lines[0].split()[1])
    headers = {}
    for line in lines[1:]:
        name, _, value = line.partition(":")
        headers[name.strip().lower()] = value.strip()
    return Reply(status, headers, body)
