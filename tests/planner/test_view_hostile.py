"""Hostile clients against the live view on a real server on 127.0.0.1 (issue 43): a
flood of ``GET /state`` beside STOP, requests another origin could make, a rebinding
``Host``, frames, and browsers that hold the push channel. The cross-origin cases also
run in headless Chromium (Debian's, through Playwright; marker ``browser``): a page on
another port posting a form and a ``no-cors`` fetch, framing the view, and a page whose
name a DNS rebinding points at 127.0.0.1.

No timed asserts: STOP's place among the flood is counted in answers, not timed (the
times are in ``benchmarks/bench_hostile.py``)."""

from __future__ import annotations

import contextlib
import http.client
import itertools
import json
import socket
import threading
from collections.abc import Callable, Iterator
from typing import Any

import pytest

from bridge.ros.rosport.msgs import Bool, Odometry
from firmware_proto.model.worldmap import load_map
from planner.view import ViewConfig, ViewHub, ViewServer
from planner.view.hub import PLANS_KEPT, TRAIL_LEN

WORLD = load_map("lab")
ACT = {"X-Rover-View": "1"}
TIMEOUT_S = 30.0


def _odom(x: float, y: float) -> Odometry:
    msg = Odometry()
    msg.pose.pose.position.x = x
    msg.pose.pose.position.y = y
    msg.pose.pose.orientation.w = 1.0
    return msg


class _Actions:
    def __init__(self) -> None:
        self.stops = 0
        self.clears = 0
        self.lock = threading.Lock()

    def stop(self) -> str:
        with self.lock:
            self.stops += 1
        return "sent"

    def clear(self) -> bool:
        with self.lock:
            self.clears += 1
        return True


@pytest.fixture
def make_view() -> Iterator[Callable[..., tuple[ViewServer, _Actions]]]:
    """Factory of started views (config fields as keywords), each closed after the
    test."""
    started: list[tuple[ViewServer, ViewHub]] = []

    def make(**config: Any) -> tuple[ViewServer, _Actions]:
        actions = _Actions()
        hub = ViewHub(WORLD, rtt_s=0.5).start()
        server = ViewServer(
            hub,
            ViewConfig(**({"client_timeout_s": 2.0} | config)),
            on_stop=actions.stop,
            on_clear=actions.clear,
        ).start()
        started.append((server, hub))
        return server, actions

    yield make
    for server, hub in started:
        server.close()
        hub.close()


def _request(
    server: ViewServer,
    method: str,
    path: str,
    headers: dict[str, str] | None = None,
    body: bytes | None = b"",
) -> tuple[int, dict[str, str], bytes]:
    host, port = server.address
    conn = http.client.HTTPConnection(host, port, timeout=TIMEOUT_S)
    try:
        conn.request(method, path, body=body if method == "POST" else None, headers=headers or {})
        response = conn.getresponse()
        data = response.read()
        return response.status, {k.lower(): v for k, v in response.getheaders()}, data
    finally:
        conn.close()


def _latch_with_replan(server: ViewServer, orchestrator: Any) -> None:
    """Put the hub where clear-STOP would be allowed: latched, a re-plan approved."""
    from firmware_proto.model.pose import Pose

    mission = orchestrator("lab").plan_mission(Pose(2.2, 3.0, 0.0), start=Pose(1.2, 3.0, 0.0))
    assert mission.approved
    hub = server.hub
    hub.tap("sent", "/ground/emergency_stop", Bool(data=True))
    hub.planned(mission)
    deadline = threading.Event()
    for _ in range(200):
        if hub.clear_allowed()[0]:
            return
        deadline.wait(0.05)
    raise AssertionError("the hub never allowed clear-STOP")


