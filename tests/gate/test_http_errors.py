"""Bad requests over real HTTP: schema violations with pointers, framing, media type,
size, paths, methods, tokens; every error body is JSON and keep-alive survives."""

from __future__ import annotations

import copy
import json
from collections.abc import Callable
from typing import Any

import pytest

from gate.config import DEFAULT_MAX_BODY_BYTES
from gate.server import GateServer

from .client import Client, call, parse_raw, post_plan, raw_exchange
from .plans import STOP_AT_LAB_START, fwd, plan, step

GOOD = plan((2.2, 3.0, 0.0), fwd(1.0))


def _mutated(change: Callable[[dict[str, Any]], object]) -> dict[str, Any]:
    body = copy.deepcopy(GOOD)
    change(body)
    return body


def _error(reply_body: bytes) -> dict[str, Any]:
    body: dict[str, Any] = json.loads(reply_body)
    assert set(body) >= {"error", "status", "message"}
    return body


SCHEMA_CASES: list[tuple[str, Any, set[str]]] = [
    ("extra property at the root", _mutated(lambda p: p.update(speed=1)), {"/speed"}),
    ("extra property in the goal", _mutated(lambda p: p["goal"].update(z=0)), {"/goal/z"}),
    (
        "extra property in a step",
        _mutated(lambda p: p["commands"][0].update(note="x")),
        {"/commands/0/note"},
    ),
    ("no commands", _mutated(lambda p: p.update(commands=[])), {"/commands"}),
    (
        "13 commands",
        _mutated(lambda p: p.update(commands=[step("STOP", 0, 0)] * 13)),
        {"/commands"},
    ),
    ("speed 61", _mutated(lambda p: p["commands"][0].update(speed=61)), {"/commands/0/speed"}),
    (
        "distance -1",
        _mutated(lambda p: p["commands"][0].update(distance=-1)),
        {"/commands/0/distance"},
    ),
    (
        "distance 30001",
        _mutated(lambda p: p["commands"][0].update(distance=30001)),
        {"/commands/0/distance"},
    ),
    (
        "unknown command",
        _mutated(lambda p: p["commands"][0].update(command="JUMP")),
        {"/commands/0/command"},
    ),
    (
        "speed as a string",
        _mutated(lambda p: p["commands"][0].update(speed="10")),
        {"/commands/0/speed"},
    ),
    (
        "speed as a fraction",
        _mutated(lambda p: p["commands"][0].update(speed=10.5)),
        {"/commands/0/speed"},
    ),
    (
        "speed as a boolean",
        _mutated(lambda p: p["commands"][0].update(speed=True)),
        {"/commands/0/speed"},
    ),
    ("goal x as a string", _mutated(lambda p: p["goal"].update(x="1")), {"/goal/x"}),
    ("goal as a list", _mutated(lambda p: p.update(goal=[1, 2, 0])), {"/goal"}),
    ("commands as an object", _mutated(lambda p: p.update(commands={})), {"/commands"}),
    ("missing goal", _mutated(lambda p: p.pop("goal")), {""}),
    ("a list instead of a plan", [GOOD], {""}),
    (
        "two violations",
        _mutated(lambda p: (p["commands"][0].update(speed=61), p["goal"].update(z=1))),
        {"/commands/0/speed", "/goal/z"},
    ),
]


@pytest.mark.parametrize(
    ("body", "pointers"), [c[1:] for c in SCHEMA_CASES], ids=[c[0] for c in SCHEMA_CASES]
)
def test_schema_violations_are_400_with_their_pointers(
    http_gate: GateServer, body: Any, pointers: set[str]
) -> None:
    reply = post_plan(http_gate.address, body)
    assert reply.status == 400
    error = _error(reply.body)
    assert error["error"] == "plan_schema"
    assert {v["pointer"] for v in error["violations"]} == pointers
    assert all(v["message"] for v in error["violations"])


