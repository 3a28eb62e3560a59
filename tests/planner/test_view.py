"""The live view's server and hub on a real HTTP server on 127.0.0.1: the page, the push
channel, STOP and clear-STOP, bad requests, tokens, and browsers that stop reading."""

from __future__ import annotations

import contextlib
import http.client
import json
import math
import socket
import threading
import time
from collections.abc import Iterator
from typing import Any

import pytest

from bridge.ros.rosport.msgs import Bool, Odometry, String
from firmware_proto.model.pose import Pose
from firmware_proto.model.worldmap import load_map
from planner.view import ClientQueue, ViewConfig, ViewHub, ViewServer

WORLD = load_map("lab")
ACT = {"X-Rover-View": "1"}
"""What the page sends with STOP and clear-STOP (a page of another origin cannot)."""


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
        self.stopped = threading.Event()

    def stop(self) -> str:
        self.stops += 1
        self.stopped.set()
        return "sent"

    def clear(self) -> bool:
        self.clears += 1
        return True


@pytest.fixture
def view() -> Iterator[tuple[ViewServer, _Actions]]:
    actions = _Actions()
    hub = ViewHub(WORLD, rtt_s=0.5).start()
    server = ViewServer(
        hub, ViewConfig(client_timeout_s=2.0), on_stop=actions.stop, on_clear=actions.clear
    ).start()
    try:
        yield server, actions
    finally:
        server.close()
        hub.close()


def _request(
    server: ViewServer,
    method: str,
    path: str,
    body: bytes | None = None,
    headers: dict[str, str] | None = None,
) -> tuple[int, dict[str, Any]]:
    host, port = server.url.split("//")[1].split("/")[0].rsplit(":", 1)
    conn = http.client.HTTPConnection(host, int(port), timeout=5)
    try:
        conn.request(method, path, body=body, headers=headers or {})
        response = conn.getresponse()
        data = response.read()
        ctype = response.getheader("Content-Type", "")
        return response.status, json.loads(data) if "json" in ctype else {"text": data.decode()}
    finally:
        conn.close()


class _Stream:
    """A push-channel client reading Server-Sent Events off a socket."""

    def __init__(self, server: ViewServer, query: str = "") -> None:
        host, port = server.url.split("//")[1].split("/")[0].rsplit(":", 1)
        self.sock = socket.socket()
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        self.sock.settimeout(5)
        self.sock.connect((host, int(port)))
        self.sock.sendall(f"GET /events{query} HTTP/1.1\r\nHost: {host}:{port}\r\n\r\n".encode())
        self.file = self.sock.makefile("rb")
        self.status_line = self.file.readline().decode()

    def next_event(self, name: str) -> dict[str, Any]:
        """The next event called ``name`` (others skipped)."""
        event = ""
        for raw in self.file:
            line = raw.decode().rstrip("\n")
            if line.startswith("event: "):
                event = line[len("event: ") :]
            elif line.startswith("data: ") and event == name:
                data: dict[str, Any] = json.loads(line[len("data: ") :])
                return data
        raise AssertionError(f"the stream ended before a {name!r} event")

    def close(self) -> None:
        self.file.close()
        self.sock.close()


def test_page_state_and_bad_requests(view: tuple[ViewServer, _Actions]) -> None:
    server, _ = view
    assert server.url.startswith("http://127.0.0.1:")
    status, page = _request(server, "GET", "/")
    assert status == 200 and "<canvas" in page["text"] and 'id="stop"' in page["text"]
    assert "http" not in page["text"].split("<script>")[1]  # nothing fetched from elsewhere
    status, state = _request(server, "GET", "/state")
    assert status == 200 and state["map"]["name"] == "lab"
    assert state["map"]["traction"][0]["id"] == "sandbox"
    assert state["limits"] == [0.25, 12.0]
    for method, path, body, headers, code in (
        ("GET", "/nope", None, {}, 404),
        ("POST", "/nope", b"", {}, 404),
        ("PUT", "/stop", b"", {}, 405),
        ("DELETE", "/", None, {}, 405),
        ("POST", "/stop", b"x", {"Content-Length": "99999"} | ACT, 413),
        ("POST", "/stop", b"x", {"Content-Length": "many"}, 400),
        ("POST", "/stop", b"", {}, 403),  # no X-Rover-View: a form of another site
        ("POST", "/clear_stop", b"", {}, 403),
    ):
        got, answer = _request(server, method, path, body, headers)
        assert got == code, (method, path, answer)
        assert answer["error"], answer
    # Still serving.
    assert _request(server, "GET", "/state")[0] == 200