# -- STOP never waits ---------------------------------------------------------------------
class _Flood:
    """``conns`` connections, each with ``per_conn`` ``GET /state`` pipelined, and a
    thread that reads their answers and counts the whole ones. They come from three
    addresses (127.0.0.2-4), each under the server's limit of connections from one."""

    def __init__(self, server: ViewServer, conns: int, per_conn: int) -> None:
        host, port = server.address
        self.socks = [
            socket.create_connection(
                (host, port), timeout=TIMEOUT_S, source_address=(f"127.0.0.{2 + i % 3}", 0)
            )
            for i in range(conns)
        ]
        self.expected = conns * per_conn
        self.answered = 0
        self._lock = threading.Lock()
        self._done = threading.Event()
        request = f"GET /state HTTP/1.1\r\nHost: {host}:{port}\r\n\r\n".encode()
        self._thread = threading.Thread(target=self._read, name="flood-reader", daemon=True)
        self._thread.start()
        for sock in self.socks:
            sock.sendall(request * per_conn)

    def count(self) -> int:
        with self._lock:
            return self.answered

    def _read(self) -> None:
        import selectors

        buffers = {sock: b"" for sock in self.socks}
        with selectors.DefaultSelector() as sel:
            for sock in self.socks:
                sel.register(sock, selectors.EVENT_READ)
            while not self._done.is_set() and self.count() < self.expected:
                for key, _ in sel.select(0.1):
                    conn = key.fileobj
                    assert isinstance(conn, socket.socket)
                    chunk = conn.recv(1 << 16)
                    if not chunk:
                        sel.unregister(conn)
                        continue
                    buffers[conn] += chunk
                    while True:
                        head, sep, rest = buffers[conn].partition(b"\r\n\r\n")
                        if not sep:
                            break
                        length = int(head.lower().split(b"content-length: ")[1].split(b"\r\n")[0])
                        if len(rest) < length:
                            break
                        buffers[conn] = rest[length:]
                        with self._lock:
                            self.answered += 1

    def wait(self) -> bool:
        self._thread.join(TIMEOUT_S)
        return self.count() == self.expected

    def close(self) -> None:
        self._done.set()
        self._thread.join(TIMEOUT_S)
        for sock in self.socks:
            sock.close()


def test_stop_is_answered_ahead_of_a_flood_of_state_requests(
    make_view: Callable[..., tuple[ViewServer, _Actions]],
) -> None:
    """The issue's reproducer, counted rather than timed: 300 connections each send 5
    ``GET /state``, then STOP. STOP is answered while most of the flood is still
    unanswered: it does not queue behind the requests that came before it (it did: each
    state took 40 ms of the event loop, and STOP waited 9 to 32 s)."""
    server, actions = make_view()
    flood = _Flood(server, 300, 5)
    try:
        status, _, body = _request(server, "POST", "/stop", ACT)
        answered = flood.count()
        assert status == 202 and json.loads(body) == {"stop": "sent"}
        assert actions.stops == 1
        assert answered < flood.expected // 2, (
            f"STOP was answered after {answered} of {flood.expected} state requests"
        )
        assert flood.wait(), "the flood was not served in full afterwards"
    finally:
        flood.close()


def test_the_state_is_encoded_once_per_change_and_bounded() -> None:
    hub = ViewHub(WORLD).start()
    try:
        first = hub.state_json()
        assert hub.state_json() is first  # nothing changed: the same bytes, shared
        assert hub.state_json(max_age_s=60.0) is first
        hub.tap("received", "/ground/odom_ground", _odom(2.0, 2.0))
        for _ in range(200):
            if hub.state()["poses"]:
                break
            threading.Event().wait(0.01)
        assert hub.state_json(max_age_s=60.0) is first  # young enough for a flood
        changed = hub.state_json()
        assert changed is not first and json.loads(changed)["poses"]["reported"]["x"] == 2.0
        assert json.loads(changed) == json.loads(json.dumps(hub.state()))
    finally:
        hub.close()


