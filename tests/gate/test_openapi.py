"""The OpenAPI document matches the server: every documented path, method and status
is produced by a real request, and real responses validate against the documented
schemas; every undocumented method on a documented path is a 405."""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from typing import Any

import pytest
from jsonschema import Draft202012Validator

from gate.options import QUERY_PARAMETERS
from gate.routes import ROUTES
from gate.server import GateServer
from gate.validator import Validator

from .client import Reply, call, parse_raw, post_plan, raw_exchange
from .held import HeldPool
from .plans import STOP_AT_LAB_START, fwd, plan, step

TOKEN = "open-sesame"
METHODS = ("GET", "POST", "PUT", "PATCH", "DELETE", "OPTIONS")


def _schema_validator(doc: dict[str, Any], ref: str) -> Draft202012Validator:
    root = {"$ref": ref, "components": doc["components"]}
    return Draft202012Validator(root)


def _check_against_doc(doc: dict[str, Any], path: str, method: str, reply: Reply) -> None:
    op = doc["paths"][path][method.lower()]
    documented = op["responses"][str(reply.status)]
    schema = documented["content"]["application/json"]["schema"]
    assert reply.headers["content-type"] == "application/json"
    body = json.loads(reply.body)
    if "$ref" in schema:
        _schema_validator(doc, schema["$ref"]).validate(body)
    else:
        Draft202012Validator(schema).validate(body)
    for header in documented.get("headers", {}):
        assert header.lower() in reply.headers, (path, method, reply.status, header)


@pytest.fixture
def secured(
    make_gate: Callable[..., GateServer], validator: Validator
) -> Iterator[tuple[GateServer, HeldPool]]:
    pool = HeldPool(validator, hold=False)
    gate = make_gate(worker_pool=pool, workers=1, queue_depth=1, token=TOKEN, body_timeout_s=0.5)
    yield gate, pool
    pool.release.set()


def test_document_is_valid_json_schema_throughout(http_gate: GateServer) -> None:
    doc = call(http_gate.address, "GET", "/openapi.json").json()
    assert doc["openapi"].startswith("3.1")
    for name, schema in doc["components"]["schemas"].items():
        Draft202012Validator.check_schema(schema), name
    assert "security" not in doc and "securitySchemes" not in doc["components"]
    assert {p: sorted(m) for p, m in doc["paths"].items()} == {
        r.template: sorted(m.lower() for m in r.methods) for r in ROUTES
    }
    for item in doc["paths"].values():
        for op in item.values():
            assert "401" not in op["responses"]
    params = doc["paths"]["/validate_plan"]["post"]["parameters"]
    assert [p["name"] for p in params] == list(QUERY_PARAMETERS)
    assert params[0]["schema"]["enum"] == ["lab", "scn01", "scn02", "scn03"]
    body_schema = doc["paths"]["/validate_plan"]["post"]["requestBody"]["content"][
        "application/json"
    ]["schema"]
    plan_validator = _schema_validator(doc, body_schema["$ref"])
    assert plan_validator.is_valid(STOP_AT_LAB_START)
    assert not plan_validator.is_valid(STOP_AT_LAB_START | {"extra": 1})
    bad_speed = plan((0, 0, 0), step("FWD", 61, 1))
    assert not plan_validator.is_valid(bad_speed)