def test_stop_and_clear_stop(view: tuple[ViewServer, _Actions]) -> None:
    server, actions = view
    hub = server.hub
    clear = ACT
    status, answer = _request(server, "POST", "/clear_stop", b"", clear)
    assert status == 409 and "not latched" in answer["error"]
    stream = _Stream(server)
    try:
        stream.next_event("hello")
        status, answer = _request(server, "POST", "/stop", b"", ACT)
        assert status == 202 and answer == {"stop": "sent"}
        assert actions.stopped.is_set() and server.stops == 1
        assert stream.next_event("stop")["source"] == "view"
        hub.tap("sent", "/ground/emergency_stop", Bool(data=True))
        assert stream.next_event("tick")["latched"] is True
    finally:
        stream.close()
    status, answer = _request(server, "POST", "/clear_stop", b"", clear)
    assert status == 409 and "no re-plan" in answer["error"], answer
    assert actions.clears == 0


def test_poses_are_pushed_with_the_time_they_reached_the_ground_station(
    view: tuple[ViewServer, _Actions],
) -> None:
    server, _ = view
    hub = server.hub
    stream = _Stream(server)
    try:
        assert stream.status_line.startswith("HTTP/1.1 200")
        hello = stream.next_event("hello")
        assert hello["map"]["start"] == [1.2, 3.0, 0.0]
        hub.tap("received", "/ground/odom", _odom(0.0, 0.0))
        hub.tap("received", "/ground/odom_ground", _odom(1.5, 3.25))
        pose = stream.next_event("pose")
        assert pose["src"] == "reported" and (pose["x"], pose["y"]) == (1.5, 3.25)
        assert pose["tap_s"] > 0
        hub.tap("received", "/ground/odom", _odom(0.5, 0.0))  # odom, tied to the map
        pose = stream.next_event("pose")
        assert pose["src"] == "odom" and math.isclose(pose["x"], 2.0)
        hub.tap("received", "/ground/command_status", String(data="stopped"))
        assert stream.next_event("status")["status"] == "stopped"
        assert stream.next_event("tick")["rtt_s"] is None
    finally:
        stream.close()


def test_a_browser_that_stops_reading_costs_the_mission_nothing(
    view: tuple[ViewServer, _Actions],
) -> None:
    server, _ = view
    hub = server.hub
    stuck = _Stream(server)  # connects, then never reads again
    reader = _Stream(server)
    last = 9.0  # the x of the pose sent last
    seen_last = threading.Event()

    def read() -> None:  # a browser that keeps up
        with contextlib.suppress(AssertionError, OSError):
            while not math.isclose(reader.next_event("pose")["x"], last):
                pass
            seen_last.set()

    reading = threading.Thread(target=read)
    try:
        reader.next_event("hello")
        reading.start()
        # The mission's thread: a queue put per message, however much the stuck browser
        # falls behind; poses until its socket is full, its write times out and it is
        # dropped (bounded: 30 s).
        taps = 0
        pose = _odom(1.0, 3.0)
        deadline = time.monotonic() + 30.0
        while hub.clients > 1 and time.monotonic() < deadline:
            for _ in range(1000):
                hub.tap("received", "/ground/odom_ground", pose)
            taps += 1000
            threading.Event().wait(0.01)  # let the hub and the connections run
        assert hub.clients == 1, f"the stuck browser is still connected after {taps} poses"
        hub.tap("received", "/ground/odom_ground", _odom(last, 3.0))
        # The reading browser gets the latest pose, whatever its queue dropped.
        assert seen_last.wait(30), "the reading client never got the last pose"
    finally:
        stuck.close()
        reader.close()
        reading.join(10)


def test_client_queue_drops_oldest() -> None:
    q = ClientQueue(maxlen=3)
    for i in range(5):
        q.put(str(i).encode())
    assert q.take(0.1) == [b"2", b"3", b"4"] and q.dropped == 2
    assert q.take(0.01) == []
    q.close()
    assert q.take(5.0) == []  # closed: no wait