@pytest.mark.parametrize(
    ("body", "why"),
    [
        (b"{", "not JSON"),
        (b"", "empty body"),
        (b'{"goal": NaN}', "NaN is not JSON"),
        (b'{"goal": {"x": 1, "x": 2}}', "duplicate key"),
        (b"\xff\xfe{}", "not UTF-8"),
        (b"\xef\xbb\xbf{}", "a byte-order mark"),
    ],
)
def test_non_json_bodies_are_400(http_gate: GateServer, body: bytes, why: str) -> None:
    reply = post_plan(http_gate.address, body)
    assert reply.status == 400, why
    assert _error(reply.body)["error"] == "not_json"


@pytest.mark.parametrize(
    "content_type",
    [None, "text/plain", "application/x-www-form-urlencoded", "application/json; charset=latin-1"],
)
def test_wrong_content_type_is_415(http_gate: GateServer, content_type: str | None) -> None:
    headers = {} if content_type is None else {"Content-Type": content_type}
    with Client(http_gate.address) as client:
        client.conn.putrequest("POST", "/validate_plan", skip_accept_encoding=True)
        for k, v in headers.items():
            client.conn.putheader(k, v)
        body = json.dumps(GOOD).encode()
        client.conn.putheader("Content-Length", str(len(body)))
        client.conn.endheaders(body)
        response = client.conn.getresponse()
        assert response.status == 415
        assert _error(response.read())["error"] == "unsupported_media_type"
        # The unused body was drained: the connection keeps working.
        assert client.request("GET", "/health").status == 200


def test_json_with_utf8_charset_is_accepted(http_gate: GateServer) -> None:
    reply = post_plan(http_gate.address, STOP_AT_LAB_START)
    assert reply.status == 200
    with Client(http_gate.address) as client:
        r = client.post_plan(
            STOP_AT_LAB_START, headers={"Content-Type": "application/json; charset=UTF-8"}
        )
        assert r.status == 200


def test_oversize_body_is_refused_by_its_declared_length_before_reading(
    http_gate: GateServer,
) -> None:
    # Headers only: the gate must answer without waiting for the 10 MB it announced.
    head = (
        b"POST /validate_plan HTTP/1.1\r\nHost: localhost\r\nContent-Type: application/json\r\n"
        b"Content-Length: 10000000\r\n\r\n"
    )
    reply = parse_raw(raw_exchange(http_gate.address, head))
    assert reply.status == 413
    assert reply.headers["connection"] == "close"
    assert _error(reply.body)["error"] == "payload_too_large"


def test_oversize_body_sent_in_full_still_gets_its_413(http_gate: GateServer) -> None:
    big = b'{"goal": {"x": 1, "y": 1, "yaw_deg": 0}, "pad": "' + b"x" * 100_000 + b'"}'
    reply = post_plan(http_gate.address, big)
    assert reply.status == 413


def test_body_at_the_limit_is_read(http_gate: GateServer) -> None:
    text = json.dumps(STOP_AT_LAB_START)
    padded = text + " " * (DEFAULT_MAX_BODY_BYTES - len(text))
    assert post_plan(http_gate.address, padded).status == 200
    assert post_plan(http_gate.address, padded + " ").status == 413


def _chunked(payload: bytes, size: int = 7) -> bytes:
    out = b""
    for i in range(0, len(payload), size):
        part = payload[i : i + size]
        out += f"{len(part):x}\r\n".encode() + part + b"\r\n"
    return out + b"0\r\n\r\n"


def test_chunked_bodies_are_read(http_gate: GateServer) -> None:
    payload = json.dumps(STOP_AT_LAB_START).encode()
    head = (
        b"POST /validate_plan HTTP/1.1\r\nHost: localhost\r\nContent-Type: application/json\r\n"
        b"Transfer-Encoding: chunked\r\nConnection: close\r\n\r\n"
    )
    reply = parse_raw(raw_exchange(http_gate.address, head + _chunked(payload)))
    assert reply.status == 200
    assert json.loads(reply.body)["approved"] is True


