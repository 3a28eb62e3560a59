"""The HTTP serving layer on its own: limits, error wording, a minimal ASGI app served
on 127.0.0.1. The gate's and the view's tests drive it through their applications."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import threading
from collections.abc import Iterator
from typing import Any

import pytest

from firmware_proto.http import (
    ClientGoneError,
    HttpService,
    RequestBodyError,
    ServeLimits,
    read_body,
)
from firmware_proto.http.protocol import classify_protocol_error
from firmware_proto.model.schemacheck import MAX_DEPTH, json_depth, schema_violations

TIMEOUT_S = 30.0


def _render(status: int, code: str, message: str) -> tuple[str, bytes]:
    return "application/json", json.dumps({"code": code, "message": message}).encode()


async def _echo(scope: Any, receive: Any, send: Any) -> None:
    """Answers with the body's length, or the body error's status."""
    if scope["type"] != "http":
        return
    try:
        body = await read_body(receive, limit_bytes=10, timeout_s=0.5)
        status, text = 200, str(len(body)).encode()
    except RequestBodyError as exc:
        status, text = exc.status, exc.code.encode()
    headers = [(b"content-length", str(len(text)).encode())]
    if status != 200:
        headers.append((b"connection", b"close"))
    await send({"type": "http.response.start", "status": status, "headers": headers})
    await send({"type": "http.response.body", "body": text})


@pytest.fixture
def service() -> Iterator[HttpService]:
    limits = ServeLimits(idle_timeout_s=0.5, head_timeout_s=0.5, max_connections=2)
    with HttpService(
        _echo,
        host="127.0.0.1",
        port=0,
        limits=limits,
        render_error=_render,
        server_name="probe",
        thread_name="probe-http",
    ) as served:
        yield served


def _exchange(address: tuple[str, int], data: bytes, *, half_close: bool = False) -> bytes:
    with socket.create_connection(address, timeout=TIMEOUT_S) as sock:
        sock.sendall(data)
        if half_close:
            sock.shutdown(socket.SHUT_WR)
        chunks = []
        while chunk := sock.recv(65536):
            chunks.append(chunk)
    return b"".join(chunks)


def test_limits_are_checked() -> None:
    for bad in ({"head_timeout_s": 0.0}, {"idle_timeout_s": float("inf")}, {"max_connections": 0}):
        with pytest.raises(ValueError, match="must be"):
            ServeLimits(**bad)


def test_protocol_errors_are_classified() -> None:
    assert classify_protocol_error(431, "Receive buffer too long") == (
        431,
        "request_header_fields_too_large",
    )
    assert classify_protocol_error(501, "Only Transfer-Encoding: chunked is supported") == (
        400,
        "bad_framing",
    )
    assert classify_protocol_error(400, "illegal request line") == (400, "bad_request")


def test_importing_the_limits_loads_no_server() -> None:
    code = (
        "import sys, firmware_proto.http\n"
        "print(sorted(m for m in ('uvicorn', 'starlette', 'h11') if m in sys.modules))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60
    )
    assert out.stdout.strip() == "[]"


def test_the_listener_is_tcp_so_asyncio_disables_nagle(service: HttpService) -> None:
    # asyncio sets TCP_NODELAY on accepted sockets only when the listener says it is
    # TCP (proto 6); with proto 0 every kept-alive answer waited ~40 ms (bench_gate).
    assert service._sock is not None
    assert service._sock.proto == socket.IPPROTO_TCP


def test_bodies_heads_and_framing(service: HttpService) -> None:
    address = service.address
    ok = _exchange(
        address, b"POST / HTTP/1.1\r\nHost: x\r\nContent-Length: 3\r\n\r\nabc", half_close=True
    )
    assert ok.startswith(b"HTTP/1.1 200 ") and ok.endswith(b"\r\n\r\n3")
    assert b"Server: probe" in ok or b"server: probe" in ok
    big = _exchange(
        address, b"POST / HTTP/1.1\r\nHost: x\r\nContent-Length: 11\r\n\r\n" + b"x" * 11
    )
    assert big.startswith(b"HTTP/1.1 413 ")
    stalled = _exchange(address, b"POST / HTTP/1.1\r\nHost: x\r\nContent-Length: 5\r\n\r\nab")
    assert stalled.startswith(b"HTTP/1.1 408 ")
    truncated = _exchange(
        address, b"POST / HTTP/1.1\r\nHost: x\r\nContent-Length: 5\r\n\r\nab", half_close=True
    )
    assert truncated.startswith(b"HTTP/1.1 400 ") and b'"truncated_body"' in truncated
    both = _exchange(
        address,
        b"POST / HTTP/1.1\r\nHost: x\r\nContent-Length: 3\r\nTransfer-Encoding: chunked\r\n\r\n",
    )
    assert both.startswith(b"HTTP/1.1 400 ") and b'"bad_framing"' in both
    slow = _exchange(address, b"GET / HTTP/1.1\r\nHo")
    assert slow.startswith(b"HTTP/1.1 408 ") and b'"request_timeout"' in slow
    assert b"application/json" in slow
    garbage = _exchange(address, b"\x00\x01 nonsense\r\n\r\n")
    assert garbage.startswith(b"HTTP/1.1 400 ") and b'"bad_request"' in garbage
    assert _exchange(address, b"") == b""  # silent: closed after the idle timeout


async def _patient(scope: Any, receive: Any, send: Any) -> None:
    """Reads the body with a long deadline: a connection mid-body is busy."""
    if scope["type"] != "http":
        return
    try:
        body = await read_body(receive, limit_bytes=10, timeout_s=TIMEOUT_S)
    except ClientGoneError:
        return
    await send({"type": "http.response.start", "status": 200, "headers": []})
    await send({"type": "http.response.body", "body": body})


def test_the_connection_cap_evicts_an_idle_connection_else_answers_503() -> None:
    limits = ServeLimits(idle_timeout_s=5.0, max_connections=2, max_connections_per_address=2)
    with HttpService(
        _patient,
        host="127.0.0.1",
        port=0,
        limits=limits,
        render_error=_render,
        server_name="probe",
        thread_name="probe-http",
    ) as served:
        address = served.address
        # Two idle connections: a third takes the oldest one's place.
        with (
            socket.create_connection(address, timeout=TIMEOUT_S) as oldest,
            socket.create_connection(address, timeout=TIMEOUT_S),
        ):
            third = _exchange(address, b"POST / HTTP/1.1\r\nHost: x\r\nContent-Length: 1\r\n\r\nz")
            assert third.startswith(b"HTTP/1.1 200 ")
            assert oldest.recv(1) == b""  # closed for it
        # Two connections whose requests wait in the application for their bodies (the
        # 100 Continue says so): nothing to evict, 503.
        head = b"POST / HTTP/1.1\r\nHost: x\r\nContent-Length: 5\r\nExpect: 100-continue\r\n\r\n"
        with (
            socket.create_connection(address, timeout=TIMEOUT_S) as one,
            socket.create_connection(address, timeout=TIMEOUT_S) as two,
        ):
            for busy in (one, two):
                busy.sendall(head)
                assert busy.recv(64).startswith(b"HTTP/1.1 100 ")
            with socket.create_connection(address, timeout=TIMEOUT_S) as probe:
                probe.sendall(b"GET / HTTP/1.1\r\nHost: x\r\n\r\n")
                answer = probe.recv(65536)
        assert answer.startswith(b"HTTP/1.1 503 ") and b'"too_many_connections"' in answer


def _read_answer(sock: socket.socket) -> bytes:
    """One answer with a Content-Length body (b"" when the server closed first)."""
    data = b""
    while b"\r\n\r\n" not in data:
        chunk = sock.recv(65536)
        if not chunk:
            return data
        data += chunk
    head, _, body = data.partition(b"\r\n\r\n")
    length = next(
        int(line.split(b":", 1)[1])
        for line in head.split(b"\r\n")
        if line.lower().startswith(b"content-length:")
    )
    while len(body) < length and (chunk := sock.recv(65536)):
        body += chunk
    return head + b"\r\n\r\n" + body


def test_a_request_waiting_unread_is_not_evicted() -> None:
    """A connection accepted while the event loop was busy holds a whole request no
    callback has read yet: it is not idle, and a newcomer over the address's limit
    takes the place of an idle connection (or is refused), never its."""
    entered = threading.Event()
    release = threading.Event()

    async def app(scope: Any, receive: Any, send: Any) -> None:
        if scope["type"] != "http":
            return
        if scope["path"] == "/hold":
            entered.set()
            release.wait(TIMEOUT_S)  # holds the event loop: nothing else is read
        headers = [(b"content-length", b"2")]
        await send({"type": "http.response.start", "status": 200, "headers": headers})
        await send({"type": "http.response.body", "body": b"ok"})

    limits = ServeLimits(idle_timeout_s=5.0, max_connections=8, max_connections_per_address=2)
    with HttpService(
        app,
        host="127.0.0.1",
        port=0,
        limits=limits,
        render_error=_render,
        server_name="probe",
        thread_name="probe-http",
    ) as served:
        address = served.address
        with socket.create_connection(address, timeout=TIMEOUT_S) as holder:
            holder.sendall(b"GET /hold HTTP/1.1\r\nHost: x\r\n\r\n")
            assert entered.wait(TIMEOUT_S)
            with (
                socket.create_connection(address, timeout=TIMEOUT_S) as waiting,
                socket.create_connection(address, timeout=TIMEOUT_S) as newcomer,
            ):
                waiting.sendall(b"GET /w HTTP/1.1\r\nHost: x\r\n\r\n")
                release.set()
                assert _read_answer(waiting).startswith(b"HTTP/1.1 200 ")
                newcomer.sendall(b"GET /n HTTP/1.1\r\nHost: x\r\n\r\n")
                answer = _read_answer(newcomer)
                # The holder, answered and idle, made room; or nothing could, and 503.
                assert answer.startswith((b"HTTP/1.1 200 ", b"HTTP/1.1 503 ")), answer
                if answer.startswith(b"HTTP/1.1 200 "):
                    assert _read_answer(holder).startswith(b"HTTP/1.1 200 ")
                    assert holder.recv(1) == b""  # evicted after its answer


def test_close_is_idempotent_and_refuses_new_connections() -> None:
    served = HttpService(
        _echo,
        host="127.0.0.1",
        port=0,
        limits=ServeLimits(),
        render_error=_render,
        server_name="probe",
        thread_name="probe-http",
    ).start()
    address = served.address
    served.close()
    served.close()
    assert served.stopped_accepting.is_set()
    with pytest.raises(ConnectionRefusedError):
        socket.create_connection(address, timeout=TIMEOUT_S).close()


def test_depth_is_measured_without_recursion() -> None:
    deep: Any = []
    for _ in range(100_000):
        deep = [deep]
    assert json_depth(deep) == 100_001
    assert json_depth(deep, limit=10) == 10
    assert json_depth(1) == 0
    assert json_depth({"a": [1, {"b": []}]}) == 4
    assert schema_violations_of(deep) == [("", f"nested deeper than {MAX_DEPTH} levels")]


def schema_violations_of(doc: Any) -> list[tuple[str, str]]:
    from jsonschema import Draft202012Validator

    return schema_violations(Draft202012Validator({"type": "array"}), doc)