def test_tokens_and_binding() -> None:
    with pytest.raises(ValueError, match="without a token"):
        ViewConfig(host="0.0.0.0")
    with pytest.raises(ValueError, match="port"):
        ViewConfig(port=70000)
    with pytest.raises(ValueError, match="token"):
        ViewConfig(token="")
    hub = ViewHub(WORLD).start()
    actions = _Actions()
    server = ViewServer(
        hub, ViewConfig(host="127.0.0.1", token="s3cret"), on_stop=actions.stop
    ).start()
    try:
        assert server.url.endswith("/?token=s3cret")
        assert _request(server, "GET", "/")[0] == 401
        status, answer = _request(
            server, "POST", "/stop", b"", {"Authorization": "Bearer nope"} | ACT
        )
        assert status == 401 and answer["error"] == "wrong bearer token"
        assert actions.stops == 0
        assert _request(server, "GET", "/state?token=nope")[0] == 401
        assert _request(server, "GET", "/?token=s3cret")[0] == 200
        ok = {"Authorization": "Bearer s3cret"} | ACT
        assert _request(server, "POST", "/stop", b"", ok)[0] == 202 and actions.stops == 1
        stream = _Stream(server, "?token=s3cret")
        try:
            assert stream.next_event("hello")["map"]["name"] == "lab"
        finally:
            stream.close()
    finally:
        server.close()
        hub.close()


def test_clear_stop_works_once_a_replan_is_approved_after_the_stop(
    view: tuple[ViewServer, _Actions], orchestrator: Any
) -> None:
    server, actions = view
    hub = server.hub
    clear = ACT
    # The table is in the way: the first attempt collides, the repaired one is approved.
    mission = orchestrator("lab").plan_mission(Pose(6.2, 3.0, 0.0), start=Pose(1.2, 3.0, 0.0))
    assert mission.approved and len(mission.attempts) >= 2
    stream = _Stream(server)
    try:
        stream.next_event("hello")
        hub.tap("sent", "/ground/emergency_stop", Bool(data=True))  # a drift STOP, say
        hub.planned(mission)  # re-planned while latched, approved
        plans = stream.next_event("plans")["plans"]
        assert [p["approved"] for p in plans][-1] is True
        rejected = [p for p in plans if not p["approved"]]
        assert rejected and rejected[0]["collision"] is not None
        status, answer = _request(server, "POST", "/clear_stop", b"", clear)
        assert status == 200 and answer == {"cleared": True} and actions.clears == 1
        hub.tap("received", "/ground/command_status", String(data="cleared"))
        assert stream.next_event("status")["latched"] is False
        # A STOP from the page voids an approval made before it.
        hub.tap("sent", "/ground/emergency_stop", Bool(data=True))
        hub.planned(mission)
        assert _request(server, "POST", "/stop", b"", ACT)[0] == 202
        # The tap's STOP is announced too: wait for the page's own, which voids the approval.
        while stream.next_event("stop")["source"] != "view":
            pass
        status, answer = _request(server, "POST", "/clear_stop", b"", clear)
        assert status == 409 and "no re-plan" in answer["error"], answer
    finally:
        stream.close()


def test_slow_clients_lock_nobody_out_of_the_view(view: tuple[ViewServer, _Actions]) -> None:
    """The view is on the gate's HTTP stack: connections that send their headers a byte
    at a time cost no thread, so the page, the state and STOP are still served."""
    server, actions = view
    host, port = server.url.split("//")[1].split("/")[0].rsplit(":", 1)
    slow = [socket.create_connection((host, int(port)), timeout=5) for _ in range(40)]
    try:
        for sock in slow:
            sock.sendall(b"GET /st")  # and never the rest
        assert _request(server, "GET", "/state")[0] == 200
        assert _request(server, "POST", "/stop", b"", ACT)[0] == 202 and actions.stops == 1
        stream = _Stream(server)
        try:
            assert stream.next_event("hello")["map"]["name"] == "lab"
        finally:
            stream.close()
    finally:
        for sock in slow:
            sock.close()


