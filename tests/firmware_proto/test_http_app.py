"""The application layer both servers share, without a server: the lane's turns, the
same-origin check, the access policy's token. (Served: tests/gate/test_hostile.py and
tests/planner/test_view_hostile.py.)"""

from __future__ import annotations

import asyncio
from typing import Any

import pytest
from starlette.requests import Request

from firmware_proto.http.app import AccessPolicy, Lane, require_same_origin
from firmware_proto.http.bindpolicy import HostPolicy
from firmware_proto.http.errors import StatusError


def test_the_lane_starts_a_few_requests_per_turn_of_the_loop_in_order() -> None:
    """Twenty requests that never wait: at most three start per turn, in the order they
    came; without the lane all twenty would run in one turn."""

    async def run() -> tuple[list[int], list[int]]:
        lane = Lane(3)
        turn = 0
        turns: list[int] = []
        order: list[int] = []
        stop = asyncio.Event()

        def tick() -> None:
            nonlocal turn
            turn += 1
            if not stop.is_set():
                asyncio.get_running_loop().call_soon(tick)

        async def request(i: int) -> None:
            await lane.enter()
            turns.append(turn)
            order.append(i)

        asyncio.get_running_loop().call_soon(tick)
        await asyncio.gather(*(request(i) for i in range(20)))
        stop.set()
        return turns, order

    turns, order = asyncio.run(run())
    assert order == list(range(20))
    per_turn = {t: turns.count(t) for t in set(turns)}
    assert max(per_turn.values()) <= 3 * 2  # a turn's budget, plus the one spent as it came
    assert len(per_turn) >= 20 // 6


def test_a_request_that_leaves_its_place_in_the_lane_frees_it() -> None:
    async def run() -> list[str]:
        lane = Lane(1)
        seen: list[str] = []

        async def request(name: str) -> None:
            await lane.enter()
            seen.append(name)

        tasks = [asyncio.create_task(request(name)) for name in ("first", "second", "third")]
        await asyncio.sleep(0)  # the first has started; the others wait their turn
        assert seen == ["first"] and lane.waiting == 2
        tasks[1].cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        return seen

    assert asyncio.run(run()) == ["first", "third"]
    with pytest.raises(ValueError, match="per_turn"):
        Lane(0)


def _request(headers: dict[str, str], query: bytes = b"") -> Request:
    scope: dict[str, Any] = {
        "type": "http",
        "method": "POST",
        "scheme": "http",
        "path": "/stop",
        "query_string": query,
        "headers": [(k.lower().encode(), v.encode()) for k, v in headers.items()],
        "server": ("127.0.0.1", 8000),
    }
    return Request(scope)


def test_same_origin_needs_the_header_and_no_other_origin() -> None:
    own = {"Host": "127.0.0.1:8000", "X-Rover-View": "1"}
    require_same_origin(_request(own), header="X-Rover-View")
    require_same_origin(
        _request(own | {"Origin": "http://127.0.0.1:8000", "Sec-Fetch-Site": "same-origin"}),
        header="X-Rover-View",
    )
    require_same_origin(_request(own | {"Sec-Fetch-Site": "none"}), header="X-Rover-View")
    for bad in (
        {"Host": "127.0.0.1:8000"},
        own | {"X-Rover-View": "0"},
        own | {"Origin": "http://127.0.0.1:8001"},
        own | {"Origin": "https://127.0.0.1:8000"},
        own | {"Origin": "null"},
        own | {"Sec-Fetch-Site": "same-site"},
        own | {"Sec-Fetch-Site": "cross-site"},
    ):
        with pytest.raises(StatusError) as info:
            require_same_origin(_request(bad), header="X-Rover-View")
        assert info.value.status == 403 and info.value.code == "cross_origin"


def test_the_token_is_read_from_the_header_or_where_allowed_the_query() -> None:
    hosts = HostPolicy.for_bind("127.0.0.1")
    header = _request({"Authorization": "Bearer abc"}).scope
    query = _request({}, b"token=abc").scope
    assert AccessPolicy(hosts, "abc").presented(header) == "abc"
    assert AccessPolicy(hosts, "abc").presented(query) is None
    assert AccessPolicy(hosts, "abc", query_token=True).presented(query) == "abc"
    with pytest.raises(ValueError, match="needs a token"):
        AccessPolicy(hosts, None, token_required=True)
