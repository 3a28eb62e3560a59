"""Who the stack's console answers (planner/stack/consoleaccess.py), as a pure function
of a request's method and headers: its own Host only, no web page, the token always, a
marked POST. The same checks on a real server: tests/planner/test_console_server.py; in
a browser: tests/planner/test_console_browser.py."""

from __future__ import annotations

import pytest

from planner.stack.consoleaccess import ConsoleAccess

TOKEN = "t0ken-of-the-stack"


def _headers(host: str = "127.0.0.1:8123", **extra: str) -> dict[str, str]:
    return {"host": host, "authorization": f"Bearer {TOKEN}", **extra}


def _status(access: ConsoleAccess, method: str, headers: dict[str, str]) -> int:
    refused = access.refusal(method, headers)
    return 200 if refused is None else refused.status


LOOPBACK = ConsoleAccess.for_bind("127.0.0.1", 8123, TOKEN)


@pytest.mark.parametrize(
    ("host", "status"),
    [
        ("127.0.0.1:8123", 200),
        ("localhost:8123", 200),
        ("LOCALHOST:8123", 200),
        ("127.0.0.1:8124", 421),  # another port: another server
        ("127.0.0.1", 421),
        ("127.0.0.2:8123", 421),
        ("rebind.evil.example:8123", 421),  # a DNS rebinding
        ("localhost.:8123", 421),
        ("", 421),
    ],
)
def test_only_its_own_host(host: str, status: int) -> None:
    assert _status(LOOPBACK, "GET", _headers(host)) == status


def test_no_host_at_all_is_refused() -> None:
    assert _status(LOOPBACK, "GET", {"authorization": f"Bearer {TOKEN}"}) == 421


def test_other_binds_name_their_own_address() -> None:
    v6 = ConsoleAccess.for_bind("::1", 9000, TOKEN)
    assert _status(v6, "GET", _headers("[::1]:9000")) == 200
    assert _status(v6, "GET", _headers("localhost:9000")) == 200
    lab = ConsoleAccess.for_bind("10.1.2.3", 9000, TOKEN)
    assert _status(lab, "GET", _headers("10.1.2.3:9000")) == 200
    assert _status(lab, "GET", _headers("localhost:9000")) == 421
    anywhere = ConsoleAccess.for_bind("0.0.0.0", 9000, TOKEN)
    assert _status(anywhere, "GET", _headers("192.168.7.9:9000")) == 200
    assert _status(anywhere, "GET", _headers("[fe80::1]:9000")) == 200
    assert _status(anywhere, "GET", _headers("rover.lab:9000")) == 421  # a name: rebinding
    assert _status(anywhere, "GET", _headers("192.168.7.9:9001")) == 421


@pytest.mark.parametrize(
    "extra",
    [
        {"origin": "http://evil.example"},
        {"origin": "null"},
        {"origin": "http://127.0.0.1:8123"},  # the console has no page: no origin is its own
        {"sec-fetch-site": "cross-site"},
        {"sec-fetch-site": "same-site"},
        {"sec-fetch-site": "same-origin"},
    ],
)
def test_no_web_page(extra: dict[str, str]) -> None:
    for method in ("GET", "POST"):
        refused = LOOPBACK.refusal(method, _headers(**extra, **{"x-rover-console": "1"}))
        assert refused is not None and refused.status == 403, (method, extra)
        assert refused.code == "cross_origin"


def test_typed_at_the_address_bar_is_not_a_page() -> None:
    assert _status(LOOPBACK, "GET", _headers(**{"sec-fetch-site": "none"})) == 200


def test_the_token_always() -> None:
    refused = LOOPBACK.refusal("GET", {"host": "127.0.0.1:8123"})
    assert refused is not None and refused.status == 401
    assert "ROVER_CONSOLE_TOKEN" in refused.message
    wrong = LOOPBACK.refusal("GET", _headers(authorization="Bearer nope"))
    assert wrong is not None and wrong.message == "wrong token"
    assert _status(LOOPBACK, "GET", _headers(authorization=f"Basic {TOKEN}")) == 401


@pytest.mark.parametrize(
    ("extra", "status"),
    [
        ({}, 403),
        ({"content-type": "text/plain"}, 403),  # a form, a no-cors fetch
        ({"content-type": "application/x-www-form-urlencoded"}, 403),
        ({"content-type": "multipart/form-data; boundary=x"}, 403),
        ({"x-rover-console": "0"}, 403),
        ({"x-rover-console": "1"}, 200),
        ({"content-type": "application/json"}, 200),
        ({"content-type": "Application/JSON; charset=utf-8"}, 200),
    ],
)
def test_a_post_is_marked(extra: dict[str, str], status: int) -> None:
    assert _status(LOOPBACK, "POST", _headers(**extra)) == status
    assert _status(LOOPBACK, "GET", _headers(**extra)) == 200  # reads need no mark


def test_the_token_is_never_shown() -> None:
    assert TOKEN not in repr(LOOPBACK)