def test_oversize_chunked_body_is_413(http_gate: GateServer) -> None:
    head = (
        b"POST /validate_plan HTTP/1.1\r\nHost: localhost\r\nContent-Type: application/json\r\n"
        b"Transfer-Encoding: chunked\r\n\r\n"
    )
    chunk = b"x" * 40_000
    body = b"".join(f"{len(chunk):x}\r\n".encode() + chunk + b"\r\n" for _ in range(2))
    reply = parse_raw(raw_exchange(http_gate.address, head + body))
    assert reply.status == 413


@pytest.mark.parametrize(
    ("headers", "status", "code"),
    [
        ("", 411, "length_required"),
        ("Content-Length: 2\r\nTransfer-Encoding: chunked\r\n", 400, "bad_framing"),
        ("Content-Length: -1\r\n", 400, "bad_framing"),
        ("Content-Length: 1, 2\r\n", 400, "bad_framing"),
        ("Transfer-Encoding: gzip\r\n", 400, "bad_framing"),
    ],
)
def test_bad_framing(http_gate: GateServer, headers: str, status: int, code: str) -> None:
    head = (
        "POST /validate_plan HTTP/1.1\r\nHost: localhost\r\nContent-Type: application/json\r\n"
        f"{headers}\r\n"
    ).encode()
    reply = parse_raw(raw_exchange(http_gate.address, head, half_close=True))
    assert reply.status == status
    assert _error(reply.body)["error"] == code


def test_truncated_body_is_400(http_gate: GateServer) -> None:
    head = (
        b"POST /validate_plan HTTP/1.1\r\nHost: localhost\r\nContent-Type: application/json\r\n"
        b"Content-Length: 100\r\n\r\n{"
    )
    reply = parse_raw(raw_exchange(http_gate.address, head, half_close=True))
    assert reply.status == 400
    assert _error(reply.body)["error"] == "truncated_body"


def test_expect_100_continue(http_gate: GateServer) -> None:
    payload = json.dumps(STOP_AT_LAB_START).encode()
    too_big = (
        b"POST /validate_plan HTTP/1.1\r\nHost: localhost\r\nContent-Type: application/json\r\n"
        b"Expect: 100-continue\r\nContent-Length: 999999\r\n\r\n"
    )
    reply = parse_raw(raw_exchange(http_gate.address, too_big))
    assert reply.status == 413  # refused before the client sends the body
    ok = (
        "POST /validate_plan HTTP/1.1\r\nHost: localhost\r\nContent-Type: application/json\r\n"
        f"Expect: 100-continue\r\nConnection: close\r\nContent-Length: {len(payload)}\r\n\r\n"
    ).encode()
    data = raw_exchange(http_gate.address, ok + payload)
    assert data.startswith(b"HTTP/1.1 100 Continue\r\n\r\nHTTP/1.1 200 OK")


@pytest.mark.parametrize(
    ("method", "path", "allow"),
    [
        ("GET", "/validate_plan", "POST"),
        ("PUT", "/validate_plan", "POST"),
        ("DELETE", "/maps", "GET, HEAD"),
        ("POST", "/health", "GET, HEAD"),
        ("PATCH", "/maps/lab", "GET, HEAD"),
        ("OPTIONS", "/openapi.json", "GET, HEAD"),
    ],
)
def test_wrong_method_is_405_with_allow(
    http_gate: GateServer, method: str, path: str, allow: str
) -> None:
    reply = call(http_gate.address, method, path)
    assert reply.status == 405
    assert reply.headers["allow"] == allow
    error = _error(reply.body)
    assert error["error"] == "method_not_allowed"
    assert ", ".join(error["allow"]) == allow


@pytest.mark.parametrize(
    "path", ["/", "/nope", "/health/", "/maps/", "/maps/lab/x", "/validate_plan/x", "/maps/%ff"]
)
def test_unknown_path_is_404(http_gate: GateServer, path: str) -> None:
    reply = call(http_gate.address, "GET", path)
    assert reply.status == 404
    assert _error(reply.body)["error"] == "not_found"