def test_a_page_opened_mid_mission_gets_its_history_and_the_ghost_halts_on_a_fault(
    orchestrator: Any,
) -> None:
    """The hub's state for a late page: goal, trails, STOPs with where they happened,
    progress, result; the ghost stops where it is when the step ends in a fault, and the
    banner says so at once, then the mission's outcome."""
    from bridge.ros.rosport.msgs import Int16MultiArray
    from planner.ground.executor import ExecutionProgress

    goal = WORLD.goal("by_the_pillar").pose
    mission = orchestrator("lab").plan_mission(goal, start=WORLD.start)
    assert mission.approved
    hub = ViewHub(WORLD, rtt_s=0.0, time_scale=4.0).start()
    try:
        hub.planned(mission)
        for i in range(5):
            hub.tap("received", "/ground/odom_ground", _odom(1.2 + 0.05 * i, 3.0))
        hub.tap("sent", "/ground/wheel_instructions", Int16MultiArray(data=[1, 60, 23000]))
        hub.progress(ExecutionProgress(0, 4, "published", 30.0, None, None, mission.verdicts[0]))
        hub.tap("received", "/ground/command_status", String(data="accepted"))

        def state_when(pred: Any, what: str) -> dict[str, Any]:
            deadline = time.monotonic() + 10
            while True:
                state = hub.state()
                if pred(state):
                    return state
                assert time.monotonic() < deadline, (what, state)
                time.sleep(0.02)

        client = hub.subscribe()
        ghosts: list[Any] = []

        def ticks(n: int) -> list[Any]:
            got: list[Any] = []
            deadline = time.monotonic() + 10
            while len(got) < n:
                assert time.monotonic() < deadline
                for record in client.take(0.5):
                    name, data = record.decode().split("\n", 2)[:2]
                    if name == "event: tick":
                        got.append(json.loads(data[len("data: ") :])["ghost"])
            return got

        ghosts = ticks(5)
        assert ghosts[-1] is not None and ghosts[0] != ghosts[-1]  # it moves
        hub.tap("received", "/ground/command_status", String(data="fault:encoder"))
        state = state_when(lambda s: s["halted"], "halted")
        assert state["result"]["text"] == "fault:encoder at step 1/4"
        assert state["result"]["ok"] is False and not state["result"]["final"]
        hub.tap("sent", "/ground/emergency_stop", Bool(data=True))
        frozen = ticks(8)[-6:]
        assert all(g == frozen[0] for g in frozen), frozen  # no further along its plan
        hub.result(False, "mission to (6.60, 0.90, 0 deg): NOT REACHED (fault)")
        state = state_when(lambda s: s["result"]["final"], "result")
        assert state["result"]["text"].endswith("NOT REACHED (fault)")
        assert state["goal"] == [goal.x, goal.y, goal.yaw_deg]
        assert len(state["trails"]["reported"]) == 5  # 5 cm apart: every one kept
        assert state["stops"] == [{"at": [1.4, 3.0], "source": "ground station"}]
        assert state["progress"]["steps"] == 4
        hub.unsubscribe(client)
    finally:
        hub.close()


@pytest.mark.browser
def test_a_plain_headless_screenshot_of_the_view_finishes(
    view: tuple[ViewServer, _Actions], tmp_path: Any
) -> None:
    """Issue #41: ``chromium --headless --screenshot URL`` hung (the push channel never
    ends loading) or showed ``connecting``. With ``?snapshot`` the page reads ``GET
    /state`` once and opens no stream: the command docs/view.md gives finishes, and the
    page it draws has the state."""
    import subprocess

    from tests.browser import CHROMIUM_ARGS, chromium_path

    path = chromium_path()
    if path is None:
        pytest.skip("no chromium: apt-get install chromium (bash .ci/bootstrap --test does)")
    server, _ = view
    url = f"{server.url}&snapshot"  # the URL carries the operator's token
    common = ["nice", "-n", "10", path, "--headless", *CHROMIUM_ARGS]
    common += ["--window-size=1200,700", "--virtual-time-budget=3000"]
    dom = subprocess.run(
        [*common, "--dump-dom", url], capture_output=True, text=True, timeout=90, check=False
    )
    assert dom.returncode == 0, dom.stderr[-2000:]
    assert '<span id="conn" class="live">snapshot (not live)</span>' in dom.stdout
    shot = tmp_path / "view.png"
    done = subprocess.run(
        [*common, f"--screenshot={shot}", url], capture_output=True, timeout=90, check=False
    )
    assert done.returncode == 0 and shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