def test_every_documented_status_happens_and_matches_its_schema(
    secured: tuple[GateServer, HeldPool],
) -> None:
    gate, pool = secured
    address = gate.address
    doc = call(address, "GET", "/openapi.json", token=TOKEN).json()
    assert doc["security"] == [{"bearerAuth": []}]
    bad_length = {"Content-Length": "x"}
    json_type = {"Content-Type": "application/json"}

    def get(path: str, **kw: Any) -> Reply:
        return call(address, "GET", path, token=kw.get("token", TOKEN), headers=kw.get("headers"))

    def post(
        body: Any,
        query: str = "",
        headers: dict[str, str] | None = None,
        token: str | None = TOKEN,
        source: str | None = None,
    ) -> Reply:
        text = body if isinstance(body, (str, bytes)) else json.dumps(body)
        return call(
            address,
            "POST",
            "/validate_plan" + (f"?{query}" if query else ""),
            text,
            headers=json_type | (headers or {}),
            token=token,
            source=source,
        )

    def post_raw(headers: str, body: bytes = b"", *, half_close: bool = True) -> Reply:
        head = (
            f"POST /validate_plan HTTP/1.1\r\nHost: localhost\r\nAuthorization: Bearer {TOKEN}\r\n"
            f"Content-Type: application/json\r\n{headers}\r\n"
        ).encode()
        return parse_raw(raw_exchange(address, head + body, half_close=half_close))

    seen: dict[tuple[str, str, int], Reply] = {}

    def record(path: str, method: str, reply: Reply) -> None:
        _check_against_doc(doc, path, method, reply)
        seen[(path, method, reply.status)] = reply

    for path, concrete in (
        ("/health", "/health"),
        ("/maps", "/maps"),
        ("/maps/{name}", "/maps/scn03"),
        ("/openapi.json", "/openapi.json"),
    ):
        record(path, "GET", get(concrete))
        record(path, "GET", get(concrete, token=None))
        record(path, "GET", get(concrete, headers=bad_length))
    record("/maps/{name}", "GET", get("/maps/nowhere"))

    record(
        "/validate_plan",
        "POST",
        post(plan((6.2, 3.0, 0.0), *(step("FWD", 60, 30000),) * 3), "render=1"),
    )
    record("/validate_plan", "POST", post(plan((3.0, 3.0, 0.0), fwd(1.0)), "start=4,3,0"))
    record("/validate_plan", "POST", post({"goal": 1}))
    record("/validate_plan", "POST", post(STOP_AT_LAB_START, "map=x"))
    record("/validate_plan", "POST", post(STOP_AT_LAB_START, token=None))
    record("/validate_plan", "POST", post_raw(""))  # 411
    record("/validate_plan", "POST", post_raw("Content-Length: 999999\r\n"))  # 413
    record(  # 408: the body stalls on an open connection
        "/validate_plan", "POST", post_raw("Content-Length: 99\r\n", b"{", half_close=False)
    )
    record("/validate_plan", "POST", post(STOP_AT_LAB_START, headers={"Content-Type": "text/csv"}))

    # With the worker held and the queue's place taken by another client (127.0.0.2):
    # 429 to the first client (it holds its share while another waits), 503 to a third
    # (the gate is full); then 503 from draining, on every operation.
    import threading

    pool.hold.set()
    before = pool.submitted
    first: list[Reply] = []
    holder = threading.Thread(target=lambda: first.append(post(STOP_AT_LAB_START)))
    holder.start()
    assert pool.entered.wait(30)
    queued: list[Reply] = []
    waiter = threading.Thread(
        target=lambda: queued.append(post(STOP_AT_LAB_START, source="127.0.0.2"))
    )
    waiter.start()
    assert pool.wait_submitted(before + 2)
    record("/validate_plan", "POST", post(STOP_AT_LAB_START))
    record("/validate_plan", "POST", post(STOP_AT_LAB_START, source="127.0.0.3"))
    gate.begin_drain()
    for path, concrete in (
        ("/health", "/health"),
        ("/maps", "/maps"),
        ("/maps/{name}", "/maps/lab"),
        ("/openapi.json", "/openapi.json"),
    ):
        record(path, "GET", get(concrete))
    pool.release.set()
    holder.join(30)
    waiter.join(30)
    record("/validate_plan", "POST", first[0])
    assert queued[0].status == 200

    documented = {
        (path, method.upper(), int(status))
        for path, item in doc["paths"].items()
        for method, op in item.items()
        for status in op["responses"]
    }
    assert documented == set(seen)
    verdict = seen[("/validate_plan", "POST", 200)].json()
    assert verdict["approved"] is True  # the held one; collision and start ones also passed


def test_undocumented_methods_are_405(http_gate: GateServer) -> None:
    doc = call(http_gate.address, "GET", "/openapi.json").json()
    for path, item in doc["paths"].items():
        concrete = path.replace("{name}", "lab")
        allowed = {m.upper() for m in item}
        for method in METHODS:
            if method in allowed:
                continue
            reply = call(http_gate.address, method, concrete)
            assert reply.status == 405, (path, method)
            allow = set(reply.headers["allow"].split(", "))
            assert allow == allowed | ({"HEAD"} if "GET" in allowed else set())


def test_real_verdicts_validate_against_the_verdict_schema(http_gate: GateServer) -> None:
    doc = call(http_gate.address, "GET", "/openapi.json").json()
    verdict_schema = _schema_validator(doc, "#/components/schemas/Verdict")
    for body, query in (
        (STOP_AT_LAB_START, ""),
        (plan((3.2, 3.0, 0.0), fwd(1.0)), "sample_hz=100"),
        (plan((1.2, 3.0, 90.0), step("LEFT", 20, 5000)), ""),
        (plan((6.2, 3.0, 0.0), *(step("FWD", 60, 30000),) * 3), "render=true"),
    ):
        reply = post_plan(http_gate.address, body, query)
        assert reply.status == 200
        verdict_schema.validate(reply.json())