def test_unknown_map_is_404_on_maps_and_400_on_validate(http_gate: GateServer) -> None:
    reply = call(http_gate.address, "GET", "/maps/atlantis")
    assert reply.status == 404
    assert _error(reply.body)["error"] == "unknown_map"
    reply = post_plan(http_gate.address, GOOD, "map=atlantis")
    assert reply.status == 400
    error = _error(reply.body)
    assert (error["error"], error["parameter"]) == ("invalid_option", "map")
    assert "scn02" in error["message"]


@pytest.mark.parametrize(
    ("query", "parameter"),
    [
        ("colour=red", "colour"),
        ("map=lab&map=scn01", "map"),
        ("start=1,2", "start"),
        ("start=1,2,nan", "start"),
        ("start=99,99,0", "start"),
        ("render=maybe", "render"),
        ("margin_m=-0.1", "margin_m"),
        ("margin_m=inf", "margin_m"),
        ("pos_tol_m=0", "pos_tol_m"),
        ("yaw_tol_deg=181", "yaw_tol_deg"),
        ("sample_hz=1000", "sample_hz"),
        ("sample_hz=", "sample_hz"),
    ],
)
def test_bad_options_are_400_naming_the_parameter(
    http_gate: GateServer, query: str, parameter: str
) -> None:
    reply = post_plan(http_gate.address, GOOD, query)
    assert reply.status == 400
    error = _error(reply.body)
    assert error["error"] == "invalid_option"
    assert error["parameter"] == parameter


def test_unknown_method_is_501_json(http_gate: GateServer) -> None:
    reply = call(http_gate.address, "BREW", "/health")
    assert reply.status == 501
    assert _error(reply.body)["status"] == 501


def test_head_has_the_get_headers_and_no_body(http_gate: GateServer) -> None:
    get = call(http_gate.address, "GET", "/maps/lab")
    with Client(http_gate.address) as client:
        head = client.request("HEAD", "/maps/lab")
        assert head.status == 200
        assert head.body == b""
        assert head.headers["content-length"] == str(len(get.body))
        assert client.request("GET", "/maps/lab").body == get.body  # still in sync


def test_keep_alive_carries_many_requests_and_survives_errors(http_gate: GateServer) -> None:
    with Client(http_gate.address) as client:
        for _ in range(3):
            assert client.post_plan(STOP_AT_LAB_START).status == 200
            assert client.post_plan(b"{").status == 400
            assert client.request("GET", "/nope").status == 404
            assert client.request("PUT", "/health", b"ignored").status == 405
        assert client.request("GET", "/health").headers.get("connection") != "close"


def test_tokens(make_gate: Callable[..., GateServer]) -> None:
    gate = make_gate(token="s3cret-token")
    for path in ("/health", "/maps", "/openapi.json", "/nope"):
        missing = call(gate.address, "GET", path)
        assert missing.status == 401
        assert missing.headers["www-authenticate"] == 'Bearer realm="rover-gate"'
        assert _error(missing.body)["error"] == "unauthorized"
        wrong = call(gate.address, "GET", path, token="s3cret-tokem")
        assert wrong.status == 401
        assert "invalid_token" in wrong.headers["www-authenticate"]
    assert (
        call(gate.address, "GET", "/health", headers={"Authorization": "Basic s3cret-token"}).status
        == 401
    )
    assert call(gate.address, "GET", "/health", token="s3cret-token").status == 200
    assert post_plan(gate.address, STOP_AT_LAB_START, token="s3cret-token").status == 200
    assert post_plan(gate.address, STOP_AT_LAB_START).status == 401


def test_every_error_body_is_json(http_gate: GateServer) -> None:
    # Errors raised by the HTTP parser itself (bad request line, bad version, a request
    # head longer than the parser keeps: 414 or 431, by how the bytes arrive).
    for data in (
        b"GARBAGE\r\n\r\n",
        b"GET / HTTP/9.9\r\n\r\n",
        b"GET /" + b"a" * 70000 + b" HTTP/1.1\r\n\r\n",
    ):
        reply = parse_raw(raw_exchange(http_gate.address, data, half_close=True))
        assert reply.status in (400, 414, 431, 505)
        assert reply.headers["content-type"] == "application/json"
        assert _error(reply.body)["status"] == reply.status