def test_the_state_stays_bounded_however_long_the_mission(orchestrator: Any) -> None:
    """Trails past their length, more plannings than are kept, and slow paths: the
    state's size is bounded by the constants (each trail point ~20 bytes, each kept
    attempt's path at most one point per centimetre of it)."""
    from firmware_proto.model.pose import Pose

    hub = ViewHub(WORLD).start()
    try:
        mission = orchestrator("lab").plan_mission(Pose(6.2, 3.0, 0.0), start=Pose(1.2, 3.0, 0.0))
        for _ in range(PLANS_KEPT):
            hub.planned(mission)
        for i in range(TRAIL_LEN + 500):
            hub.tap("received", "/ground/odom_ground", _odom(1.0 + 0.02 * (i % 300), i // 300))
        for _ in range(500):
            state = hub.state()
            if len(state["plans"]) == PLANS_KEPT and len(state["trails"]["reported"]) == TRAIL_LEN:
                break
            threading.Event().wait(0.02)
        state = json.loads(hub.state_json())
        assert len(state["plans"]) == PLANS_KEPT
        assert len(state["trails"]["reported"]) == TRAIL_LEN
        for plan in state["plans"]:
            path = plan["path"]
            length_cm = sum(
                100 * ((b[0] - a[0]) ** 2 + (b[1] - a[1]) ** 2) ** 0.5
                for a, b in itertools.pairwise(path)
            )
            assert len(path) <= length_cm + 2
    finally:
        hub.close()


# -- other origins ---------------------------------------------------------------------------
def test_requests_another_origin_could_make_are_refused(
    make_view: Callable[..., tuple[ViewServer, _Actions]], orchestrator: Any
) -> None:
    server, actions = make_view()
    _latch_with_replan(server, orchestrator)
    host, port = server.address
    own = f"http://{host}:{port}"
    for path in ("/stop", "/clear_stop"):
        for headers in (
            {},  # a form: no header of its own
            {"Content-Type": "text/plain"},  # a no-cors fetch
            ACT | {"Origin": "http://127.0.0.1:1"},  # another port is another origin
            ACT | {"Origin": "null"},  # a sandboxed frame
            ACT | {"Sec-Fetch-Site": "same-site"},
            ACT | {"Sec-Fetch-Site": "cross-site", "Authorization": f"Bearer {server.token}"},
        ):
            status, _, body = _request(server, "POST", path, headers)
            assert status == 403, (path, headers, body)
            assert "refused" in json.loads(body)["error"]
    assert actions.stops == 0 and actions.clears == 0
    # A rebinding page sends its own name as Host: not this server, whatever else.
    for path in ("/", "/state", "/events", "/stop", "/clear_stop"):
        method = "POST" if path in ("/stop", "/clear_stop") else "GET"
        rebound = {"Host": f"rebind.example:{port}", "Origin": f"http://rebind.example:{port}"}
        status, _, _ = _request(server, method, path, ACT | rebound, None)
        assert status == 421, path
    assert actions.stops == 0 and actions.clears == 0
    # The page itself may: same origin, the header.
    same = ACT | {"Origin": own, "Sec-Fetch-Site": "same-origin"}
    assert _request(server, "POST", "/clear_stop", same)[0] == 200 and actions.clears == 1
    assert _request(server, "POST", "/stop", same)[0] == 202 and actions.stops == 1
    assert _request(server, "POST", "/stop", ACT | {"Host": f"localhost:{port}"})[0] == 202


def test_no_page_may_frame_or_sniff_the_view(
    make_view: Callable[..., tuple[ViewServer, _Actions]],
) -> None:
    server, _ = make_view()
    for path in ("/", "/state", "/nope"):
        _, headers, _ = _request(server, "GET", path)
        assert headers["x-frame-options"] == "DENY", path
        assert "frame-ancestors 'none'" in headers["content-security-policy"], path
        assert headers["x-content-type-options"] == "nosniff", path
    _, headers, _ = _request(server, "GET", "/")
    assert "connect-src 'self'" in headers["content-security-policy"]


def test_a_token_makes_clear_stop_no_easier_from_another_origin(
    make_view: Callable[..., tuple[ViewServer, _Actions]], orchestrator: Any
) -> None:
    token = "view-token-0123456789"
    server, actions = make_view(token=token)
    _latch_with_replan(server, orchestrator)
    bearer = {"Authorization": f"Bearer {token}"}
    for extra in ({"Origin": "http://evil.example"}, {"Sec-Fetch-Site": "cross-site"}, {}):
        headers = bearer | extra | (ACT if extra else {})
        assert _request(server, "POST", "/clear_stop", headers)[0] == 403, extra
    assert actions.clears == 0
    assert _request(server, "POST", "/clear_stop", bearer | ACT)[0] == 200


# -- the push channel -------------------------------------------------------------------------
class _Reader:
    """A push-channel client on a raw socket (from ``source``); reads only when asked."""

    def __init__(self, server: ViewServer, query: str = "", source: str = "127.0.0.1") -> None:
        host, port = server.address
        self.sock = socket.create_connection(
            (host, port), timeout=TIMEOUT_S, source_address=(source, 0)
        )
        self.sock.sendall(f"GET /events{query} HTTP/1.1\r\nHost: {host}:{port}\r\n\r\n".encode())
        self.file = self.sock.makefile("rb")

    def events(self) -> Iterator[tuple[str, str]]:
        """``(event, data)`` pairs as they come, ``retry:`` hints as ``("retry", ms)``."""
        event = ""
        for raw in self.file:
            line = raw.decode().rstrip("\r\n")
            if line.startswith("retry: "):
                yield "retry", line[len("retry: ") :]
            elif line.startswith("event: "):
                event = line[len("event: ") :]
            elif line.startswith("data: "):
                yield event, line[len("data: ") :]

    def until(self, name: str) -> list[tuple[str, str]]:
        """Every event up to and with the first ``name``."""
        seen = []
        for event in self.events():
            seen.append(event)
            if event[0] == name:
                return seen
        raise AssertionError(f"the stream ended before {name!r}: {seen}")

    def first(self, *names: str) -> tuple[str, str]:
        """The first event among ``names``."""
        for name, data in self.events():
            if name in names:
                return name, data
        raise AssertionError(f"the stream ended before any of {names}")

    def close(self) -> None:
        self.file.close()
        self.sock.close()


@pytest.fixture
def readers() -> Iterator[Callable[..., _Reader]]:
    opened: list[_Reader] = []

    def open_reader(server: ViewServer, query: str = "", source: str = "127.0.0.1") -> _Reader:
        reader = _Reader(server, query, source)
        opened.append(reader)
        return reader

    yield open_reader
    for reader in opened:
        reader.close()


def _wait_viewers(server: ViewServer, count: int) -> None:
    for _ in range(500):
        if server.viewers == count:
            return
        threading.Event().wait(0.01)
    raise AssertionError(f"{server.viewers} viewers, expected {count}")


def test_idle_readers_cannot_lock_the_operator_out(
    make_view: Callable[..., tuple[ViewServer, _Actions]], readers: Callable[..., _Reader]
) -> None:
    """Sixteen readers that never read hold every place; a new viewer still gets the
    view, the operator's (with the token) and an anonymous one alike: the oldest idle
    reader makes room and is told why, with a hint to come back later."""
    server, _ = make_view(max_clients=16, max_clients_per_address=16)
    idle = [readers(server) for _ in range(16)]
    _wait_viewers(server, 16)
    operator = readers(server, f"?token={server.token}")
    assert operator.first("hello")[0] == "hello"
    anonymous = readers(server)
    assert anonymous.first("hello")[0] == "hello"
    assert server.viewers == 16 and server.evicted == 2
    for oldest in idle[:2]:  # they were told, and when to come back
        assert ("retry", "5000") in oldest.until("evicted")


def test_a_place_held_by_the_token_is_never_taken_by_an_anonymous_viewer(
    make_view: Callable[..., tuple[ViewServer, _Actions]], readers: Callable[..., _Reader]
) -> None:
    server, _ = make_view(max_clients=2, max_clients_per_address=2, busy_retry_s=7.0)
    held = [readers(server, f"?token={server.token}") for _ in range(2)]
    for reader in held:
        assert reader.first("hello")[0] == "hello"
    refused = readers(server)
    events = refused.until("busy")  # a 200 stream that says busy and when to retry
    assert ("retry", "7000") in events and "hello" not in {name for name, _ in events}
    assert server.refused == 1 and server.evicted == 0 and server.viewers == 2
    # Another token holder does get in (the oldest holder makes room).
    assert readers(server, f"?token={server.token}").first("hello")[0] == "hello"
    assert held[0].first("evicted")[0] == "evicted"


def test_one_address_cannot_take_every_place(
    make_view: Callable[..., tuple[ViewServer, _Actions]], readers: Callable[..., _Reader]
) -> None:
    """Beyond its share, a new reader from an address evicts that address's oldest,
    never another address's."""
    server, _ = make_view(max_clients=4, max_clients_per_address=2)
    other = readers(server, source="127.0.0.3")
    assert other.first("hello")[0] == "hello"
    mine = [readers(server, source="127.0.0.2") for _ in range(3)]
    for reader in mine:
        assert reader.first("hello")[0] == "hello"
    assert mine[0].first("evicted")[0] == "evicted"
    assert server.viewers == 3 and server.evicted == 1
    server.hub.tap("received", "/ground/odom_ground", _odom(2.5, 2.5))
    assert other.first("pose")[0] == "pose"  # still served


def test_a_stalled_reader_is_evicted_before_a_healthy_one(
    make_view: Callable[..., tuple[ViewServer, _Actions]], readers: Callable[..., _Reader]
) -> None:
    """When full, the reader whose writes stall goes first, though it came later (the
    connection layer would cut it off after ``client_timeout_s``: long here)."""
    server, _ = make_view(max_clients=2, max_clients_per_address=2, client_timeout_s=60.0)
    healthy = readers(server)
    assert healthy.first("hello")[0] == "hello"
    stalled = readers(server)
    stalled.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    assert stalled.first("hello")[0] == "hello"
    stalled_peer = stalled.sock.getsockname()[:2]
    poses = threading.Event()

    def healthy_reads() -> None:
        with contextlib.suppress(OSError, ValueError):
            for name, _ in healthy.events():
                if name == "pose":
                    poses.set()

    reading = threading.Thread(target=healthy_reads, daemon=True)
    reading.start()
    hub = server.hub
    pose = _odom(1.0, 3.0)
    for _ in range(3000):  # until the stuck one's writes stop completing (bounded)
        for _ in range(100):
            hub.tap("received", "/ground/odom_ground", pose)
        if server.viewer_state(stalled_peer)["stalled"]:
            break
        threading.Event().wait(0.02)
    assert server.viewer_state(stalled_peer)["stalled"]
    healthy_peer = healthy.sock.getsockname()[:2]
    for _ in range(3000):  # the reading one catches up; the other's writes stay stuck
        states = server.viewer_state(stalled_peer), server.viewer_state(healthy_peer)
        if states[0]["stalled"] and not states[1]["stalled"]:
            break
        threading.Event().wait(0.02)
    assert states[0]["stalled"] and not states[1]["stalled"], states
    newcomer = readers(server)
    assert newcomer.first("hello")[0] == "hello"
    assert server.evicted == 1
    assert stalled_peer not in server.peers
    assert healthy.sock.getsockname()[:2] in server.peers
    assert poses.wait(TIMEOUT_S)


# -- in Chromium -----------------------------------------------------------------------------


def _attacks(view: str) -> dict[str, str]:
    """Pages of another origin that try STOP and clear-STOP on ``view`` (its origin)."""
    fetches = "".join(
        f'fetch("{view}{path}", {{method: "POST", mode: "no-cors", body: "x"}})'
        ".then(() => done.push(1), () => done.push(0));"
        for path in ("/stop", "/clear_stop")
    )
    return {
        "/form.html": (
            f'<form method="POST" action="{view}/stop" enctype="text/plain">'
            '<input name="x" value="1"></form><script>document.forms[0].submit()</script>'
        ),
        "/clear_form.html": (
            f'<form method="POST" action="{view}/clear_stop" enctype="text/plain">'
            '<input name="x" value="1"></form><script>document.forms[0].submit()</script>'
        ),
        "/fetch.html": f"<script>window.done = []; {fetches}</script>",
        "/frame.html": f'<iframe id="f" src="{view}/" width="800" height="600"></iframe>',
    }


@pytest.mark.browser
def test_pages_of_another_origin_cannot_stop_clear_or_frame_the_view(
    make_view: Callable[..., tuple[ViewServer, _Actions]], orchestrator: Any
) -> None:
    from tests.browser import REBIND, WITHOUT_PRIVATE_NETWORK_ACCESS, OtherSite, chromium

    server, actions = make_view()
    _latch_with_replan(server, orchestrator)
    host, port = server.address
    view = f"http://{host}:{port}"
    other = OtherSite(_attacks(view), TIMEOUT_S)
    try:
        resolve = f"--host-resolver-rules=MAP {REBIND} 127.0.0.1"
        with chromium((resolve, WITHOUT_PRIVATE_NETWORK_ACCESS)) as browser:
            page = browser.new_page()
            # A form posted from another port: the browser sends it, the view refuses it.
            for form in ("/form.html", "/clear_form.html"):
                with page.expect_response(lambda r: r.request.method == "POST") as posted:
                    page.goto(other.origin + form)
                assert posted.value.status == 403, form
            # A no-cors fetch: sent, refused.
            page.goto(other.origin + "/fetch.html")
            page.wait_for_function("window.done && window.done.length === 2", timeout=30_000)
            # A frame: the browser does not show the view inside another site's page.
            page.goto(other.origin + "/frame.html")
            frame = page.frame_locator("#f")
            assert frame.locator("#stop").count() == 0
            framed = [f for f in page.frames if f.url.startswith(view)]
            assert all(f.locator("#stop").count() == 0 for f in framed)
            # A rebinding page: its name is not this server's, so nothing is served to it.
            rebound = f"http://{REBIND}:{port}"
            response = page.goto(rebound + "/")
            assert response is not None and response.status == 421
            # The attack itself: the page comes from the attacker's server (here, the
            # browser's route), then the name points at 127.0.0.1 and the page's own
            # origin is the view's port.
            page.route(
                rebound + "/attack.html",
                lambda route: route.fulfill(body="<p>attack</p>", content_type="text/html"),
            )
            page.goto(rebound + "/attack.html")
            page.unroute(rebound + "/attack.html")
            statuses = page.evaluate(
                """async () => {
                    const out = [];
                    for (const path of ["/stop", "/clear_stop", "/state"]) {
                        const r = await fetch(path, {method: path === "/state" ? "GET" : "POST",
                                                     headers: {"X-Rover-View": "1"}});
                        out.push(r.status);
                    }
                    return out;
                }"""
            )
            assert statuses == [421, 421, 421]
            assert actions.stops == 0 and actions.clears == 0
            # The view's own page can: STOP from its button (the control of this test).
            page.goto(server.url)
            page.wait_for_function("() => roverView.counts.hello > 0", timeout=30_000)
            page.click("#stop")
            page.wait_for_function("() => roverView.stopPosts > 0", timeout=30_000)
            assert actions.stops == 1
            assert "STOP sent" in page.inner_text("#msg")
    finally:
        other.close()
    assert server.stops == 1


@pytest.mark.browser
def test_the_operators_browser_gets_its_view_beside_idle_readers(
    make_view: Callable[..., tuple[ViewServer, _Actions]], readers: Callable[..., _Reader]
) -> None:
    """Sixteen idle readers hold the push channel: the page still gets its view. With
    every place held by the token's holders, an anonymous page is told to come back,
    and does, by itself, once a place is free."""
    from tests.browser import chromium

    server, _ = make_view(max_clients=16, max_clients_per_address=16, busy_retry_s=0.5)
    idle = [readers(server) for _ in range(16)]
    _wait_viewers(server, 16)
    host, port = server.address
    with chromium() as browser:
        page = browser.new_page()
        page.goto(server.url)  # the operator's URL, with the token
        page.wait_for_function("() => roverView.counts.hello > 0", timeout=30_000)
        anonymous = browser.new_page()
        anonymous.goto(f"http://{host}:{port}/")
        anonymous.wait_for_function("() => roverView.counts.hello > 0", timeout=30_000)
        assert server.evicted == 2
        # Now only the token's holders: the anonymous page is refused, then retries.
        for reader in idle:
            reader.close()
        holders = [readers(server, f"?token={server.token}") for _ in range(15)]
        for reader in holders:
            reader.first("hello")
        _wait_viewers(server, 16)  # the operator's page and 15 holders
        late = browser.new_page()
        late.goto(f"http://{host}:{port}/")
        late.wait_for_function("() => roverView.counts.busy > 0", timeout=30_000)
        assert late.evaluate("roverView.counts.hello") == 0
        holders[0].close()
        late.wait_for_function("() => roverView.counts.hello > 0", timeout=30_000)


def test_tokens_come_from_files_never_the_command_line(tmp_path: Any) -> None:
    """``--view-token`` and ``rover go --token`` would show the token in ``ps``:
    refused, saying what to use instead; the file options serve."""
    import argparse

    from planner.ground.cli_go import _gate_token
    from planner.ground.cli_go import add_arguments as add_go_arguments
    from planner.view.cli_view import add_view_arguments, view_config

    parser = argparse.ArgumentParser()
    add_view_arguments(parser, record_default=None)
    with pytest.raises(ValueError, match="ps"):
        view_config(parser.parse_args(["--view", "--view-token", "k3Jf9-xQ2mPz8vLw"]))
    token = tmp_path / "token"
    token.write_text("k3Jf9-xQ2mPz8vLw\n")
    config = view_config(
        parser.parse_args(
            [
                "--view",
                "--view-host",
                "0.0.0.0",
                "--view-token-file",
                str(token),
                "--view-allowed-host",
                "ground.lab",
            ]
        )
    )
    assert config is not None and config.token == "k3Jf9-xQ2mPz8vLw"
    assert config.allowed_hosts == ("ground.lab",)
    weak = tmp_path / "weak"
    weak.write_text("t\n")
    with pytest.raises(ValueError, match="too weak"):
        view_config(
            parser.parse_args(["--view", "--view-host", "0.0.0.0", "--view-token-file", str(weak)])
        )
    go = argparse.ArgumentParser()
    add_go_arguments(go)
    with pytest.raises(ValueError, match="--token-file"):
        _gate_token(go.parse_args(["--goal", "1,1,0", "--token", "k3Jf9-xQ2mPz8vLw"]))
    assert _gate_token(go.parse_args(["--goal", "1,1,0", "--token-file", str(token)])) == (
        "k3Jf9-xQ2mPz8vLw"
    )
